"""Aspheric plano-convex lens: flat back towards its focus, convex front that collimates.

The projection lens of an LED projector module and of a matrix high beam. Light from the
lens's focus F on its axis crosses the flat back face (refracted there), and the front
face is shaped so that every such ray leaves parallel to the axis: a point at F is imaged
at infinity without spherical aberration, and a point beside F at about the angle
atan(offset / f) on the other side of the axis (the image is inverted; the lens is
corrected on the axis only, so off the axis its light bends a few per cent further:
:func:`image_angle_deg` traces it). The front profile
follows from equal optical path (the wavefront after the lens is a plane):

    |F B| + n |B P| − z_P = const,

with B the ray's point on the flat back face and P on the front face; the normal at P is
n·d′ − ẑ (Snell's law in vector form: d′ the ray inside the glass, ẑ the ray outside).
Fresnel reflection, total internal reflection and the glass itself are left to the
tracer's dielectric: the mesh carries only the shape and exact vertex normals.

Parameters of :func:`lens_design`

=====================  =====  ========  =================================================
name                   unit   default   meaning
=====================  =====  ========  =================================================
``diameter_m``         m      0.060     clear diameter of the lens
``back_distance_m``    m      0.040     focus to flat back face (the working distance)
``edge_m``             m      0.002     glass thickness at the rim (sets the centre
                                        thickness)
``ior``                –      1.52      refractive index (crown glass B270: 1.52; PMMA 1.49)
=====================  =====  ========  =================================================

Axes as ``docs/reference/conventions.md``: the lens axis is parallel to +Z (light goes
towards +Z), metres.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from lightsim.errors import InputError

from .gltf_writer import GltfMaterial

__all__ = ["LensDesign", "image_angle_deg", "lens_design", "lens_glass", "lens_mesh",
           "offset_for_angle_m"]

_BAND = 1e-5  # m: width of the strip where the normal turns at a crease (rim edges)


@dataclass(frozen=True)
class LensDesign:
    """A designed plano-convex asphere (SI units, lens axis along +Z through the origin).

    Attributes
    ----------
    diameter_m, back_distance_m, ior : float
        As given (see the module table).
    thickness_m : float
        Centre thickness in m.
    focal_length_m : float
        Paraxial effective focal length f = back distance + thickness / n, in m: an offset
        x in the focal plane leaves the lens at atan(x / f).
    profile_r_m, profile_z_m : ndarray
        The front face's profile (radius, height above the flat back) in m, from the
        vertex (r = 0) to the rim.
    profile_nr, profile_nz : ndarray
        Its outward unit normal (radial and axial components).
    collect_half_angle_deg : float
        Half-angle, seen from the focus, of the cone of rays that reach the front face
        inside the rim, in degrees.
    """

    diameter_m: float
    back_distance_m: float
    ior: float
    thickness_m: float
    focal_length_m: float
    profile_r_m: np.ndarray
    profile_z_m: np.ndarray
    profile_nr: np.ndarray
    profile_nz: np.ndarray
    collect_half_angle_deg: float


def _front_profile(d: float, t: float, n: float, samples: int
                   ) -> tuple[np.ndarray, ...]:
    """Front face for a back face at distance d from the focus and centre thickness t.

    Rays leave the focus at angle α from the axis; returns (r, z, n_r, n_z) with z above
    the back face, and α, for α from 0 to 80° (cut to the aperture by the caller).
    """
    alpha = np.linspace(0.0, math.radians(80.0), samples)
    s_in = np.sin(alpha) / n  # refraction at the flat back face
    c_in = np.sqrt(1.0 - s_in * s_in)
    rb = d * np.tan(alpha)  # height on the back face
    l1 = d / np.cos(alpha)  # focus → back face
    const = d + n * t - t  # optical path of the axial ray, minus its z beyond the back face
    # along the glass ray: l1 + n·s − s·c_in = const  →  s
    s = (const - l1) / (n - c_in)
    r = rb + s * s_in
    z = s * c_in
    nr, nz = n * s_in, n * c_in - 1.0
    norm = np.hypot(nr, nz)
    return r, z, nr / norm, nz / norm, alpha


def lens_design(diameter_m: float = 0.060, back_distance_m: float = 0.040,
                edge_m: float = 0.002, ior: float = 1.52, samples: int = 400) -> LensDesign:
    """Design the asphere: the centre thickness that leaves ``edge_m`` of glass at the rim.

    Raises
    ------
    InputError
        Sizes that are not positive and finite, an index below 1, or a lens that cannot
        reach its diameter (the front face would turn back before the rim: the working
        distance is too short for the diameter).
    """
    for what, value in (("lens diameter", diameter_m), ("lens working distance",
                                                        back_distance_m),
                        ("lens edge thickness", edge_m)):
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{what} must be a positive length, got {value!r} m")
    if not (math.isfinite(ior) and 1.0 < ior <= 3.0):
        raise InputError(f"lens refractive index must be in (1, 3], got {ior!r}")
    radius = 0.5 * diameter_m
    if radius > 1.2 * back_distance_m:
        raise InputError(f"a Ø{diameter_m * 1e3:g} mm lens cannot collimate from "
                         f"{back_distance_m * 1e3:g} mm: its rim would be beyond 50° from "
                         "the focus")

    def edge_for(t: float) -> tuple[float, tuple]:
        prof = _front_profile(back_distance_m, t, ior, samples)
        r, z = prof[0], prof[1]
        good = (z > 0) & np.concatenate([[True], np.diff(r) > 0])
        last = int(np.argmin(good)) if not good.all() else len(r)
        prof = tuple(q[:last] for q in prof)
        if last < 2 or prof[0][-1] < radius:
            return -1.0, ()
        return float(np.interp(radius, prof[0], prof[1])), prof

    lo, hi = edge_m, 20 * diameter_m
    if edge_for(hi)[0] < edge_m:
        raise InputError(f"no plano-convex asphere of Ø{diameter_m * 1e3:g} mm collimates "
                         f"from {back_distance_m * 1e3:g} mm")
    for _ in range(80):  # bisection on the centre thickness; edge thickness grows with it
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if edge_for(mid)[0] < edge_m else (lo, mid)
    t = hi
    _, (r, z, nr, nz, alpha) = edge_for(t)
    keep = r < radius
    rim = [float(np.interp(radius, r, q)) for q in (z, nr, nz, alpha)]
    r = np.concatenate([r[keep], [radius]])
    z, nr, nz = (np.concatenate([q[keep], [v]]) for q, v in zip((z, nr, nz), rim))
    norm = np.hypot(nr, nz)
    return LensDesign(diameter_m, back_distance_m, ior, t, back_distance_m + t / ior,
                      r, z, nr / norm, nz / norm, math.degrees(rim[3]))


def image_angle_deg(design: LensDesign, offset_m: float, rays: int = 96) -> float:
    """Where the lens sends a point of its focal plane: the mean exit angle (°) of a fan
    of meridional rays from ``offset_m`` beside the focus, weighted by a Lambertian
    source facing the lens, measured towards the offset's side (so ≈ −atan(offset / f)).

    Off the axis the collimating asphere is not distortion-free; the builder places
    the matrix's dies with this mapping rather than with atan(x / f).
    """
    n, d = design.ior, design.back_distance_m
    radius = 0.5 * design.diameter_m
    pr, pz = design.profile_r_m, design.profile_z_m
    alpha = np.linspace(-math.radians(60.0), math.radians(60.0), rays)
    angles, weights = [], []
    for a in alpha:
        xb = offset_m + d * math.tan(a)
        if abs(xb) >= radius:
            continue
        sa = math.sin(a) / n
        ca = math.sqrt(1.0 - sa * sa)

        def gap(t: float, xb: float = xb, sa: float = sa, ca: float = ca) -> float:
            x = xb + t * sa
            return t * ca - float(np.interp(abs(x), pr, pz))  # > 0: beyond the front face

        lo, hi = 0.0, 4.0 * design.thickness_m
        if gap(hi) <= 0:
            continue
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if gap(mid) < 0 else (lo, mid)
        x = xb + hi * sa
        if abs(x) >= radius:
            continue
        nr = float(np.interp(abs(x), pr, design.profile_nr)) * math.copysign(1.0, x)
        nz = float(np.interp(abs(x), pr, design.profile_nz))
        # refraction glass → air (n → 1) about the outward normal (nr, nz)
        cos_i = sa * nr + ca * nz
        k = 1.0 - n * n * (1.0 - cos_i * cos_i)
        if k < 0:
            continue  # total internal reflection: not part of the image
        ox = n * sa + (math.sqrt(k) - n * cos_i) * nr
        oz = n * ca + (math.sqrt(k) - n * cos_i) * nz
        angles.append(math.degrees(math.atan2(ox, oz)))
        weights.append(math.cos(a))
    if not weights:
        raise InputError(f"no light from {offset_m * 1e3:g} mm beside the focus passes the lens")
    return float(np.average(angles, weights=weights))


def offset_for_angle_m(design: LensDesign, angles_deg: np.ndarray) -> np.ndarray:
    """The focal-plane offsets (m) whose light leaves the lens at ``angles_deg`` (°, the
    sign convention of :func:`image_angle_deg`: a positive angle needs a negative
    offset). Interpolated in a table of :func:`image_angle_deg` over 61 offsets within
    60 % of the lens radius (the mapping is smooth and falls monotonically there)."""
    half = 0.6 * 0.5 * design.diameter_m
    table_x = np.linspace(-half, half, 61)
    table_a = np.array([image_angle_deg(design, x) for x in table_x])
    a = np.asarray(angles_deg, dtype=np.float64)
    if np.any(a > table_a[0]) or np.any(a < table_a[-1]):
        raise InputError(f"angles beyond ±{table_a[0]:.1f}° need dies further off the "
                         "axis than the lens images well")
    return np.interp(a, table_a[::-1], table_x[::-1])


def lens_glass(ior: float, thickness_m: float) -> GltfMaterial:
    """Clear lens glass of index ``ior`` (no absorption modelled)."""
    return GltfMaterial(name=f"lens glass n={ior:g}", base_color=(1.0, 1.0, 1.0),
                        roughness=0.0, transmission=1.0, ior=ior, thickness=thickness_m)


def lens_mesh(design: LensDesign, back_z_m: float, centre_xy_m: tuple[float, float] = (0, 0),
              sectors: int = 96, rings: int = 48
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed mesh of the lens with its flat back at ``z = back_z_m``: vertices (m), faces
    (outward), unit vertex normals (the front face's exact normals).

    Rings on the front face are spaced evenly in the profile's arc length; the rim is a
    cylinder whose creases turn the normal within a 10 µm strip, so every vertex is shared
    and the mesh is closed.
    """
    if sectors < 8 or rings < 4:
        raise InputError("the lens mesh needs ≥ 8 sectors and ≥ 4 rings")
    r, z, nr, nz = design.profile_r_m, design.profile_z_m, design.profile_nr, design.profile_nz
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(r), np.diff(z)))])
    s = np.linspace(0.0, arc[-1], rings + 1)
    fr, fz = np.interp(s, arc, r), np.interp(s, arc, z)
    fnr, fnz = np.interp(s, arc, nr), np.interp(s, arc, nz)
    norm = np.hypot(fnr, fnz)
    fnr, fnz = fnr / norm, fnz / norm
    radius, edge = fr[-1], fz[-1]
    # the closed profile, walked from the back pole outwards, up the rim, over the front to
    # its pole: (r, z, n_r, n_z); creases get a band row so normals switch within _BAND
    prof = [(0.0, 0.0, 0.0, -1.0), (radius, 0.0, 0.0, -1.0), (radius, _BAND, 1.0, 0.0),
            (radius, edge - _BAND, 1.0, 0.0)]
    prof += [(fr[k], fz[k], fnr[k], fnz[k]) for k in range(rings, -1, -1)]
    prof[-1] = (0.0, fz[0], 0.0, 1.0)
    pr, pz, pnr, pnz = (np.array(c, dtype=np.float64) for c in zip(*prof))
    v, f, n = revolve(pr, pz, pnr, pnz, sectors)
    v = v + np.array([centre_xy_m[0], centre_xy_m[1], back_z_m])
    return v, f, n


