"""Multi-facet reflector: azimuthal sectors of paraboloids sharing one focus, each aimed.

Each facet is a piece of a paraboloid whose focus is the lamp's focus F = (0, 0, f) and
whose axis points along the facet's aim direction d: light from F leaves the facet exactly
along d, so the facet puts the filament's images around the wall direction (h, v) it is
aimed at. In polar form about the focus a paraboloid of focal length f and axis d is

    ρ(u) = 2 f / (1 − u·d),     normal  n ∝ d − u   (facing the focus)

for the unit direction u from F to the surface point (the reflection of u about n is d).
A facet covers the directions from F towards an azimuthal sector φ ∈ [φ₀, φ₁) of the base
paraboloid (the plain reflector of focal length f between the vertex hole and the rim), so
the facets tile the same solid angle as the plain reflector; where neighbours differ in
aim their surfaces meet in small radial steps, which light from F cannot pass through.

Parameters

=============  =====  ============================================================
name           unit   meaning
=============  =====  ============================================================
f              m      common focal length (focus at (0, 0, f))
r_hole, r_rim  m      radii of the base paraboloid's vertex hole and rim
facets         –      :class:`Facet` list: azimuth range (rad), aim (h, v in °), optional
                      ring (base radii r0–r1, m) and own focal length (m)
rings          –      rings per facet (evenly spaced in base radius)
columns        –      vertices per ring and facet
=============  =====  ============================================================

Wall directions follow ``docs/reference/conventions.md``: H is to the driver's right, which is
world −X; V is up (+Y); the lamp shines along +Z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lightsim.errors import InputError

__all__ = ["Facet", "aim_direction", "faceted_reflector_mesh"]


@dataclass(frozen=True)
class Facet:
    """One reflector sector.

    Attributes
    ----------
    phi0_rad, phi1_rad : float
        Azimuth range about the lamp axis, measured from world +X towards +Y, in rad.
    h_deg, v_deg : float
        Wall direction the facet sends light from the focus to (H right, V up), in °.
    r0_m, r1_m : float or None
        Range of the base paraboloid's radius the facet covers (a ring), in m; ``None``:
        from the vertex hole to the rim.
    focal_m : float or None
        The facet's own focal length in m (``None``: the common one). A longer focal length
        puts the facet further from the focus and makes its filament images smaller.
    """

    phi0_rad: float
    phi1_rad: float
    h_deg: float
    v_deg: float
    r0_m: float | None = None
    r1_m: float | None = None
    focal_m: float | None = None


def aim_direction(h_deg: float, v_deg: float) -> np.ndarray:
    """Unit vector towards wall angles (H right = world −X, V up), lamp along +Z."""
    d = np.array([-math.tan(math.radians(h_deg)), math.tan(math.radians(v_deg)), 1.0])
    return d / np.linalg.norm(d)


def faceted_reflector_mesh(f: float, r_hole: float, r_rim: float, facets: list[Facet],
                           rings: int = 40, columns: int = 24
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (m), faces (facing the focus) and exact normals of a faceted reflector.

    Facet k covers the directions from the focus towards the base paraboloid (focal length
    ``f``) between radii ``r0_m``–``r1_m`` and azimuths ``phi0_rad``–``phi1_rad``; its surface
    is the paraboloid of focal length ``focal_m`` (default ``f``) about its aim direction.

    Raises
    ------
    InputError
        No facets, sizes that make no reflector, or an aim so steep that a facet would
        reach to infinity (u·d → 1).
    """
    if not facets:
        raise InputError("a faceted reflector needs at least one facet")
    if not (0 < r_hole < r_rim and f > 0) or rings < 1 or columns < 2:
        raise InputError("faceted reflector: need 0 < hole < rim radius, f > 0, rings ≥ 1, "
                         "columns ≥ 2")
    focus = np.array([0.0, 0.0, f])
    verts, faces, norms = [], [], []
    n = 0
    for fc in facets:
        r0 = r_hole if fc.r0_m is None else float(fc.r0_m)
        r1 = r_rim if fc.r1_m is None else float(fc.r1_m)
        fk = f if fc.focal_m is None else float(fc.focal_m)
        if not (r_hole - 1e-12 <= r0 < r1 <= r_rim + 1e-12):
            raise InputError(f"facet ring {r0}–{r1} m is not inside the reflector "
                             f"({r_hole}–{r_rim} m)")
        if not (math.isfinite(fk) and 0.25 * f <= fk <= 4 * f):
            raise InputError(f"facet focal length {fk} m is not within ¼–4× the common {f} m")
        r = np.linspace(r0, r1, rings + 1)
        if not (math.isfinite(fc.h_deg) and math.isfinite(fc.v_deg)
                and abs(fc.h_deg) < 45 and abs(fc.v_deg) < 45):
            raise InputError(f"facet aim ({fc.h_deg}, {fc.v_deg})° is not within ±45°")
        if not fc.phi1_rad > fc.phi0_rad:
            raise InputError("a facet's azimuth range must be increasing")
        d = aim_direction(fc.h_deg, fc.v_deg)
        phi = np.linspace(fc.phi0_rad, fc.phi1_rad, columns)
        rr, pp = np.meshgrid(r, phi, indexing="ij")  # (rings+1, columns)
        base = np.column_stack([(rr * np.cos(pp)).ravel(), (rr * np.sin(pp)).ravel(),
                                (rr * rr / (4 * f)).ravel()])
        u = base - focus
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        cos_ud = u @ d
        if np.any(cos_ud > 1 - 1e-6):
            raise InputError(f"facet aim ({fc.h_deg}, {fc.v_deg})° turns the paraboloid "
                             "away to infinity")
        rho = 2 * fk / (1 - cos_ud)
        p = focus + rho[:, None] * u
        nm = d[None, :] - u
        nm /= np.linalg.norm(nm, axis=1, keepdims=True)
        i, j = np.meshgrid(np.arange(rings), np.arange(columns - 1), indexing="ij")
        a = (i * columns + j).ravel() + n
        b = ((i + 1) * columns + j).ravel() + n
        c = ((i + 1) * columns + j + 1).ravel() + n
        e = (i * columns + j + 1).ravel() + n
        # r-then-φ order faces into the bowl (as the plain reflector's mesh)
        faces += [np.column_stack([a, b, c]), np.column_stack([a, c, e])]
        verts.append(p)
        norms.append(nm)
        n += len(p)
    return np.vstack(verts), np.vstack(faces).astype(np.int64), np.vstack(norms)
