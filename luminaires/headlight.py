"""Parametric filament headlight → glTF parts / GLB (the paper's HEADLIGHT scene, §6.3).

A paraboloid reflector with a halogen bulb at its focus and a clear or fluted cover lens.
Axes and units follow ``docs/reference/conventions.md``: metres, +Y up, the lamp shines along
+Z, the reflector vertex at the origin and its focus at ``(0, 0, f)``. Wall coordinate H (the
driver's right) is world −X.

Parts (glTF nodes, in this order)

============  ==========================================================================
node          what
============  ==========================================================================
filament      the lit coil's envelope, emitter (``extras.lightsim.flux_lm``, ``emission``,
              ``bulb``)
bulb          quartz envelope (n = 1.46): a closed glass shell — outer surface with outward
              normals, inner surface facing the cavity — with a dome at the tip and a flat
              base 2 mm behind the reflector vertex (through the hole)
shield        opaque dark parts of the bulb (albedo 0.05, both sides): the H4 shield cup and
              the black tip cap (present only if the bulb has one of them)
reflector     paraboloid z = (x² + y²)/(4f), aluminised mirror (metallicFactor 1, baseColor =
              reflectance), hole at the vertex for the bulb, exact analytic vertex normals
lens          polycarbonate cover (n = 1.59), a closed circular slab in front of the
              aperture; the fluted version has vertical C¹ "wave" flutes on the upper half
              of its inner face that spread the beam horizontally (uniformly within
              ± ``flute_spread_deg``); the lower half, which carries the light of the 15°
              step-up and of the strip just below the cut-off, stays clear
============  ==========================================================================

Parameters of :func:`build_headlight`

======================  =====  ===========  ==================================================
name                    unit   default      meaning
======================  =====  ===========  ==================================================
bulb                    –      ``H4-low``   preset of :mod:`lightsim.luminaires.bulbs`
focal_length_m          m      0.025        paraboloid focal length f
aperture_m              m      0.160        reflector aperture (rim) diameter
hole_diameter_m         m      bulb Ø + 4   diameter of the hole at the vertex
                               mm
reflectance             –      0.88         mirror reflectance (aluminised, typical)
lens                    –      ``fluted``   ``clear``, ``fluted`` or ``none``
lens_thickness_m        m      0.003        cover lens thickness
lens_gap_m              m      0.005        gap between reflector rim (or bulb tip) and lens
lens_margin_m           m      0.004        lens radius beyond the reflector aperture
flute_pitch_m           m      0.005        flute period across the lens (X)
flute_spread_deg        °      8.0          maximum horizontal deflection by a flute
flux_lm                 lm     preset       luminous flux of the lit filament
emission                –      isotropic    ``isotropic`` or ``lambertian``
traffic                 –      ``right``    ``left`` mirrors the shield cup's 15° step in X
reflector_rings         –      100          rings of the reflector mesh (evenly spaced in r)
reflector_sectors       –      384          vertices per ring at the rim (halved inwards)
======================  =====  ===========  ==================================================

Geometry of the passing beam (H4 low, right-hand traffic). The passing filament lies
entirely ahead of the focus and 0.7 mm above the axis. Every reflector point images a source
ahead of the focus across the axis (the reflected ray crosses it) and a raised source lower:
the upper reflector half returns all its light below the horizontal, and the top edges of
its filament images — from the reflector points next to the horizontal plane — form the
horizontal cut-off slightly below H–H. The shield cup shades the lower reflector half, whose
light would go up. Its rim on world −X lies 6° below the horizontal (the lower half just
below the horizontal still returns light downwards, the filament being raised); its rim on
world +X lies 15° lower (21°). The lit wedge between them, on +X below the horizontal,
returns its light across the axis to world −X — H > 0, the driver's right — and upwards,
along a line rising 15° from the cut-off: the step-up of the asymmetric beam. (The cup's
edge is *lowered* 15° on +X; the image inversion turns that into the *raised* cut-off on −X.)
``traffic="left"`` mirrors the cup, and with it the step, to world +X.

Checked by tracing mirror reflections only (glass ignored, 2·10⁶ photons, wall at 25 m; see
``luminaires/examples/README.md``): the cut-off lies 0.15–0.35° below H–H for H < 0, and
the 1250 cd (2 lx) contour rises at 14° from H ≈ +0.8° to +6.8° (on H < 0 for left-hand
traffic). With the exact vertex normals, a ray from the focus leaves the default reflector
mesh parallel to the axis within 1·10⁻⁴ rad (facet error of the interpolated normals).
"""

