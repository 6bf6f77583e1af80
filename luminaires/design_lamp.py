"""The designed lamp: facet layout, aims from traced filament images, GLB, one simulation.

The lamp is the parametric headlight (:mod:`lightsim.luminaires.headlight`: H4 bulb with
its passing filament, shield cup and tip cap, clear cover lens) whose paraboloid is
replaced by a multi-facet reflector (:mod:`lightsim.luminaires.reflector`) of
``rings × sectors`` facets: ring r covers the base paraboloid's radii between two
circles, sector s an azimuth range. Every facet is a paraboloid about the lamp's focus
with its own aim direction (h_k, v_k) and focal length f_k.

**Start by filament images** (:func:`facet_images`). For every facet the code traces the
filament (points on its coil envelope) to sample points of the facet and back out, keeps
the rays the shield cup does not stop, and records the images' angular offsets from the
facet's aim. Facet k is then aimed so that its whole image lies just under the cut-off
line c(h) (flat at ``v0`` on the opposite side, rising 15° from H = 0 on the traffic side,
as R112 annex 9 draws it): the top of a low beam is the upper edge of the filament images.

**Design variables** x (degrees, dimensionless scales), per ring r:

    h_k = h0 + spread_r · cos φ_k · (1.4 on the non-traffic side) − (image centre offset)
    v_k = min over the image of [c(h_k + Δh) − Δv] − drop_r·w_k  image top on the cut-off
    f_k = f · scale_r                                            image size ∝ 1/f_k

(w_k = clip((h_k − DROP_FROM_DEG) / (2° − DROP_FROM_DEG), 0, 1), DROP_FROM_DEG = −1.5°:
facets aimed to the traffic side and the hot spot next to the elbow sink below the line,
so H-V stays dark; the flat cut-off further left stays made of image tops on it, sharp),
h0 (where the hot spot sits) and ``lift``, which raises the vertex ring's large, dim
images above the cut-off so that points 7 and 8 (on H, 65–625 cd) and the sums of points
1–6 get their light. The flat cut-off level v0 is calibrated against the simulator
(:mod:`lightsim.luminaires.design`) so that the lamp needs no aiming (and its road view
is the aimed one). After the image-based aiming come the optional wings, overhead-sign
and foreground slivers, and the per-facet aim shifts the optimisers find
(``Layout.facet_shifts_deg``).

Parameters (the fields of :class:`Layout`; the design vector x as above)

=================  =====  ===========  =================================================
name               unit   default      meaning
=================  =====  ===========  =================================================
rings, sectors     –      3, 8         facet layout (rings × sectors facets)
focal_length_m     m      0.025        common (base) focal length
aperture_m         m      0.160        lamp opening (rim diameter of the base paraboloid)
bulb, traffic      –      H4-low,      bulb preset (the H4 passing filament and its cup),
                          right        traffic side
cutoff_v_deg       deg    −0.57        level v0 of the flat cut-off the image tops sit on
ring_offsets_deg   deg    ()           calibrated offset of every ring
sign_share         –      0            share of a vertex-ring facet's azimuth per
                                       overhead-sign sliver (× its weight in
                                       :data:`SIGN_AIMS`)
facet_shifts_deg   deg    ()           (facet, Δh, Δv) added after the image-based aims
shaded_spread_deg  deg    0            extra spread of the cup's edge facets (foreground)
shaded_drop_deg    deg    8            how far under v0 those facets are aimed
foreground_share   –      0            share of a second-ring facet per foreground sliver
wing_facets        –      ()           main facets re-aimed to the wide foreground
wing_deg           deg    16.5         centre of the wings' image medians (L/R of V)
wing_drop_deg      deg    2.5          how far under v0 the wings' image medians lie
=================  =====  ===========  =================================================
"""

from __future__ import annotations

import json
import math
import os
import struct
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes
from lightsim.render.frame import luminous
from lightsim.simulate import SimulateOptions, load

from .bulbs import get_bulb
from .gltf_writer import GltfMaterial, GltfPart, glb_bytes
from .headlight import (
    HeadlightParams,
    build_headlight,
    headlight_asset_extras,
    shield_rim_angles_deg,
)
from .reflector import Facet, aim_direction, faceted_reflector_mesh
from .regulations.check import aperture_config, regulation_check

