"""Wavefront photon tracer: emission, embree ray casting, surface interaction, bookkeeping.

A batch of photons is cut into chunks, one chunk per Python thread at a time. Each thread
emits its chunk (:mod:`lightsim.emitters`) and traces it to the end: per bounce one embree
cast of its live rays (GIL released) and one serial numba kernel (GIL released) that
applies the surface optics to every ray and compacts the survivors in place, writing the
float32 rays embree casts next. No OpenMP region runs in the loop, so no spinning worker
competes with embree for the two cores; chunks are independent, so the result does not
depend on the number of threads or chunks (photon i is a function of its sample point and
key). Records come back bounce-major, in photon order, as one wavefront would give them.

The interaction (:func:`_interact_one`) only dispatches to the BSDF kernel of the surface
hit (:mod:`lightsim.materials`, one signature for all) and books the ledger:

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
``min_chunk``      photon 8192      smallest chunk a thread traces (4 chunks per thread
                                    and batch otherwise: load balance)
=================  =====  ========  ===================================================

Ray origins are pushed off the surface by ε = 2⁻¹⁸ · (|p|∞ + 0.01 · scene scale) along the
geometric normal (≈ 32 float32 ulps): enough at a wall 1 km away, small next to a 0.7 mm
glass wall at 0.1 m from the origin.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from lightsim.emitters import EmitterMix
from lightsim.materials import (
    DIFFUSE,
    MIRROR,
    WALL,
    dielectric_bsdf,
    diffuse_bsdf,
    mirror_bsdf,
    wall_bsdf,
)
from lightsim.raycast import WALL_MAX_TRIANGLES, RayCaster
from lightsim.sampling import uniform

# bookkeeping categories (columns of the ledger)
LEDGER = ("wall", "absorbed_diffuse", "absorbed_mirror", "absorbed_volume", "escaped",
          "roulette", "max_depth")
L_WALL, L_ABS_DIFF, L_ABS_MIRR, L_ABS_VOL, L_ESC, L_RR, L_MAXD = range(len(LEDGER))

# photon flags
F_SPECULAR = np.uint8(1)  # the path had at least one specular bounce (caustic path)
F_DIFFUSE = np.uint8(2)   # the path had at least one diffuse bounce (indirect light)

# ray status after an interaction
ALIVE, ENDED = 0, 1


# ------------------------------------------------------------------------------------------
# Surface interaction: what the kernels read, the ledger helper, the per-ray dispatch
# ------------------------------------------------------------------------------------------

class Geometry(NamedTuple):
    """The traced triangle soup as the kernels read it.

    Attributes
    ----------
    tri_v : (T, 3, 3) float64
        Triangle corners (m).
    face_n : (T, 3) float64
        Unit geometric normals (winding order).
    corner_n : (T, 3, 3) float64
        Unit shading normals at the corners.
    tri_part : (T,) int32
        Material (part) index of each triangle.
    is_wall : (T,) bool
        The triangle belongs to the measurement wall (detector).
    packed : (T, 24) float64
        All of the above per triangle in one row (corners 0–8, face normal 9–11, corner
        normals 12–20, part 21, wall 22): the interaction reads one 192-byte row per hit
        instead of five scattered ones (a hit is a cache miss on a large mesh).
    """

    tri_v: np.ndarray
    face_n: np.ndarray
    corner_n: np.ndarray
    tri_part: np.ndarray
    is_wall: np.ndarray
    packed: np.ndarray

    @classmethod
    def from_scene(cls, scene) -> Geometry:
        tri_v = np.ascontiguousarray(scene.triangles, dtype=np.float64)
        face_n = np.ascontiguousarray(scene.face_normals, dtype=np.float64)
        corner_n = np.ascontiguousarray(scene.corner_normals, dtype=np.float64)
        part = scene.tri_part.astype(np.int32)
        wall = scene.tri_is_wall.astype(np.bool_)
        packed = np.zeros((len(tri_v), 24))
        packed[:, 0:9] = tri_v.reshape(-1, 9)
        packed[:, 9:12] = face_n
        packed[:, 12:21] = corner_n.reshape(-1, 9)
        packed[:, 21] = part
        packed[:, 22] = wall
        return cls(tri_v, face_n, corner_n, part, wall, packed)

    def with_wall_of(self, scene) -> Geometry:
        """This geometry with the wall rows taken from ``scene`` (the same lamp with the
        wall moved, :meth:`~lightsim.scene.Scene.with_wall_transform`): a copy and a few
        rows instead of a pass over every triangle of the lamp."""
        from lightsim.scene import WALL, Scene

        rows = np.flatnonzero(self.is_wall)
        walls = Scene([p for p in scene.surfaces if p.role == WALL], None,
                      channels=scene.channels)
        if len(rows) != walls.n_triangles:
            raise ValueError("with_wall_of: the scene's wall has another triangle count")
        tri_v, face_n = self.tri_v.copy(), self.face_n.copy()
        corner_n, packed = self.corner_n.copy(), self.packed.copy()
        tri_v[rows] = walls.triangles
        face_n[rows] = walls.face_normals
        corner_n[rows] = walls.corner_normals
        packed[rows, 0:9] = tri_v[rows].reshape(-1, 9)
        packed[rows, 9:12] = face_n[rows]
        packed[rows, 12:21] = corner_n[rows].reshape(-1, 9)
        return Geometry(tri_v, face_n, corner_n, self.tri_part, self.is_wall, packed)


class Wavefront(NamedTuple):
    """The rays in flight (one row each; the first ``m`` rows are live).

    Attributes
    ----------
    o, d : (m, 3) float64
        Origins (m) and unit directions.
    power : (m, C) float64
        Photon flux (tracer units).
    p_ref : (m,) float64
        Largest emitted channel flux of each photon (the roulette reference).
    flags : (m,) uint8
        F_SPECULAR / F_DIFFUSE path flags.
    keys : (m,) uint64
        Random-number keys.
    lid : (m,) int64
        Index of the emitted photon (ledger row, record source).
    """

    o: np.ndarray
    d: np.ndarray
    power: np.ndarray
    p_ref: np.ndarray
    flags: np.ndarray
    keys: np.ndarray
    lid: np.ndarray


class Hits(NamedTuple):
    """embree's closest hits: triangle (−1 = miss), distance (m), barycentrics u, v."""

    prim: np.ndarray
    tfar: np.ndarray
    u: np.ndarray
    v: np.ndarray


