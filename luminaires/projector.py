"""Bi-function LED projector module → glTF parts / GLB.

An LED faces up at the first focus F1 of an ellipsoidal reflector that covers the upper
half-space; the reflector sends the light through its second focus F2, ahead of the LED,
where the shield's edge cuts the beam; an aspheric plano-convex lens whose focus is at
the shield edge projects that edge to the road as the cut-off (the image is inverted, so
the light passing above the edge goes below H–H). The low-beam shield's edge steps down
by ``step_deg`` on world +X, which the lens turns into the cut-off rising on world −X,
the driver's right (``traffic="left"`` mirrors it). For the high beam the shield is
flipped down, out of the light.

The reflector is split into azimuthal sectors, each an ellipsoid with the common F1 and
its own second focus moved sideways along the shield edge by ``fL·tan(h)``: sector k
puts its share of the light at H = h_k below the cut-off, which widens the beam (the
plain ellipsoid, ``spread_deg = 0``, would give a narrow spot).

Axes and units follow ``docs/reference/conventions.md``: metres, +Y up, the lamp shines
along +Z; the LED centre (F1) is the origin, F2 is at (0, 0, L). Wall coordinate H (the
driver's right) is world −X.

Parts (glTF nodes, in this order)

============  ==========================================================================
node          what
============  ==========================================================================
led_00 …      the LED dies: flat squares facing +Y, Lambertian emitters
              (``extras.lightsim.flux_lm``, ``emission``, ``led``, ``group``)
board         the LED's board and heat sink, black, just below the dies
reflector     the ellipsoid sectors, aluminised mirror, exact vertex normals
shield        black sheet in the plane z = L: the low beam's cut-off edge with its step
              (``beam="low"``), or turned 90° about its lower edge to lie flat, out of
              the light (``beam="high"``)
baffle        black lens holder wall just ahead of the shield, with a window for the
              light converging through F2 (it stops direct LED light from reaching the
              lens)
lens          the aspheric plano-convex lens (:mod:`lightsim.luminaires.asphere`),
              flat back towards the shield; its focus on the shield edge
sign_NN       thin wedge prisms (same glass) in front of the lens's lowest strip: they
              lift a small copy of the beam above the cut-off, the light R149 asks for
              there (points B1–B8: overhead signs and the left verge)
============  ==========================================================================

Parameters of :class:`ProjectorParams` (the defaults are the shipped example, tuned until
its low beam passes UN R149 class B; see ``luminaires/examples/README.md``)

======================  =====  ===========  ================================================
name                    unit   default      meaning
======================  =====  ===========  ================================================
beam                    –      ``low``      ``low`` (shield up) or ``high`` (flipped down)
traffic                 –      ``right``    ``left`` mirrors the step, aims and prisms
led                     –      ``LED-2x1``  LED preset (:data:`~lightsim.luminaires.bulbs.LEDS`)
flux_lm                 lm     540          flux of all dies together (None: the preset's)
focal_distance_m        m      0.040        F1 to F2 (L = 2c)
semi_major_m            m      0.029        semi-major axis a of the ellipsoid (> L/2)
reflectance             –      0.90         mirror reflectance (aluminised)
spread_deg              °      11.5         sector aims span aim ± spread in H, evenly
aim_deg                 °      0.43         H of the middle of the sector aims
left_drop_deg           °      2.1          how much lower the oncoming side's sectors aim
right_drop_deg          °      0.65         the same for the kerb side's sectors
sectors                 –      12           azimuthal sectors of the reflector
cutoff_deg              °      0.70         cut-off below H–H on the non-step side
step_deg                °      45           angle of the step (45°: the kink; or 15°)
step_rise_deg           °      0.64         how far the cut-off rises on the step side
lens_diameter_m         m      0.060        lens clear diameter
lens_distance_m         m      0.040        shield edge to the lens's flat back face
lens_ior                –      1.52         lens glass (crown glass)
sign_prisms             °, °,  (−8, 0.85,   bands of wedge prisms around the lower half of
                        m      0.26 mm),    the lens: (H, V) deflection and band width of
                               (0, 3.5,     each (H towards the kerb side > 0), stacked
                               0.28 mm),    outwards
                               (0, 5.5,
                               0.38 mm)
sign_radius             –      0.80         inner radius of the prism bands / lens radius
======================  =====  ===========  ================================================
"""

