"""Analytic validation scenes: geometry built by code, each with its exact answer.

Every builder returns an :class:`AnalyticScene`: the in-memory :class:`~lightsim.scene.Scene`
(parts from :mod:`lightsim.validation.scenes.primitives` plus a measurement wall) and the
exact illuminance E(h, v) on that wall in lux, as a function of the wall coordinates
(h, v in m, see ``docs/reference/conventions.md``). :func:`pixel_average` turns it into the exact
mean over every wall pixel, which is what an unbiased estimate of a pixel measures.

========================  =====  =========  ===============================================
parameter                 unit   default    meaning
========================  =====  =========  ===============================================
``flux``                  lm     1000       luminous flux Φ of the source
``distance`` (isotropic)  m      2          source–wall distance d
``f``, ``rim``            m      0.1, 0.15  paraboloid focal length, rim (aperture) radius
``reflectance``           –      0.88       mirror reflectance R
``wall_distance``         m      0.6        paraboloid vertex–wall distance
``thickness`` (slab)      m      0.02       glass plate thickness t
``ior``                   –      1.5        glass index n
``sigma``                 1/m    0          Beer–Lambert absorption coefficient σ
``radius`` (ring)         m      0.1        inner radius R of the mirror ring
``elevation`` (ring)      deg    30         elevation α of the distant (collimated) light
``disk_radius``           m      0.05       radius a of the Lambertian disk emitter
``albedo`` (box)          –      0.7        albedo ρ of the closed diffuse box
``shield_z`` (shield)     m      0.25       plane of the black shield's straight edge
``slope``, ``offset``     °, m   10, 0.05   the shadow line on the wall: v = tan(slope) h
                                            + offset (lit below it, as a low beam)
``resolution``            px     64 × 64    wall pixels W × H
========================  =====  =========  ===============================================

Exact answers (derivations in the docstrings of the functions below):

* isotropic point source, plane at distance d: E = Φ cos³θ / (4π d²) = Φ d / (4π r³);
* point source at the focus of a paraboloid z = r²/(4f) of reflectance R and rim radius a:
  reflected E(r) = R Φ / (4π f²) / (1 + r²/(4f²))² for r < a, plus the direct light
  Φ cos³θ / (4π (D − f)²) where the reflector does not block it;
* glass plate: every internal reflection order k carries (1−R)² R²ᵏ a²ᵏ⁺¹ of the flux
  (R: unpolarised single-surface Fresnel reflectance, a = exp(−σ t / cos θₜ)) and lands
  laterally shifted; summed over k this is the multiple-reflection slab transmittance;
* ring caustic: the envelope of parallel rays reflected inside a circle of radius R is a
  nephroid whose cusp lies R/2 from the axis (on the side the light travels towards);
* Lambertian polygon emitter: Lambert's contour integral (exact for the mesh), equal to
  the disk formula E = πL a² / (a² + d²) on the axis, L = Φ / (π A);
* closed box of albedo ρ: nothing escapes; the flux arriving at the walls, summed over all
  bounces, is Φ (1 − ρᴰ) / (1 − ρ) for a depth limit D;
* shield cut-off: a black half-plane between an isotropic point source and the wall
  casts an exact step — E = Φ D / (4π ρ³) below the projected edge, 0 above — whose
  pixel means are integrated exactly (:func:`step_pixel_average`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.materials import DIFFUSE, Material
from lightsim.scene import EMITTER, SURFACE, Part, Scene, WallFrame, make_wall
from lightsim.validation.scenes import primitives as prim

LuxFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


# ------------------------------------------------------------------------------------------
# Exact formulas
# ------------------------------------------------------------------------------------------

def fresnel_unpolarised(cos_i: np.ndarray, n: float) -> tuple[np.ndarray, np.ndarray]:
    """Fresnel reflectances (R_s, R_p) from air (n = 1) into a medium of index ``n``.

    Parameters
    ----------
    cos_i : array_like
        Cosine of the angle of incidence (dimensionless, in [0, 1]).
    n : float
        Refractive index of the second medium (≥ 1).

    Returns
    -------
    rs, rp : ndarray
        Reflectance of the s- and p-polarised parts; the unpolarised reflectance is their
        mean (what :func:`lightsim.materials.fresnel_dielectric` returns).
    """
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    s2t = (1.0 - c * c) / (n * n)
    ct = np.sqrt(np.maximum(0.0, 1.0 - s2t))
    rs = ((c - n * ct) / (c + n * ct)) ** 2
    rp = ((n * c - ct) / (n * c + ct)) ** 2
    return rs, rp


def isotropic_plane_lux(flux: float, distance: float, rho: np.ndarray) -> np.ndarray:
    """E (lx) on a plane at ``distance`` (m) from an isotropic point source of ``flux`` (lm).

    E = Φ cos³θ / (4π d²) = Φ d / (4π (d² + ρ²)^{3/2}) at a distance ρ (m) from the foot
    of the perpendicular: the intensity Φ/(4π) cd, the inverse square of the distance
    d/cosθ and the cosine of incidence.
    """
    rho = np.asarray(rho, dtype=np.float64)
    return flux * distance / (4.0 * math.pi * (distance**2 + rho**2) ** 1.5)


def rectangle_solid_angle(x0: float, x1: float, y0: float, y1: float, d: float) -> float:
    """Solid angle (sr) of the rectangle [x0, x1] × [y0, y1] in a plane at distance ``d`` (m).

    Uses Ω(x, y) = atan(x y / (d √(d² + x² + y²))) for the rectangle [0, x] × [0, y] with
    a corner at the foot of the perpendicular, combined by inclusion–exclusion.
    """
    def corner(x: float, y: float) -> float:
        return math.atan2(x * y, d * math.sqrt(d * d + x * x + y * y))

    return corner(x1, y1) - corner(x0, y1) - corner(x1, y0) + corner(x0, y0)


def paraboloid_reflected_lux(flux: float, f: float, reflectance: float,
                             r: np.ndarray) -> np.ndarray:
    """Illuminance (lx) of the beam of a paraboloid with an isotropic source at its focus.

    Derivation: a ray leaving the focus at angle ψ from the axis towards the vertex meets
    the paraboloid z = r²/(4f) at the radius r = 2f tan(ψ/2) (polar equation
    ρ = 2f / (1 + cos ψ)) and leaves parallel to the axis. The flux in dψ is
    (Φ/2) sin ψ dψ; it lands on the ring 2π r dr with dr = f sec²(ψ/2) dψ, so
    E = R Φ cos⁴(ψ/2) / (4π f²) = R Φ / (4π f²) / (1 + r²/(4f²))²: the flux per solid
    angle from the focus mapped onto the aperture disk. Valid inside the rim (r < a) at
    any distance along the axis (the beam is parallel).
    """
    r = np.asarray(r, dtype=np.float64)
    return reflectance * flux / (4.0 * math.pi * f * f) / (1.0 + r * r / (4.0 * f * f)) ** 2


def disk_lux(luminance: float, a: float, d: float, rho: np.ndarray) -> np.ndarray:
    """E (lx) of a Lambertian disk (luminance L cd/m², radius a m) on a parallel plane.

    E = (πL/2) [1 − (d² + ρ² − a²) / √((d² + ρ² + a²)² − 4 a² ρ²)] at distance d (m)
    and off-axis distance ρ (m) (the view factor of a disk to a parallel element); on the
    axis E = πL a² / (a² + d²) = (Φ/A) a² / (a² + d²) with L = Φ/(πA).
    """
    rho = np.asarray(rho, dtype=np.float64)
    s = d * d + rho * rho
    return 0.5 * math.pi * luminance * (1.0 - (s - a * a) / np.sqrt((s + a * a) ** 2
                                                                      - 4 * a * a * rho * rho))


def lambert_polygon_lux(luminance: float, polygon: np.ndarray, points: np.ndarray,
                        normal: np.ndarray) -> np.ndarray:
    """E (lx) at ``points`` from a planar Lambertian polygon (Lambert's contour formula).

    E = (L/2) |Σᵢ γᵢ n · (Rᵢ × Rᵢ₊₁) / |Rᵢ × Rᵢ₊₁||, with Rᵢ the vectors from the point
    to the vertices and γᵢ the angle between Rᵢ and Rᵢ₊₁: exact for a polygon the point
    sees whole and in front of it.

    Parameters
    ----------
    luminance : float
        L (cd/m²).
    polygon : (V, 3) array
        Vertices in order around the polygon (m).
    points : (..., 3) array
        Receiver points (m).
    normal : (3,) array
        Unit normal of the receiving surface (towards the emitter).
    """
    pts = np.asarray(points, dtype=np.float64)
    shape = pts.shape[:-1]
    p = pts.reshape(-1, 3)
    poly = np.asarray(polygon, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    total = np.zeros(len(p))
    for i in range(len(poly)):
        r1 = poly[i] - p
        r2 = poly[(i + 1) % len(poly)] - p
        cr = np.cross(r1, r2)
        crn = np.linalg.norm(cr, axis=1)
        cos_g = np.einsum("ij,ij->i", r1, r2) / (np.linalg.norm(r1, axis=1)
                                                  * np.linalg.norm(r2, axis=1))
        gamma = np.arccos(np.clip(cos_g, -1.0, 1.0))
        total += gamma * (cr @ n) / np.maximum(crn, 1e-300)
    return (0.5 * luminance * np.abs(total)).reshape(shape)


def nephroid_axis_crossing(radius: float, phi: np.ndarray) -> np.ndarray:
    """Where a ray reflected inside a circle crosses the symmetry axis (m from the centre).

    A ray parallel to the axis at height R sin φ meets the circle at (R cos φ, R sin φ),
    whose normal points to the centre; the reflected ray makes the angle 2φ with the
    axis and crosses it at x = R cos φ − R sin φ cos 2φ / sin 2φ = R / (2 cos φ). The
    crossings fill [R/2, R): the caustic (a nephroid) has its cusp at R/2, the paraxial
    focus of the circular mirror.
    """
    return radius / (2.0 * np.cos(np.asarray(phi, dtype=np.float64)))


class SlabExact:
    """Exact E (lx) behind a glass plate (isotropic point source; incoherent reflections).

    Source at the origin, plate faces perpendicular to the axis, wall at distance D. A ray
    at angle θ refracts to θₜ (sin θ = n sin θₜ); the part that crosses the plate
    2k + 1 times (k internal round trips) carries Tₖ(θ) = (1−R)² R²ᵏ a²ᵏ⁺¹ of the flux,
    with R the unpolarised Fresnel reflectance of one surface and a = exp(−σ t / cos θₜ),
    and lands at ρₖ(θ) = (D − t) tan θ + (2k + 1) t tan θₜ (independent of where the
    plate stands). Conservation of flux in dθ gives

        Eₖ(ρ) = Φ/(4π) · Tₖ(θ) · sin θ / (ρₖ dρₖ/dθ),  θ = θₖ(ρ),

    with the θ → 0 limit Φ Tₖ(0) / (4π (D − t + (2k+1) t/n)²). Σₖ Tₖ is the slab
    transmittance (1−R)² a / (1 − R² a²) (:func:`lightsim.materials.slab_transmittance`).
    The orders are summed until the next one carries < 1e-12 of the flux; ρₖ(θ) is
    tabulated on a fine θ grid and inverted by interpolation.

    Parameters
    ----------
    flux : float
        Φ (lm).
    wall_distance : float
        D (m), source to wall.
    thickness : float
        t (m).
    ior : float
        n.
    sigma : float
        σ (1/m).
    theta_max : float
        Largest angle (rad) to tabulate (cover the wall).
    """

    def __init__(self, flux: float, wall_distance: float, thickness: float, ior: float,
                 sigma: float = 0.0, theta_max: float = 1.2, n_grid: int = 20001) -> None:
        self.flux, self.D, self.t, self.n, self.sigma = (float(flux), float(wall_distance),
                                                         float(thickness), float(ior),
                                                         float(sigma))
        th = np.linspace(0.0, theta_max, n_grid)
        self.theta = th
        st = np.sin(th) / self.n
        ct = np.sqrt(1.0 - st * st)
        R = self.reflectance(th)
        a = np.exp(-self.sigma * self.t / ct)
        self.orders: list[tuple[np.ndarray, np.ndarray]] = []
        D, t, n = self.D, self.t, self.n
        k = 0
        while True:
            m = 2 * k + 1
            tk = (1.0 - R) ** 2 * R ** (2 * k) * a**m
            rho = (D - t) * np.tan(th) + m * t * st / ct
            drho = (D - t) / np.cos(th) ** 2 + m * t / ct**2 * np.cos(th) / (n * ct)
            with np.errstate(invalid="ignore", divide="ignore"):
                g = np.where(th > 0, np.sin(th) / (rho * drho), 0.0)
            g[0] = 1.0 / (D - t + m * t / n) ** 2
            self.orders.append((rho, self.flux / (4 * math.pi) * tk * g))
            if np.max((R * a) ** 2 * R ** (2 * k) * a ** (2 * k)) < 1e-12 or k > 200:
                break
            k += 1

    def reflectance(self, theta: np.ndarray) -> np.ndarray:
        """Unpolarised single-surface reflectance R(θ) (the tracer's model)."""
        rs, rp = fresnel_unpolarised(np.cos(theta), self.n)
        return 0.5 * (rs + rp)

    def transmittance(self, theta: np.ndarray) -> np.ndarray:
        """Σₖ Tₖ(θ) = (1−R)² a / (1 − R² a²) with the unpolarised R (the tracer's model)."""
        theta = np.asarray(theta, dtype=np.float64)
        R = self.reflectance(theta)
        a = self.absorption(theta)
        return (1 - R) ** 2 * a / (1 - R * R * a * a)

    def transmittance_polarised(self, theta: np.ndarray) -> np.ndarray:
        """Transmittance of unpolarised light with the s and p parts tracked separately.

        ½ Σ_{x∈{s,p}} (1−Rₓ)² a / (1 − Rₓ² a²): the physical answer. The tracer keeps no
        polarisation state and uses the mean R at every surface, which differs from this
        by 0.01 % at 20°, 0.1 % at 35° and 1.4 % at 60° for n = 1.5.
        """
        theta = np.asarray(theta, dtype=np.float64)
        rs, rp = fresnel_unpolarised(np.cos(theta), self.n)
        a = self.absorption(theta)
        return 0.5 * sum((1 - r) ** 2 * a / (1 - r * r * a * a) for r in (rs, rp))

    def absorption(self, theta: np.ndarray) -> np.ndarray:
        """Single-pass internal transmittance a(θ) = exp(−σ t / cos θₜ)."""
        st = np.sin(np.asarray(theta, dtype=np.float64)) / self.n
        return np.exp(-self.sigma * self.t / np.sqrt(1.0 - st * st))

    def lux(self, rho: np.ndarray) -> np.ndarray:
        """E (lx) at wall radius ``rho`` (m) from the foot of the perpendicular."""
        rho = np.asarray(rho, dtype=np.float64)
        out = np.zeros_like(rho)
        for rk, ek in self.orders:
            if np.any(rho > rk[-1]):
                raise ValueError(f"wall radius {rho.max():.3g} m beyond the tabulated "
                                 f"θ range ({rk[-1]:.3g} m)")
            out += np.interp(rho, rk, ek)
        return out


# ------------------------------------------------------------------------------------------
# Scene containers and their functions
# ------------------------------------------------------------------------------------------

@dataclass
class AnalyticScene:
    """A validation scene with its exact answer.

    Attributes
    ----------
    name : str
        Short case name (``isotropic``, ``paraboloid``, ``slab``, …).
    title : str
        One-line description.
    scene : Scene
        The scene (its ``wall`` is the detector the answer refers to).
    flux : float
        Emitted luminous flux Φ (lm).
    exact : callable (h, v) → E
        Exact illuminance (lx) at wall coordinates (m); None where the case's answer is
        not a lux map (ring caustic: see ``extra``).
    density : callable (h, v) → n
        Expected number of photons arriving per m² per emitted photon (1/m²), used for
        the expected kNN radius; defaults to E / Φ.
    regions : list of (label, predicate)
        Profile regions: ``predicate(h, v)`` → bool mask of the pixels (by centre) that
        belong to the region. Pixels near a discontinuity of ``exact`` are left out.
    wall_flux : float or None
        Exact flux (lm) reaching the wall, if known in closed form.
    wall_flux_sigma : float or None
        Photon-statistics standard deviation (lm) of the wall flux for one emitted photon
        (divide by √N); from the photon-power distribution (independent photons).
    params : dict
        Parameters for reports (SI units).
    extra : dict
        Case-specific data (e.g. the cusp position).
    radial : bool
        ``exact`` and ``density`` depend on √(h² + v²) only (to 1e-5 for the 256-gon
        emitter), so they may be tabulated along r.
    pixel_means : callable (frame) → (H, W) lx, optional
        Exact pixel means where ``exact`` has a discontinuity inside pixels (the
        generic :func:`pixel_average` quadrature assumes a smooth answer).
    """

    name: str
    title: str
    scene: Scene
    flux: float
    exact: LuxFn | None
    density: LuxFn | None = None
    regions: list[tuple[str, Callable[[np.ndarray, np.ndarray], np.ndarray]]] = \
        field(default_factory=list)
    wall_flux: float | None = None
    wall_flux_sigma: float | None = None
    params: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    radial: bool = False
    pixel_means: Callable[[WallFrame], np.ndarray] | None = None

    @property
    def frame(self) -> WallFrame:
        assert self.scene.wall is not None
        return self.scene.wall

    def photon_density(self, h: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Photons per m² per emitted photon (1/m²) at wall coordinates (m)."""
        if self.density is not None:
            return self.density(h, v)
        assert self.exact is not None
        return self.exact(h, v) / self.flux


def gauss_nodes(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes on [−½, ½] and weights summing to 1."""
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * x, 0.5 * w


def pixel_average(fn: LuxFn, frame: WallFrame, n: int = 4) -> np.ndarray:
    """Mean of ``fn`` (lx) over every wall pixel, (H, W), by n × n Gauss–Legendre points.

    Exact to rounding for polynomials of degree < 2n in each direction; for the smooth
    answers here the quadrature error is far below 1e-6 relative (pixels that straddle
    a discontinuity are excluded from the comparisons).
    """
    h, v = frame.pixel_centres()
    dh, dv = frame.pixel_size_m
    x, w = gauss_nodes(n)
    out = np.zeros((len(v), len(h)))
    for xi, wi in zip(x, w):
        for yj, wj in zip(x, w):
            hh, vv = np.meshgrid(h + xi * dh, v - yj * dv)
            out += wi * wj * fn(hh, vv)
    return out


def _gauss_v(fn: LuxFn, h: np.ndarray, c: np.ndarray, d: np.ndarray, x: np.ndarray,
             w: np.ndarray) -> np.ndarray:
    """∫_c^d fn(h, v) dv by Gauss–Legendre nodes ``x`` and weights ``w`` (lx·m)."""
    vh, vm = 0.5 * (d - c), 0.5 * (d + c)
    acc = np.zeros_like(h)
    for yj, wj in zip(x, w):
        acc += wj * fn(h, vm + vh * yj)
    return acc * vh


def step_pixel_average(fn: LuxFn, frame: WallFrame, slope: float, offset: float,
                       n: int = 6) -> np.ndarray:
    """Exact mean over every pixel of ``fn`` (lx, smooth) times the step [v < s h + c].

    Each pixel [h0, h1] × [v0, v1] is cut where the line v = s h + c crosses v0 and v1, so
    that on every piece the clipped upper limit min(v1, max(v0, s h + c)) is linear in h;
    on each piece n × n Gauss–Legendre points (in h, and in v over the clipped interval)
    integrate the smooth E — exact to rounding for polynomials of degree < 2n.
    """
    hc, vc = frame.pixel_centres()
    dh, dv = frame.pixel_size_m
    x, w = np.polynomial.legendre.leggauss(n)
    out = np.zeros((len(vc), len(hc)))
    H0, V0 = np.meshgrid(hc - dh / 2, vc - dv / 2)
    H1, V1 = H0 + dh, V0 + dv
    # breakpoints in h (per pixel), sorted: h0, crossings clipped into the pixel, h1
    with np.errstate(divide="ignore", invalid="ignore"):
        if slope != 0:
            ca = np.clip((V0 - offset) / slope, H0, H1)
            cb = np.clip((V1 - offset) / slope, H0, H1)
        else:
            ca, cb = H0, H0
    brk = np.sort(np.stack([H0, np.minimum(ca, cb), np.maximum(ca, cb), H1]), axis=0)
    for a, b in itertools.pairwise(brk):
        half, mid = 0.5 * (b - a), 0.5 * (b + a)
        for xi, wi in zip(x, w):
            h = mid + half * xi
            top = np.clip(slope * h + offset, V0, V1)
            out += wi * half * _gauss_v(fn, h, V0, top, x, w)
    return out / (dh * dv)


def circle_pixel_average(fn: LuxFn, frame: WallFrame, radius: float, n: int = 6
                         ) -> np.ndarray:
    """Exact mean over every pixel of ``fn`` (lx), smooth except across the circle
    √(h² + v²) = ``radius`` (a beam's rim), (H, W).

    Each pixel is cut in h where the circle crosses its top and bottom edges or is
    vertical, and at every h node the v-interval is cut where the circle crosses it, so
    that ``fn`` is smooth on every piece; n × n Gauss–Legendre points per piece.
    """
    hc, vc = frame.pixel_centres()
    dh, dv = frame.pixel_size_m
    x, w = np.polynomial.legendre.leggauss(n)
    H0, V0 = np.meshgrid(hc - dh / 2, vc - dv / 2)
    H1, V1 = H0 + dh, V0 + dv
    R2 = radius * radius
    cand = [H0, H1]
    for vv in (V0, V1):
        root = np.sqrt(np.maximum(R2 - vv * vv, 0.0))
        cand += [-root, root]
    cand += [np.full_like(H0, -radius), np.full_like(H0, radius)]
    brk = np.sort(np.clip(np.stack(cand), H0, H1), axis=0)
    out = np.zeros_like(H0)
    for a, b in itertools.pairwise(brk):
        half, mid = 0.5 * (b - a), 0.5 * (b + a)
        for xi, wi in zip(x, w):
            h = mid + half * xi
            root = np.sqrt(np.maximum(R2 - h * h, 0.0))
            vb = np.sort(np.clip(np.stack([V0, -root, root, V1]), V0, V1), axis=0)
            for c, d in itertools.pairwise(vb):
                out += wi * half * _gauss_v(fn, h, c, d, x, w)
    return out / (dh * dv)


def binomial_sigma(flux: float, p: float) -> float:
    """Per-photon standard deviation (lm) of a flux estimate where a fraction p arrives.

    Each photon carries Φ or nothing: σ₁ = Φ √(p (1 − p)); the estimate from N photons
    has σ₁ / √N.
    """
    return flux * math.sqrt(max(p * (1.0 - p), 0.0))


def collimated_quad(flux: float, centre, direction, width: float, height: float,
                    up=(0.0, 1.0, 0.0), name: str = "sun") -> Part:
    """A rectangular collimated emitter: every photon leaves along ``direction``.

    A distant source (sun, test beam): irradiance Φ / (width × height) lx on a plane
    perpendicular to the beam. ``up`` fixes the orientation of the ``height`` side.
    """
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    u = np.cross(np.asarray(up, dtype=np.float64), d)
    if np.linalg.norm(u) < 1e-9:
        u = np.cross(np.array([1.0, 0.0, 0.0]), d)
    u /= np.linalg.norm(u)
    w = np.cross(d, u)
    c = np.asarray(centre, dtype=np.float64)
    hw, hh = width / 2, height / 2
    verts = np.array([c - hw * u - hh * w, c + hw * u - hh * w, c + hw * u + hh * w,
                      c - hw * u + hh * w])
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    n = np.cross(verts[1] - verts[0], verts[2] - verts[0])
    if n @ d < 0:
        faces = faces[:, ::-1].copy()
    return Part(name, EMITTER, verts, faces, None, Material(name, DIFFUSE),
                flux_lm=float(flux), emission="collimated")


def _annuli(edges: np.ndarray, label: str = "ρ", unit: str = "m", scale: float = 1.0,
            exclude: Callable[[np.ndarray], np.ndarray] | None = None,
            fmt: str = "{:.3g}"
            ) -> list[tuple[str, Callable[[np.ndarray, np.ndarray], np.ndarray]]]:
    """Annular regions between consecutive ``edges`` of the wall radius (m)."""
    out = []
    for lo, hi in itertools.pairwise(edges):
        def pred(h, v, lo=lo, hi=hi):
            r = np.hypot(h, v)
            m = (r >= lo) & (r < hi)
            if exclude is not None:
                m &= ~exclude(r)
            return m
        out.append((f"{label} {fmt.format(lo * scale)}–{fmt.format(hi * scale)} {unit}", pred))
    return out


def _theta_annuli(distance: float, degrees: np.ndarray
                  ) -> list[tuple[str, Callable[[np.ndarray, np.ndarray], np.ndarray]]]:
    edges = distance * np.tan(np.radians(degrees))
    out = []
    for (lo, hi), (a, b) in zip(itertools.pairwise(edges), itertools.pairwise(degrees)):
        def pred(h, v, lo=lo, hi=hi):
            r = np.hypot(h, v)
            return (r >= lo) & (r < hi)
        out.append((f"E θ {a:g}–{b:g}°", pred))
    return out


# ------------------------------------------------------------------------------------------
# Builders
# ------------------------------------------------------------------------------------------

def isotropic_case(flux: float = 1000.0, distance: float = 2.0, wall_size: float = 4.0,
                   resolution: tuple[int, int] = (64, 64),
                   source_radius: float = 1e-4) -> AnalyticScene:
    """Isotropic point source at distance d in front of a square wall (cos³θ law)."""
    wall, frame = make_wall(distance, (wall_size, wall_size), resolution=resolution)
    scene = Scene([prim.point_source(flux, radius=source_radius), wall], frame)
    half = wall_size / 2
    theta_edge = math.degrees(math.atan(half / distance))
    degs = np.arange(0.0, theta_edge - 2.0, 5.0)
    degs = np.append(degs, math.floor(theta_edge - 1.0))
    omega = rectangle_solid_angle(-half, half, -half, half, distance)
    p = omega / (4 * math.pi)
    return AnalyticScene(
        "isotropic", "isotropic point source in front of a plane: E = Φ cos³θ / (4π d²)",
        scene, flux, lambda h, v: isotropic_plane_lux(flux, distance, np.hypot(h, v)),
        regions=_theta_annuli(distance, degs), wall_flux=flux * p,
        wall_flux_sigma=binomial_sigma(flux, p),
        params={"flux_lm": flux, "distance_m": distance, "wall_size_m": wall_size,
                "source_radius_m": source_radius}, radial=True)


def paraboloid_case(flux: float = 1000.0, f: float = 0.1, rim: float = 0.15,
                    reflectance: float = 0.88, wall_distance: float = 0.6,
                    wall_size: float = 0.5, resolution: tuple[int, int] = (64, 64),
                    radial: int = 64, azimuthal: int = 256, source_radius: float = 1e-5
                    ) -> AnalyticScene:
    """Isotropic source at the focus of a paraboloid mirror; wall across the beam.

    The wall (plane z = D, vertex at the origin) receives the parallel reflected beam
    E_refl(r) = R Φ / (4π f²) / (1 + r²/(4f²))² inside the rim r < a, plus the direct
    light Φ cos³θ / (4π (D − f)²) from the focus at angles θ (from +Z) below
    π − ψ_rim, ψ_rim = 2 atan(a / (2f)) (steeper rays hit the reflector).
    """
    mirror = prim.paraboloid(f, rim, reflectance=reflectance, radial=radial,
                             azimuthal=azimuthal)
    src = prim.point_source(flux, radius=source_radius, centre=(0.0, 0.0, f))
    if wall_distance <= rim * rim / (4 * f) or wall_distance <= f:
        raise InputError("the wall must lie beyond the focus and the reflector's rim")
    wall, frame = make_wall(wall_distance, (wall_size, wall_size), resolution=resolution)
    scene = Scene([src, mirror, wall], frame, channels=1)
    psi_rim = 2 * math.atan(rim / (2 * f))
    theta_max = math.pi - psi_rim
    dz = wall_distance - f

    def direct(h, v):
        rho = np.hypot(h, v)
        e = isotropic_plane_lux(flux, dz, rho)
        return np.where(np.arctan2(rho, dz) < theta_max, e, 0.0)

    def exact(h, v):
        r = np.hypot(h, v)
        refl = np.where(r < rim, paraboloid_reflected_lux(flux, f, reflectance, r), 0.0)
        return refl + direct(h, v)

    def density(h, v):
        r = np.hypot(h, v)
        refl = np.where(r < rim, paraboloid_reflected_lux(flux, f, 1.0, r), 0.0)
        return (refl + direct(h, v)) / flux

    px = max(frame.pixel_size_m)
    near_rim = lambda r: np.abs(r - rim) < 1.5 * px  # noqa: E731
    half = wall_size / 2
    inside = np.linspace(0.0, rim, 7)
    outside = np.linspace(rim, half, 4)
    regions = (_annuli(inside, "E_refl+dir r", "mm", 1e3, near_rim, "{:.0f}")
               + _annuli(outside, "E_direct r", "mm", 1e3, near_rim, "{:.0f}"))
    # wall flux: the whole reflected beam plus the direct light on the square
    p_refl = (1.0 - math.cos(psi_rim)) / 2.0
    omega = rectangle_solid_angle(-half, half, -half, half, dz)
    if math.atan(math.hypot(half, half) / dz) > theta_max:
        raise InputError("wall too large: the reflector shadows part of its direct light")
    p_dir = omega / (4 * math.pi)
    wf = flux * (reflectance * p_refl + p_dir)
    second = flux**2 * (reflectance**2 * p_refl + p_dir)
    return AnalyticScene(
        "paraboloid", "isotropic source at the focus of a paraboloid mirror: "
        "E = R Φ / (4π f²) / (1 + r²/4f²)² + direct", scene, flux, exact, density,
        regions, wf, math.sqrt(max(second - wf * wf, 0.0)),
        params={"flux_lm": flux, "focal_length_m": f, "rim_radius_m": rim,
                "reflectance": reflectance, "wall_distance_m": wall_distance,
                "wall_size_m": wall_size, "mesh": [radial, azimuthal]},
        extra={"psi_rim_rad": psi_rim, "reflected_flux_lm": reflectance * flux * p_refl},
        radial=True, pixel_means=lambda fr: circle_pixel_average(exact, fr, rim))


def covered_paraboloid_case(flux: float = 1000.0, f: float = 0.02, rim: float = 0.03,
                            reflectance: float = 0.88, wall_distance: float = 0.5,
                            wall_size: float = 0.06, cover_z: float = 0.03,
                            thickness: float = 0.004, ior: float = 1.5,
                            resolution: tuple[int, int] = (64, 64), radial: int = 128,
                            azimuthal: int = 512, source_radius: float = 1e-5
                            ) -> AnalyticScene:
    """The paraboloid of :func:`paraboloid_case` behind a flat clear cover glass.

    The reflected beam is parallel to the axis, so it meets the plate (faces at
    ``cover_z`` and ``cover_z + thickness``, perpendicular to the axis) at normal
    incidence: it is neither shifted nor spread, and all its internal reflection orders
    together keep the slab transmittance T(0) = (1−R)² / (1 − R²), R = ((n−1)/(n+1))².
    The direct light from the focus crosses the plate as in :class:`SlabExact`. Neglected
    (below 1e-4 of the lit-region mean for the defaults): light the plate sends back that
    the mirror returns onto the wall (it passes the focus and leaves at steep angles).
    """
    base = paraboloid_case(flux, f, rim, reflectance, wall_distance, wall_size, resolution,
                           radial, azimuthal, source_radius)
    if not (rim * rim / (4 * f) < cover_z and cover_z + thickness < wall_distance):
        raise InputError("the cover glass must lie between the reflector's rim and the wall")
    half = wall_size / 2
    dz = wall_distance - f
    theta_corner = math.atan(math.hypot(half, half) / dz)
    plate = 2.2 * max(rim, (cover_z + thickness - f) * math.tan(theta_corner) + half)
    slab = prim.slab(thickness, plate, cover_z, ior, 0.0, name="cover")
    src, mirror, wall = base.scene.parts
    scene = Scene([src, mirror, slab, wall], base.frame, channels=1)
    r0 = ((ior - 1.0) / (ior + 1.0)) ** 2
    t0 = (1.0 - r0) ** 2 / (1.0 - r0 * r0)
    direct = SlabExact(flux, dz, thickness, ior, theta_max=min(theta_corner + 0.1, 1.55))

    def exact(h, v):
        r = np.hypot(h, v)
        refl = np.where(r < rim, t0 * paraboloid_reflected_lux(flux, f, reflectance, r), 0.0)
        return refl + direct.lux(r)

    def density(h, v):
        r = np.hypot(h, v)
        refl = np.where(r < rim, paraboloid_reflected_lux(flux, f, 1.0, r), 0.0)
        return (refl + direct.lux(r)) / flux

    return AnalyticScene(
        "covered-paraboloid", "paraboloid behind a cover glass: E = T(0) R Φ / (4π f²) / "
        "(1 + r²/4f²)² + direct through the plate", scene, flux, exact, density,
        base.regions, params={**base.params, "cover_z_m": cover_z, "thickness_m": thickness,
                              "ior": ior, "t0": t0},
        extra={**base.extra, "t0": t0}, radial=True,
        pixel_means=lambda fr: circle_pixel_average(exact, fr, rim))


def slab_case(flux: float = 1000.0, wall_distance: float = 1.0, thickness: float = 0.02,
              ior: float = 1.5, sigma: float = 0.0, z0: float = 0.1, wall_size: float = 1.6,
              resolution: tuple[int, int] = (64, 64), source_radius: float = 1e-5
              ) -> AnalyticScene:
    """Isotropic source, a clear (or absorbing) glass plate, then the wall.

    The answer is :class:`SlabExact`; the profile is checked in rings of the incidence
    angle θ (the θ of the ray that lands there without the plate's small lateral shift).
    """
    half = wall_size / 2
    theta_corner = math.atan(math.hypot(half, half) / wall_distance)
    # the plate must catch every ray that reaches the wall, with its internal bounces
    plate = 2 * (z0 + thickness * 30) * math.tan(theta_corner) + 0.05
    slab = prim.slab(thickness, plate, z0, ior, sigma)
    wall, frame = make_wall(wall_distance, (wall_size, wall_size), resolution=resolution)
    scene = Scene([prim.point_source(flux, radius=source_radius), slab, wall], frame,
                  channels=1)
    ex = SlabExact(flux, wall_distance, thickness, ior, sigma,
                   theta_max=min(theta_corner + 0.1, 1.55))
    theta_edge = math.degrees(math.atan(half / wall_distance))
    degs = np.append(np.arange(0.0, theta_edge - 2.0, 5.0), math.floor(theta_edge - 1.0))
    exact = lambda h, v: ex.lux(np.hypot(h, v))  # noqa: E731
    a0 = math.exp(-sigma * thickness)
    return AnalyticScene(
        "slab-absorbing" if sigma > 0 else "slab",
        f"glass plate n={ior:g}, t={thickness * 1e3:g} mm" + (f", σ={sigma:g}/m"
                                                              if sigma > 0 else "")
        + ": E(θ) × slab transmittance with multiple reflections", scene, flux, exact,
        # photons keep their power through Fresnel choices; absorption scales it by ~a
        lambda h, v: exact(h, v) / (flux * a0),
        _theta_annuli(wall_distance, degs),
        params={"flux_lm": flux, "wall_distance_m": wall_distance, "thickness_m": thickness,
                "ior": ior, "sigma_per_m": sigma, "plate_z_m": z0, "wall_size_m": wall_size},
        extra={"model": ex}, radial=True)


def ring_case(flux: float = 1000.0, radius: float = 0.1, elevation_deg: float = 30.0,
              thickness: float = 1e-3, segments: int = 256, floor_size: float = 0.26,
              resolution: tuple[int, int] = (129, 129), reflectance: float = 0.9
              ) -> AnalyticScene:
    """The coffee-cup caustic: a mirror ring on a floor lit by distant (collimated) light.

    Geometry: which configuration puts the cusp at R/2? Light parallel to the ring's axis
    (straight down into the cup) never meets the vertical wall, so there is no caustic.
    The nephroid is the envelope of rays *parallel to the plane of the circle*; the
    ring's wall is vertical, so reflection flips only the horizontal part of a ray's
    direction and keeps its descent. Oblique light (elevation α above the floor, along
    +X) therefore reflects, in horizontal projection, exactly as parallel rays in a
    circle, and the landing point of a ray reflected at height y lies on its projected
    reflected line, y / tan α beyond the wall. The floor pattern's fold (where the map
    (azimuth, height) → floor point is singular) is exactly the envelope of the
    projected lines: the 2-D nephroid, cusp at x = +R/2 (:func:`nephroid_axis_crossing`),
    provided the paraxial rays reflect low enough: the cusp ray reflects at height
    y = (R/2) tan α. With the ring height H = R tan α every ray that reaches the far wall
    inside passes over the near rim (it is 2R tan α higher there) and the cusp ray
    (y = H/2) is caught.

    The floor (y = 0, facing +Y) is the detector. Wall coordinates: h = −x, v = z, so
    the cusp is at (h, v) = (−R/2, 0). The direct light on the floor is
    E = (Φ / A_beam) sin α outside the shadow of the near wall.
    """
    alpha = math.radians(elevation_deg)
    height = radius * math.tan(alpha)
    ring = prim.cylinder_ring(radius, height, thickness, reflectance, segments=segments)
    d = np.array([math.cos(alpha), -math.sin(alpha), 0.0])
    beam_w = floor_size + 0.04
    beam_h = beam_w
    start = 2.0 * floor_size
    sun = collimated_quad(flux, -start * d, d, beam_w, beam_h, up=(0.0, 0.0, 1.0))
    if sun.vertices[:, 1].min() <= height + 1e-3:
        raise InputError("the collimated emitter intersects the ring: increase its distance")
    floor = prim.floor(floor_size, 0.0, 0.8, name="floor", as_wall=True)
    half = floor_size / 2
    frame = WallFrame(np.zeros(3), np.array([-1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]),
                      np.array([0.0, 1.0, 0.0]), (-half, half), (-half, half), height,
                      tuple(resolution))
    scene = Scene([sun, ring, floor], frame, channels=1)
    e_dir = flux / (beam_w * beam_h) * math.sin(alpha)

    def direct(h, v):
        # lit unless the ray towards the light meets the near wall below its rim
        x, z = -np.asarray(h, float), np.asarray(v, float)
        inside = np.hypot(x, z) < radius
        xw = -np.sqrt(np.maximum(radius**2 - z**2, 0.0))
        shadow = inside & ((x - xw) * math.tan(alpha) < height)
        return np.where(shadow, 0.0, e_dir)

    return AnalyticScene(
        "ring", "mirror ring lit by oblique distant light: nephroid caustic, cusp at R/2",
        scene, flux, None,
        params={"flux_lm": flux, "radius_m": radius, "elevation_deg": elevation_deg,
                "height_m": height, "thickness_m": thickness, "segments": segments,
                "reflectance": reflectance, "floor_size_m": floor_size},
        extra={"cusp_hv": (-radius / 2, 0.0), "direct_lux": e_dir, "direct": direct,
               "axis": "h"})


def lambertian_case(flux: float = 100.0, disk_radius: float = 0.05, distance: float = 0.1,
                    wall_size: float = 0.6, segments: int = 256,
                    resolution: tuple[int, int] = (64, 64)) -> AnalyticScene:
    """A Lambertian disk emitter facing a parallel wall: luminance and illuminance.

    L = Φ / (π A) with A the area of the emitter mesh (a 256-gon); E from Lambert's
    contour integral over that polygon (equal to the disk formula to ~1e-4).
    """
    src = prim.disk_source(flux, disk_radius, segments=segments)
    wall, frame = make_wall(distance, (wall_size, wall_size), resolution=resolution)
    scene = Scene([src, wall], frame)
    polygon = src.vertices[1:]
    tri = src.triangles
    area = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                      axis=1).sum())
    lum = flux / (math.pi * area)

    def exact(h, v):
        pts = frame.to_world(h, v)
        return lambert_polygon_lux(lum, polygon, pts, frame.normal)

    edges = np.linspace(0.0, wall_size / 2, 7)
    regions = _annuli(edges, "E r", "mm", 1e3, None, "{:.0f}")
    return AnalyticScene(
        "lambertian", "Lambertian disk emitter: L = Φ/(πA), E = (Φ/A) a²/(a²+d²) on axis",
        scene, flux, exact, regions=regions,
        params={"flux_lm": flux, "disk_radius_m": disk_radius, "distance_m": distance,
                "wall_size_m": wall_size, "segments": segments, "area_m2": area},
        extra={"luminance": lum,
               "axis_lux": float(disk_lux(lum, disk_radius, distance, np.zeros(1))[0])},
        radial=True)


def shield_case(flux: float = 1000.0, wall_distance: float = 1.0, shield_z: float = 0.25,
                slope_deg: float = 10.0, offset: float = 0.05,
                wall_size: tuple[float, float] = (1.0, 0.5),
                resolution: tuple[int, int] = (64, 32), source_radius: float = 1e-5
                ) -> AnalyticScene:
    """Isotropic point source behind a black shield with a straight edge: an exact cut-off.

    The shield (albedo 0, in the plane z = ``shield_z``) covers y ≥ tan(slope) h +
    offset · z_s / D (h = −x, the wall's horizontal axis), so the wall at z = D is lit
    by the direct light E = Φ D / (4π ρ³), ρ = √(h² + v² + D²), below the line
    v = tan(slope) h + offset and is dark above it: a step of the full E, tilted so
    that pixels straddle it at every offset (like the 15° shoulder of a low beam).
    """
    D = float(wall_distance)
    if not (0 < shield_z < D):
        raise InputError("the shield must lie between the source and the wall")
    t = math.tan(math.radians(slope_deg))
    wall, frame = make_wall(D, wall_size, resolution=resolution)
    src = prim.point_source(flux, radius=source_radius)
    # the shield reaches beyond every wall point's line of sight above the cut-off
    X = 1.5 * (0.5 * wall_size[0]) * shield_z / D + abs(t) * wall_size[0]
    Y = 1.5 * (0.5 * wall_size[1] + abs(t) * wall_size[0]) * shield_z / D + X
    c_s = offset * shield_z / D
    # wall h runs along −x (seen from behind the lamp, looking along +Z): h = −x
    verts = np.array([[X, -t * X + c_s, shield_z], [-X, t * X + c_s, shield_z],
                      [-X, Y, shield_z], [X, Y, shield_z]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    n = np.cross(verts[1] - verts[0], verts[2] - verts[0])
    if n[2] > 0:  # face the source (−Z side)
        faces = faces[:, ::-1].copy()
    shield = Part("shield", SURFACE, verts, faces, None,
                  Material("shield", DIFFUSE, np.zeros(3)))
    scene = Scene([src, shield, wall], frame, channels=1)

    def direct(h, v):
        return flux * D / (4 * math.pi * (h * h + v * v + D * D) ** 1.5)

    def exact(h, v):
        return np.where(v < t * h + offset, direct(h, v), 0.0)

    px = max(frame.pixel_size_m)
    near = lambda h, v: np.abs(v - (t * h + offset)) * math.cos(math.atan(t)) < 1.5 * px  # noqa: E731
    regions = [("lit side", lambda h, v: (v < t * h + offset) & ~near(h, v)),
               ("shadow side", lambda h, v: (v >= t * h + offset) & ~near(h, v))]
    return AnalyticScene(
        "shield", "point source behind a straight black shield edge: "
        "E = Φ D / (4π ρ³) below v = tan(α) h + c, 0 above", scene, flux, exact, None,
        regions, None, None,
        params={"flux_lm": flux, "wall_distance_m": D, "shield_z_m": shield_z,
                "slope_deg": slope_deg, "offset_m": offset, "wall_size_m": list(wall_size)},
        extra={"slope": t, "offset_m": offset},
        pixel_means=lambda fr: step_pixel_average(direct, fr, t, offset))


def closed_box(flux: float = 10.0, albedo: float = 0.7, size: float = 2.0) -> Scene:
    """A point source inside a closed diffuse box of albedo ρ (no wall): energy balance."""
    h = size / 2
    box = prim.box((-h, -h, -h), (h, h, h), Material("box", DIFFUSE, np.full(3, albedo)), "box")
    return Scene([prim.point_source(flux, centre=(0.1 * h, -0.2 * h, 0.05 * h)), box], None,
                 channels=1)


def box_incident_flux(flux: float, albedo: float, max_depth: int) -> float:
    """Flux (lm) arriving at the walls of a closed box, summed over all bounces.

    Φ (1 + ρ + … + ρᴰ⁻¹) = Φ (1 − ρᴰ) / (1 − ρ): every arrival reflects ρ of its flux,
    none escapes; the tracer ends paths after D bounces (Russian roulette is unbiased).
    """
    return flux * (1.0 - albedo**max_depth) / (1.0 - albedo)