class RecordBuffer(NamedTuple):
    """Photon records written by the kernels (see :class:`PhotonRecords`)."""

    pos: np.ndarray
    nrm: np.ndarray
    power: np.ndarray
    part: np.ndarray
    flags: np.ndarray
    source: np.ndarray


class TraceParams(NamedTuple):
    """Scalar parameters of the interaction (see the module docstring)."""

    eps_floor: float
    rr_threshold: float
    rr_min_depth: int
    record_all: bool


@njit(cache=True, inline="always")
def _offset(px, py, pz, nx, ny, nz, sign, eps_floor):
    eps = 3.814697265625e-06 * (max(abs(px), abs(py), abs(pz)) + eps_floor)
    return px + sign * eps * nx, py + sign * eps * ny, pz + sign * eps * nz


@njit(cache=True, inline="always")
def _book(ledger, j, row, power):
    """The ledger helper: all of a photon's remaining flux goes to one ledger row."""
    for c in range(power.shape[0]):
        ledger[j, row, c] += power[c]
        power[c] = 0.0


@njit(cache=True, inline="always")
def _interact_one(i, wf, hits, g, mats, prm, depth, last_bounce, rec, r, ledger):
    """One ray's surface interaction: dispatch to the BSDF of the surface hit, roulette.

    ``g`` is the packed row of the triangle hit (:class:`Geometry`). Writes a record at
    row ``r`` of ``rec`` if the photon is detected (wall, or any diffuse surface when
    recording all). Returns (status, recorded, origin, direction)
    of the continuing ray; the ray's flux is updated in ``wf.power[i]``.
    """
    j = wf.lid[i]
    power = wf.power[i]
    k = hits.prim[i]
    if k < 0:  # escaped to infinity
        _book(ledger, j, L_ESC, power)
        return ENDED, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    t = float(hits.tfar[i])
    dx, dy, dz = wf.d[i, 0], wf.d[i, 1], wf.d[i, 2]
    bu, bv = hits.u[i], hits.v[i]
    # the hit point from barycentrics lies on the triangle (o + t·d with a float32 t
    # can land just outside a neighbouring face at an edge and leak out of a box)
    b1 = min(max(float(bu), 0.0), 1.0)
    b2 = min(max(float(bv), 0.0), 1.0 - b1)
    # pulled strictly inside the triangle: a point on an edge lies on the plane of the
    # adjacent face too, and the normal offset alone would not clear that face
    b1 = (b1 + 1e-6) / (1.0 + 3e-6)
    b2 = (b2 + 1e-6) / (1.0 + 3e-6)
    b0 = 1.0 - b1 - b2
    px = b0 * g[0] + b1 * g[3] + b2 * g[6]
    py = b0 * g[1] + b1 * g[4] + b2 * g[7]
    pz = b0 * g[2] + b1 * g[5] + b2 * g[8]
    gx, gy, gz = g[9], g[10], g[11]
    front = dx * gx + dy * gy + dz * gz < 0.0
    # facing geometric normal: on the side the photon came from
    fs = 1.0 if front else -1.0
    ng = (fs * gx, fs * gy, fs * gz)
    m = int(g[21])
    kind = WALL if g[22] != 0.0 else mats.kind[m]
    key = wf.keys[i]
    ctr = np.uint64(depth * 8)
    d = (dx, dy, dz)

    recorded = False
    if kind == WALL or (kind == DIFFUSE and prm.record_all):
        recorded = True
        rec.pos[r, 0], rec.pos[r, 1], rec.pos[r, 2] = px, py, pz
        rec.nrm[r, 0], rec.nrm[r, 1], rec.nrm[r, 2] = ng[0], ng[1], ng[2]
        for c in range(power.shape[0]):
            rec.power[r, c] = power[c]
        rec.part[r] = m
        rec.flags[r] = wf.flags[i]
        rec.source[r] = j
    if kind == WALL:
        wall_bsdf(mats, m, d, ng, ng, front, t, key, ctr, power, ledger[j, L_WALL])
        return ENDED, recorded, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if kind == DIFFUSE:
        wx, wy, wz, side = diffuse_bsdf(mats, m, d, ng, ng, front, t, key, ctr, power,
                                        ledger[j, L_ABS_DIFF])
        wf.flags[i] |= F_DIFFUSE
    else:
        # interpolated shading normal, oriented like the geometric one
        w0 = 1.0 - bu - bv
        sx = w0 * g[12] + bu * g[15] + bv * g[18]
        sy = w0 * g[13] + bu * g[16] + bv * g[19]
        sz = w0 * g[14] + bu * g[17] + bv * g[20]
        ln = math.sqrt(sx * sx + sy * sy + sz * sz)
        if ln > 1e-12:
            ns = (fs * sx / ln, fs * sy / ln, fs * sz / ln)
        else:
            ns = ng
        wf.flags[i] |= F_SPECULAR
        if kind == MIRROR:
            wx, wy, wz, side = mirror_bsdf(mats, m, d, ng, ns, front, t, key, ctr, power,
                                           ledger[j, L_ABS_MIRR])
        else:
            wx, wy, wz, side = dielectric_bsdf(mats, m, d, ng, ns, front, t, key, ctr, power,
                                               ledger[j, L_ABS_VOL])
    ln = math.sqrt(wx * wx + wy * wy + wz * wz)
    wx, wy, wz = wx / ln, wy / ln, wz / ln
    ox, oy, oz = _offset(px, py, pz, ng[0], ng[1], ng[2], side, prm.eps_floor)

    # Russian roulette on weak photons, then the depth limit
    pmax = 0.0
    for c in range(power.shape[0]):
        pmax = max(pmax, power[c])
    if pmax <= 0.0:
        return ENDED, recorded, ox, oy, oz, wx, wy, wz
    p_ref = wf.p_ref[i]
    if depth + 1 >= prm.rr_min_depth and pmax < prm.rr_threshold * p_ref:
        q = pmax / (prm.rr_threshold * p_ref)
        if uniform(key, ctr + np.uint64(1)) >= q:
            _book(ledger, j, L_RR, power)
            return ENDED, recorded, ox, oy, oz, wx, wy, wz
        for c in range(power.shape[0]):
            boost = power[c] / q - power[c]
            ledger[j, L_RR, c] -= boost
            power[c] += boost
    if last_bounce:
        _book(ledger, j, L_MAXD, power)
        return ENDED, recorded, ox, oy, oz, wx, wy, wz
    return ALIVE, recorded, ox, oy, oz, wx, wy, wz


