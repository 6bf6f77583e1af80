"""Materials: the table the tracer reads, and the numba kernels of surface optics.

Three kinds of surface, as glTF materials map onto them (see docs/reference/conventions.md):

=============  =======================================  =========  ===========================
kind           parameter                                unit       default
=============  =======================================  =========  ===========================
``diffuse``    albedo ρ (RGB, Lambertian reflectance)    –          baseColorFactor (0.5 grey
                                                                   for a part with no material)
``mirror``     reflectance R (RGB, specular)            –          baseColorFactor
``dielectric`` index of refraction n                    –          1.5 (glTF default)
``dielectric`` absorption coefficient σ (RGB)           1/m        0 (clear); −ln(c)/d from
                                                                   KHR_materials_volume
=============  =======================================  =========  ===========================

The outside of every dielectric is air (n = 1). Fresnel reflectance is the exact
unpolarised one; beyond the critical angle light is totally reflected. Light travelling a
distance t inside a dielectric keeps exp(−σ t) of its flux (Beer–Lambert).

The tracer runs one luminous channel unless a material is coloured (RGB albedo or
attenuation not grey); then three channels. With one channel a material's value is its
luminance-weighted mean (Rec. 709 weights), which is exact for grey materials.

BSDF kernels
------------
Each kind of surface is one numba function with one signature (see :data:`BSDF_SIGNATURE`),
plus the wall detector (kind :data:`WALL`, a diffuse surface that records and ends the
photon); :func:`scatter` dispatches on the kind and is what the tracer calls per hit. A
kernel samples the outgoing direction of one photon, scales its flux ``power[i]`` in place
by the surface's throughput and adds what the surface took (absorbed, or detected by the
wall) to ``ledger[row, col]``. The photon is given as arrays and row indices, not as row
views: a view made per photon costs reference counting in the tracer's loop.

=================  ========================================================  ==========
argument           meaning                                                   unit
=================  ========================================================  ==========
``mats``           :class:`MaterialArrays` (kind, value, ior, sigma)          –, 1/m
``m``              material index                                            –
``d``              incident unit direction (dx, dy, dz)                      –
``ng``             unit geometric normal on the side the photon came from    –
``ns``             unit shading normal on that side (= ng for diffuse)        –
``front``          the photon arrives on the front (outside) face             –
``t``              distance travelled to the hit (Beer–Lambert inside glass)  m
``key``, ``ctr``   random-number key and counter base of this bounce:        –
                   ``ctr`` the dielectric's Fresnel choice, ``ctr + 2`` and
                   ``ctr + 3`` the diffuse direction
``power``, ``i``   (n, C) photon flux, row ``i`` scaled in place              tracer units
``ledger``,        (rows, columns, C) energy ledger: the flux the surface      tracer units
``row``, ``col``   took is added to ``ledger[row, col]``
returns            (wx, wy, wz, side): outgoing direction (not normalised)    –
                   and side +1 reflected, −1 transmitted, 0 ended
=================  ========================================================  ==========
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from lightsim.errors import InputError
from lightsim.io.gltf_check import check_material
from lightsim.sampling import uniform

DIFFUSE, MIRROR, DIELECTRIC = 0, 1, 2
WALL = 3  # the measurement wall: a detector, not a material of the table
KIND_NAMES = {DIFFUSE: "diffuse", MIRROR: "mirror", DIELECTRIC: "dielectric", WALL: "wall"}
BSDF_SIGNATURE = ("(mats, m, d, ng, ns, front, t, key, ctr, power, i, ledger, row, col)"
                  " -> (wx, wy, wz, side)")
LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 luminance weights of linear RGB


@dataclass
class Material:
    """One material.

    Attributes
    ----------
    name : str
    kind : int
        DIFFUSE, MIRROR or DIELECTRIC.
    rgb : (3,) array
        Albedo (diffuse) or reflectance (mirror), linear RGB in [0, 1]; unused for
        dielectrics.
    ior : float
        Index of refraction (dielectric only).
    sigma : (3,) array
        Absorption coefficient (1/m) per channel (dielectric only).
    """

    name: str
    kind: int
    rgb: np.ndarray = field(default_factory=lambda: np.ones(3))
    ior: float = 1.5
    sigma: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        self.rgb = np.asarray(self.rgb, dtype=np.float64).reshape(3)
        self.sigma = np.asarray(self.sigma, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(self.rgb)) or np.any(self.rgb < 0) or np.any(self.rgb > 1):
            raise InputError(f"material '{self.name}': colour/reflectance must lie in [0, 1], "
                             f"got {self.rgb.tolist()}")
        if self.kind == DIELECTRIC:
            if not math.isfinite(self.ior) or self.ior < 1.0:
                raise InputError(f"material '{self.name}': index of refraction must be ≥ 1, "
                                 f"got {self.ior}")
            if not np.all(np.isfinite(self.sigma)) or np.any(self.sigma < 0):
                raise InputError(f"material '{self.name}': absorption must be ≥ 0 and finite")

    @property
    def coloured(self) -> bool:
        """True if the material treats red, green and blue differently."""
        if self.kind == DIELECTRIC:
            return bool(np.ptp(self.sigma) > 1e-12)
        return bool(np.ptp(self.rgb) > 1e-12)

    def describe(self) -> str:
        if self.kind == DIELECTRIC:
            extra = f", σ={self.sigma.round(4).tolist()} 1/m" if np.any(self.sigma > 0) else ""
            return f"dielectric n={self.ior:g}{extra}"
        word = "albedo" if self.kind == DIFFUSE else "reflectance"
        return f"{KIND_NAMES[self.kind]} {word}={self.rgb.round(4).tolist()}"


def material_from_gltf(name: str, mat: dict) -> tuple[Material, bool]:
    """Map a glTF material JSON to a :class:`Material`.

    Every field read is checked first (:func:`lightsim.io.gltf_check.check_material`):
    numbers must be finite and in the glTF range, ``emissiveFactor`` non-negative.

    Returns
    -------
    material : Material
    emissive : bool
        True if the material has a non-zero ``emissiveFactor`` (the part is an emitter).

    Raises
    ------
    InputError
        One line naming the material and the field.
    """
    mat_name = mat.get("name") if isinstance(mat, dict) else None
    mat_name = mat_name if isinstance(mat_name, str) and mat_name else name
    check_material(f"material '{mat_name}'", mat)
    pbr = mat.get("pbrMetallicRoughness", {})
    base = np.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]), dtype=np.float64)[:3]
    if not mat:
        base = np.full(3, 0.5)  # a CAD part without material: grey diffuse, not glTF's metal
    metallic = float(pbr.get("metallicFactor", 1.0)) if mat else 0.0
    ext = mat.get("extensions", {})
    emissive = np.asarray(mat.get("emissiveFactor", [0.0, 0.0, 0.0]), dtype=np.float64)
    is_emissive = bool(np.any(emissive > 0))
    transmission = float(ext.get("KHR_materials_transmission", {}).get("transmissionFactor", 0))
    if transmission > 0:
        ior = float(ext.get("KHR_materials_ior", {}).get("ior", 1.5))
        vol = ext.get("KHR_materials_volume", {})
        sigma = np.zeros(3)
        dist = vol.get("attenuationDistance")
        if dist is not None and math.isfinite(dist):  # +inf (glTF's default): no absorption
            color = np.asarray(vol.get("attenuationColor", [1.0, 1.0, 1.0]), dtype=np.float64)
            sigma = np.maximum(-np.log(color) / float(dist), 0.0)
        return Material(mat_name, DIELECTRIC, np.ones(3), ior, sigma), is_emissive
    if metallic >= 0.5:
        return Material(mat_name, MIRROR, base), is_emissive
    return Material(mat_name, DIFFUSE, base), is_emissive


class MaterialArrays(NamedTuple):
    """The material table as the numba kernels read it (one row per material).

    Attributes
    ----------
    kind : (n,) int32
        DIFFUSE, MIRROR or DIELECTRIC.
    value : (n, C) float64
        Albedo (diffuse) or reflectance (mirror) per channel, in [0, 1].
    ior : (n,) float64
        Index of refraction (dielectric; outside is air).
    sigma : (n, C) float64
        Absorption coefficient per channel (1/m, dielectric).
    """

    kind: np.ndarray
    value: np.ndarray
    ior: np.ndarray
    sigma: np.ndarray


@dataclass
class MaterialTable:
    """Materials as flat arrays for the numba kernels.

    Attributes
    ----------
    kind : (n,) int32
    value : (n, C) float64
        Albedo or reflectance per channel.
    ior : (n,) float64
    sigma : (n, C) float64
        Absorption coefficient (1/m) per channel.
    """

    materials: list[Material]
    channels: int
    kind: np.ndarray
    value: np.ndarray
    ior: np.ndarray
    sigma: np.ndarray

    @classmethod
    def build(cls, materials: list[Material], channels: int | None = None) -> MaterialTable:
        """Flatten ``materials``; ``channels`` defaults to 3 if any is coloured, else 1."""
        if channels is None:
            channels = 3 if any(m.coloured for m in materials) else 1
        n = len(materials)
        kind = np.array([m.kind for m in materials], dtype=np.int32)
        ior = np.array([m.ior for m in materials], dtype=np.float64)
        rgb = np.array([m.rgb for m in materials], dtype=np.float64).reshape(n, 3)
        sig = np.array([m.sigma for m in materials], dtype=np.float64).reshape(n, 3)
        if channels == 1:
            value, sigma = (rgb @ LUMA)[:, None], (sig @ LUMA)[:, None]
        else:
            value, sigma = rgb, sig
        return cls(materials, channels, kind, np.ascontiguousarray(value), ior,
                   np.ascontiguousarray(sigma))

    @property
    def coloured(self) -> bool:
        return any(m.coloured for m in self.materials)

    @property
    def arrays(self) -> MaterialArrays:
        """The table for the numba kernels."""
        return MaterialArrays(self.kind, self.value, self.ior, self.sigma)


# --------------------------------------------------------------------------------------
# Fresnel reflectance
# --------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def fresnel_dielectric(cos_i: float, eta_i: float, eta_t: float) -> float:
    """Exact unpolarised Fresnel reflectance; 1 beyond the critical angle.

    Parameters
    ----------
    cos_i : float
        Cosine of the angle of incidence (≥ 0).
    eta_i, eta_t : float
        Refractive indices of the incident and transmitted media.
    """
    cos_i = min(max(cos_i, 0.0), 1.0)
    sin2_t = (eta_i / eta_t) ** 2 * (1.0 - cos_i * cos_i)
    if sin2_t >= 1.0:
        return 1.0
    cos_t = math.sqrt(1.0 - sin2_t)
    rs = (eta_i * cos_i - eta_t * cos_t) / (eta_i * cos_i + eta_t * cos_t)
    rp = (eta_t * cos_i - eta_i * cos_t) / (eta_t * cos_i + eta_i * cos_t)
    return 0.5 * (rs * rs + rp * rp)


def slab_transmittance(n: float, cos_i: float = 1.0, absorption: float = 1.0) -> float:
    """Transmittance of a parallel slab with incoherent multiple reflections.

    T = (1−R)² a / (1 − R² a²), with R the single-surface Fresnel reflectance and a the
    internal single-pass transmittance (exp(−σ t / cos θ_t)). Without absorption this is
    (1−R)/(1+R): 0.9231 for n = 1.5 at normal incidence.
    """
    r = fresnel_dielectric(cos_i, 1.0, n)
    return (1.0 - r) ** 2 * absorption / (1.0 - r * r * absorption * absorption)


# --------------------------------------------------------------------------------------
# Direction cores (scalars in, scalars out; unit vectors, normals on the incident side)
# --------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def cosine_direction(nx: float, ny: float, nz: float, u1: float, u2: float
                     ) -> tuple[float, float, float]:
    """Cosine-distributed unit direction about the unit normal n (Lambert), u1, u2 in [0, 1)."""
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    lx, ly, lz = r * math.cos(phi), r * math.sin(phi), math.sqrt(max(0.0, 1.0 - u1))
    # orthonormal basis around n without branches on the axes (Duff et al. 2017)
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (lx * (1.0 + sign * nx * nx * a) + ly * b + lz * nx,
            lx * (sign * b) + ly * (sign + ny * ny * a) + lz * ny,
            lx * (-sign * nx) + ly * (-ny) + lz * nz)


@njit(cache=True, inline="always")
def mirror_direction(dx, dy, dz, sx, sy, sz, fgx, fgy, fgz):
    """Reflection of d about the shading normal s, or about the geometric normal g where
    s would send it through the surface. Returns the unnormalised outgoing direction."""
    c_i = dx * sx + dy * sy + dz * sz
    wx, wy, wz = dx - 2 * c_i * sx, dy - 2 * c_i * sy, dz - 2 * c_i * sz
    if wx * fgx + wy * fgy + wz * fgz <= 0.0:
        c_i = dx * fgx + dy * fgy + dz * fgz
        wx, wy, wz = dx - 2 * c_i * fgx, dy - 2 * c_i * fgy, dz - 2 * c_i * fgz
    return wx, wy, wz


@njit(cache=True, inline="always")
def dielectric_direction(dx, dy, dz, sx, sy, sz, fgx, fgy, fgz, front, ior, key, ctr):
    """The Fresnel choice (random number ``ctr``) and Snell refraction of
    :func:`dielectric_bsdf`: returns (wx, wy, wz, side), the unnormalised outgoing
    direction and side +1 reflected, −1 transmitted."""
    eta_i, eta_t = (1.0, ior) if front else (ior, 1.0)
    cos_i = -(dx * sx + dy * sy + dz * sz)
    nsx, nsy, nsz = sx, sy, sz
    if cos_i <= 0.0:  # shading normal faces away: use the geometric one
        nsx, nsy, nsz = fgx, fgy, fgz
        cos_i = -(dx * fgx + dy * fgy + dz * fgz)
    F = fresnel_dielectric(cos_i, eta_i, eta_t)
    if uniform(key, ctr) < F:
        wx, wy, wz = dx + 2 * cos_i * nsx, dy + 2 * cos_i * nsy, dz + 2 * cos_i * nsz
        side = 1.0
        if wx * fgx + wy * fgy + wz * fgz <= 0.0:
            c_g = -(dx * fgx + dy * fgy + dz * fgz)
            wx, wy, wz = dx + 2 * c_g * fgx, dy + 2 * c_g * fgy, dz + 2 * c_g * fgz
        return wx, wy, wz, side
    eta = eta_i / eta_t
    cos_t = math.sqrt(max(0.0, 1.0 - eta * eta * (1.0 - cos_i * cos_i)))
    f = eta * cos_i - cos_t
    wx, wy, wz = eta * dx + f * nsx, eta * dy + f * nsy, eta * dz + f * nsz
    side = -1.0
    if wx * fgx + wy * fgy + wz * fgz >= 0.0:
        # the shading normal bent the ray back: refract about the geometry
        c_g = -(dx * fgx + dy * fgy + dz * fgz)
        s2 = eta * eta * (1.0 - c_g * c_g)
        if s2 < 1.0:
            f = eta * c_g - math.sqrt(1.0 - s2)
            wx = eta * dx + f * fgx
            wy = eta * dy + f * fgy
            wz = eta * dz + f * fgz
        else:
            wx, wy, wz = dx + 2 * c_g * fgx, dy + 2 * c_g * fgy, dz + 2 * c_g * fgz
            side = 1.0
    return wx, wy, wz, side


# --------------------------------------------------------------------------------------
# BSDF kernels: one per kind, one signature (see the module docstring), and the dispatch
# --------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def wall_bsdf(mats, m, d, ng, ns, front, t, key, ctr, power, i, ledger, row, col):
    """The measurement wall: all flux is detected (booked to ``ledger[row, col]``), the
    photon ends."""
    for c in range(power.shape[1]):
        ledger[row, col, c] += power[i, c]
        power[i, c] = 0.0
    return d[0], d[1], d[2], 0.0


@njit(cache=True, inline="always")
def diffuse_bsdf(mats, m, d, ng, ns, front, t, key, ctr, power, i, ledger, row, col):
    """Lambertian reflection: (1 − ρ) absorbed, the rest leaves cosine-distributed about ng
    (random numbers ``ctr + 2``, ``ctr + 3``).

    Reflection only, on the side the photon came from; the shading normal is not used.
    """
    for c in range(power.shape[1]):
        rho = mats.value[m, c]
        ledger[row, col, c] += (1.0 - rho) * power[i, c]
        power[i, c] *= rho
    wx, wy, wz = cosine_direction(ng[0], ng[1], ng[2], uniform(key, ctr + np.uint64(2)),
                                  uniform(key, ctr + np.uint64(3)))
    return wx, wy, wz, 1.0


@njit(cache=True, inline="always")
def mirror_bsdf(mats, m, d, ng, ns, front, t, key, ctr, power, i, ledger, row, col):
    """Perfect specular reflection about ns with reflectance R; (1 − R) absorbed.

    Where the shading normal would reflect the photon through the geometric surface, the
    reflection is about ng instead (:func:`mirror_direction`).
    """
    for c in range(power.shape[1]):
        r = mats.value[m, c]
        ledger[row, col, c] += (1.0 - r) * power[i, c]
        power[i, c] *= r
    wx, wy, wz = mirror_direction(d[0], d[1], d[2], ns[0], ns[1], ns[2], ng[0], ng[1], ng[2])
    return wx, wy, wz, 1.0


@njit(cache=True, inline="always")
def dielectric_bsdf(mats, m, d, ng, ns, front, t, key, ctr, power, i, ledger, row, col):
    """Smooth dielectric (air outside): Beer–Lambert for a path inside, then Fresnel.

    A photon arriving from inside (``front`` false) first keeps exp(−σ t) of its flux
    (the rest is absorbed). It then reflects with probability F (exact unpolarised
    Fresnel; F = 1 beyond the critical angle; random number ``ctr``) or refracts by
    Snell's law; the flux is unchanged by the choice (the choice is the weighting).
    Shading normals that would send the photon to the wrong side are replaced by the
    geometric normal (:func:`dielectric_direction`).
    """
    if not front:  # the photon travelled inside this material: Beer–Lambert
        for c in range(power.shape[1]):
            s = mats.sigma[m, c]
            if s > 0.0:
                keep = math.exp(-s * t)
                ledger[row, col, c] += (1.0 - keep) * power[i, c]
                power[i, c] *= keep
    return dielectric_direction(d[0], d[1], d[2], ns[0], ns[1], ns[2], ng[0], ng[1], ng[2],
                                front, mats.ior[m], key, ctr)


@njit(cache=True, inline="always")
def scatter(kind, mats, m, d, ng, ns, front, t, key, ctr, power, i, ledger, row, col):
    """The BSDF kernel of ``kind`` (DIFFUSE, MIRROR, DIELECTRIC or WALL) applied to one
    photon: the tracer's one entry to the surface optics. Arguments and return value as
    every kernel's (:data:`BSDF_SIGNATURE`)."""
    if kind == DIFFUSE:
        return diffuse_bsdf(mats, m, d, ng, ns, front, t, key, ctr, power, i, ledger, row, col)
    if kind == MIRROR:
        return mirror_bsdf(mats, m, d, ng, ns, front, t, key, ctr, power, i, ledger, row, col)
    if kind == DIELECTRIC:
        return dielectric_bsdf(mats, m, d, ng, ns, front, t, key, ctr, power, i, ledger, row,
                               col)
    return wall_bsdf(mats, m, d, ng, ns, front, t, key, ctr, power, i, ledger, row, col)