__all__ = ["DROP_FROM_DEG", "FG_LIT_MIN", "FOREGROUND_AIMS", "LIT_MIN", "RISE_CAP_DEG",
           "SHADED_DROP_DEG", "SIGN_AIMS", "TARGET_V_DEG", "WING_HALF_WIDTH_DEG", "FacetImage",
           "Layout", "bounds", "cutoff_line", "facet_images", "facets_for", "filament_points",
           "hole_diameter", "read_design", "shift_all", "simulate_lamp", "start_vector",
           "unshaded", "with_shifts", "write_design", "write_facets"]

LENS_GAP_M = 0.03  # room for facets aimed off-axis or with longer focal lengths
STEP_DEG = 15.0  # R112 annex 9: the cut-off rises 15° on the traffic side
ELBOW_DEG = 1.0  # where the designed rise starts (deg right of V); measured: from V, H-V
# got 2 100 cd (zone III ≤ 625)
TARGET_V_DEG = -0.57  # where --aim puts the cut-off inflection
SCALE_BOUNDS = (0.6, 1.15)
MAX_RADIUS_M: float | None = None  # kNN radius cap in the loop (None: the engine default)
LEFT_SPREAD = 1.4  # the non-traffic side spreads further: the hot spot sits right of V
LIT_MIN = 0.6
FG_LIT_MIN = 0.2
"""Cup-shaded facets lit at least this much (the ones on the cup's edges, 0.28–0.37 of
their rays pass) become foreground facets when ``Layout.shaded_spread_deg`` > 0; the
others (lit < 0.15: only stray light, inverted images) stay ``SHADED_DROP_DEG`` down."""
RISE_CAP_DEG = 2.0
"""The traffic-side cut-off rises 15° from the elbow up to this far above v0 (deg): facets
aimed far to the traffic side for the foreground put their image tops at most here."""
DROP_FROM_DEG = -1.5  # the drop ramps in from here (deg, + = traffic side) to 2°: the hot spot
# near V sinks too (measured: ramping from V left H-V at 2 100 cd, zone III ≤ 625)
SIGN_AIMS = ((-8.0, 0.5, 0.85), (-5.5, -0.8, 1.0), (-3.5, 2.8, 0.7), (-0.5, 2.0, 2.3),
             (4.6, 1.9, 1.6), (-8.0, 4.0, 1.7), (-0.5, 4.0, 1.3), (10.0, 4.2, 1.3),
             (-10.0, -2.0, 4.0))
"""Where the overhead-sign slivers put their image centres (deg) and their relative widths
(× ``sign_share``; measured: the V and right points get less overlap from the others):
R112 asks for 65–625 cd
above the cut-off (points 7, 8, the sums of points 1–3 and 4–6), a dim glow over zone III
that a lamp cannot leave to stray light. The last sliver widens the left foreground (25L)."""
FOREGROUND_AIMS = ((-24.0, -3.5, 1.0), (24.0, -3.5, 1.0), (-14.0, -2.6, 1.0),
                   (14.0, -2.6, 1.0), (-28.0, -3.9, 1.0), (28.0, -3.9, 1.0),
                   (-19.0, -3.0, 1.0), (19.0, -3.0, 1.0))
"""Image medians (deg) and relative widths (× ``Layout.foreground_share``) of the
foreground slivers cut off the second ring's lit facets: 1 lx on the road ±5 m wide at
10 m needs ≈ 2.2 k cd at 26.6° L/R, 3.7° D (the facets aimed by the cut-off stay within
±12°)."""
WING_HALF_WIDTH_DEG = 2.5
"""The wing facets' image medians spread over ``Layout.wing_deg`` ± this (deg)."""
SHADED_DROP_DEG = 8.0
"""Facets the cup leaves less lit than ``LIT_MIN`` are aimed ``SHADED_DROP_DEG`` under the
cut-off: the light that reaches them past the cup's rims and end plates (and, reflected
inside the bulb glass, around the cup) is stray; their images are inverted (they extend
upwards from the aim by several degrees), so aimed near the cut-off they light zone III."""