@njit(cache=True, nogil=True)
def _bounce(wf, m, hits, geom, mats, prm, depth, last_bounce, rec, ledger, o32, d32,
            esc_d, esc_p, record_escaped):
    """One bounce of the first ``m`` rays of a wavefront, fused with its compaction.

    Interacts every ray (:func:`_interact_one`), writes the records densely into ``rec``,
    the escaped photons into ``esc_d``/``esc_p`` (if ``record_escaped``), and moves the
    surviving rays to the front of ``wf`` in order, with float32 copies of their origins
    and directions in ``o32``/``d32`` for the next embree cast. Serial and without the
    GIL: the tracer runs one wavefront chunk per Python thread, embree casts included.

    Returns (alive, records, escaped) counts.
    """
    C = wf.power.shape[1]
    # gather the hit triangles' rows first: independent loads the CPU overlaps (a hit is a
    # cache miss on a large mesh, and Halton-ordered photons hit scattered triangles)
    packed = geom.packed
    rows = np.empty((m, packed.shape[1]))
    for i in range(m):
        k = hits.prim[i]
        if k >= 0:
            for q in range(packed.shape[1]):
                rows[i, q] = packed[k, q]
    w = 0
    r = 0
    e = 0
    for i in range(m):
        if record_escaped and hits.prim[i] < 0:
            for q in range(3):
                esc_d[e, q] = wf.d[i, q]
            for c in range(C):
                esc_p[e, c] = wf.power[i, c]
            e += 1
        st, recd, ox, oy, oz, wx, wy, wz = _interact_one(i, wf, hits, rows[i], mats, prm,
                                                         depth, last_bounce, rec, r, ledger)
        if recd:
            r += 1
        if st != ALIVE:
            continue
        wf.o[w, 0], wf.o[w, 1], wf.o[w, 2] = ox, oy, oz
        wf.d[w, 0], wf.d[w, 1], wf.d[w, 2] = wx, wy, wz
        o32[w, 0], o32[w, 1], o32[w, 2] = ox, oy, oz
        d32[w, 0], d32[w, 1], d32[w, 2] = wx, wy, wz
        if w != i:
            for c in range(C):
                wf.power[w, c] = wf.power[i, c]
            wf.p_ref[w] = wf.p_ref[i]
            wf.flags[w] = wf.flags[i]
            wf.keys[w] = wf.keys[i]
            wf.lid[w] = wf.lid[i]
        w += 1
    return w, r, e


