"""Reflector design to a regulation target: a ring-and-sector multi-facet low beam.

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
h0 (where the hot spot
sits) and ``lift``, which raises the vertex ring's large, dim images above the cut-off so
that points 7 and 8 (on H, 65–625 cd) and the sums of points 1–6 get their light. The flat
cut-off level v0 is calibrated (below) so that the lamp needs no aiming (and its road view
is the aimed one).
Inner rings (large images) give width and foreground, outer rings (small images) the hot
spot under 75R/50R.

**Objective** (minimised), from a low-resolution simulation of the written GLB as it
stands (the calibrated lamp needs no aiming; the aim correction ``--aim`` would apply is a
term of its own), every regulation point evaluated with the kNN estimate per interleave
set and its 95 % interval:

    J = Σ_rules hinge(ln(lo / (min·(1+s))))² + hinge(ln(max·(1−s) / hi))²
        + zone maxima (upper bound of the zone's brightest probe)
        + cut-off: not found (J += 100), sharpness G outside 0.13–0.40, inflections of the
          three scans more than 0.15° apart (annex 9 linearity: 0.2°), cut-off more than
          0.1° from 0.57° D
        + smoothness: hinge(ln(max(lux / smoothed lux) / smooth_max))²  over the lit wall
        + road reach: hinge(ln(max_x I(x) / I_1lx(x) / (1+s)))² along the road line
          reach_target ahead (I_1lx = r³/h; continuous, unlike the 1 lx contour)
        + foreground: hinge(ln(min over the road points of I / I(1 lx) / (1+s)))²
          (``foreground_m`` > 0; :func:`foreground_points`)

with hinge(m) = max(0, −m) and s = ``safety``. lo/hi are the interval bounds, so noise
counts against the lamp.

**Calibration**: before optimising, each ring of the start lamp is simulated alone (the
other rings aimed at the foreground) and shifted by the aim correction its cut-off asks
for (median of the three annex-9 scans; two steps): the bulb glass and the coil's finite
size put the real cut-off a few tenths of a degree — differently for every ring — from
the traced images' tops. The designed lamp then needs no aiming.

**Optimiser** ``"model"`` (the CLI's default): after the calibration, ``model_rounds``
rounds of (measure every movable facet's footprint with the simulator, then Powell on the
per-facet aim shifts against the deterministic footprint model; the shifts go into
``Layout.facet_shifts_deg``), :mod:`lightsim.luminaires.facet_model`.

**Optimiser** ``"simulator"``: :func:`scipy.optimize.minimize` with ``method="Powell"``
(bounded, from the geometric start), in ``rounds`` rounds of at most ``evaluations``
function evaluations.
Within a round every evaluation uses the same photon seed (common random numbers: the
optimiser sees geometry); every round re-draws the noise (seed + round) so that no round's
winner is an artefact of one noise realisation. The returned lamp is re-simulated with a
fresh seed and ``validate_factor`` × the photons (:attr:`DesignResult.validation`).
Deterministic for a seed.

Parameters of :func:`design_lowbeam`

================  =====  ===========  =====================================================
name              unit   default      meaning
================  =====  ===========  =====================================================
regulation        –      –            rule set id (``r112-b-passing``)
bulb              –      ``H4-low``   bulb preset (the H4 passing filament and its cup)
rings, sectors    –      3, 8         facet layout (rings × sectors facets)
focal_length_m    m      0.025        common (base) focal length
aperture_m        m      0.160        lamp opening (rim diameter of the base paraboloid)
photons           –      300 000      photons per evaluation
resolution        px     80×256       wall pixels per evaluation (0.1° vertical: the
                                      cut-off's sharpness G needs it)
evaluations       –      30           Powell function evaluations per round
rounds            –      2            rounds (each with its own photon seed)
seed              –      1            photon seed of round 0
safety            –      0.10         relative margin asked beyond every limit
reach_m           m      25           1 lx road reach asked for (lamp 0.65 m high)
reach_weight      –      1            weight of the reach term in J
smooth_max        –      2.0          largest allowed lux / Gaussian-smoothed lux (σ 1°)
validate_factor   –      4            photons of the fresh-seed validation run ÷ photons
optimiser         –      simulator    ``"model"`` (CLI default) or ``"simulator"``
model_rounds      –      1            footprint-model rounds
model_photons     –      1 000 000    photons per footprint run
model_resolution  px     200×256      footprint map W×H
model_evaluations –      3000         Powell evaluations of the model per round
model_safety      –      0.05         relative margin of the model beyond every limit
interval_photons  –      12 000 000   photons of the check run whose intervals the model
                                      asks for (0: no interval)
sign_share        –      0 (CLI 0.03) ``Layout``: share of a vertex-ring facet's azimuth
                                      per overhead-sign sliver (× its weight in
                                      ``SIGN_AIMS``), dim light above the cut-off
foreground_m      m      0 (CLI 5)    1 lx asked on the road at ±w/2, ±w (10 m) and
                                      ±w/2 (15 m); 0: no foreground term
wing_facets       –      ()           ``Layout``: main facets re-aimed to the wide
                                      foreground, image medians at ±(``wing_deg`` ±
                                      2.5°), ``wing_drop_deg`` under v0 (16.5°, 2.5°)
aim_photons       –      0 (CLI 4 M)  photons of the whole-lamp aim step (320×128,
                                      before each model round and twice at the end)
aim_rounds        –      True         also aim before each model round (False: only
                                      at the end; the rounds' aim term is the model
                                      finder's own, as before the aim step existed)
remeasure_steps   –      True         keep a model round's shifts (× 1, ½, ¼) only if
                                      the re-simulated lamp's J is below the start's
model_smooth_px   px     0            Gaussian σ on every footprint
================  =====  ===========  =====================================================
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes

from .gltf_writer import GltfMaterial, GltfPart, glb_bytes
from .headlight import HeadlightParams, build_headlight, headlight_asset_extras
from .reflector import Facet, aim_direction, faceted_reflector_mesh

__all__ = ["DesignResult", "Layout", "Term", "design_lowbeam", "facet_images",
           "facets_for", "objective_terms", "read_design", "start_vector", "write_design"]

LENS_GAP_M = 0.03  # room for facets aimed off-axis or with longer focal lengths
STEP_DEG = 15.0  # R112 annex 9: the cut-off rises 15° on the traffic side
ELBOW_DEG = 1.0  # where the designed rise starts (deg right of V); measured: from V, H-V
# got 2 100 cd (zone III ≤ 625)
TARGET_V_DEG = -0.57  # where --aim puts the cut-off inflection
SHARPNESS = (0.13, 0.40)
LINEARITY_DEG = 0.2
SCALE_BOUNDS = (0.6, 1.15)
MAX_RADIUS_M: float | None = None  # kNN radius cap in the loop (None: the engine default)
CALIBRATION_STEPS = 2
LEFT_SPREAD = 1.4  # the non-traffic side spreads further: the hot spot sits right of V
LIT_MIN = 0.6
FG_LIT_MIN = 0.2
"""Cup-shaded facets lit at least this much (the ones on the cup's edges, 0.28–0.37 of
their rays pass) become foreground facets when ``Layout.shaded_spread_deg`` > 0; the
others (lit < 0.15: only stray light, inverted images) stay ``SHADED_DROP_DEG`` down."""
RISE_CAP_DEG = 2.0
"""The traffic-side cut-off rises 15° from the elbow up to this far above v0 (deg): facets
aimed far to the traffic side for the foreground put their image tops at most here."""
FOREGROUND_POINTS = ((10.0, 0.5), (10.0, 1.0), (15.0, 0.5))
"""(distance ahead in m, × ``foreground_m`` to each side) where the objective asks for
1 lx on the road: ±w/2 and ±w at 10 m, ±w/2 at 15 m (the broad foreground of a real low
beam; 1 lx at 15 m needs > 5 k cd even on the axis)."""
REACH_LATERAL_M = (-15.0, 15.0)
"""Lateral span (m, right positive) of the road line on which the reach term looks for
1 lx (the road view's width)."""
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
        calibrates it against the simulator (:func:`design_lowbeam`).
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


def _filament_points(layout: Layout, n: int = 96) -> np.ndarray:
    """Points (n, 3) on the lit coil envelope, lamp coordinates (m), fixed pattern."""
    from .bulbs import get_bulb

    spec = get_bulb(layout.bulb)
    ox, oy, oz = spec.filament_offset_m
    mirror = -1.0 if layout.traffic == "left" else 1.0
    c = np.array([mirror * ox, oy, layout.focal_length_m + oz])
    g = np.random.default_rng(12345)
    t = g.uniform(-0.5, 0.5, n) * spec.filament_length_m
    a = g.uniform(0, 2 * math.pi, n)
    rad = 0.5 * spec.filament_diameter_m
    return c + np.column_stack([rad * np.cos(a), rad * np.sin(a), t])


def _unshaded(s: np.ndarray, p: np.ndarray, layout: Layout) -> np.ndarray:
    """Which segments filament point s → reflector point p the shield cup lets through."""
    from .bulbs import get_bulb
    from .headlight import shield_rim_angles_deg

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
    fil = _filament_points(layout)
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
        lit = _unshaded(np.broadcast_to(s, w.shape), np.broadcast_to(p[None], w.shape), layout)
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


def _with_shifts(layout: Layout, facets: list[int], shifts_deg: np.ndarray) -> Layout:
    """``layout`` with shifts (K, 2) deg added to facets ``facets``' stored shifts."""
    old = {int(k): (dh, dv) for k, dh, dv in layout.facet_shifts_deg}
    for k, (dh, dv) in zip(facets, np.asarray(shifts_deg, float).reshape(-1, 2)):
        a, b = old.get(int(k), (0.0, 0.0))
        old[int(k)] = (a + float(dh), b + float(dv))
    return replace(layout, facet_shifts_deg=tuple(
        (k, round(a, 4), round(b, 4)) for k, (a, b) in sorted(old.items())))


def _shift_all(layout: Layout, n_facets: int, dv_deg: float) -> Layout:
    """``layout`` with every one of its ``n_facets`` facets aimed ``dv_deg`` higher (the
    whole pattern moves as ``--aim`` would move it)."""
    return _with_shifts(layout, list(range(n_facets)),
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
    import json
    import struct

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
# objective
# ---------------------------------------------------------------------------------------


@dataclass
class Term:
    """One objective term: its log-margin (negative = short of the target) and penalty."""

    name: str
    margin: float
    penalty: float
    value: float | None = None
    target: str = ""


def _hinge(m: float) -> float:
    return max(0.0, -m) ** 2


def rule_interval(r: dict[str, Any]) -> tuple[float, float]:
    """(lo, hi) cd a regulation row is judged by: its 95 % interval, with a zone's upper
    bound taken at its brightest probe (``max_interval_cd``); NaN without an interval."""
    lo, hi = (float(t) for t in r.get("interval_cd") or (math.nan, math.nan))
    if r.get("kind") == "zone" and "max_interval_cd" in r:
        hi = float(r["max_interval_cd"][1])
    return lo, hi


def _rule_terms(results: list[dict[str, Any]], safety: float) -> list[Term]:
    out = []
    for r in results:
        lim = r.get("limit") or {}
        if not lim or r.get("verdict") == "info":
            continue
        lo, hi = rule_interval(r)
        m = math.inf
        txt = []
        if lim.get("min") is not None and lim["min"] > 0:
            m = min(m, math.log(max(lo, 1.0) / (lim["min"] * (1 + safety))))
            txt.append(f"≥ {lim['min']:g}")
        if lim.get("max") is not None and lim["max"] > 0:
            m = min(m, math.log(lim["max"] * (1 - safety) / max(hi, 1.0)))
            txt.append(f"≤ {lim['max']:g}")
        if math.isfinite(m):
            out.append(Term(str(r["name"]), m, _hinge(m), float(r["value_cd"]), ", ".join(txt)))
    return out


def smoothness(lux: np.ndarray, frame: Any, sigma_deg: float = 1.0) -> float:
    """max(lux / Gaussian-smoothed lux) over pixels brighter than 10 % of the maximum:
    an isolated filament image stands out as a ratio well above 1."""
    from scipy.ndimage import gaussian_filter

    lux = np.nan_to_num(np.asarray(lux, float))
    if lux.size == 0 or lux.max() <= 0:
        return 1.0
    h0, h1 = frame.h_range_m
    px_deg = math.degrees(math.atan2((h1 - h0) / lux.shape[1], frame.distance_m))
    sm = gaussian_filter(lux, sigma_deg / max(px_deg, 1e-9), mode="constant")
    lit = lux > 0.1 * lux.max()
    return float(np.max(lux[lit] / np.maximum(sm[lit], 1e-30)))


def objective_terms(reg: dict[str, Any], lux: np.ndarray, frame: Any, *, safety: float,
                    reach_m: float, smooth_max: float, foreground_m: float = 0.0,
                    reach_weight: float = 1.0) -> list[Term]:
    """All terms of J for one simulated lamp (see the module docstring)."""
    from lightsim.render.road import road_illuminance_from
    from lightsim.wall import sample_wall

    terms = _rule_terms(reg["results"], safety)
    cut = reg["aim"]["cutoff"]
    if not cut.get("found"):
        terms.append(Term("cut-off", -10.0, 100.0, None, "found"))
        return terms
    g = float(cut["sharpness_g"])
    m = min(math.log(g / SHARPNESS[0]), math.log(SHARPNESS[1] / g))
    terms.append(Term("sharpness G", m, _hinge(m), g, "0.13–0.40"))
    spread = cut.get("spread_deg")
    if spread is not None:
        m = (LINEARITY_DEG * 0.75 - float(spread)) / LINEARITY_DEG
        terms.append(Term("linearity", m, _hinge(m), float(spread), "≤ 0.2° apart"))
    dv = float(reg["aim"].get("dv_deg", 0.0))  # applied (0 for an unaimed evaluation)
    shift = float(cut.get("aim_dv_deg") or 0.0)  # what --aim would apply
    m = (0.1 - abs(shift)) / 0.1
    terms.append(Term("aim shift", m, 0.25 * _hinge(m), shift, "|dv| ≤ 0.1°"))
    sm = smoothness(lux, frame)
    m = math.log(smooth_max / sm)
    terms.append(Term("smoothness", m, _hinge(m), sm, f"≤ {smooth_max:g}"))
    def intensity(h: np.ndarray, v: np.ndarray) -> Any:
        return sample_wall(lux, frame, h, v - dv)

    road = road_illuminance_from(intensity, 0.65, REACH_LATERAL_M, (0.0, 100.0), 0.5)
    reach = road.reach_m(1.0) or 0.5
    # the margin comes from the intensity along the road line at the asked distance, not
    # from the 1 lx contour: the contour moves in grid steps, so the optimiser saw no
    # gradient (measured: raising --reach or its weight lost rules and not a metre of reach)
    m = math.log(reach_ratio(intensity, reach_m) / (1 + safety))
    terms.append(Term("reach 1 lx", m, reach_weight * _hinge(m), reach, f"≥ {reach_m:g} m"))
    if foreground_m > 0:
        terms.append(foreground_term(intensity, foreground_m, safety))
    return terms


def _road_points(x: np.ndarray, z: np.ndarray, mount_height_m: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Wall angles (h, v in deg) of road points (x lateral, right positive; z ahead; m)
    seen from a lamp ``mount_height_m`` above the road, and the cd each needs for 1 lx
    there (E = I·h / r³)."""
    r2 = x * x + z * z + mount_height_m ** 2
    need = r2 * np.sqrt(r2) / mount_height_m
    return np.degrees(np.arctan2(x, z)), np.degrees(np.arctan2(-mount_height_m, z)), need


def reach_points(reach_m: float, mount_height_m: float = 0.65,
                 lateral_m: tuple[float, float] = REACH_LATERAL_M, step_m: float = 0.25
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Wall angles (h, v in deg) of the road line ``reach_m`` ahead (lateral positions
    ``lateral_m`` every ``step_m``; lamp ``mount_height_m`` above the road) and the cd
    each needs for 1 lx there (E = I·h / r³)."""
    x = np.arange(lateral_m[0], lateral_m[1] + 0.5 * step_m, step_m)
    return _road_points(x, np.full_like(x, float(reach_m)), mount_height_m)


def reach_ratio(intensity_hv: Callable[[np.ndarray, np.ndarray], Any], reach_m: float,
                mount_height_m: float = 0.65) -> float:
    """Largest I / I(1 lx) along the road line ``reach_m`` ahead (:func:`reach_points`):
    ≥ 1 exactly when the road's 1 lx reach is at least ``reach_m``, and continuous in the
    pattern (the contour's distance moves in grid steps)."""
    h, v, need = reach_points(reach_m, mount_height_m)
    cd = np.nan_to_num(np.asarray(intensity_hv(h, v), float), nan=0.0)
    return float(np.max(np.maximum(cd, 1e-3) / need))


def foreground_points(foreground_m: float, mount_height_m: float = 0.65
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Wall angles (h, v in deg) and the cd for 1 lx on the road at
    :data:`FOREGROUND_POINTS` (w = ``foreground_m``; lamp ``mount_height_m`` above the
    road; H positive to the right)."""
    x: list[float] = []
    z: list[float] = []
    for zz, f in FOREGROUND_POINTS:
        x += [-f * foreground_m, f * foreground_m]
        z += [zz, zz]
    return _road_points(np.asarray(x), np.asarray(z), mount_height_m)


def foreground_term(intensity_hv: Callable[[np.ndarray, np.ndarray], Any],
                    foreground_m: float, safety: float) -> Term:
    """1 lx on the road beside the car: the smallest of intensity / (intensity for 1 lx)
    over :func:`foreground_points`, with the safety margin."""
    h, v, need = foreground_points(foreground_m)
    cd = np.nan_to_num(np.asarray(intensity_hv(h, v), float), nan=0.0)
    ratio = float(np.min(np.maximum(cd, 1e-3) / need))
    m = math.log(ratio / (1 + safety))
    return Term("foreground 1 lx", m, _hinge(m), ratio,
                f"≥ 1 lx at ±{foreground_m:g} m (10 m), ±{0.5 * foreground_m:g} m (15 m)")


# ---------------------------------------------------------------------------------------
# simulation of one candidate and the optimiser
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
    from lightsim.engine.server import Session
    from lightsim.luminaires.regulations.check import aperture_config, regulation_check
    from lightsim.render.frame import luminous
    from lightsim.simulate import SimulateOptions, load

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


@dataclass
class DesignResult:
    """Outcome of :func:`design_lowbeam`.

    Attributes
    ----------
    x : list of float
        Best design vector (module docstring).
    objective : float
        J at ``x`` in the round that found it.
    layout : Layout
    history : list of dict
        Per evaluation: ``round``, ``x``, ``objective``, ``failing`` (terms with a negative
        margin), ``seconds``.
    terms : list of Term
        J's terms at ``x`` (in the round that found it).
    validation : list of Term
        The terms of ``x`` re-simulated with a fresh seed and more photons (empty when
        ``validate_factor`` is 0).
    validation_objective : float
    calibration_deg : list of list of float
        Per calibration step, the correction of every ring (deg);
        ``layout.ring_offsets_deg`` holds their sums.
    seconds : float
        Wall-clock time, s.
    """

    x: list[float]
    objective: float
    layout: Layout
    history: list[dict[str, Any]] = field(default_factory=list)
    terms: list[Term] = field(default_factory=list)
    validation: list[Term] = field(default_factory=list)
    validation_objective: float = math.nan
    calibration_deg: list[list[float]] = field(default_factory=list)
    seconds: float = 0.0
    model: list[dict[str, Any]] = field(default_factory=list)
    """Per footprint-model round: J at the start and end, evaluations, footprint time."""


def design_lowbeam(regulation: str, *, layout: Layout | None = None,
                   photons: int = 300_000, resolution: tuple[int, int] = (80, 256),
                   evaluations: int = 30, rounds: int = 2, seed: int = 1,
                   safety: float = 0.10, reach_m: float = 25.0, smooth_max: float = 2.0,
                   validate_factor: int = 4, x0: np.ndarray | None = None,
                   progress: Callable[[int, dict[str, Any]], None] | None = None,
                   optimiser: str = "simulator", model_rounds: int = 1,
                   model_photons: int = 1_000_000,
                   model_resolution: tuple[int, int] = (200, 256),
                   model_evaluations: int = 3000, calibrate: bool = True,
                   interval_photons: int = 12_000_000, model_safety: float = 0.05,
                   first_round: int = 0,
                   note: Callable[[str], None] | None = None,
                   foreground_m: float = 0.0, aim_photons: int = 0,
                   aim_resolution: tuple[int, int] = (320, 128),
                   remeasure_steps: bool = True, model_smooth_px: float = 0.0,
                   aim_rounds: bool = True, reach_weight: float = 1.0,
                   linearity_photons: int = 0) -> DesignResult:
    """Optimise the facet layout against ``regulation`` (one rule set id or several,
    comma-separated; see the module docstring).

    ``optimiser="model"``: after the calibration, ``model_rounds`` rounds of (measure the
    movable facets' footprints with ``model_photons`` photons each, then Powell on the
    facet shifts against the footprint model, :mod:`lightsim.luminaires.facet_model`),
    the final aim steps and (``linearity_photons`` > 0) the linearity step
    (:mod:`lightsim.luminaires.linearity`: the facets that make the cut-off at annex 9's
    scans moved up or down, each try simulated with that many photons) with one more aim
    step after it; ``"simulator"``: Powell on x with a simulation per evaluation
    (``rounds`` × ``evaluations``)."""
    from scipy.optimize import minimize

    from lightsim.luminaires.regulations import load_ruleset

    layout = layout or Layout()
    layout.check()
    regs = tuple(t.strip() for t in str(regulation).split(",") if t.strip())
    if not regs:
        raise InputError("--regulation: give at least one rule set id")
    for r in regs:
        load_ruleset(r)
    regulation, also = regs[0], regs[1:]
    if optimiser not in ("model", "simulator"):
        raise InputError(f"--optimiser must be model or simulator, got {optimiser!r}")
    if model_rounds < 0 or model_photons < 1 or model_evaluations < 1:
        raise InputError("--model-rounds must be ≥ 0, --model-photons and "
                         "--model-evaluations ≥ 1")
    if evaluations < 1 or photons < 1 or rounds < 1:
        raise InputError("--evaluations, --rounds and --photons must be ≥ 1")
    if not (0 <= safety < 1):
        raise InputError(f"safety margin must lie in [0, 1), got {safety}")
    if validate_factor < 0:
        raise InputError("the validation photon factor must be ≥ 0")
    t0 = time.perf_counter()
    history: list[dict[str, Any]] = []
    best: dict[str, Any] = {"j": math.inf}
    lo_b = np.array([b[0] for b in bounds(layout)])
    hi_b = np.array([b[1] for b in bounds(layout)])
    x = np.clip(np.asarray(start_vector(layout) if x0 is None else x0, float), lo_b, hi_b)
    if not (math.isfinite(reach_weight) and reach_weight >= 0):
        raise InputError(f"--reach-weight must be ≥ 0, got {reach_weight}")
    kw = dict(safety=safety, reach_m=reach_m, smooth_max=smooth_max, foreground_m=foreground_m,
              reach_weight=reach_weight)
    if (aim_photons < 0 or foreground_m < 0 or not math.isfinite(foreground_m)
            or not (math.isfinite(model_smooth_px) and 0 <= model_smooth_px <= 20)):
        raise InputError("--aim-photons and --foreground must be ≥ 0, --model-smooth 0–20")
    if linearity_photons < 0:
        raise InputError(f"--linearity-photons must be ≥ 0, got {linearity_photons}")
    with tempfile.TemporaryDirectory(prefix="lightsim-design-") as tmp:
        glb = Path(tmp) / "candidate.glb"

        def run(xv: np.ndarray, s: int, n: int) -> tuple[float, list[Term]]:
            try:
                write_design(glb, xv, layout)
            except InputError:
                return 1e3, [Term("geometry", -10.0, 1e3)]
            # unaimed: the calibrated lamp needs no aiming, and the probes then move
            # smoothly with the geometry (an aim re-estimated per candidate would not)
            reg, lux, frame = simulate_lamp(glb, regulation, photons=n,
                                            resolution=resolution, seed=s,
                                            traffic=layout.traffic, aim=False, also=also)
            terms = objective_terms(reg, lux, frame, **kw)
            for extra in reg["also"]:
                terms += [replace(t, name=f"{t.name} ({extra['ruleset']})")
                          for t in _rule_terms(extra["results"], safety)]
            return float(sum(t.penalty for t in terms)), terms

        # calibrate the image model's level against the simulator, ring by ring: the bulb
        # glass and the coil's finite size move each ring's real cut-off from where the
        # traced images put it (by different amounts: two rings off by different amounts
        # make two edges). Each ring alone (the others aimed away) is simulated and shifted
        # until its cut-off sits at 0.57° D, so the lamp needs no aiming.
        calibration = []
        x_flat = x.copy()
        x_flat[1] = 0.0  # without the lifted vertex ring
        offsets = list(layout.ring_offsets_deg) or [0.0] * layout.rings
        for _ in range(CALIBRATION_STEPS if calibrate else 0):
            step = []
            for r in range(layout.rings):
                layout = replace(layout, ring_offsets_deg=tuple(offsets))
                write_design(glb, x_flat, layout, only_ring=r)
                reg, _lux, _fr = simulate_lamp(glb, regulation, photons=photons,
                                               resolution=resolution, seed=seed,
                                               traffic=layout.traffic, aim=False)
                found = [sc["v_inflection_deg"] for sc in
                         reg["aim"]["cutoff"].get("scans", []) if sc.get("found")]
                # the median of the three annex-9 scans: one may lock on a weaker edge
                dv = (float(np.clip(TARGET_V_DEG - np.median(found), -1.0, 1.0))
                      if found else 0.0)
                offsets[r] += dv
                step.append(dv)
            calibration.append(step)
            if max(abs(d) for d in step) < 0.05:
                break
        layout = replace(layout, ring_offsets_deg=tuple(offsets))
        model_info: list[dict[str, Any]] = []
        if optimiser == "model":
            from .facet_model import (
                NOISE_CD,
                NOISE_PHOTONS,
                measure_footprints,
                model_terms,
                optimise_shifts,
            )

            def aim_step(lay: Layout) -> tuple[Layout, float]:
                """Simulate the lamp as the check run does (``aim_resolution``, unaimed)
                and lower/raise every facet by the aim correction its cut-off asks for."""
                write_design(glb, x, lay)
                reg, _l, _f = simulate_lamp(glb, regulation, photons=aim_photons,
                                            resolution=aim_resolution, seed=seed + 500,
                                            traffic=lay.traffic, aim=False)
                cut = reg["aim"]["cutoff"]
                dv = (float(np.clip(cut.get("aim_dv_deg") or 0.0, -0.5, 0.5))
                      if cut.get("found", True) else 0.0)
                n_all = len(facets_for(x, lay, hole_diameter(lay)))
                return _shift_all(lay, n_all, dv), dv

            def remeasure(lay: Layout, model: Any, sh: np.ndarray, s_round: int,
                          aim_off: float | None) -> tuple[float, list[Term]]:
                """J of the lamp with shifts ``sh`` simulated on the model's wall (the
                whole lamp, the model's reference photons and seed)."""
                write_design(glb, x, _with_shifts(lay, model.facets, sh))
                _r, lux, _f = simulate_lamp(glb, regulation, photons=4 * model_photons,
                                            resolution=model_resolution, seed=s_round,
                                            traffic=lay.traffic, aim=False)
                terms = model_terms(model, sh, regs, lay.traffic, lux=np.nan_to_num(lux),
                                    **mkw, aim_offset_deg=aim_off)
                return float(sum(t.penalty for t in terms)), terms

            noise = (NOISE_CD * math.sqrt(NOISE_PHOTONS / interval_photons)
                     if interval_photons > 0 else 0.0)
            mkw = dict(safety=model_safety, reach_m=reach_m, smooth_max=smooth_max,
                       reach_weight=reach_weight,
                       noise_cd=noise, foreground_m=foreground_m)
            best = {"j": math.nan, "x": [float(t) for t in x], "terms": []}
            for rnd in range(first_round, first_round + model_rounds):
                aim_dv = math.nan
                if aim_photons > 0 and aim_rounds:
                    layout, aim_dv = aim_step(layout)
                    if note is not None:
                        note(f"round {rnd}: aim step {aim_dv:+.3f}° (every facet)")
                model = measure_footprints(x, layout, regulation, photons=model_photons,
                                           resolution=model_resolution, seed=seed + rnd,
                                           residual_factor=4, progress=note,
                                           smooth_px=model_smooth_px)
                aim_off = None
                if aim_photons > 0 and aim_rounds:
                    # after the aim step the check run's cut-off sits at 0.57° D: the
                    # model's aim term asks to keep it there, in the model finder's terms
                    from lightsim.render.cutoff import find_cutoff

                    c0 = find_cutoff(model.lux(np.zeros((len(model.facets), 2))),
                                     model.frame, layout.traffic)
                    if c0.aim_dv_deg is not None:
                        aim_off = -float(c0.aim_dv_deg)

                def shown(i: int, j: float, terms: list[Term], rnd: int = rnd) -> None:
                    entry = {"round": rnd, "x": [float(t) for t in x], "objective": j,
                             "failing": [t.name for t in terms if t.margin < 0],
                             "seconds": time.perf_counter() - t0, "model_evaluation": i}
                    history.append(entry)
                    if progress is not None:
                        progress(len(history), entry)

                res = optimise_shifts(model, regs, layout.traffic, safety=model_safety,
                                      reach_m=reach_m, smooth_max=smooth_max,
                                      evaluations=model_evaluations, progress=shown,
                                      noise_cd=noise, foreground_m=foreground_m,
                                      aim_offset_deg=aim_off, reach_weight=reach_weight)
                # trust region: the round's shifts are kept only if the re-simulated lamp
                # (same seed and photons as the model's reference, so the comparison is
                # noise-fair) is better than the round's start; else halve them
                tried = []
                accepted = 0.0
                j_acc, terms_acc = res.start_objective, res.terms
                for t in (1.0, 0.5, 0.25) if remeasure_steps else ():
                    jr, tr = remeasure(layout, model, t * res.shifts_deg, seed + rnd, aim_off)
                    tried.append({"step": t, "objective": jr})
                    if note is not None:
                        mt = {q.name: q.penalty for q in res.terms}
                        diff = sorted(tr, key=lambda q: -abs(q.penalty - mt.get(q.name, 0.0)))
                        note(f"round {rnd}: shifts × {t:g} re-measured J {jr:.4f} (model "
                             f"{res.objective:.4f} at × 1, start {res.start_objective:.4f}); "
                             "model vs lamp: " + ", ".join(
                                 f"{q.name} {mt.get(q.name, 0.0):.3f}/{q.penalty:.3f}"
                                 for q in diff[:4]))
                    if jr < res.start_objective:
                        accepted, j_acc, terms_acc = t, jr, tr
                        break
                if not remeasure_steps:
                    accepted, j_acc = 1.0, res.objective
                layout = _with_shifts(layout, model.facets, accepted * res.shifts_deg)
                best = {"j": j_acc, "x": [float(t) for t in x], "terms": terms_acc}
                model_info.append({"round": rnd, "start_objective": res.start_objective,
                                   "objective": res.objective,
                                   "remeasured": tried, "accepted_step": accepted,
                                   "aim_step_deg": (aim_dv if math.isfinite(aim_dv)
                                                    else None),
                                   "evaluations": res.evaluations,
                                   "footprint_seconds": model.seconds,
                                   "facets": len(model.facets)})
            for _ in range(2 if aim_photons > 0 else 0):  # the lamp needs no --aim
                layout, aim_dv = aim_step(layout)
                if note is not None:
                    note(f"final aim step {aim_dv:+.3f}° (every facet)")
                model_info.append({"round": "aim", "aim_step_deg": aim_dv})
                if abs(aim_dv) < 0.01:
                    break
            if linearity_photons > 0:
                from .linearity import linearity_step

                layout, lin = linearity_step(x, layout, regs, photons=linearity_photons,
                                             footprint_photons=max(linearity_photons // 8, 1),
                                             resolution=aim_resolution, seed=seed + 600,
                                             terms_kw=mkw, note=note)
                model_info.append({"round": "linearity", **lin.to_dict()})
                if lin.shifts_deg and aim_photons > 0:  # the level at 2.5° may have moved
                    layout, aim_dv = aim_step(layout)
                    if note is not None:
                        note(f"aim step after the linearity step {aim_dv:+.3f}° "
                             "(every facet)")
                    model_info.append({"round": "aim", "aim_step_deg": aim_dv})
        for rnd in range(rounds if optimiser == "simulator" else 0):
            s_round = seed + rnd
            round_best: dict[str, Any] = {"j": math.inf}

            def evaluate(xv: np.ndarray, rnd: int = rnd, s_round: int = s_round,
                         round_best: dict[str, Any] = round_best) -> float:
                t1 = time.perf_counter()
                j, terms = run(np.asarray(xv, float), s_round, photons)
                entry = {"round": rnd, "x": [float(t) for t in xv], "objective": j,
                         "failing": [t.name for t in terms if t.margin < 0],
                         "seconds": time.perf_counter() - t1}
                history.append(entry)
                if j < round_best["j"]:
                    round_best.update(j=j, x=entry["x"], terms=terms)
                if progress is not None:
                    progress(len(history), entry)
                return j

            minimize(evaluate, x, method="Powell", bounds=list(zip(lo_b, hi_b)),
                     options={"maxfev": int(evaluations), "xtol": 0.05, "ftol": 1e-3})
            x = np.array(round_best["x"])
            # rounds are compared at their own noise: keep the last round's winner, which
            # has survived every re-draw so far
            best = {"j": round_best["j"], "x": round_best["x"], "terms": round_best["terms"]}
        validation: list[Term] = []
        vj = math.nan
        if validate_factor:
            vj, validation = run(np.array(best["x"]), seed + 1000, photons * validate_factor)
    return DesignResult(x=best["x"], objective=best["j"], layout=layout, history=history,
                        terms=best["terms"], validation=validation, validation_objective=vj,
                        calibration_deg=calibration, seconds=time.perf_counter() - t0,
                        model=model_info)