@dataclass(frozen=True)
class Layout:
    """Facet layout and lamp size.

    Attributes
    ----------
    rings, sectors : int
        Facets = rings × sectors (rings evenly spaced in base radius).
    cutoff_v_deg : float
        Level v0 (deg) of the flat cut-off line the image tops are placed on; the design
        calibrates it against the simulator
        (:func:`lightsim.luminaires.design.design_lowbeam`).
    focal_length_m, aperture_m : float
        Base paraboloid's focal length and rim diameter, m.
    bulb, traffic : str
    """

    rings: int = 3
    sectors: int = 8
    focal_length_m: float = 0.025
    aperture_m: float = 0.160
    bulb: str = "H4-low"
    traffic: str = "right"
    cutoff_v_deg: float = TARGET_V_DEG
    ring_offsets_deg: tuple[float, ...] = ()
    sign_share: float = 0.0
    facet_shifts_deg: tuple[tuple[int, float, float], ...] = ()
    """(facet index, Δh, Δv in deg) added to the aims of facets (main facets, then the
    overhead-sign slivers) after the image-based aiming: what the footprint-model
    optimiser (:mod:`lightsim.luminaires.facet_model`) and the final aim step change."""
    shaded_spread_deg: float = 0.0
    """Extra horizontal spread (× cos φ, deg) of the cup-shaded facets lit ≥ ``FG_LIT_MIN``
    (0: they stay with their ring's spread, ``SHADED_DROP_DEG`` down)."""
    shaded_drop_deg: float = SHADED_DROP_DEG
    """How far under v0 (deg) those foreground facets are aimed."""
    foreground_share: float = 0.0
    """Share of a lit second-ring facet's azimuth per foreground sliver (× its weight in
    :data:`FOREGROUND_AIMS`; 0: none)."""
    wing_facets: tuple[int, ...] = ()
    """Main facets (indices) re-aimed to the wide foreground ("wings") beside the car: on
    their side of V (the sign of their aim), their filament images' medians are spread
    evenly over ``wing_deg`` ± ``WING_HALF_WIDTH_DEG`` at ``wing_drop_deg`` under v0."""
    wing_deg: float = 16.5
    """Centre (deg left/right of V) of the wings' image medians."""
    wing_drop_deg: float = 2.5
    """How far under v0 (deg) the wings' image medians lie (3.7° D is 10 m ahead of a
    lamp 0.65 m high)."""

    @property
    def n_params(self) -> int:
        return 2 + 3 * self.rings

    def check(self) -> None:
        if not (1 <= self.rings <= 8 and 2 <= self.sectors <= 32):
            raise InputError(f"--rings must be 1–8 and --sectors 2–32, got {self.rings}, "
                             f"{self.sectors}")
        if not (math.isfinite(self.shaded_spread_deg) and 0 <= self.shaded_spread_deg <= 30
                and math.isfinite(self.shaded_drop_deg) and 0 <= self.shaded_drop_deg <= 20):
            raise InputError("--shaded-spread must be 0–30° and --shaded-drop 0–20°")
        if not (math.isfinite(self.foreground_share) and 0 <= self.foreground_share < 0.9):
            raise InputError(f"--foreground-share must be 0–0.9, got {self.foreground_share}")
        n_main = self.rings * self.sectors
        if not (all(0 <= int(k) < n_main for k in self.wing_facets)
                and len(set(self.wing_facets)) == len(self.wing_facets)
                and math.isfinite(self.wing_deg) and 0 <= self.wing_deg <= 28
                and math.isfinite(self.wing_drop_deg) and 0 <= self.wing_drop_deg <= 10):
            raise InputError(f"--wing-facets must be distinct main facets (0–{n_main - 1}), "
                             "--wing 0–28° and --wing-drop 0–10°")
        if not (math.isfinite(self.sign_share) and 0 <= self.sign_share
                and self.sign_share * sum(a[2] for a in SIGN_AIMS) < 0.9 * self.sectors):
            raise InputError(f"--sign-share must be ≥ 0 and small enough for "
                             f"{len(SIGN_AIMS)} slivers, got {self.sign_share}")


def start_vector(layout: Layout) -> np.ndarray:
    """Initial x = (h0, lift, then spread, drop, scale per ring from the vertex out)."""
    x = [2.2, 0.4]
    for r in range(layout.rings):
        t = (r + 0.5) / layout.rings  # 0 at the vertex, 1 at the rim
        x += [7.0 * (1 - t) + 1.0, 0.7, 0.7 + 0.45 * t]
    return np.array(x)


def bounds(layout: Layout) -> list[tuple[float, float]]:
    """Powell bounds of x (degrees, scales)."""
    b = [(-1.0, 4.0), (0.0, 1.5)]
    for _ in range(layout.rings):
        b += [(0.0, 12.0), (0.0, 3.0), SCALE_BOUNDS]
    return b