@njit(cache=True, nogil=True)
def _near_hits(prim, tfar, bound):
    """Indices of hits closer than ``bound`` (m): candidates for false self-hits."""
    out = np.empty(prim.shape[0], np.int64)
    n = 0
    for i in range(prim.shape[0]):
        if prim[i] >= 0 and tfar[i] < bound:
            out[n] = i
            n += 1
    return out[:n]


@njit(cache=True, nogil=True)
def _group_ledger(ledger, group, n_groups):
    """Per-photon ledger rows summed per group, in photon order (like ``np.bincount``)."""
    out = np.zeros((n_groups, ledger.shape[1], ledger.shape[2]))
    for i in range(ledger.shape[0]):
        g = group[i]
        for k in range(ledger.shape[1]):
            for c in range(ledger.shape[2]):
                out[g, k, c] += ledger[i, k, c]
    return out


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


def _caster_for(scene, caster: RayCaster | None, threads: int | None) -> RayCaster:
    """The ray caster of ``scene``: the wall (up to WALL_MAX_TRIANGLES) outside embree, so
    a ``caster`` of the same lamp with the wall elsewhere is reused with the wall moved
    (:meth:`RayCaster.with_wall`) instead of rebuilt."""
    wall = scene.tri_is_wall
    exact = 0 < int(wall.sum()) <= WALL_MAX_TRIANGLES
    if caster is None:
        return RayCaster(scene.triangles, threads=threads, wall=wall if exact else None)
    if exact and caster.exact_wall and caster.n_triangles == len(wall):
        return caster.with_wall(scene.wall_triangles)
    return caster