from __future__ import annotations

import itertools
import math
import os
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes

from .asphere import LensDesign, lens_design, lens_glass, lens_mesh
from .bulbs import LedSpec, get_led
from .gltf_writer import GltfMaterial, GltfPart, glb_bytes

__all__ = [
    "BLACK",
    "LED_MATERIAL",
    "ProjectorParams",
    "build_projector",
    "led_die_parts",
    "write_projector",
]

MM = 1e-3

#: LED die: emissive white (the flux is in the node extras).
LED_MATERIAL = GltfMaterial(name="LED die (emitter)", base_color=(1.0, 1.0, 1.0),
                            roughness=1.0, emissive=(1.0, 1.0, 1.0))
#: Board, shield and lens holder: blackened, so they absorb instead of scattering glare.
BLACK = GltfMaterial(name="black", base_color=(0.05, 0.05, 0.05), roughness=0.9,
                     double_sided=True)


@dataclass(frozen=True)
class ProjectorParams:
    """Parameters of :func:`build_projector` (SI units; see the module table)."""

    beam: str = "low"
    traffic: str = "right"
    led: str = "LED-2x1"
    flux_lm: float | None = 540.0
    focal_distance_m: float = 0.040
    semi_major_m: float = 0.029
    reflectance: float = 0.90
    spread_deg: float = 11.5
    aim_deg: float = 0.43
    left_drop_deg: float = 2.1
    right_drop_deg: float = 0.65
    sectors: int = 12
    cutoff_deg: float = 0.70
    step_deg: float = 45.0
    step_rise_deg: float = 0.64
    lens_diameter_m: float = 0.060
    lens_distance_m: float = 0.040
    lens_ior: float = 1.52
    sign_prisms: tuple[tuple[float, float, float], ...] = (
        (-8.0, 0.85, 0.00026), (0.0, 3.5, 0.00028), (0.0, 5.5, 0.00038))
    sign_radius: float = 0.80

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in fields(cls)]


# ---------------------------------------------------------------------------------------
# LED dies
# ---------------------------------------------------------------------------------------


def led_die_parts(spec: LedSpec, centre: tuple[float, float, float],
                  first_index: int = 0, group: str = "led") -> list[GltfPart]:
    """The dies of an LED as emitting squares ``led_NN`` facing +Y, in a row along X.

    Parameters
    ----------
    spec : LedSpec
        Dies, size, pitch and total flux (shared equally).
    centre : tuple of 3 float
        Centre of the row in m.
    first_index : int
        Number of the first die's name.
    group : str
        ``extras.lightsim.group``: dies of one group are driven together.
    """
    s = 0.5 * spec.die_side_m
    # a square in the XZ plane; the (−,−), (−,+), (+,+) winding faces +Y (the reflector)
    corners = np.array([[-s, 0, -s], [-s, 0, s], [s, 0, s], [s, 0, -s]])
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    parts = []
    flux = spec.flux_lm / spec.dies
    for k in range(spec.dies):
        x = (k - 0.5 * (spec.dies - 1)) * spec.pitch_m
        v = corners + np.array(centre) + [x, 0.0, 0.0]
        parts.append(GltfPart(
            f"led_{first_index + k:02d}", v, faces, None, LED_MATERIAL,
            extras={"lightsim": {"flux_lm": flux, "emission": "lambertian",
                                 "led": spec.name, "group": group,
                                 "die_side_m": spec.die_side_m}}))
    return parts


# ---------------------------------------------------------------------------------------
# reflector
# ---------------------------------------------------------------------------------------