# ---------------------------------------------------------------------------------------
# filament images (the geometric start)
# ---------------------------------------------------------------------------------------


def _hv(o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Wall angles (deg) of directions (…, 3): H right = world −X, V up."""
    return (np.degrees(np.arctan2(-o[..., 0], o[..., 2])),
            np.degrees(np.arctan2(o[..., 1], o[..., 2])))


def filament_points(layout: Layout, n: int = 96) -> np.ndarray:
    """Points (n, 3) on the lit coil envelope, lamp coordinates (m), fixed pattern."""
    spec = get_bulb(layout.bulb)
    ox, oy, oz = spec.filament_offset_m
    mirror = -1.0 if layout.traffic == "left" else 1.0
    c = np.array([mirror * ox, oy, layout.focal_length_m + oz])
    g = np.random.default_rng(12345)
    t = g.uniform(-0.5, 0.5, n) * spec.filament_length_m
    a = g.uniform(0, 2 * math.pi, n)
    rad = 0.5 * spec.filament_diameter_m
    return c + np.column_stack([rad * np.cos(a), rad * np.sin(a), t])


def unshaded(s: np.ndarray, p: np.ndarray, layout: Layout) -> np.ndarray:
    """Which segments filament point s → reflector point p the shield cup lets through."""
    spec = get_bulb(layout.bulb)
    cup = spec.shield
    if cup is None:
        return np.ones(np.broadcast_shapes(s.shape, p.shape)[:-1], bool)
    mirror = -1.0 if layout.traffic == "left" else 1.0
    cx, cy, cz = mirror * cup.centre_m[0], cup.centre_m[1], layout.focal_length_m + cup.centre_m[2]
    start, end = shield_rim_angles_deg(cup, layout.traffic)
    d = p - s
    ax, ay = s[..., 0] - cx, s[..., 1] - cy
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = 2 * (ax * d[..., 0] + ay * d[..., 1])
    c = ax * ax + ay * ay - cup.radius_m ** 2  # < 0: the filament is inside the cup
    t = (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))) / (2 * np.maximum(a, 1e-30))
    # where the segment leaves the cup's cylinder, or first its end plane (the end plates
    # are sectors of the same arc)
    z0, z1 = cz - 0.5 * cup.length_m, cz + 0.5 * cup.length_m
    zc = s[..., 2] + t * d[..., 2]
    dz = np.where(np.abs(d[..., 2]) > 1e-30, d[..., 2], 1e-30)
    t_plane = np.where(zc < z0, (z0 - s[..., 2]) / dz, (z1 - s[..., 2]) / dz)
    t_hit = np.where((zc >= z0) & (zc <= z1), t, t_plane)
    x = s + t_hit[..., None] * d
    theta = np.degrees(np.arctan2(x[..., 1] - cy, x[..., 0] - cx)) % 360.0
    return ~((theta >= start) & (theta <= end))


@dataclass
class FacetImage:
    """Angular offsets (deg) of a facet's filament images from its aim, lit rays only."""

    dh: np.ndarray
    dv: np.ndarray
    lit_fraction: float


def facet_images(facets: list[Facet], layout: Layout, hole_m: float, samples: int = 5
                 ) -> list[FacetImage]:
    """Trace the filament to ``samples``² points of every facet (mirror, exact normals)."""
    f = layout.focal_length_m
    focus = np.array([0.0, 0.0, f])
    fil = filament_points(layout)
    out = []
    for fc in facets:
        r0 = 0.5 * hole_m if fc.r0_m is None else fc.r0_m
        r1 = 0.5 * layout.aperture_m if fc.r1_m is None else fc.r1_m
        rr, pp = np.meshgrid(np.linspace(r0, r1, samples + 2)[1:-1],
                             np.linspace(fc.phi0_rad, fc.phi1_rad, samples + 2)[1:-1])
        base = np.column_stack([(rr * np.cos(pp)).ravel(), (rr * np.sin(pp)).ravel(),
                                (rr * rr / (4 * f)).ravel()])
        u = base - focus
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        d = aim_direction(fc.h_deg, fc.v_deg)
        fk = f if fc.focal_m is None else fc.focal_m
        p = focus + (2 * fk / (1 - u @ d))[:, None] * u
        n = d[None, :] - u
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        s = fil[:, None, :]
        w = p[None, :, :] - s
        w /= np.linalg.norm(w, axis=2, keepdims=True)
        o = w - 2 * np.sum(w * n[None], axis=2, keepdims=True) * n[None]
        h, v = _hv(o)
        lit = unshaded(np.broadcast_to(s, w.shape), np.broadcast_to(p[None], w.shape), layout)
        out.append(FacetImage(dh=(h - fc.h_deg)[lit], dv=(v - fc.v_deg)[lit],
                              lit_fraction=float(lit.mean())))
    return out


def cutoff_line(h: np.ndarray, v0: float, traffic: str = "right",
                elbow_deg: float | None = None) -> np.ndarray:
    """The cut-off c(h) (deg): flat at v0, rising 15° from H = ``elbow_deg`` on the traffic
    side (default :data:`ELBOW_DEG`: the rise starts right of V so that H-V, 0.57° above
    the elbow and a corner of zone III, stays dark)."""
    e = ELBOW_DEG if elbow_deg is None else elbow_deg
    side = h if traffic == "right" else -h
    return v0 + np.minimum(np.maximum(side - e, 0.0) * math.tan(math.radians(STEP_DEG)),
                           RISE_CAP_DEG)


def facets_for(x: np.ndarray, layout: Layout, hole_m: float) -> list[Facet]:
    """The facets of design vector ``x`` (see the module docstring), aims by their images."""
    x = np.asarray(x, float)
    if x.shape != (layout.n_params,) or not np.all(np.isfinite(x)):
        raise InputError(f"a design vector of {layout.n_params} finite numbers is needed")
    v0, h0, lift = float(layout.cutoff_v_deg), float(x[0]), float(x[1])
    f = layout.focal_length_m
    r_edges = np.linspace(0.5 * hole_m, 0.5 * layout.aperture_m, layout.rings + 1)
    p_edges = 2 * math.pi * np.arange(layout.sectors + 1) / layout.sectors
    facets: list[Facet] = []
    targets: list[tuple[float, float]] = []
    for r in range(layout.rings):
        spread, drop, scale = (float(t) for t in x[2 + 3 * r: 5 + 3 * r])
        for k in range(layout.sectors):
            phi = 0.5 * (p_edges[k] + p_edges[k + 1])
            c = math.cos(phi) * (LEFT_SPREAD if (math.cos(phi) < 0) == (layout.traffic == "right")
                                 else 1.0)
            h = h0 + spread * c
            facets.append(Facet(float(p_edges[k]), float(p_edges[k + 1]), h, v0,
                                float(r_edges[r]), float(r_edges[r + 1]), f * scale))
            off = layout.ring_offsets_deg[r] if r < len(layout.ring_offsets_deg) else 0.0
            # the vertex ring is lifted; every ring carries its calibrated offset
            targets.append((h, drop, (lift if r == 0 else 0.0) + off))
    # two passes: the image offsets depend (weakly) on the aim itself
    for _ in range(2):
        images = facet_images(facets, layout, hole_m)
        new = []
        for fc, img, (h, drop, up) in zip(facets, images, targets):
            if img.lit_fraction < LIT_MIN:  # (mostly) shaded by the cup: foreground
                hs, vs = h, v0 - SHADED_DROP_DEG
                if layout.shaded_spread_deg > 0 and img.lit_fraction >= FG_LIT_MIN:
                    # the cup's edge facets light the foreground beside the car
                    cphi = math.cos(0.5 * (fc.phi0_rad + fc.phi1_rad))
                    hs = h + layout.shaded_spread_deg * cphi
                    vs = v0 - layout.shaded_drop_deg
                new.append(Facet(fc.phi0_rad, fc.phi1_rad, float(np.clip(hs, -40, 40)), vs,
                                 fc.r0_m, fc.r1_m, fc.focal_m))
                continue
            hc = float(np.median(img.dh))
            hk = h - hc
            # highest aim that keeps the image's upper edge (98th percentile) under c(h)
            room = cutoff_line(hk + img.dh, v0, layout.traffic) - img.dv
            # the drop sinks facets aimed to the traffic side (hot spot) only: the flat
            # cut-off stays formed by image tops exactly on c(h), so it is sharp and needs
            # no aiming
            side = hk if layout.traffic == "right" else -hk
            w = float(np.clip((side - DROP_FROM_DEG) / (2.0 - DROP_FROM_DEG), 0, 1))
            vk = float(np.percentile(room, 2.0)) - drop * w + up
            new.append(Facet(fc.phi0_rad, fc.phi1_rad, float(np.clip(hk, -40, 40)),
                             float(np.clip(vk, -40, 40)), fc.r0_m, fc.r1_m, fc.focal_m))
        facets = new
    facets = _with_wings(facets, layout, hole_m)
    facets = _with_sign_slivers(facets, layout, hole_m)
    for k, dh, dv in layout.facet_shifts_deg:
        k = int(k)
        if not (0 <= k < len(facets) and math.isfinite(dh) and math.isfinite(dv)):
            raise InputError(f"facet shift ({k}, {dh}, {dv}) is not a finite shift of a "
                             "facet")
        fc = facets[k]
        facets[k] = replace(fc, h_deg=float(np.clip(fc.h_deg + dh, -40, 40)),
                            v_deg=float(np.clip(fc.v_deg + dv, -40, 40)))
    return facets


def _aim_median(fc: Facet, th: float, tv: float, layout: Layout, hole_m: float) -> Facet:
    """``fc`` aimed so that the median of its traced filament images lies at (th, tv) deg
    (three passes: the images change with the aim)."""
    fc = replace(fc, h_deg=th, v_deg=tv)
    for _ in range(3):
        img = facet_images([fc], layout, hole_m)[0]
        if not img.dh.size:
            break
        fc = replace(fc, h_deg=float(np.clip(th - np.median(img.dh), -40, 40)),
                     v_deg=float(np.clip(tv - np.median(img.dv), -40, 40)))
    return fc


def _with_wings(facets: list[Facet], layout: Layout, hole_m: float) -> list[Facet]:
    """Re-aim ``layout.wing_facets`` to the wide foreground: per side of V (the sign of
    the facet's image-based aim), image medians evenly over ``wing_deg`` ±
    :data:`WING_HALF_WIDTH_DEG`, ``wing_drop_deg`` under v0, outer rings (small, bright
    images) nearest V, then by index."""
    if not layout.wing_facets:
        return facets
    out = list(facets)
    for sign in (-1.0, 1.0):
        side = sorted((int(k) for k in layout.wing_facets
                       if (facets[int(k)].h_deg >= 0) == (sign > 0)),
                      key=lambda k: (-(k // layout.sectors), k))
        n = len(side)
        for i, k in enumerate(side):
            th = sign * (layout.wing_deg
                         + (WING_HALF_WIDTH_DEG * (2 * i / (n - 1) - 1) if n > 1 else 0.0))
            out[k] = _aim_median(facets[k], th, layout.cutoff_v_deg - layout.wing_drop_deg,
                                 layout, hole_m)
    return out


def with_shifts(layout: Layout, facets: list[int], shifts_deg: np.ndarray) -> Layout:
    """``layout`` with shifts (K, 2) deg added to facets ``facets``' stored shifts."""
    old = {int(k): (dh, dv) for k, dh, dv in layout.facet_shifts_deg}
    for k, (dh, dv) in zip(facets, np.asarray(shifts_deg, float).reshape(-1, 2)):
        a, b = old.get(int(k), (0.0, 0.0))
        old[int(k)] = (a + float(dh), b + float(dv))
    return replace(layout, facet_shifts_deg=tuple(
        (k, round(a, 4), round(b, 4)) for k, (a, b) in sorted(old.items())))


def shift_all(layout: Layout, n_facets: int, dv_deg: float) -> Layout:
    """``layout`` with every one of its ``n_facets`` facets aimed ``dv_deg`` higher (the
    whole pattern moves as ``--aim`` would move it)."""
    return with_shifts(layout, list(range(n_facets)),
                       np.column_stack([np.zeros(n_facets), np.full(n_facets, dv_deg)]))


def _with_sign_slivers(facets: list[Facet], layout: Layout, hole_m: float) -> list[Facet]:
    """Cut ``layout.sign_share`` of a lit vertex-ring facet's azimuth off per
    :data:`SIGN_AIMS` entry and aim that sliver's image centre there (the vertex ring's
    images are the largest: the sliver makes a broad, dim patch); then the same with
    ``layout.foreground_share`` of the second ring's lit facets per
    :data:`FOREGROUND_AIMS` entry (the broad foreground beside the car)."""
    out = _slivers(facets, layout, hole_m, 0, SIGN_AIMS, float(layout.sign_share))
    if layout.foreground_share > 0 and layout.rings > 1:
        out = _slivers(out, layout, hole_m, 1, FOREGROUND_AIMS,
                       float(layout.foreground_share))
    return out


def _slivers(facets: list[Facet], layout: Layout, hole_m: float, ring: int,
             aims: tuple[tuple[float, float, float], ...], share: float) -> list[Facet]:
    """Cut ``share`` × weight of a lit facet of ``ring`` off per entry of ``aims``
    (h, v, weight; deg, deg, –) and aim the sliver so that its image median lies there."""
    if share <= 0:
        return facets
    if not share * sum(a[2] for a in aims) < 0.9 * layout.sectors:
        raise InputError("the sliver share is too large for the ring")
    n0 = ring * layout.sectors
    images = facet_images(facets[n0:n0 + layout.sectors], layout, hole_m)
    lit = [n0 + k for k, im in enumerate(images) if im.lit_fraction >= LIT_MIN]
    if not lit:
        return facets
    out = list(facets)
    cut: dict[int, float] = {}
    for i, (th, tv, weight) in enumerate(aims):
        if layout.traffic == "left":
            th = -th
        k = lit[i % len(lit)]
        fc = out[k]
        width = share * weight * (fc.phi1_rad - fc.phi0_rad) / (1.0 - cut.get(k, 0.0))
        cut[k] = cut.get(k, 0.0) + share * weight
        if cut[k] >= 0.9:
            raise InputError("the sliver share is too large for the ring's lit facets")
        p1 = fc.phi1_rad - width
        out[k] = replace(fc, phi1_rad=p1)
        out.append(_aim_median(replace(fc, phi0_rad=p1), th, tv, layout, hole_m))
    return out

# ---------------------------------------------------------------------------------------
# the lamp
# ---------------------------------------------------------------------------------------


def _base_parts(layout: Layout) -> tuple[list[GltfPart], HeadlightParams, int, float]:
    params = HeadlightParams(bulb=layout.bulb, focal_length_m=layout.focal_length_m,
                             aperture_m=layout.aperture_m, lens="clear",
                             traffic=layout.traffic, lens_gap_m=LENS_GAP_M,
                             reflector_rings=8, reflector_sectors=32)
    parts = build_headlight(**{k: v for k, v in asdict(params).items()})
    i = next(k for k, p in enumerate(parts) if p.name == "reflector")
    hole = float(parts[i].extras["lightsim"]["hole_diameter_m"])
    return parts, params, i, hole


def hole_diameter(layout: Layout) -> float:
    """The vertex hole of the parametric headlight for this bulb, m."""
    return _base_parts(layout)[3]


def _parts(facets: list[Facet], layout: Layout) -> tuple[list[GltfPart], HeadlightParams]:
    parts, params, i, hole = _base_parts(layout)
    old = parts[i]
    rings_per = max(2, 24 // layout.rings)
    v, fc, nm = faceted_reflector_mesh(layout.focal_length_m, 0.5 * hole,
                                       0.5 * layout.aperture_m, facets, rings=rings_per,
                                       columns=max(4, 96 // layout.sectors))
    lens = next((p for p in parts if p.name == "lens"), None)
    if lens is not None and float(v[:, 2].max()) >= float(lens.vertices[:, 2].min()):
        raise InputError("the facets' rim reaches the cover lens: aim them less steeply")
    mat = GltfMaterial(**asdict(old.material))
    extras = {"lightsim": {"surface": "multi-facet paraboloids (rings × sectors)",
                           "focal_length_m": layout.focal_length_m,
                           "aperture_m": layout.aperture_m, "hole_diameter_m": hole,
                           "facets": [asdict(t) for t in facets]}}
    parts[i] = GltfPart("reflector", v, fc, nm, mat, extras=extras)
    return parts, params


def write_design(path: str | os.PathLike, x: np.ndarray, layout: Layout | None = None,
                 info: dict[str, Any] | None = None, only_ring: int | None = None) -> int:
    """Write the lamp of design vector ``x`` as a GLB (atomically); returns its size.

    ``only_ring``: every other ring is aimed 15° down (to the foreground), for calibrating
    that ring alone."""
    layout = layout or Layout()
    layout.check()
    hole = hole_diameter(layout)
    facets = facets_for(np.asarray(x, float), layout, hole)
    if only_ring is not None:
        facets = [f if k // layout.sectors == only_ring else replace(f, v_deg=-15.0)
                  for k, f in enumerate(facets)]
    return write_facets(path, facets, layout, x, info)


def write_facets(path: str | os.PathLike, facets: list[Facet], layout: Layout,
                 x: np.ndarray | None = None, info: dict[str, Any] | None = None) -> int:
    """Write the lamp with these facets as a GLB (atomically); returns its size."""
    parts, params = _parts(facets, layout)
    extras = headlight_asset_extras(params)
    extras["lightsim"]["generator"] = "lightsim.luminaires.design"
    extras["lightsim"]["design"] = {"x": None if x is None else [float(t) for t in x],
                                    "layout": asdict(layout),
                                    "parameters": "h0, lift (deg); per ring: spread (deg), "
                                                  "drop (deg), focal scale",
                                    **(info or {})}
    data = glb_bytes(parts, asset_extras=extras)
    write_bytes(path, data)
    return len(data)


def read_design(path: str | os.PathLike) -> tuple[np.ndarray, Layout, dict[str, Any]]:
    """x, layout and the stored design record of a GLB written by :func:`write_design`."""
    try:
        data = Path(path).read_bytes()
        magic, _version, _length = struct.unpack("<4sII", data[:12])
        n, kind = struct.unpack("<I4s", data[12:20])
        if magic != b"glTF" or kind != b"JSON":
            raise ValueError("not a binary glTF")
        doc = json.loads(data[20:20 + n])
        rec = doc["asset"]["extras"]["lightsim"]["design"]
        lay = dict(rec["layout"])
        lay["ring_offsets_deg"] = tuple(float(t) for t in lay.get("ring_offsets_deg", ()))
        lay["facet_shifts_deg"] = tuple((int(k), float(a), float(b))
                                        for k, a, b in lay.get("facet_shifts_deg", ()))
        lay["wing_facets"] = tuple(int(k) for k in lay.get("wing_facets", ()))
        layout = Layout(**lay)
        x = np.asarray(rec["x"], float)
    except (OSError, ValueError, KeyError, TypeError, struct.error) as e:
        raise InputError(f"{path}: not a lamp written by lightsim design ({e})") from None
    layout.check()
    if x.shape != (layout.n_params,) or not np.all(np.isfinite(x)):
        raise InputError(f"{path}: its design vector does not fit its layout")
    return x, layout, rec


# ---------------------------------------------------------------------------------------
# one simulation of the lamp
# ---------------------------------------------------------------------------------------


def simulate_lamp(glb: str | os.PathLike, regulation: str, *, photons: int,
                  resolution: tuple[int, int], seed: int, traffic: str = "right",
                  aperture: float | None = 0.0, aim: bool = True,
                  max_radius_m: float | None = MAX_RADIUS_M, also: tuple[str, ...] = ()
                  ) -> tuple[dict[str, Any], np.ndarray, Any]:
    """Simulate ``glb`` in this process; (regulation dict, lux map, wall frame).

    ``max_radius_m`` caps the kNN radius (m on the wall) so that a glare point next to the
    bright side of the cut-off (HV, 0.57° above the elbow) is not estimated from the hot
    spot's photons (``None``: the engine's default, a few pixels)."""
    opts = SimulateOptions(str(glb), out_dir=str(Path(glb).parent), photons=photons,
                           resolution=resolution, regulation=regulation, traffic=traffic,
                           aperture=aperture, aim=aim,
                           config={"seed": seed, **({} if max_radius_m is None
                                                    else {"max_radius": max_radius_m})})
    scene = load(opts)
    config = aperture_config(opts.run_config(), regulation, traffic, scene.wall, aperture,
                             aim, False)
    session = Session(scene, config, workers=0, regulation=regulation)
    try:
        est = session.run(photons=photons)
        lux = luminous(est.lux)
        try:
            reg = regulation_check(session, lux, regulation, traffic, aim)
        except InputError:  # no cut-off to aim at
            reg = regulation_check(session, lux, regulation, traffic, False)
            reg["aim"]["cutoff"]["found"] = False
        # further rule sets on the same run (kNN at their probes)
        reg["also"] = [regulation_check(session, lux, name, traffic,
                                        aim and reg["aim"]["cutoff"].get("found", True))
                       for name in also]
    finally:
        session.close()
    return reg, lux, scene.wall
