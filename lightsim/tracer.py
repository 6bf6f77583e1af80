"""Wavefront photon tracer: emission, embree ray casting, surface interaction, bookkeeping.

Each bounce casts the whole active wavefront with embree (threads, GIL released), then one
parallel numba kernel applies the surface optics to every ray:

* **wall** (detector): the photon is recorded and ends there;
* **diffuse**: the photon is recorded (if recording all surfaces), (1 − ρ) of its flux is
  absorbed and it continues in a cosine-distributed direction with ρ of it;
* **mirror**: (1 − R) is absorbed, the rest reflects about the shading normal;
* **dielectric**: Beer–Lambert absorption along the path just travelled inside, then exact
  unpolarised Fresnel: reflect with probability F (always beyond the critical angle),
  otherwise refract by Snell's law (flux unchanged: the choice itself is the weighting).

Russian roulette ends photons whose flux fell below a fraction of their emitted flux; a
survivor's flux is divided by its survival probability. Energy bookkeeping is exact, not
statistical: every lumen of every photon is booked to exactly one of *wall*, *absorbed*
(diffuse, mirror, volume), *escaped*, *roulette* (net of the flux added to survivors) or
*max depth*; the parts sum to the emitted flux to rounding.

Shading normals: on mirrors and dielectrics the vertex normals are interpolated
barycentrically (glTF ``NORMAL``); where a shading normal would send the ray through the
geometric surface (grazing light on a coarse mesh) the geometric normal is used instead.

=================  =====  ========  ===================================================
parameter          unit   default   meaning
=================  =====  ========  ===================================================
``max_depth``      –      32        bounces before a photon is ended (booked max_depth)
``rr_threshold``   –      0.05      roulette when flux < this × emitted flux
``rr_min_depth``   –      3         no roulette before this many bounces
``record``         –      ``wall``  ``wall``: record only wall photons; ``all``: every
                                    diffuse hit (needed by camera views)
``batch``          photon 262144    photons per wavefront batch (memory bound)
=================  =====  ========  ===================================================

Ray origins are pushed off the surface by ε = 2⁻¹⁸ · (|p|∞ + 0.01 · scene scale) along the
geometric normal (≈ 32 float32 ulps): enough at a wall 1 km away, small next to a 0.7 mm
glass wall at 0.1 m from the origin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange

from lightsim.materials import DIFFUSE, LUMA, MIRROR, fresnel_dielectric
from lightsim.raycast import RayCaster
from lightsim.sampling import uniform

# bookkeeping categories (columns of the ledger)
LEDGER = ("wall", "absorbed_diffuse", "absorbed_mirror", "absorbed_volume", "escaped",
          "roulette", "max_depth")
L_WALL, L_ABS_DIFF, L_ABS_MIRR, L_ABS_VOL, L_ESC, L_RR, L_MAXD = range(len(LEDGER))

EMISSION_MODES = ("isotropic", "lambertian", "collimated", "goniometric", "rayfile")

# photon flags
F_SPECULAR = np.uint8(1)  # the path had at least one specular bounce (caustic path)
F_DIFFUSE = np.uint8(2)   # the path had at least one diffuse bounce (indirect light)

# ray status after an interaction
ALIVE, ENDED = 0, 1


# ------------------------------------------------------------------------------------------
# Emission
# ------------------------------------------------------------------------------------------

@dataclass
class EmitterTable:
    """All emitters as arrays: mesh triangles with a flux × area CDF, and point sources
    with an intensity distribution (IES/LDT).

    Attributes
    ----------
    triangles : (E, 3, 3) float64
    normals : (E, 3) float64
        Outward face normals (Lambertian and collimated emission).
    mode : (E,) int8
        0 isotropic, 1 Lambertian, 2 collimated (along the face normal: a distant source).
    cdf : (E,) float64
        Cumulative probability of emitting from each triangle.
    flux : float
        Total luminous flux Φ (lm) of all emitters.
    mesh_share : float
        Fraction of Φ that mesh emitters carry; the rest comes from ``points``.
    points : list of (position (3,), CandelaGrid, flux lm)
    """

    triangles: np.ndarray
    normals: np.ndarray
    mode: np.ndarray
    cdf: np.ndarray
    flux: float
    mesh_share: float = 1.0
    points: list = field(default_factory=list)

    @classmethod
    def from_scene(cls, scene) -> EmitterTable:
        tris, norms, modes, weights, points = [], [], [], [], []
        for p in scene.emitters:
            if p.distribution is not None:
                points.append((p.vertices.mean(axis=0), p.distribution, p.flux_lm))
                continue
            t = p.triangles
            n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
            area = 0.5 * np.linalg.norm(n, axis=1)
            tris.append(t)
            norms.append(n / np.maximum(2 * area[:, None], 1e-300))
            modes.append(np.full(len(t), EMISSION_MODES.index(p.emission), np.int8))
            weights.append(p.flux_lm * area / area.sum())
        total = float(scene.total_flux)
        if tris:
            w = np.concatenate(weights)
            cdf = np.cumsum(w) / w.sum()
            cdf[-1] = 1.0
            mesh_flux = float(w.sum())
            return cls(np.concatenate(tris), np.concatenate(norms), np.concatenate(modes), cdf,
                       total, mesh_flux / total, points)
        return cls(np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, np.int8), np.zeros(0),
                   total, 0.0, points)


@njit(cache=True, inline="always")
def _cosine_direction(nx, ny, nz, u1, u2):
    """Cosine-distributed unit direction about the unit normal n (Lambert)."""
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


@njit(cache=True, parallel=True)
def _emit_kernel(u, tris, normals, mode, cdf):
    n = u.shape[0]
    origin = np.empty((n, 3))
    direction = np.empty((n, 3))
    for i in prange(n):
        k = np.searchsorted(cdf, u[i, 2], side="right")
        if k >= cdf.shape[0]:
            k = cdf.shape[0] - 1
        s = math.sqrt(u[i, 3])
        b1 = s * (1.0 - u[i, 4])
        b2 = s * u[i, 4]
        b0 = 1.0 - b1 - b2
        for j in range(3):
            origin[i, j] = b0 * tris[k, 0, j] + b1 * tris[k, 1, j] + b2 * tris[k, 2, j]
        phi = 2.0 * math.pi * u[i, 1]
        if mode[k] == 2:
            for j in range(3):
                direction[i, j] = normals[k, j]
        elif mode[k] == 1:
            dx, dy, dz = _cosine_direction(normals[k, 0], normals[k, 1], normals[k, 2],
                                           u[i, 0], u[i, 1])
            direction[i, 0], direction[i, 1], direction[i, 2] = dx, dy, dz
        else:
            z = 1.0 - 2.0 * u[i, 0]
            r = math.sqrt(max(0.0, 1.0 - z * z))
            direction[i, 0] = r * math.cos(phi)
            direction[i, 1] = r * math.sin(phi)
            direction[i, 2] = z
    return origin, direction


def emit(table: EmitterTable, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Photon origins (m) and unit directions from sample points (n, 5) in [0, 1).

    Dimension 2 first chooses between mesh emitters and point sources by flux, then the
    triangle (or the point source); its remainder is reused so the choice stays
    stratified.
    """
    u = np.ascontiguousarray(points, dtype=np.float64)
    if not table.points:
        return _emit_kernel(u, table.triangles, table.normals, table.mode, table.cdf)
    from lightsim.luminaires.photometric import sample_directions

    origin = np.empty((len(u), 3))
    direction = np.empty((len(u), 3))
    share = table.mesh_share
    mesh = u[:, 2] < share
    if np.any(mesh):
        um = u[mesh].copy()
        um[:, 2] = np.minimum(um[:, 2] / share, np.nextafter(1.0, 0.0))
        origin[mesh], direction[mesh] = _emit_kernel(um, table.triangles, table.normals,
                                                     table.mode, table.cdf)
    fluxes = np.array([f for _, _, f in table.points])
    edges = share + (1.0 - share) * np.concatenate([[0.0], np.cumsum(fluxes) / fluxes.sum()])
    for k, (pos, grid, _) in enumerate(table.points):
        sel = (~mesh) & (u[:, 2] >= edges[k]) & ((u[:, 2] < edges[k + 1])
                                                  | (k == len(table.points) - 1))
        if np.any(sel) and hasattr(grid, "sample_rays"):  # a ray file (lightsim.raysource)
            origin[sel], direction[sel] = grid.sample_rays(u[sel])
        elif np.any(sel):
            origin[sel] = pos
            direction[sel] = sample_directions(grid, u[sel, 0], u[sel, 1])[0]
    return origin, direction