def _sector_aims(p: ProjectorParams, f_lens: float) -> np.ndarray:
    """Second focus of each sector, (x, y) in m beside F2 in its plane.

    H spans aim ± spread evenly over the sectors: those beside the LED aim wide, the top
    ones at the centre.
    A sector aimed at H (mirrored for left-hand traffic) has its second focus raised by
    ``f·tan(drop)``, drop growing from 0 at H = 0 to ``left_drop_deg`` at 3° towards the
    oncoming side and to ``right_drop_deg`` at 3° towards the kerb: its image then sits
    higher on the shield, more of it passes the edge and it lands lower on the road. The
    oncoming side is kept dimmer near the cut-off (R149's 50L and 75L maxima) and the
    kerb side's light fills the points below its raised cut-off (50R).
    """
    k = np.arange(p.sectors)
    phi_mid = (k + 0.5) * math.pi / p.sectors  # 0 = world +X, π = world −X
    side = 1.0 - 2.0 * phi_mid / math.pi  # +1 at world +X … −1 at world −X, evenly
    mirror = 1.0 if p.traffic == "right" else -1.0
    h = mirror * p.aim_deg + p.spread_deg * side
    kerb = mirror * h  # H towards the kerb side (> 0) or the oncoming side (< 0)
    drop = (p.left_drop_deg * np.clip(-kerb / 3.0, 0.0, 1.0)
            + p.right_drop_deg * np.clip(kerb / 3.0, 0.0, 1.0))
    return np.column_stack([f_lens * np.tan(np.radians(h)),
                            f_lens * np.tan(np.radians(drop))])