from __future__ import annotations

import itertools
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes

from .asphere import revolve
from .bulbs import BulbSpec, ShieldCupSpec, get_bulb
from .filament import EMISSION_MODES, filament_part
from .gltf_writer import GltfMaterial, GltfPart, glb_bytes

__all__ = [
    "BULB_GLASS",
    "LENS_POLYCARBONATE",
    "SHIELD_BLACK",
    "HeadlightParams",
    "build_headlight",
    "example_headlight",
    "flute_slope_for_spread",
    "paraboloid_normals",
    "write_headlight",
]

MM = 1e-3
#: the shipped example lamps (``luminaires/examples/README.md`` gives each one's command)
EXAMPLES_DIR = Path(__file__).parent / "examples"


def example_headlight() -> Path:
    """Path of the shipped example headlight (``examples/headlight.glb``, made by
    :func:`write_headlight` with the defaults of ``lightsim luminaire headlight``)."""
    return EXAMPLES_DIR / "headlight.glb"


#: Quartz envelope: clear dielectric n = 1.46 (fused silica, visible).
BULB_GLASS = GltfMaterial(
    name="quartz glass", base_color=(1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.46,
    thickness=0.8 * MM,
)  # fmt: skip
#: Cover lens: clear polycarbonate n = 1.59 (1.586 at 589 nm); no absorption modelled.
LENS_POLYCARBONATE = GltfMaterial(
    name="polycarbonate", base_color=(1.0, 1.0, 1.0), roughness=0.0, transmission=1.0,
    ior=1.59, thickness=3.0 * MM,
)  # fmt: skip
#: Shield cup and tip cap: blackened, so they absorb instead of scattering glare.
SHIELD_BLACK = GltfMaterial(
    name="black shield", base_color=(0.05, 0.05, 0.05), roughness=0.9, double_sided=True
)

_SECTOR_MARGIN = 1.3  # a ring keeps ≥ margin × the sectors its normal turn needs
_FLUTE_STEP = 1e-4  # m: width of the step from the clear lower to the fluted upper lens half
_BAND = 1e-5  # m: width of the normal-transition strip at a crease (bulb base, lens rim)


@dataclass(frozen=True)
class HeadlightParams:
    """Parameters of :func:`build_headlight` (SI units; see the module table)."""

    bulb: str = "H4-low"
    focal_length_m: float = 0.025
    aperture_m: float = 0.160
    hole_diameter_m: float | None = None
    reflectance: float = 0.88
    lens: Literal["clear", "fluted", "none"] = "fluted"
    lens_thickness_m: float = 0.003
    lens_gap_m: float = 0.005
    lens_margin_m: float = 0.004
    flute_pitch_m: float = 0.005
    flute_spread_deg: float = 8.0
    flux_lm: float | None = None
    emission: str = "isotropic"
    traffic: Literal["right", "left"] = "right"
    reflector_rings: int = 100
    reflector_sectors: int = 384


# ---------------------------------------------------------------------------------------
# reflector
# ---------------------------------------------------------------------------------------


def paraboloid_normals(points: np.ndarray, focal_length_m: float) -> np.ndarray:
    """Unit normals of the paraboloid z = (x² + y²)/(4f), facing the focus side.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Points in m (only x and y are used).
    focal_length_m : float
        Focal length f in m.

    Returns
    -------
    ndarray, shape (n, 3)
        ``(−x/(2f), −y/(2f), 1) / ‖·‖`` — the gradient of z − (x² + y²)/(4f), pointing into
        the bowl (+Z at the vertex).
    """
    p = np.asarray(points, dtype=np.float64)
    g = np.column_stack(
        [-p[:, 0] / (2 * focal_length_m), -p[:, 1] / (2 * focal_length_m), np.ones(len(p))]
    )
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def _reflector_mesh(
    f: float, r_hole: float, r_rim: float, rings: int, sectors: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paraboloid annulus r ∈ [r_hole, r_rim]: vertices, faces (facing the focus), normals.

    Rings are evenly spaced in r; each ring has ``sectors / 2^m`` vertices, halved towards
    the vertex as long as the normal still turns no more per sector than on the rim (the
    azimuthal turn per sector is ∝ sin(tilt of the normal)). Rings with twice the vertices of
    their inner neighbour are stitched with three triangles per inner sector, so there are
    no T-junctions. With vertices exactly on the surface and exact normals, the remaining
    error of a barycentrically interpolated normal is the O(h²) facet error.
    """
    r = np.linspace(r_hole, r_rim, rings + 1)
    tilt = np.arctan(r / (2 * f))
    need = sectors * np.sin(tilt) / np.sin(tilt[-1])
    counts = []
    for k in range(rings + 1):
        s = sectors
        # halve while the coarser ring still has a margin; counts stay multiples of 4 (symmetry)
        while s % 8 == 0 and s // 2 >= _SECTOR_MARGIN * need[k]:
            s //= 2
        counts.append(s)
    counts = np.maximum.accumulate(counts)  # never fewer vertices further out
    vertices, starts = [], []
    n = 0
    for k in range(rings + 1):
        phi = 2 * np.pi * np.arange(counts[k]) / counts[k]
        vertices.append(np.column_stack([r[k] * np.cos(phi), r[k] * np.sin(phi),
                                         np.full(counts[k], r[k] * r[k] / (4 * f))]))  # fmt: skip
        starts.append(n)
        n += counts[k]
    faces = []
    for k in range(rings):
        s0, s1, i0, i1 = counts[k], counts[k + 1], starts[k], starts[k + 1]
        j = np.arange(s0)
        jn = (j + 1) % s0
        # (∂/∂r × ∂/∂φ) points into the bowl, so r-then-φ order faces the focus
        if s1 == s0:
            faces += [np.column_stack([i0 + j, i1 + j, i1 + jn]),
                      np.column_stack([i0 + j, i1 + jn, i0 + jn])]  # fmt: skip
        else:  # s1 == 2 s0: inner A, B; outer C, D (between), E
            a, b = i0 + j, i0 + jn
            c, d, e = i1 + 2 * j, i1 + 2 * j + 1, i1 + (2 * j + 2) % s1
            faces += [np.column_stack([a, c, d]), np.column_stack([a, d, b]),
                      np.column_stack([b, d, e])]  # fmt: skip
    v = np.vstack(vertices)
    return v, np.vstack(faces).astype(np.int64), paraboloid_normals(v, f)


# ---------------------------------------------------------------------------------------
# surfaces of revolution (bulb envelope, tip cap)
# ---------------------------------------------------------------------------------------


def _capsule_profile(
    radius: float, z_base: float, z_apex: float, dome_steps: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Profile (r, z, nr, nz) of a closed cylinder with a flat base and a hemispherical dome."""
    zd = z_apex - radius  # dome centre (start of the hemisphere)
    t = np.linspace(0.0, 0.5 * np.pi, dome_steps + 1)
    r = [0.0, radius, radius, radius, *(radius * np.cos(t[1:]))]
    z = [z_base, z_base, z_base + _BAND, zd, *(zd + radius * np.sin(t[1:]))]
    # the base rim is a crease: the base keeps its −Z normal up to the rim and the wall turns
    # to radial within a _BAND-wide strip, so every vertex stays shared (watertight mesh)
    nr = [0.0, 0.0, 1.0, 1.0, *np.cos(t[1:])]
    nz = [-1.0, -1.0, 0.0, 0.0, *np.sin(t[1:])]
    r[-1] = 0.0
    return np.array(r), np.array(z), np.array(nr), np.array(nz)


def _bulb_envelope(
    spec: BulbSpec, focus_z: float, z_base: float, sectors: int = 48, dome_steps: int = 12
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed quartz shell: outer capsule (outward) + inner capsule (facing the cavity)."""
    env = spec.envelope
    ro = 0.5 * env.outer_diameter_m
    ri = ro - env.wall_m
    apex = focus_z + env.apex_z_m
    vo, fo, no = revolve(*_capsule_profile(ro, z_base, apex, dome_steps), sectors)
    vi, fi, ni = revolve(
        *_capsule_profile(ri, z_base + env.wall_m, apex - env.wall_m, dome_steps), sectors
    )
    # the inner surface bounds the glass from the cavity side: reversed winding, normals
    # pointing into the cavity (away from the glass)
    vertices = np.vstack([vo, vi])
    faces = np.vstack([fo, fi[:, ::-1] + len(vo)])
    normals = np.vstack([no, -ni])
    return vertices, faces, normals


def _tip_cap(
    spec: BulbSpec, focus_z: float, sectors: int = 48, dome_steps: int = 12
) -> tuple[np.ndarray, np.ndarray]:
    """Opaque cap just outside the glass dome, from its equator to the apex (open sheet)."""
    ro = 0.5 * spec.envelope.outer_diameter_m + 0.05 * MM  # painted on: 50 µm off the glass
    zd = focus_z + spec.envelope.apex_z_m - 0.5 * spec.envelope.outer_diameter_m
    t = np.linspace(0.0, 0.5 * np.pi, dome_steps + 1)
    r = ro * np.cos(t)
    r[-1] = 0.0
    v, f, _ = revolve(r, zd + ro * np.sin(t), np.cos(t), np.sin(t), sectors)
    return v, f


# ---------------------------------------------------------------------------------------
# shield cup
# ---------------------------------------------------------------------------------------


def shield_rim_angles_deg(shield: ShieldCupSpec, traffic: str) -> tuple[float, float]:
    """Angular extent ``(start, end)`` of the cup's arc in degrees, counter-clockwise from +X.

    Angles are measured about the cup axis in the x–y plane, seen from the front (+Z), from
    world +X towards +Y. The arc runs from ``start`` through 270° (straight down) to ``end``.
    For right-hand traffic the rim on world +X is the lowered one (its light reaches the
    lower reflector half on +X and is returned upwards on −X, the driver's right).
    """
    drop, step = shield.rim_drop_deg, shield.step_deg
    if traffic == "left":  # the mirror image x → −x, i.e. θ → 180° − θ (mod 360°)
        return 180.0 + drop + step, 360.0 - drop
    return 180.0 + drop, 360.0 - drop - step


def _shield_cup(
    shield: ShieldCupSpec, focus_z: float, traffic: str, arc_steps: int = 48
) -> tuple[np.ndarray, np.ndarray]:
    """Trough sheet + end plates (an open, connected sheet; no normals needed: diffuse)."""
    start, end = np.radians(shield_rim_angles_deg(shield, traffic))
    cx, cy, cz = shield.centre_m
    cz += focus_z
    theta = np.linspace(start, end, arc_steps + 1)
    z0, z1 = cz - 0.5 * shield.length_m, cz + 0.5 * shield.length_m
    ring = np.column_stack(
        [cx + shield.radius_m * np.cos(theta), cy + shield.radius_m * np.sin(theta)]
    )
    n = len(theta)
    # vertices: rear arc, front arc, rear centre, front centre
    vertices = np.vstack(
        [
            np.column_stack([ring, np.full(n, z0)]),
            np.column_stack([ring, np.full(n, z1)]),
            [[cx, cy, z0], [cx, cy, z1]],
        ]
    )
    i = np.arange(n - 1)
    rear_c, front_c = 2 * n, 2 * n + 1
    faces = np.vstack(
        [
            # trough: arc points counter-clockwise, rear→front: faces point to the axis
            np.column_stack([i, n + i, n + i + 1]),
            np.column_stack([i, n + i + 1, i + 1]),
            # end plates face the inside of the trough too (consistent winding)
            np.column_stack([np.full(n - 1, rear_c), i, i + 1]),  # rear plate, faces +Z
            np.column_stack([np.full(n - 1, front_c), n + i + 1, n + i]),  # front, −Z
        ]
    ).astype(np.int64)
    return vertices, faces


# ---------------------------------------------------------------------------------------
# cover lens
# ---------------------------------------------------------------------------------------


def flute_slope_for_spread(spread_deg: float, ior: float) -> float:
    """Largest flute surface slope (dz/dx) that deflects a +Z ray by ``spread_deg``.

    The ray enters the tilted inner face and leaves through the flat front face; the
    deflection grows monotonically with the tilt, so it is solved by bisection.

    Parameters
    ----------
    spread_deg : float
        Wanted maximum horizontal deflection in degrees (0 ≤ spread < critical limit).
    ior : float
        Refractive index of the lens.

    Returns
    -------
    float
        tan of the tilt angle of the inner surface.
    """

    def deflection(tilt: float) -> float:
        # inner surface normal (pointing into the glass) tilted by `tilt` about Y
        n = np.array([-math.sin(tilt), 0.0, math.cos(tilt)])
        d = np.array([0.0, 0.0, 1.0])
        cos_i = float(d @ n)
        eta = 1.0 / ior
        k = 1 - eta * eta * (1 - cos_i * cos_i)
        t = eta * d + (math.sqrt(k) - eta * cos_i) * n  # refracted into the glass
        # flat front face: tangential components scale by ior
        tx = t[0] * ior
        if abs(tx) >= 1:
            return math.pi / 2
        return math.asin(abs(tx))

    target = math.radians(spread_deg)
    if target <= 0:
        return 0.0
    lo, hi = 0.0, math.radians(80.0)
    if deflection(hi) < target:
        raise InputError(f"flute spread {spread_deg}° is not reachable with n = {ior}")
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if deflection(mid) < target else (lo, mid)
    return math.tan(0.5 * (lo + hi))


def _flute_height(x: np.ndarray, pitch: float, slope: float) -> tuple[np.ndarray, np.ndarray]:
    """C¹ wave profile h(x), dh/dx: slope is a triangle wave in [−slope, slope], mean h = 0.

    Piecewise parabolic (alternating convex/concave) so the slope — hence the deflection —
    is uniformly distributed across a flute; a crest sits at x = 0 (mirror symmetric).
    """
    u = np.mod(x / pitch + 0.25, 1.0)
    first = u < 0.5
    h = np.where(first, u - 2 * u * u, (2 * u - 1) * (u - 1)) * pitch * slope
    dh = np.where(first, 1 - 4 * u, 4 * u - 3) * slope
    return h, dh


def _lens_mesh(
    radius: float,
    z_back: float,
    thickness: float,
    pitch: float,
    slope: float,
    column_step: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed circular lens: flat front, (fluted) back, cylindrical rim; outward normals.

    The faces are grids of columns in X, at multiples of ``column_step`` (a quarter flute
    period puts a vertex on every breakpoint of the wave, between which its slope — and so
    the unnormalised normal — is linear), with 6 points per column across the chord. The
    back face is ``z_back`` (clear) for y ≤ 0 and ``z_back + h(x)`` (fluted) for
    y ≥ _FLUTE_STEP; the strip between is the step from one to the other, where the shading
    normals turn from flat to fluted. No vertex carries a vertical tilt, so the lens never
    deflects light vertically (which would blur the cut-off). Front face at
    ``z_back + thickness``.
    """
    # columns: multiples of column_step strictly inside, plus end columns near ±radius
    edge = 0.01 * radius
    xs = np.arange(math.ceil((-radius + edge) / column_step),
                   math.floor((radius - edge) / column_step) + 1) * column_step  # fmt: skip
    xs = np.concatenate([[-radius + 0.5 * edge], xs, [radius - 0.5 * edge]])
    chord = np.sqrt(radius * radius - xs * xs)
    step = np.minimum(_FLUTE_STEP, 0.5 * chord)[:, None]
    ch = chord[:, None]
    gy = np.hstack([-ch, -0.5 * ch, 0 * ch, step, 0.5 * (step + ch), ch])
    rows = gy.shape[1]
    fluted = np.tile(np.arange(rows) >= 3, len(xs))  # rows from y = step upwards
    gy = gy.ravel()
    gx = np.repeat(xs, rows)
    ncol = len(xs)
    h, dh = np.zeros_like(gx), np.zeros_like(gx)
    if slope > 0:
        h[fluted], dh[fluted] = _flute_height(gx[fluted], pitch, slope)
    z_front = z_back + thickness
    front = np.column_stack([gx, gy, np.full_like(gx, z_front)])
    back = np.column_stack([gx, gy, z_back + h])
    n_front = np.tile([0.0, 0.0, 1.0], (len(gx), 1))
    # back face z = z_back + h(x), glass in front of it: outward normal (h', 0, −1)
    n_back = np.column_stack([dh, np.zeros_like(dh), -np.ones_like(dh)])
    n_back /= np.linalg.norm(n_back, axis=1, keepdims=True)
    npts = len(gx)

    # grid faces (i: column, j: row); (i,j),(i+1,j),(i+1,j+1) faces +Z
    i, j = np.meshgrid(np.arange(ncol - 1), np.arange(rows - 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    a, b = i * rows + j, (i + 1) * rows + j
    c, d = (i + 1) * rows + j + 1, i * rows + j + 1
    grid = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    faces = [grid, grid[:, ::-1] + npts]  # front (+Z), back (−Z)

    # boundary loop, counter-clockwise seen from +Z: bottom chain left→right, right end
    # column upwards, top chain right→left, left end column downwards
    cols = np.arange(ncol)
    loop = np.concatenate(
        [
            cols * rows,  # j = 0 (bottom)
            (ncol - 1) * rows + np.arange(1, rows),  # right end column
            cols[-2::-1] * rows + rows - 1,  # top
            np.arange(rows - 2, 0, -1),  # left end column
        ]
    )
    lx, ly = gx[loop], gy[loop]
    radial = np.column_stack([lx, ly, np.zeros_like(lx)])
    on_end = (loop // rows == 0) | (loop // rows == ncol - 1)
    inner = on_end & (loop % rows != 0) & (loop % rows != rows - 1)
    radial[inner] = 0.0
    radial[inner, 0] = np.sign(lx[inner])  # end columns are straight: normal ±X
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    # rim rows from back to front: back boundary, back band, front band, front boundary; the
    # band rows carry the rim's radial normal _BAND away from the crease (shared vertices)
    back_band = back[loop] + [0.0, 0.0, _BAND]
    front_band = front[loop] - [0.0, 0.0, _BAND]
    base = 2 * npts
    m = len(loop)
    rim_rows = [loop + npts, base + np.arange(m), base + m + np.arange(m), loop]
    k = np.arange(m)
    kn = (k + 1) % m
    for lo, hi in itertools.pairwise(rim_rows):
        faces.append(np.column_stack([lo[k], lo[kn], hi[kn]]))
        faces.append(np.column_stack([lo[k], hi[kn], hi[k]]))
    vertices = np.vstack([front, back, back_band, front_band])
    normals = np.vstack([n_front, n_back, radial, radial])
    return vertices, np.vstack(faces).astype(np.int64), normals


# ---------------------------------------------------------------------------------------
# assembly
# ---------------------------------------------------------------------------------------


def _finite_positive(value: float, what: str, unit: str = "m") -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(number) or number <= 0:
        shown = f"{number * 1e3:g} mm" if unit == "m" else f"{number:g} {unit}"
        raise InputError(f"{what} must be positive, got {shown}")
    return number


def _validate(p: HeadlightParams) -> tuple[BulbSpec, float, float]:
    """Check the parameters; return (bulb spec with flux, hole radius, rim z)."""
    spec = get_bulb(p.bulb)
    if p.flux_lm is not None:
        spec = spec.with_flux(p.flux_lm)
    if p.emission not in EMISSION_MODES:
        raise InputError(f"unknown emission {p.emission!r} (isotropic or lambertian)")
    if p.traffic not in ("right", "left"):
        raise InputError(f"unknown traffic side {p.traffic!r} (right or left)")
    if p.lens not in ("clear", "fluted", "none"):
        raise InputError(f"unknown lens {p.lens!r} (clear, fluted or none)")
    f = _finite_positive(p.focal_length_m, "focal length")
    ap = _finite_positive(p.aperture_m, "aperture")
    if not 5 * MM <= f <= 200 * MM:
        raise InputError(f"focal length {f * 1e3:g} mm is outside 5–200 mm")
    if ap > 1.0:
        raise InputError(f"aperture {ap * 1e3:g} mm is larger than 1 m")
    ro = 0.5 * spec.envelope.outer_diameter_m
    hole = p.hole_diameter_m if p.hole_diameter_m is not None else 2 * ro + 4 * MM
    hole = _finite_positive(hole, "hole diameter")
    if 0.5 * hole <= ro:
        raise InputError(
            f"vertex hole Ø{hole * 1e3:g} mm does not clear the Ø"
            f"{2 * ro * 1e3:g} mm bulb"
        )
    if ap <= hole + 10 * MM:
        raise InputError(
            f"aperture {ap * 1e3:g} mm must exceed the vertex hole Ø{hole * 1e3:g} mm by 10 mm"
        )
    # filament and bulb rear must sit in front of the vertex hole region, i.e. z > 0
    rear = f + spec.filament_offset_m[2] - 0.5 * spec.filament_length_m
    if rear <= 1 * MM:
        raise InputError(
            f"focal length {f * 1e3:g} mm puts the filament behind the reflector vertex"
        )
    if not (math.isfinite(p.reflectance) and 0.0 < p.reflectance <= 1.0):
        raise InputError(f"reflectance {p.reflectance} is not in (0, 1]")
    if p.lens != "none":
        _finite_positive(p.lens_thickness_m, "lens thickness")
        _finite_positive(p.lens_gap_m, "lens gap")
        _finite_positive(p.flute_pitch_m, "flute pitch")
        if not (math.isfinite(p.lens_margin_m) and p.lens_margin_m >= 0):
            raise InputError(f"lens margin must be ≥ 0 m, got {p.lens_margin_m}")
        if not (math.isfinite(p.flute_spread_deg) and 0.0 <= p.flute_spread_deg <= 30.0):
            raise InputError(f"flute spread {p.flute_spread_deg}° is outside 0–30°")
    if p.reflector_rings < 4 or p.reflector_sectors < 16 or p.reflector_sectors % 4:
        raise InputError("the reflector needs ≥ 4 rings and ≥ 16 sectors (a multiple of 4)")
    return spec, 0.5 * hole, (0.5 * ap) ** 2 / (4 * f)


def build_headlight(
    bulb: str = "H4-low",
    focal_length_m: float = 0.025,
    aperture_m: float = 0.160,
    lens: Literal["clear", "fluted", "none"] = "fluted",
    flux_lm: float | None = None,
    emission: str = "isotropic",
    traffic: Literal["right", "left"] = "right",
    **options: Any,
) -> list[GltfPart]:
    """Build the parametric headlight as glTF parts.

    Parameters
    ----------
    bulb : str
        Bulb preset (``H1``, ``H3``, ``H4-high``, ``H4-low``, ``H7``).
    focal_length_m : float
        Reflector focal length in m.
    aperture_m : float
        Reflector aperture diameter in m.
    lens : {"fluted", "clear", "none"}
        Cover lens.
    flux_lm : float, optional
        Luminous flux in lm; default the preset's.
    emission : {"isotropic", "lambertian"}
        Emission law of the filament.
    traffic : {"right", "left"}
        Traffic side (mirrors the shield's 15° step).
    **options
        Further :class:`HeadlightParams` fields (``hole_diameter_m``, ``reflectance``,
        ``lens_thickness_m``, ``lens_gap_m``, ``lens_margin_m``, ``flute_pitch_m``,
        ``flute_spread_deg``, ``reflector_rings``, ``reflector_sectors``).

    Returns
    -------
    list of GltfPart
        ``filament``, ``bulb``, ``shield`` (if any), ``reflector``, ``lens`` (if any).

    Raises
    ------
    InputError
        Unknown bulb, non-positive flux, sizes that do not make a lamp.
    """
    try:
        params = HeadlightParams(
            bulb=bulb, focal_length_m=focal_length_m, aperture_m=aperture_m, lens=lens,
            flux_lm=flux_lm, emission=emission, traffic=traffic, **options,
        )  # fmt: skip
    except TypeError as exc:
        raise InputError(f"unknown headlight option: {exc}") from None
    return _build(params)


def _build(p: HeadlightParams) -> list[GltfPart]:
    spec, r_hole, z_rim = _validate(p)
    f = p.focal_length_m
    mirror = -1.0 if p.traffic == "left" else 1.0
    ox, oy, oz = spec.filament_offset_m
    centre = (mirror * ox, oy, f + oz)
    axis = (mirror * spec.filament_axis[0], spec.filament_axis[1], spec.filament_axis[2])
    parts = [filament_part(spec, centre, axis, spec.flux_lm, p.emission)]

    # glass envelope: closed base 2 mm behind the vertex (through the hole, like the real
    # bulb whose pinch and cap sit behind the reflector)
    vb, fb, nb = _bulb_envelope(spec, f, z_base=-2 * MM)
    parts.append(GltfPart("bulb", vb, fb, nb, BULB_GLASS, extras={"lightsim": {
        "bulb": spec.name, "glass": "quartz", "wall_m": spec.envelope.wall_m}}))  # fmt: skip

    pieces: list[tuple[np.ndarray, np.ndarray]] = []
    if spec.shield is not None:
        pieces.append(_shield_cup(spec.shield, f, p.traffic))
    if spec.envelope.tip_cap:
        pieces.append(_tip_cap(spec, f))
    if pieces:
        offsets = np.cumsum([0] + [len(v) for v, _ in pieces[:-1]])
        vs = np.vstack([v for v, _ in pieces])
        fs = np.vstack([fc + o for (_, fc), o in zip(pieces, offsets)])
        extras: dict[str, Any] = {
            "cup": spec.shield is not None,
            "tip_cap": spec.envelope.tip_cap,
        }
        if spec.shield is not None:
            extras["traffic"] = p.traffic
            extras["step_deg"] = spec.shield.step_deg
            extras["rim_angles_deg"] = list(shield_rim_angles_deg(spec.shield, p.traffic))
        parts.append(GltfPart("shield", vs, fs, None, SHIELD_BLACK, extras={"lightsim": extras}))

    vr, fr, nr = _reflector_mesh(f, r_hole, 0.5 * p.aperture_m, p.reflector_rings,
                                 p.reflector_sectors)  # fmt: skip
    reflector_material = GltfMaterial(
        name="aluminised reflector", base_color=(p.reflectance,) * 3, metallic=1.0,
        roughness=0.05, double_sided=True,
    )  # fmt: skip
    parts.append(GltfPart("reflector", vr, fr, nr, reflector_material, extras={"lightsim": {
        "surface": "paraboloid", "focal_length_m": f, "aperture_m": p.aperture_m,
        "hole_diameter_m": 2 * r_hole}}))  # fmt: skip

    if p.lens != "none":
        tip = f + spec.envelope.apex_z_m
        z_back = max(z_rim, tip) + p.lens_gap_m
        slope = flute_slope_for_spread(p.flute_spread_deg, LENS_POLYCARBONATE.ior or 1.59)
        fluted = p.lens == "fluted" and slope > 0
        if fluted:
            # the back face bulges ±pitch·slope/8 about its mean plane: keep the gap
            z_back += p.flute_pitch_m * slope / 8
        vl, fl, nl = _lens_mesh(
            radius=0.5 * p.aperture_m + p.lens_margin_m,
            z_back=z_back,
            thickness=p.lens_thickness_m,
            pitch=p.flute_pitch_m,
            slope=slope if fluted else 0.0,
            column_step=p.flute_pitch_m / 4 if fluted else 8 * MM,
        )
        material = LENS_POLYCARBONATE
        if p.lens_thickness_m != 0.003:
            material = GltfMaterial(**{**asdict(material), "thickness": p.lens_thickness_m})
        lens_extras: dict[str, Any] = {"type": p.lens if fluted else "clear",
                                       "thickness_m": p.lens_thickness_m}  # fmt: skip
        if fluted:
            lens_extras.update(flute_pitch_m=p.flute_pitch_m,
                               flute_spread_deg=p.flute_spread_deg)  # fmt: skip
        parts.append(GltfPart("lens", vl, fl, nl, material, extras={"lightsim": lens_extras}))
    return parts


def headlight_asset_extras(params: HeadlightParams) -> dict[str, Any]:
    """The ``asset.extras`` recording how a headlight file was made (parameters in SI)."""
    return {
        "lightsim": {
            "generator": "lightsim.luminaires.headlight",
            "units": {"length": "m", "flux": "lm"},
            "axes": "+Y up, lamp shines along +Z, reflector vertex at origin, focus (0,0,f)",
            "parameters": asdict(params),
        }
    }


def write_headlight(path: str | os.PathLike, **kwargs: Any) -> dict[str, Any]:
    """Build the headlight and write it as a GLB file (atomically).

    Parameters
    ----------
    path : path-like
        Destination ``.glb``.
    **kwargs
        Arguments of :func:`build_headlight`.

    Returns
    -------
    dict
        ``{"path", "bytes", "triangles": {part: count}, "flux_lm", "bulb"}``.
    """
    parts = build_headlight(**kwargs)
    params = HeadlightParams(**kwargs)
    data = glb_bytes(parts, asset_extras=headlight_asset_extras(params))
    write_bytes(path, data)
    emitter = parts[0].extras["lightsim"] if parts[0].extras else {}
    return {
        "path": os.fspath(path),
        "bytes": len(data),
        "triangles": {part.name: part.triangle_count for part in parts},
        "flux_lm": emitter.get("flux_lm"),
        "bulb": emitter.get("bulb"),
    }