def revolve(r: np.ndarray, z: np.ndarray, nr: np.ndarray, nz: np.ndarray, sectors: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Revolve a profile (r, z) with normals (n_r, n_z) about the Z axis.

    Points with r = 0 become single pole vertices. A profile walked from the bottom pole
    over the outside to the top pole gives outward faces (counter-clockwise from outside).
    """
    phi = 2 * np.pi * np.arange(sectors) / sectors
    c, s = np.cos(phi), np.sin(phi)
    verts, norms, rows = [], [], []
    count = 0
    for ri, zi, nri, nzi in zip(r, z, nr, nz):
        if ri == 0.0:
            verts.append(np.array([[0.0, 0.0, zi]]))
            norms.append(np.array([[0.0, 0.0, math.copysign(1.0, nzi)]]))
            rows.append(np.array([count]))
            count += 1
        else:
            verts.append(np.column_stack([ri * c, ri * s, np.full(sectors, zi)]))
            norms.append(np.column_stack([nri * c, nri * s, np.full(sectors, nzi)]))
            rows.append(count + np.arange(sectors))
            count += sectors
    faces = []
    j = np.arange(sectors)
    jn = (j + 1) % sectors
    for lo, hi in itertools.pairwise(rows):
        if len(lo) == 1:
            faces.append(np.column_stack([np.full(sectors, lo[0]), hi[jn], hi[j]]))
        elif len(hi) == 1:
            faces.append(np.column_stack([lo[j], lo[jn], np.full(sectors, hi[0])]))
        else:
            faces.append(np.column_stack([lo[j], lo[jn], hi[jn]]))
            faces.append(np.column_stack([lo[j], hi[jn], hi[j]]))
    n = np.vstack(norms)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.vstack(verts), np.vstack(faces).astype(np.int64), n