def _sector_mesh(a: float, f2: np.ndarray, phi0: float, phi1: float, lens_ok,
                 rings: int = 48, columns: int = 12
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One ellipsoid sector with foci at the origin and ``f2``: vertices, faces facing
    the foci, exact normals. Directions u from F1 run from the back pole (−Z) forward
    to the largest polar angle whose reflected ray still reaches the lens (``lens_ok``)."""
    c = 0.5 * float(np.linalg.norm(f2))
    e_axis = f2 / (2 * c)
    b2 = a * a - c * c

    def points(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
        u = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                      np.cos(theta)], axis=-1)
        r = b2 / (a - c * (u @ e_axis))
        return r[..., None] * u

    phis = np.linspace(phi0, phi1, columns + 1)
    lo, hi = math.radians(5.0), math.radians(175.0)  # θ from +Z: find the front edge
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if lens_ok(points(np.full_like(phis, mid), phis), f2) else (mid, hi)
    theta = np.linspace(hi, math.pi, rings + 1)
    tt, pp = np.meshgrid(theta[:-1], phis, indexing="ij")
    grid = points(tt, pp).reshape(-1, 3)
    pole = points(np.array([math.pi]), np.array([0.0]))
    v = np.vstack([grid, pole])
    w = columns + 1
    i, j = np.meshgrid(np.arange(rings - 1), np.arange(columns), indexing="ij")
    a0 = (i * w + j).ravel()
    b0 = ((i + 1) * w + j).ravel()
    faces = [np.column_stack([a0, a0 + 1, b0 + 1]), np.column_stack([a0, b0 + 1, b0])]
    last = (rings - 1) * w + np.arange(columns)
    faces.append(np.column_stack([last, last + 1, np.full(columns, len(v) - 1)]))
    f = np.vstack(faces).astype(np.int64)
    # inward normal: minus the bisector of the directions to the two foci
    d1 = v / np.linalg.norm(v, axis=1, keepdims=True)
    d2 = (v - f2) / np.linalg.norm(v - f2, axis=1, keepdims=True)
    n = -(d1 + d2)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    # orient faces towards the foci (the normals' side)
    tri = v[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", fn, n[f].sum(axis=1)) < 0
    f[flip] = f[flip][:, ::-1]
    return v, f, n


def _reflector(p: ProjectorParams, lens: LensDesign, lens_axis_y: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    L = p.focal_distance_m
    back_z = L + p.lens_distance_m
    # the reflected light must reach the lens's front inside its rim: aim at the back face
    # within the radius the focus's own cone reaches, less 5 %
    r_ok = 0.95 * p.lens_distance_m * math.tan(math.radians(lens.collect_half_angle_deg))

    def lens_ok(pts: np.ndarray, f2: np.ndarray) -> bool:
        dz = f2[2] - pts[:, 2]
        if np.any(dz <= 1e-6):
            return False
        q = f2 + (f2 - pts) * ((back_z - f2[2]) / dz)[:, None]
        return bool(np.all(np.hypot(q[:, 0], q[:, 1] - lens_axis_y) <= r_ok))

    aims = _sector_aims(p, lens.focal_length_m)
    verts, faces, norms = [], [], []
    n = 0
    for k, (x, y) in enumerate(aims):
        f2 = np.array([x, y, L])
        if p.semi_major_m <= 0.5 * float(np.linalg.norm(f2)) + 1 * MM:
            raise InputError(f"semi-major axis {p.semi_major_m / MM:g} mm is too short for "
                             f"foci {np.linalg.norm(f2) / MM:.1f} mm apart")
        v, f, nm = _sector_mesh(p.semi_major_m, f2, k * math.pi / p.sectors,
                                (k + 1) * math.pi / p.sectors, lens_ok)
        verts.append(v)
        faces.append(f + n)
        norms.append(nm)
        n += len(v)
    return np.vstack(verts), np.vstack(faces), np.vstack(norms)


# ---------------------------------------------------------------------------------------
# shield, baffle, board
# ---------------------------------------------------------------------------------------


def shield_edge(p: ProjectorParams, f_lens: float, half_width: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """The shield's upper edge in the plane z = L: x (m, increasing) and y (m).

    Flat at y = 0 (through F2) on the non-step side, falling at ``step_deg`` from x = 0
    on the step side (world +X for right-hand traffic) until the cut-off has risen by
    ``step_rise_deg``, then flat.
    """
    drop = f_lens * math.tan(math.radians(p.step_rise_deg))
    x1 = drop / math.tan(math.radians(p.step_deg))
    x = np.array([-half_width, 0.0, x1, half_width])
    y = np.array([0.0, 0.0, -drop, -drop])
    if p.traffic == "left":
        x, y = -x[::-1], y[::-1]
    return x, y


def _strip(x: np.ndarray, y_top: np.ndarray, y_bottom: float, z: float
           ) -> tuple[np.ndarray, np.ndarray]:
    """A sheet in the plane z between y_bottom and the polyline (x, y_top), facing −Z."""
    top = np.column_stack([x, y_top, np.full_like(x, z)])
    bot = np.column_stack([x, np.full_like(x, y_bottom), np.full_like(x, z)])
    v = np.vstack([bot, top])
    m = len(x)
    i = np.arange(m - 1)
    # (bottom i, top i+1, bottom i+1) winds clockwise seen from −Z … facing −Z
    f = np.vstack([np.column_stack([i, m + i + 1, i + 1]),
                   np.column_stack([i, m + i, m + i + 1])])
    return v, f.astype(np.int64)


def _shield(p: ProjectorParams, f_lens: float, half_width: float, bottom: float
            ) -> tuple[np.ndarray, np.ndarray]:
    L = p.focal_distance_m
    x, y = shield_edge(p, f_lens, half_width)
    v, f = _strip(x, y, bottom, L)
    if p.beam == "high":  # turned back by 90° about its lower edge: lies flat, under F2
        rel = v - [0.0, bottom, L]
        v = np.column_stack([v[:, 0], bottom + rel[:, 2], L - rel[:, 1]])
    return v, f


def _baffle(z: float, window: tuple[float, float, float, float], outer: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """A square black wall of half-side ``outer`` at z with the window (x0, x1, y0, y1)."""
    x0, x1, y0, y1 = window
    xs = [-outer, x0, x1, outer]
    ys = [-outer, y0, y1, outer]
    verts, faces = [], []
    for i in range(3):
        for j in range(3):
            if i == 1 and j == 1:
                continue  # the window
            k = len(verts)
            verts += [[xs[i], ys[j], z], [xs[i + 1], ys[j], z], [xs[i + 1], ys[j + 1], z],
                      [xs[i], ys[j + 1], z]]
            faces += [[k, k + 2, k + 1], [k, k + 3, k + 2]]
    return np.array(verts), np.array(faces, dtype=np.int64)


def _rim_arcs(span: tuple[float, float], blocks: int) -> list[tuple[float, float]]:
    """``blocks`` equal angular ranges (rad) covering ``span`` about the lens axis, each
    0.1 mrad short of the next so that neighbouring blocks share no edge (each stays a
    closed solid of its own)."""
    edges = np.linspace(span[0], span[1], blocks + 1)
    return [(a0, a1 - 1e-4) for a0, a1 in itertools.pairwise(edges)]


def _rim_wedge(r0: float, width: float, axis_y: float, a0: float, a1: float,
               z0: float, wedge_rad: float, toward: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """A closed wedge block over the band r0 … r0 + width between azimuths a0, a1 about
    the lens axis: flat back at z0, front at z0 + 1.5 mm + s·tan(wedge) with s the
    distance along ``toward`` (xy) from the block's thinnest corner; thicker that way,
    so it deflects light that way; outward faces."""
    r1 = r0 + width
    ring = np.array([[r0 * math.cos(a0), r0 * math.sin(a0)],
                     [r1 * math.cos(a0), r1 * math.sin(a0)],
                     [r1 * math.cos(a1), r1 * math.sin(a1)],
                     [r0 * math.cos(a1), r0 * math.sin(a1)]])
    ring[:, 1] += axis_y
    # counter-clockwise seen from +Z
    area = np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1])
    if area < 0:
        ring = ring[::-1]
    g = np.asarray(toward, dtype=np.float64)
    g = g / max(float(np.linalg.norm(g)), 1e-300)
    along = ring @ g
    back = np.column_stack([ring, np.full(4, z0)])
    front = np.column_stack([ring, z0 + 1.5 * MM + (along - along.min()) * math.tan(wedge_rad)])
    v = np.vstack([back, front])
    f = [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]]
    for i in range(4):
        j = (i + 1) % 4
        f += [[i, j, 4 + j], [i, 4 + j, 4 + i]]
    return v, np.array(f, dtype=np.int64)


def _box(lo: tuple[float, float, float], hi: tuple[float, float, float]
         ) -> tuple[np.ndarray, np.ndarray]:
    """A closed box (outward faces)."""
    x = (lo[0], hi[0])
    y = (lo[1], hi[1])
    z = (lo[2], hi[2])
    v = np.array([[x[i & 1], y[(i >> 1) & 1], z[i >> 2]] for i in range(8)])
    f = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                  [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]])
    return v, f.astype(np.int64)


# ---------------------------------------------------------------------------------------
# assembly
# ---------------------------------------------------------------------------------------


def _check(p: ProjectorParams) -> LedSpec:
    if p.beam not in ("low", "high"):
        raise InputError(f"unknown beam {p.beam!r} (low or high)")
    if p.traffic not in ("right", "left"):
        raise InputError(f"unknown traffic side {p.traffic!r} (right or left)")
    spec = get_led(p.led)
    if p.flux_lm is not None:
        spec = spec.with_flux(p.flux_lm)
    for name in ("focal_distance_m", "semi_major_m", "lens_diameter_m", "lens_distance_m"):
        value = getattr(p, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise InputError(f"{name.removesuffix('_m').replace('_', ' ')} must be a "
                             f"positive length, got {value!r} m")
    if not 10 * MM <= p.focal_distance_m <= 200 * MM:
        raise InputError(f"focal distance {p.focal_distance_m / MM:g} mm is outside "
                         "10–200 mm")
    if p.semi_major_m <= 0.5 * p.focal_distance_m + 2 * MM:
        raise InputError(f"semi-major axis {p.semi_major_m / MM:g} mm must exceed half the "
                         f"focal distance ({p.focal_distance_m / 2 / MM:g} mm) by 2 mm")
    if p.semi_major_m > 2 * p.focal_distance_m:
        raise InputError(f"semi-major axis {p.semi_major_m / MM:g} mm is more than twice "
                         "the focal distance: the reflector would not reach the lens")
    if not (math.isfinite(p.reflectance) and 0.0 < p.reflectance <= 1.0):
        raise InputError(f"reflectance {p.reflectance!r} is not in (0, 1]")
    if not (math.isfinite(p.spread_deg) and 0.0 <= p.spread_deg <= 20.0):
        raise InputError(f"spread {p.spread_deg!r}° is outside 0–20°")
    if not (isinstance(p.sectors, int) and 1 <= p.sectors <= 64):
        raise InputError(f"reflector sectors must be 1–64, got {p.sectors!r}")
    if not (math.isfinite(p.cutoff_deg) and 0.0 <= p.cutoff_deg <= 3.0):
        raise InputError(f"cut-off {p.cutoff_deg!r}° below H–H is outside 0–3°")
    if not (math.isfinite(p.step_deg) and 5.0 <= p.step_deg <= 60.0):
        raise InputError(f"step angle {p.step_deg!r}° is outside 5–60°")
    if not (math.isfinite(p.step_rise_deg) and 0.0 < p.step_rise_deg <= 3.0):
        raise InputError(f"step rise {p.step_rise_deg!r}° is outside (0, 3]°")
    if not (math.isfinite(p.sign_radius) and 0.2 <= p.sign_radius <= 0.95):
        raise InputError(f"sign prism band radius {p.sign_radius!r} is outside 0.2–0.95 of "
                         "the lens radius")
    for prism in p.sign_prisms:
        if not (len(prism) == 3 and all(math.isfinite(v) for v in prism)
                and 0.0 < math.hypot(prism[0], prism[1]) <= 15.0
                and 0.0 < prism[2] <= 0.1 * p.lens_diameter_m):
            raise InputError(f"sign prism {prism!r} needs an (H, V) deflection within 15° "
                             "and a band width up to a tenth of the lens diameter")
    if spec.dies * spec.pitch_m > 0.5 * p.focal_distance_m:
        raise InputError("the LED is too large for the reflector")
    return spec


def build_projector(**kwargs: Any) -> tuple[list[GltfPart], dict[str, Any]]:
    """Build the projector module as glTF parts.

    Parameters
    ----------
    **kwargs
        :class:`ProjectorParams` fields.

    Returns
    -------
    parts : list of GltfPart
        ``led_NN`` …, ``board``, ``reflector``, ``shield``, ``baffle``, ``lens``.
    facts : dict
        Derived figures: lens focal length and thickness (m), lens axis height (m),
        collected half-angle (°), LED luminance (cd/m²).

    Raises
    ------
    InputError
        Unknown option or preset, sizes that do not make a projector.
    """
    unknown = sorted(set(kwargs) - set(ProjectorParams.names()))
    if unknown:
        raise InputError(f"unknown projector option(s): {', '.join(unknown)}")
    p = ProjectorParams(**kwargs)
    spec = _check(p)
    L = p.focal_distance_m
    lens = lens_design(p.lens_diameter_m, p.lens_distance_m, ior=p.lens_ior)
    fl = lens.focal_length_m
    # the lens axis lies below the shield edge so the edge is imaged cutoff_deg below H–H
    axis_y = -fl * math.tan(math.radians(p.cutoff_deg))
    parts = led_die_parts(spec, (0.0, 0.0, 0.0))
    back = p.semi_major_m - 0.5 * L  # reflector's back vertex behind F1
    vb, fb = _box((-12 * MM, -1.6 * MM, -back - 2 * MM), (12 * MM, -0.1 * MM, 4 * MM))
    parts.append(GltfPart("board", vb, fb, None, BLACK))
    vr, fr, nr = _reflector(p, lens, axis_y)
    reflector = GltfMaterial(name="aluminised reflector", base_color=(p.reflectance,) * 3,
                             metallic=1.0, roughness=0.05, double_sided=True)
    parts.append(GltfPart("reflector", vr, fr, nr, reflector, extras={"lightsim": {
        "surface": "ellipsoid sectors", "focal_distance_m": L,
        "semi_major_m": p.semi_major_m, "sectors": p.sectors,
        "spread_deg": p.spread_deg}}))
    half_w = 0.5 * p.lens_diameter_m * 0.6
    bottom = -0.5 * p.lens_diameter_m * 0.45
    vs, fs = _shield(p, fl, half_w + 2 * MM, bottom - 2 * MM)
    parts.append(GltfPart("shield", vs, fs, None, BLACK, extras={"lightsim": {
        "beam": p.beam, "traffic": p.traffic, "step_deg": p.step_deg,
        "step_rise_deg": p.step_rise_deg, "cutoff_deg": p.cutoff_deg}}))
    window = (-half_w, half_w, bottom, 0.5 * p.lens_diameter_m * 0.3)
    vw, fw = _baffle(L + 1 * MM, window, 0.5 * p.lens_diameter_m + 6 * MM)
    parts.append(GltfPart("baffle", vw, fw, None, BLACK))
    vl, fl_, nl = lens_mesh(lens, L + p.lens_distance_m, (0.0, axis_y))
    parts.append(GltfPart("lens", vl, fl_, nl, lens_glass(p.lens_ior, lens.thickness_m),
                          extras={"lightsim": {"type": "aspheric plano-convex",
                                               "focal_length_m": fl,
                                               "thickness_m": lens.thickness_m}}))
    # sign-light prisms: bands of wedge blocks around the lower half of the lens, stacked
    # outwards from sign_radius (the light there comes from every reflector sector, so each
    # lifted copy spans the beam's width), in front of the lens vertex where the light is
    # collimated. Each kind deflects a small share of the beam by (H, V).
    z0 = L + p.lens_distance_m + lens.thickness_m + 2 * MM
    glass = lens_glass(p.lens_ior, 1.5 * MM)
    r_band = 0.5 * p.lens_diameter_m * p.sign_radius
    mirror = 1.0 if p.traffic == "right" else -1.0
    for k, (h_deg, v_deg, width) in enumerate(p.sign_prisms):
        # towards wall (H, V): world (−tan H, tan V); the wedge thickens that way
        toward = np.array([-math.tan(math.radians(mirror * h_deg)),
                           math.tan(math.radians(v_deg))])
        wedge = math.atan(float(np.linalg.norm(toward))) / (p.lens_ior - 1.0)
        blocks = [_rim_wedge(r_band, width, axis_y, a0, a1, z0, wedge, toward)
                  for a0, a1 in _rim_arcs((math.pi, 2 * math.pi), 12)]
        r_band += width + 1e-5
        vp = np.vstack([v for v, _ in blocks])
        fp = np.vstack([f + 8 * i for i, (_, f) in enumerate(blocks)])
        parts.append(GltfPart(f"sign_{k:02d}", vp, fp, None, glass, extras={"lightsim": {
            "type": "wedge prisms", "deflection_h_deg": mirror * h_deg,
            "deflection_v_deg": v_deg, "width_m": width}}))
    facts = {"params": asdict(p), "led": spec.name, "flux_lm": spec.flux_lm,
             "luminance_cd_m2": spec.luminance_cd_m2, "lens_focal_length_m": fl,
             "lens_thickness_m": lens.thickness_m, "lens_axis_y_m": axis_y,
             "lens_half_angle_deg": lens.collect_half_angle_deg}
    return parts, facts


def write_projector(path: str | os.PathLike, **kwargs: Any) -> dict[str, Any]:
    """Build the projector and write it as a GLB file (atomically).

    Returns
    -------
    dict
        The build's facts plus ``path``, ``bytes`` and ``triangles`` ({part: count}).
    """
    parts, facts = build_projector(**kwargs)
    extras = {"lightsim": {
        "generator": "lightsim.luminaires.projector", "units": {"length": "m", "flux": "lm"},
        "axes": "+Y up, lamp shines along +Z, LED at the origin (F1), F2 at (0, 0, L)",
        "parameters": facts["params"]}}
    data = glb_bytes(parts, asset_extras=extras)
    write_bytes(path, data)
    return {**facts, "path": os.fspath(path), "bytes": len(data),
            "triangles": {part.name: part.triangle_count for part in parts}}