# ------------------------------------------------------------------------------------------
# Surface interaction kernel
# ------------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _offset(px, py, pz, nx, ny, nz, sign, eps_floor):
    eps = 3.814697265625e-06 * (max(abs(px), abs(py), abs(pz)) + eps_floor)
    return px + sign * eps * nx, py + sign * eps * ny, pz + sign * eps * nz


@njit(cache=True, parallel=True)
def _interact(o, d, power, p_ref, flags, keys, depth, prim, tfar, bu, bv,
              tri_v, face_n, corner_n, tri_part, is_wall,
              mat_kind, mat_value, mat_ior, mat_sigma,
              eps_floor, rr_threshold, rr_min_depth, last_bounce, record_all,
              status, rec, rec_pos, rec_nrm, rec_pow, rec_part, rec_flag, ledger, lid):
    # ledger rows are per emitted photon (lid): summed once per batch, in photon order
    n = o.shape[0]
    C = power.shape[1]
    for i in prange(n):
        j = lid[i]
        status[i] = ALIVE
        rec[i] = False
        k = prim[i]
        if k < 0:  # escaped to infinity
            for c in range(C):
                ledger[j, L_ESC, c] += power[i, c]
                power[i, c] = 0.0
            status[i] = ENDED
            continue
        t = float(tfar[i])
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        # the hit point from barycentrics lies on the triangle (o + t·d with a float32 t
        # can land just outside a neighbouring face at an edge and leak out of a box)
        b1 = min(max(float(bu[i]), 0.0), 1.0)
        b2 = min(max(float(bv[i]), 0.0), 1.0 - b1)
        # pulled strictly inside the triangle: a point on an edge lies on the plane of the
        # adjacent face too, and the normal offset alone would not clear that face
        b1 = (b1 + 1e-6) / (1.0 + 3e-6)
        b2 = (b2 + 1e-6) / (1.0 + 3e-6)
        b0 = 1.0 - b1 - b2
        px = b0 * tri_v[k, 0, 0] + b1 * tri_v[k, 1, 0] + b2 * tri_v[k, 2, 0]
        py = b0 * tri_v[k, 0, 1] + b1 * tri_v[k, 1, 1] + b2 * tri_v[k, 2, 1]
        pz = b0 * tri_v[k, 0, 2] + b1 * tri_v[k, 1, 2] + b2 * tri_v[k, 2, 2]
        gx, gy, gz = face_n[k, 0], face_n[k, 1], face_n[k, 2]
        cos_g = dx * gx + dy * gy + dz * gz
        front = cos_g < 0.0
        # facing geometric normal: on the side the photon came from
        fs = 1.0 if front else -1.0
        fgx, fgy, fgz = fs * gx, fs * gy, fs * gz
        m = tri_part[k]
        kind = mat_kind[m]
        key = keys[i]
        ctr = np.uint64(depth * 8)

        if is_wall[k] or kind == DIFFUSE:
            if is_wall[k] or record_all:
                rec[i] = True
                rec_pos[i, 0], rec_pos[i, 1], rec_pos[i, 2] = px, py, pz
                rec_nrm[i, 0], rec_nrm[i, 1], rec_nrm[i, 2] = fgx, fgy, fgz
                for c in range(C):
                    rec_pow[i, c] = power[i, c]
                rec_part[i] = m
                rec_flag[i] = flags[i]
            if is_wall[k]:
                for c in range(C):
                    ledger[j, L_WALL, c] += power[i, c]
                    power[i, c] = 0.0
                status[i] = ENDED
                continue
            for c in range(C):
                rho = mat_value[m, c]
                ledger[j, L_ABS_DIFF, c] += (1.0 - rho) * power[i, c]
                power[i, c] *= rho
            nx_, ny_, nz_ = _cosine_direction(fgx, fgy, fgz, uniform(key, ctr + np.uint64(2)),
                                              uniform(key, ctr + np.uint64(3)))
            flags[i] |= F_DIFFUSE
            out_side = 1.0
        else:
            # interpolated shading normal, oriented like the geometric one
            w0 = 1.0 - bu[i] - bv[i]
            sx = w0 * corner_n[k, 0, 0] + bu[i] * corner_n[k, 1, 0] + bv[i] * corner_n[k, 2, 0]
            sy = w0 * corner_n[k, 0, 1] + bu[i] * corner_n[k, 1, 1] + bv[i] * corner_n[k, 2, 1]
            sz = w0 * corner_n[k, 0, 2] + bu[i] * corner_n[k, 1, 2] + bv[i] * corner_n[k, 2, 2]
            ln = math.sqrt(sx * sx + sy * sy + sz * sz)
            if ln > 1e-12:
                sx, sy, sz = fs * sx / ln, fs * sy / ln, fs * sz / ln
            else:
                sx, sy, sz = fgx, fgy, fgz
            flags[i] |= F_SPECULAR
            if kind == MIRROR:
                for c in range(C):
                    rr_ = mat_value[m, c]
                    ledger[j, L_ABS_MIRR, c] += (1.0 - rr_) * power[i, c]
                    power[i, c] *= rr_
                c_i = dx * sx + dy * sy + dz * sz
                nx_, ny_, nz_ = dx - 2 * c_i * sx, dy - 2 * c_i * sy, dz - 2 * c_i * sz
                if nx_ * fgx + ny_ * fgy + nz_ * fgz <= 0.0:
                    c_i = dx * fgx + dy * fgy + dz * fgz
                    nx_, ny_, nz_ = dx - 2 * c_i * fgx, dy - 2 * c_i * fgy, dz - 2 * c_i * fgz
                out_side = 1.0
            else:  # DIELECTRIC
                if not front:  # we travelled inside this material: Beer–Lambert
                    for c in range(C):
                        s_ = mat_sigma[m, c]
                        if s_ > 0.0:
                            keep = math.exp(-s_ * t)
                            ledger[j, L_ABS_VOL, c] += (1.0 - keep) * power[i, c]
                            power[i, c] *= keep
                eta_i, eta_t = (1.0, mat_ior[m]) if front else (mat_ior[m], 1.0)
                cos_i = -(dx * sx + dy * sy + dz * sz)
                nsx, nsy, nsz = sx, sy, sz
                if cos_i <= 0.0:  # shading normal faces away: use the geometric one
                    nsx, nsy, nsz = fgx, fgy, fgz
                    cos_i = -(dx * fgx + dy * fgy + dz * fgz)
                F = fresnel_dielectric(cos_i, eta_i, eta_t)
                if uniform(key, ctr) < F:
                    nx_, ny_, nz_ = dx + 2 * cos_i * nsx, dy + 2 * cos_i * nsy, dz + 2 * cos_i * nsz
                    out_side = 1.0
                    if nx_ * fgx + ny_ * fgy + nz_ * fgz <= 0.0:
                        c_g = -(dx * fgx + dy * fgy + dz * fgz)
                        nx_, ny_, nz_ = dx + 2 * c_g * fgx, dy + 2 * c_g * fgy, dz + 2 * c_g * fgz
                else:
                    eta = eta_i / eta_t
                    cos_t = math.sqrt(max(0.0, 1.0 - eta * eta * (1.0 - cos_i * cos_i)))
                    f = eta * cos_i - cos_t
                    nx_, ny_, nz_ = eta * dx + f * nsx, eta * dy + f * nsy, eta * dz + f * nsz
                    out_side = -1.0
                    if nx_ * fgx + ny_ * fgy + nz_ * fgz >= 0.0:
                        # the shading normal bent the ray back: refract about the geometry
                        c_g = -(dx * fgx + dy * fgy + dz * fgz)
                        s2 = eta * eta * (1.0 - c_g * c_g)
                        if s2 < 1.0:
                            f = eta * c_g - math.sqrt(1.0 - s2)
                            nx_ = eta * dx + f * fgx
                            ny_ = eta * dy + f * fgy
                            nz_ = eta * dz + f * fgz
                        else:
                            nx_, ny_, nz_ = (dx + 2 * c_g * fgx, dy + 2 * c_g * fgy,
                                             dz + 2 * c_g * fgz)
                            out_side = 1.0
        ln = math.sqrt(nx_ * nx_ + ny_ * ny_ + nz_ * nz_)
        d[i, 0], d[i, 1], d[i, 2] = nx_ / ln, ny_ / ln, nz_ / ln
        o[i, 0], o[i, 1], o[i, 2] = _offset(px, py, pz, fgx, fgy, fgz, out_side, eps_floor)

        # Russian roulette on weak photons, then the depth limit
        pmax = 0.0
        for c in range(C):
            pmax = max(pmax, power[i, c])
        if pmax <= 0.0:
            status[i] = ENDED
            continue
        if depth + 1 >= rr_min_depth and pmax < rr_threshold * p_ref[i]:
            q = pmax / (rr_threshold * p_ref[i])
            if uniform(key, ctr + np.uint64(1)) >= q:
                for c in range(C):
                    ledger[j, L_RR, c] += power[i, c]
                    power[i, c] = 0.0
                status[i] = ENDED
                continue
            for c in range(C):
                boost = power[i, c] / q - power[i, c]
                ledger[j, L_RR, c] -= boost
                power[i, c] += boost
        if last_bounce:
            for c in range(C):
                ledger[j, L_MAXD, c] += power[i, c]
                power[i, c] = 0.0
            status[i] = ENDED