class PhotonTracer:
    """Traces photon batches through a scene (see the module docstring for parameters)."""

    def __init__(self, scene, *, max_depth: int = 32, rr_threshold: float = 0.05,
                 rr_min_depth: int = 3, record: str = "wall", threads: int | None = None,
                 batch: int = 262144, caster: RayCaster | None = None,
                 min_chunk: int = 8192) -> None:
        if record not in ("wall", "all"):
            raise ValueError("record must be 'wall' or 'all'")
        self.scene = scene
        self.max_depth = int(max_depth)
        self.rr_threshold = float(rr_threshold)
        self.rr_min_depth = int(rr_min_depth)
        self.record_all = record == "all"
        self.batch = int(batch)
        self.caster = _caster_for(scene, caster, threads)
        self.emitters = EmitterMix.from_scene(scene)
        mats = scene.materials
        self.channels = mats.channels
        prev = getattr(caster, "geometry", None) if caster is not None else None
        if (prev is not None and self.caster.exact_wall and self.caster is not caster
                and len(prev.tri_part) == self.caster.n_triangles):
            self._geom = prev.with_wall_of(scene)  # same lamp, the wall moved
        else:
            self._geom = Geometry.from_scene(scene)
        # the packed lamp rides with its embree scene: a tracer reusing this caster
        # (only the wall or materials changed) reuses the lamp's rows too
        self.caster.geometry = self._geom
        self._mats = mats.arrays
        self.eps_floor = 0.01 * scene.scale
        self._params = TraceParams(self.eps_floor, self.rr_threshold, self.rr_min_depth,
                                   self.record_all)
        self.scene_extent = scene.extent  # no ray origin lies farther out than the geometry
        self.threads = self.caster.threads
        self.min_chunk = int(min_chunk)
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None

    def close(self) -> None:
        """Stop the tracer's threads and the ray caster's."""
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None
        self.caster.close()

    def __del__(self) -> None:  # pragma: no cover - best effort
        if getattr(self, "_pool", None) is not None:
            self._pool.shutdown(wait=False)

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
        points = np.ascontiguousarray(points, dtype=np.float64)
        power = np.full((len(points), self.channels), self.emitters.flux_lm)
        if weight is not None:
            power *= np.asarray(weight, dtype=np.float64)[:, None]

        def source(lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
            return self.emitters.sample(points[lo:hi])  # photon i from point i only

        return self._trace(source, len(points), power, keys, group, n_groups, record_escaped)

    def trace(self, origins: np.ndarray, directions: np.ndarray, power: np.ndarray,
              keys: np.ndarray, group: np.ndarray | None = None, n_groups: int = 1,
              record_escaped: bool = False) -> TraceResult:
        """Trace photons given their origins (m), unit directions and powers (n, C).

        The ledger is (n_groups, len(LEDGER), C); per group it is summed in photon order,
        so a set's bookkeeping is bit-identical however sets are batched together.
        """
        def source(lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
            # copies: the tracer moves its rays in place
            return (np.array(origins[lo:hi], dtype=np.float64),
                    np.array(directions[lo:hi], dtype=np.float64))

        return self._trace(source, len(origins), power, keys, group, n_groups, record_escaped)

    def _trace(self, source, n: int, power: np.ndarray, keys: np.ndarray,
               group: np.ndarray | None, n_groups: int, record_escaped: bool) -> TraceResult:
        C = self.channels
        power = np.asarray(power, dtype=np.float64).reshape(n, C)
        keys = np.asarray(keys, dtype=np.uint64)
        group = np.zeros(n, np.int64) if group is None else np.asarray(group, np.int64)
        parts: list[PhotonRecords] = []
        ledger = np.zeros((n_groups, len(LEDGER), C))
        esc_d, esc_p = [], []
        caustic_source = np.zeros(n, dtype=np.bool_)
        rays = 0
        for lo in range(0, n, self.batch):
            hi = min(n, lo + self.batch)
            rec, led, nrays, ed, ep = self._trace_batch(source, lo, hi, power, keys, group,
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
            emitted[:, c] = np.bincount(group, weights=power[:, c], minlength=n_groups)
        return TraceResult(PhotonRecords.concatenate(parts, C), emitted, ledger, rays,
                           caustic_source,
                           np.concatenate(esc_d) if record_escaped and esc_d else None,
                           np.concatenate(esc_p) if record_escaped and esc_p else None)

    def _cast(self, o: np.ndarray, d: np.ndarray, o32: np.ndarray, d32: np.ndarray) -> Hits:
        """Closest hits of one chunk (this thread), skipping false self-hits at t ≈ 0.

        embree starts rays at t = 0, and an origin rounded to float32 can sit exactly on a
        neighbouring face near an edge. A hit closer than the origin offset is false when
        the ray moves away from that face's plane on the side where its (float64) origin
        lies; such rays are re-cast from a little further along.
        """
        prim, tfar, bu, bv = self.caster.cast(o32, d32)
        # a cheap global bound first: only rays that hit very close need the per-ray test
        bound = 4 * 3.814697265625e-06 * (self.scene_extent + self.eps_floor)
        near = _near_hits(prim, tfar, bound)
        if len(near) == 0:
            return Hits(prim, tfar, bu, bv)
        t_min = np.full(len(o), -1.0)
        t_min[near] = 4 * 3.814697265625e-06 * (np.abs(o[near]).max(axis=1) + self.eps_floor)
        tri, fn = self._geom.tri_v, self._geom.face_n
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
            p2, t2, u2, v2 = self.caster.cast(
                np.ascontiguousarray(o[close] + step[:, None] * d[close], dtype=np.float32),
                np.ascontiguousarray(d32[close]))
            prim[close], tfar[close], bu[close], bv[close] = p2, t2 + step, u2, v2
        return Hits(prim, tfar, bu, bv)

    def _trace_chunk(self, source, lo: int, hi: int, power, keys, ledger, record_escaped):
        """Trace photons lo..hi to the end in this thread: emit, then per bounce one embree
        cast and one fused interaction + compaction kernel. ``source(lo, hi)`` returns new
        arrays of origins and directions (they become the wavefront). Returns per-bounce
        records, escaped photons and the ray count."""
        n = hi - lo
        C = self.channels
        origins, directions = source(lo, hi)  # fresh arrays: traced in place
        o = np.ascontiguousarray(origins, dtype=np.float64).reshape(n, 3)
        d = np.ascontiguousarray(directions, dtype=np.float64).reshape(n, 3)
        pw = power[lo:hi].copy()
        wf = Wavefront(o, d, pw, pw.max(axis=1) if n else np.zeros(0),
                       np.zeros(n, np.uint8), keys[lo:hi].copy(),
                       np.arange(lo, hi, dtype=np.int64))
        o32 = o.astype(np.float32)
        d32 = d.astype(np.float32)
        recs: list[PhotonRecords] = []
        escs: list[tuple[np.ndarray, np.ndarray]] = []
        rays = 0
        m = n
        for depth in range(self.max_depth):
            if m == 0:
                break
            hits = self._cast(o[:m], d[:m], o32[:m], d32[:m])
            rays += m
            rb = RecordBuffer(np.empty((m, 3), np.float32), np.empty((m, 3), np.float32),
                              np.empty((m, C), np.float32), np.empty(m, np.int32),
                              np.empty(m, np.uint8), np.empty(m, np.int64))
            esc = ((np.empty((m, 3), np.float32), np.empty((m, C))) if record_escaped
                   else (np.empty((0, 3), np.float32), np.empty((0, C))))
            m, r, e = _bounce(wf, m, hits, self._geom, self._mats, self._params, depth,
                              depth == self.max_depth - 1, rb, ledger, o32, d32, esc[0], esc[1],
                              record_escaped)
            recs.append(PhotonRecords(*(a[:r] for a in rb)))
            escs.append((esc[0][:e], esc[1][:e]))
        return recs, escs, rays

    def _trace_batch(self, source, lo, hi, power, keys, group, n_groups, record_escaped):
        """One batch in chunks over the threads; records in (bounce, photon) order."""
        n = hi - lo
        C = self.channels
        K = len(LEDGER)
        ledger = np.zeros((n, K, C))  # per photon of the batch, summed per group below
        step = max(self.min_chunk, -(-n // (4 * self.threads)))
        bounds = list(range(0, n, step)) + [n]

        def work(k: int):
            a, b = bounds[k], bounds[k + 1]
            return self._trace_chunk(lambda x, y: source(lo + x, lo + y), a, b,
                                     power[lo:hi], keys[lo:hi], ledger, record_escaped)

        if self._pool is None or len(bounds) <= 2:
            chunks = [work(k) for k in range(len(bounds) - 1)]
        else:
            chunks = list(self._pool.map(work, range(len(bounds) - 1)))
        # bounce-major like one wavefront: bounce 0 of every chunk, then bounce 1, …
        depth = max((len(c[0]) for c in chunks), default=0)
        recs = [c[0][k] for k in range(depth) for c in chunks if k < len(c[0])]
        escs = [c[1][k] for k in range(depth) for c in chunks if k < len(c[1])]
        rays = sum(c[2] for c in chunks)
        led = _group_ledger(ledger, group[lo:hi], n_groups)
        ed = np.concatenate([e[0] for e in escs]) if escs else np.zeros((0, 3), np.float32)
        ep = np.concatenate([e[1] for e in escs]) if escs else np.zeros((0, C))
        return PhotonRecords.concatenate(recs, C), led, rays, ed, ep