# ------------------------------------------------------------------------------------------
# Driver
# ------------------------------------------------------------------------------------------

@dataclass
class PhotonRecords:
    """Photons recorded on diffuse surfaces (incident flux).

    Attributes
    ----------
    position : (n, 3) float32
        Hit point (m).
    normal : (n, 3) float32
        Geometric normal facing the side the photon came from.
    power : (n, C) float32
        Photon flux in the unnormalised units of the tracer: divide sums by the number of
        photons emitted in the set to get lumens.
    part : (n,) int32
        Index of the surface part (``scene.surfaces``).
    flags : (n,) uint8
        F_SPECULAR (caustic path) / F_DIFFUSE (indirect).
    source : (n,) int64
        Index of the emitted photon (within the traced batch) that made this record.
    """

    position: np.ndarray
    normal: np.ndarray
    power: np.ndarray
    part: np.ndarray
    flags: np.ndarray
    source: np.ndarray

    @classmethod
    def empty(cls, channels: int) -> PhotonRecords:
        return cls(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32),
                   np.zeros((0, channels), np.float32), np.zeros(0, np.int32),
                   np.zeros(0, np.uint8), np.zeros(0, np.int64))

    @classmethod
    def concatenate(cls, parts: list[PhotonRecords], channels: int) -> PhotonRecords:
        if not parts:
            return cls.empty(channels)
        return cls(*(np.concatenate([getattr(p, f) for p in parts])
                     for f in ("position", "normal", "power", "part", "flags", "source")))

    def __len__(self) -> int:
        return len(self.position)


@dataclass
class TraceResult:
    """Records and bookkeeping of one traced batch.

    ``ledger`` is (n_groups, len(LEDGER), C) float64 in the tracer's unnormalised flux
    units (sums of photon powers); ``emitted`` is (n_groups, C) likewise.
    ``escaped_dir``/``escaped_power`` hold photons
    that left the scene (for far-field intensity), if requested.
    """

    records: PhotonRecords
    emitted: np.ndarray
    ledger: np.ndarray
    rays: int
    caustic_source: np.ndarray  # (n_emitted,) bool: produced a caustic record
    escaped_dir: np.ndarray | None = None
    escaped_power: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    def luminous(self, values: np.ndarray) -> np.ndarray:
        """Channel values → luminous (lm) using Rec. 709 weights for RGB."""
        v = np.asarray(values, dtype=np.float64)
        return v[..., 0] if v.shape[-1] == 1 else v @ LUMA


class PhotonTracer:
    """Traces photon batches through a scene (see the module docstring for parameters)."""

    def __init__(self, scene, *, max_depth: int = 32, rr_threshold: float = 0.05,
                 rr_min_depth: int = 3, record: str = "wall", threads: int | None = None,
                 batch: int = 262144, caster: RayCaster | None = None) -> None:
        if record not in ("wall", "all"):
            raise ValueError("record must be 'wall' or 'all'")
        self.scene = scene
        self.max_depth = int(max_depth)
        self.rr_threshold = float(rr_threshold)
        self.rr_min_depth = int(rr_min_depth)
        self.record_all = record == "all"
        self.batch = int(batch)
        self.caster = caster or RayCaster(scene.triangles, threads=threads)
        self.emitters = EmitterTable.from_scene(scene)
        mats = scene.materials
        self.channels = mats.channels
        self._geom = (np.ascontiguousarray(scene.triangles),
                      np.ascontiguousarray(scene.face_normals),
                      np.ascontiguousarray(scene.corner_normals),
                      scene.tri_part.astype(np.int32), scene.tri_is_wall.astype(np.bool_))
        self._mats = (mats.kind, mats.value, mats.ior, mats.sigma)
        self.eps_floor = 0.01 * scene.scale
        self.scene_extent = scene.extent  # no ray origin lies farther out than the geometry

    def trace_points(self, points: np.ndarray, keys: np.ndarray, weight: np.ndarray | None = None,
                     group: np.ndarray | None = None, n_groups: int = 1,
                     record_escaped: bool = False) -> TraceResult:
        """Emit and trace photons from sample points.

        Parameters
        ----------
        points : (n, 5) float64
            Sample points in [0, 1) (see :mod:`lightsim.sampling`).
        keys : (n,) uint64
            Random-number keys (one per photon).
        weight : (n,) float64, optional
            Power factor per photon (SPT); photon power = Φ · weight.
        group, n_groups :
            Group (interleave set) of each photon; bookkeeping is returned per group.
        """
        origins, directions = emit(self.emitters, points)
        power = np.full((len(points), self.channels), self.emitters.flux)
        if weight is not None:
            power *= np.asarray(weight, dtype=np.float64)[:, None]
        return self.trace(origins, directions, power, keys, group, n_groups, record_escaped)

    def trace(self, origins: np.ndarray, directions: np.ndarray, power: np.ndarray,
              keys: np.ndarray, group: np.ndarray | None = None, n_groups: int = 1,
              record_escaped: bool = False) -> TraceResult:
        """Trace photons given their origins (m), unit directions and powers (n, C).

        The ledger is (n_groups, len(LEDGER), C); per group it is summed in photon order,
        so a set's bookkeeping is bit-identical however sets are batched together.
        """
        n = len(origins)
        C = self.channels
        group = np.zeros(n, np.int64) if group is None else np.asarray(group, np.int64)
        parts: list[PhotonRecords] = []
        ledger = np.zeros((n_groups, len(LEDGER), C))
        esc_d, esc_p = [], []
        caustic_source = np.zeros(n, dtype=np.bool_)
        rays = 0
        for lo in range(0, n, self.batch):
            hi = min(n, lo + self.batch)
            rec, led, nrays, ed, ep = self._trace_batch(
                origins[lo:hi], directions[lo:hi], power[lo:hi], keys[lo:hi], group[lo:hi],
                n_groups, record_escaped)
            rec.source += lo
            caustic_source[rec.source[(rec.flags & F_SPECULAR) != 0]] = True
            parts.append(rec)
            ledger += led
            rays += nrays
            if record_escaped:
                esc_d.append(ed)
                esc_p.append(ep)
        emitted = np.zeros((n_groups, C))
        for c in range(C):
            emitted[:, c] = np.bincount(group, weights=np.asarray(power, np.float64)[:, c],
                                        minlength=n_groups)
        return TraceResult(PhotonRecords.concatenate(parts, C), emitted, ledger, rays,
                           caustic_source,
                           np.concatenate(esc_d) if record_escaped and esc_d else None,
                           np.concatenate(esc_p) if record_escaped and esc_p else None)

    def _intersect(self, o: np.ndarray, d: np.ndarray):
        """Closest hits, skipping false self-intersections at t ≈ 0.

        embree starts rays at t = 0, and an origin rounded to float32 can sit exactly on a
        neighbouring face near an edge. A hit closer than the origin offset is false when
        the ray moves away from that face's plane on the side where its (float64) origin
        lies; such rays are re-cast from a little further along.
        """
        prim, tfar, bu, bv = self.caster.intersect(o, d)
        # a cheap global bound first: only rays that hit very close need the per-ray test
        bound = 4 * 3.814697265625e-06 * (self.scene_extent + self.eps_floor)
        near = np.flatnonzero((prim >= 0) & (tfar < bound))
        if len(near) == 0:
            return prim, tfar, bu, bv
        t_min = np.full(len(o), -1.0)
        t_min[near] = 4 * 3.814697265625e-06 * (np.abs(o[near]).max(axis=1) + self.eps_floor)
        tri, fn = self._geom[0], self._geom[1]
        for _ in range(3):
            close = np.flatnonzero((prim >= 0) & (tfar < t_min))
            if len(close) == 0:
                break
            k = prim[close]
            side = np.einsum("ij,ij->i", o[close] - tri[k, 0], fn[k])
            moving = np.einsum("ij,ij->i", d[close], fn[k])
            close = close[side * moving > 0]
            if len(close) == 0:
                break
            step = t_min[close]
            p2, t2, u2, v2 = self.caster.intersect(o[close] + step[:, None] * d[close],
                                                   d[close])
            prim[close], tfar[close], bu[close], bv[close] = p2, t2 + step, u2, v2
        return prim, tfar, bu, bv

    def _trace_batch(self, origins, directions, power, keys, group, n_groups, record_escaped):
        n = len(origins)
        C = self.channels
        K = len(LEDGER)
        o = np.array(origins, dtype=np.float64)
        d = np.array(directions, dtype=np.float64)
        pw = np.array(power, dtype=np.float64).reshape(n, C)
        p_ref = pw.max(axis=1) if n else np.zeros(0)
        flags = np.zeros(n, dtype=np.uint8)
        keys = np.asarray(keys, dtype=np.uint64)
        idx = np.arange(n, dtype=np.int64)
        group = np.asarray(group, dtype=np.int64)
        ledger = np.zeros((n, K, C))
        recs = []
        esc_d, esc_p = [], []
        rays = 0
        for depth in range(self.max_depth):
            m = len(o)
            if m == 0:
                break
            prim, tfar, bu, bv = self._intersect(o, d)
            rays += m
            status = np.empty(m, dtype=np.int8)
            rec = np.empty(m, dtype=np.bool_)
            rec_pos = np.empty((m, 3))
            rec_nrm = np.empty((m, 3))
            rec_pow = np.empty((m, C))
            rec_part = np.empty(m, dtype=np.int32)
            rec_flag = np.empty(m, dtype=np.uint8)
            if record_escaped:
                miss = prim < 0
                esc_d.append(d[miss].astype(np.float32))
                esc_p.append(pw[miss].astype(np.float64))
            _interact(o, d, pw, p_ref, flags, keys, depth, prim, tfar, bu, bv,
                      *self._geom, *self._mats, self.eps_floor, self.rr_threshold,
                      self.rr_min_depth, depth == self.max_depth - 1, self.record_all,
                      status, rec, rec_pos, rec_nrm, rec_pow, rec_part, rec_flag,
                      ledger, idx)
            if rec.any():
                recs.append(PhotonRecords(rec_pos[rec].astype(np.float32),
                                          rec_nrm[rec].astype(np.float32),
                                          rec_pow[rec].astype(np.float32), rec_part[rec],
                                          rec_flag[rec], idx[rec]))
            alive = status == ALIVE
            o, d, pw, p_ref, flags, keys, idx = (
                o[alive], d[alive], pw[alive], p_ref[alive], flags[alive], keys[alive],
                idx[alive])
        led = np.zeros((n_groups, K, C))
        for kk in range(K):
            for c in range(C):
                led[:, kk, c] = np.bincount(group, weights=ledger[:, kk, c], minlength=n_groups)
        ed = np.concatenate(esc_d) if esc_d else np.zeros((0, 3), np.float32)
        ep = np.concatenate(esc_p) if esc_p else np.zeros((0, C))
        return PhotonRecords.concatenate(recs, C), led, rays, ed, ep
