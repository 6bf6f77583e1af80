"""Wavefront photon tracer: emission, embree ray casting, surface interaction, bookkeeping.

A batch of photons is cut into chunks, one chunk per Python thread at a time. Each thread
emits its chunk (:mod:`lightsim.emitters`) and traces it to the end: per bounce one embree
cast of its live rays (GIL released) and one serial numba kernel (GIL released) that
applies the surface optics to every ray and compacts the survivors in place, writing the
float32 rays embree casts next. No OpenMP region runs in the loop, so no spinning worker
competes with embree for the two cores; chunks are independent, so the result does not
depend on the number of threads or chunks (photon i is a function of its sample point and
key). Records come back bounce-major, in photon order, as one wavefront would give them;
with ``by_source`` (what a run's frames ask) in photon order, each photon's in bounce
order, sorted chunk by chunk on the tracer's threads.

The interaction (in :func:`_bounce`) hands each hit to the BSDF kernel of the surface's
kind (:func:`lightsim.materials.scatter`), which samples the outgoing direction, scales the
flux and books what the surface took in the ledger:

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
``path_length``    –      0         path signatures: surface events each record keeps
                                    (triangle and event: reflection, refraction, TIR,
                                    diffuse); 0 = none (no cost)
=================  =====  ========  ===================================================

Ray origins are pushed off the surface by ε = 2⁻¹⁸ · (|p|∞ + 0.01 · scene scale) along the
geometric normal (≈ 32 float32 ulps): enough at a wall 1 km away, small next to a 0.7 mm
glass wall at 0.1 m from the origin.
"""

from __future__ import annotations

import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from lightsim.emitters import EmitterMix
from lightsim.materials import DIELECTRIC, DIFFUSE, MIRROR, WALL, scatter
from lightsim.raycast import WALL_MAX_TRIANGLES, RayCaster, merge_wall_hit
from lightsim.sampling import uniform
from lightsim.scene import WALL as WALL_ROLE
from lightsim.scene import Scene

# bookkeeping categories (columns of the ledger)
LEDGER = ("wall", "absorbed_diffuse", "absorbed_mirror", "absorbed_volume", "escaped",
          "roulette", "max_depth")
L_WALL, L_ABS_DIFF, L_ABS_MIRR, L_ABS_VOL, L_ESC, L_RR, L_MAXD = range(len(LEDGER))
# the ledger column of the flux a surface of each kind takes (indexed by kind)
_TAKEN = tuple(col for _, col in sorted({DIFFUSE: L_ABS_DIFF, MIRROR: L_ABS_MIRR,
                                         DIELECTRIC: L_ABS_VOL, WALL: L_WALL}.items()))

# photon flags
F_SPECULAR = np.uint8(1)  # the path had at least one specular bounce (caustic path)
F_DIFFUSE = np.uint8(2)   # the path had at least one diffuse bounce (indirect light)

# path signatures (``path_length`` > 0): each step is ``triangle · 4 + event``
EV_REFLECT, EV_REFRACT, EV_TIR, EV_DIFFUSE = 0, 1, 2, 3
EVENTS = ("reflection", "refraction", "TIR", "diffuse")



# ------------------------------------------------------------------------------------------
# Surface interaction: what the kernels read, the ledger, the per-ray dispatch
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
    wall_tri : (W, 3, 3) float64; wall_index : (W,) int32
        The wall's triangles when they are intersected exactly outside embree
        (:meth:`for_caster`), and their soup indices; empty otherwise.
    wall_slab : (5,) float64
        A slab holding those triangles, or empty: unit normal n, offset h and half
        thickness r (|n·x − h| ≤ r on the wall). A ray whose hit in the lamp is nearer
        than the slab skips the exact wall test (most of the lamp's rays: the wall is
        metres away).
    """

    tri_v: np.ndarray
    face_n: np.ndarray
    corner_n: np.ndarray
    tri_part: np.ndarray
    is_wall: np.ndarray
    packed: np.ndarray
    wall_tri: np.ndarray = np.zeros((0, 3, 3))
    wall_index: np.ndarray = np.zeros(0, np.int32)
    wall_slab: np.ndarray = np.zeros(0)

    def for_caster(self, caster: RayCaster) -> Geometry:
        """With the exact wall of ``caster`` (intersected in the bounce kernel's first
        pass over the rays instead of by the caster): none if embree holds the wall."""
        tri = np.ascontiguousarray(caster.wall_triangles, dtype=np.float64)
        return self._replace(wall_tri=tri, wall_index=np.ascontiguousarray(caster.wall_index),
                             wall_slab=_wall_slab(tri))

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
        rows = np.flatnonzero(self.is_wall)
        walls = Scene([p for p in scene.surfaces if p.role == WALL_ROLE], None,
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
        return Geometry(tri_v, face_n, corner_n, self.tri_part, self.is_wall, packed,
                        self.wall_tri, self.wall_index, self.wall_slab)


def _wall_slab(tri: np.ndarray) -> np.ndarray:
    """(n, h, r) of :attr:`Geometry.wall_slab` for triangles (W, 3, 3): n the largest
    triangle's unit normal, r padded (10⁻⁶ relative and 10⁻⁹ m); r = ∞ (no ray skips the
    wall test) without a triangle of nonzero area."""
    if len(tri) == 0:
        return np.zeros(0)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.sqrt((cross ** 2).sum(axis=1))
    k = int(np.argmax(norm))
    if not norm[k] > 0.0 or not np.all(np.isfinite(tri)):
        return np.array([0.0, 0.0, 1.0, 0.0, np.inf])
    n = cross[k] / norm[k]
    dist = tri.reshape(-1, 3) @ n
    h = 0.5 * (dist.min() + dist.max())
    r = 0.5 * (dist.max() - dist.min())
    return np.array([*n, h, r * (1.0 + 1e-6) + 1e-9 * (1.0 + abs(h))])


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


_PF = 16  # rays ahead whose hit rows the bounce kernel prefetches


@intrinsic
def _prefetch(typingctx, arr, row, col):
    """Prefetch the cache line of ``arr[row, col]`` (2-D array) for reading (LLVM's
    ``llvm.prefetch``; a hint, no effect on results)."""
    def codegen(context, builder, sig, args):
        aryty = sig.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        idx = [context.cast(builder, v, t, types.intp) for v, t in zip(args[1:], sig.args[1:])]
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, idx, wraparound=False)
        i32 = ir.IntType(32)
        if getattr(ptr.type, "is_opaque", False):
            name = "llvm.prefetch.p0"
        else:
            ptr = builder.bitcast(ptr, ir.IntType(8).as_pointer())
            name = "llvm.prefetch.p0i8"
        fnty = ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, name)
        builder.call(fn, [ptr, i32(0), i32(3), i32(1)])  # read, high locality, data
        return context.get_dummy_value()

    return types.void(arr, row, col), codegen


@njit(cache=True, inline="always")
def _offset(px, py, pz, nx, ny, nz, sign, eps_floor):
    eps = 3.814697265625e-06 * (max(abs(px), abs(py), abs(pz)) + eps_floor)
    return px + sign * eps * nx, py + sign * eps * ny, pz + sign * eps * nz


@njit(cache=True, nogil=True, boundscheck=False)
def _bounce(wf, m, hits, geom, mats, prm, depth, last_bounce, rec, ledger, led_off, caustic,
            o32, d32, esc_d, esc_p, record_escaped, hist, nev, rhist, rnev):
    """One bounce of the first ``m`` rays of a wavefront, fused with its compaction.

    Per ray, in named steps: escape (no hit), the hit (point, facing geometric normal,
    kind), the record, the shading normal, scattering (the kind's BSDF kernel through
    :func:`lightsim.materials.scatter`: direction, side, flux and the ledger), the spawned
    ray, Russian roulette, the depth limit, compaction. Records go densely into ``rec``,
    escaped photons into ``esc_d``/``esc_p`` (if ``record_escaped``), and the surviving
    rays move to the front of ``wf`` in order, with float32 copies of their origins and
    directions in ``o32``/``d32`` for the next embree cast. Photon ``j`` (``wf.lid``: its
    index in the trace) books into ``ledger[j - led_off]`` (the chunk's rows), and its
    record, if on a specular path, marks ``caustic[j]``. Random numbers of a bounce at
    ``depth``: counter 8 · depth + 0 the Fresnel choice, + 1 roulette, + 2 and + 3 the
    diffuse direction.

    Path signatures (``hist`` with rows, else (0, 1)): each ray's first K surface events
    (``triangle · 4 + event``, :data:`EVENTS`) in ``hist``, their count (up to 255) in
    ``nev``; a record copies them to ``rhist``/``rnev``. Without them nothing of this runs
    but one test per hit.

    The named tuples are unpacked once, before the loop, and the loop body hands the BSDF
    only scalars, tuples of scalars and whole arrays with row indices: a row view or a
    tuple of arrays made per ray costs a reference-count increment and decrement per
    array (≈ 40 atomic calls per ray with the tuples, more than embree's cast itself).
    Serial and without the GIL: the tracer runs one wavefront chunk per Python thread,
    embree casts included.

    Returns (alive, records, escaped) counts.
    """
    wo, wd, pw, pref, wflags, wkeys, wlid = wf
    prim, tfar, hu, hv = hits
    kinds = mats.kind
    rpos, rnrm, rpow, rpart, rflags, rsrc = rec
    packed = geom.packed
    wall_tri, wall_index, slab = geom.wall_tri, geom.wall_index, geom.wall_slab
    eps_floor, rr_threshold, rr_min_depth = prm.eps_floor, prm.rr_threshold, prm.rr_min_depth
    record_all = prm.record_all
    track = hist.shape[0] > 0
    K = hist.shape[1]
    C = pw.shape[1]
    P = packed.shape[1]
    # the exact wall (outside embree) in its own pass before the loop. The hit triangles'
    # packed rows (a cache miss each on a large mesh: Halton-ordered photons hit scattered
    # triangles) are prefetched _PF rays ahead in the loop; a gather pass copying them
    # into a buffer before the loop cost 25–50 ns per ray more
    if wall_tri.shape[0] > 0:
        nx, ny, nz, h, rad = slab[0], slab[1], slab[2], slab[3], slab[4]
        for i in range(m):
            # the lamp's hit is nearer than the wall's slab (a 0.1 % margin on the
            # distance): no wall hit can replace it. A miss never skips (tfar ≥ 1e37)
            ox, oy, oz = float(o32[i, 0]), float(o32[i, 1]), float(o32[i, 2])
            dx, dy, dz = float(d32[i, 0]), float(d32[i, 1]), float(d32[i, 2])
            gap = max(abs(nx * ox + ny * oy + nz * oz - h) - rad, 0.0)
            b = float(tfar[i]) if prim[i] >= 0 else np.inf
            if gap * gap > 1.001 * (b * b) * (dx * dx + dy * dy + dz * dz):
                continue
            merge_wall_hit(i, o32, d32, prim, tfar, hu, hv, wall_tri, wall_index)
    ctr = np.uint64(depth * 8)
    w = 0
    r = 0
    e = 0
    for i in range(m):
        if i + _PF < m:  # the hit row of a ray _PF ahead: on its way while this one runs
            kp = prim[i + _PF]
            if kp >= 0:
                _prefetch(packed, kp, 0)
                _prefetch(packed, kp, 8)
                _prefetch(packed, kp, 16)
                _prefetch(packed, kp, P - 1)
        j = wlid[i]
        jl = j - led_off
        k = prim[i]
        # escape: no hit, the photon leaves to infinity
        if k < 0:
            if record_escaped:
                for q in range(3):
                    esc_d[e, q] = wd[i, q]
                for c in range(C):
                    esc_p[e, c] = pw[i, c]
                e += 1
            for c in range(C):
                ledger[jl, L_ESC, c] += pw[i, c]
                pw[i, c] = 0.0
            continue

        # the hit: point p on the triangle, facing geometric normal ng, surface kind
        t = float(tfar[i])
        dx, dy, dz = wd[i, 0], wd[i, 1], wd[i, 2]
        bu, bv = hu[i], hv[i]
        # p from barycentrics lies on the triangle (o + t·d with a float32 t can land
        # just outside a neighbouring face at an edge and leak out of a box)
        b1 = min(max(float(bu), 0.0), 1.0)
        b2 = min(max(float(bv), 0.0), 1.0 - b1)
        # pulled strictly inside the triangle: a point on an edge lies on the plane of the
        # adjacent face too, and the normal offset alone would not clear that face
        b1 = (b1 + 1e-6) / (1.0 + 3e-6)
        b2 = (b2 + 1e-6) / (1.0 + 3e-6)
        b0 = 1.0 - b1 - b2
        px = b0 * packed[k, 0] + b1 * packed[k, 3] + b2 * packed[k, 6]
        py = b0 * packed[k, 1] + b1 * packed[k, 4] + b2 * packed[k, 7]
        pz = b0 * packed[k, 2] + b1 * packed[k, 5] + b2 * packed[k, 8]
        gx, gy, gz = packed[k, 9], packed[k, 10], packed[k, 11]
        front = dx * gx + dy * gy + dz * gz < 0.0
        fs = 1.0 if front else -1.0  # ng on the side the photon came from
        ngx, ngy, ngz = fs * gx, fs * gy, fs * gz
        mi = int(packed[k, 21])
        kind = WALL if packed[k, 22] != 0.0 else kinds[mi]
        key = wkeys[i]

        # record: the photon map's entry, with the flux that arrived
        if kind == WALL or (kind == DIFFUSE and record_all):
            rpos[r, 0], rpos[r, 1], rpos[r, 2] = px, py, pz
            rnrm[r, 0], rnrm[r, 1], rnrm[r, 2] = ngx, ngy, ngz
            for c in range(C):
                rpow[r, c] = pw[i, c]
            rpart[r] = mi
            fl = wflags[i]
            rflags[r] = fl
            rsrc[r] = j
            if fl & F_SPECULAR:
                caustic[j] = True
            if track:
                for q in range(K):
                    rhist[r, q] = hist[i, q]
                rnev[r] = nev[i]
            r += 1

        # shading normal ns (specular kinds: interpolated vertex normals, facing like
        # ng) and the path's flags
        nsx, nsy, nsz = ngx, ngy, ngz
        if kind == MIRROR or kind == DIELECTRIC:
            w0 = 1.0 - bu - bv
            sx = w0 * packed[k, 12] + bu * packed[k, 15] + bv * packed[k, 18]
            sy = w0 * packed[k, 13] + bu * packed[k, 16] + bv * packed[k, 19]
            sz = w0 * packed[k, 14] + bu * packed[k, 17] + bv * packed[k, 20]
            ln = math.sqrt(sx * sx + sy * sy + sz * sz)
            if ln > 1e-12:
                nsx, nsy, nsz = fs * sx / ln, fs * sy / ln, fs * sz / ln
            wflags[i] |= F_SPECULAR
        elif kind == DIFFUSE:
            wflags[i] |= F_DIFFUSE

        # scattering: the kind's BSDF samples the outgoing direction ω and its side,
        # scales the flux and books what the surface took (absorbed, or detected)
        wx, wy, wz, side = scatter(kind, mats, mi, (dx, dy, dz), (ngx, ngy, ngz),
                                   (nsx, nsy, nsz), front, t, key, ctr, pw, i,
                                   ledger, jl, _TAKEN[kind])
        if side == 0.0:  # the wall: detected, the photon ends
            continue
        if track:
            _path_step(hist, nev, i, k, kind, side, front, mats.ior[mi], (dx, dy, dz),
                       (nsx, nsy, nsz), (ngx, ngy, ngz))

        # spawned ray: unit ω from p pushed off the surface on ω's side
        ln = math.sqrt(wx * wx + wy * wy + wz * wz)
        wx, wy, wz = wx / ln, wy / ln, wz / ln
        ox, oy, oz = _offset(px, py, pz, ngx, ngy, ngz, side, eps_floor)

        # Russian roulette on weak photons
        pmax = 0.0
        for c in range(C):
            pmax = max(pmax, pw[i, c])
        if pmax <= 0.0:
            continue
        p_ref = pref[i]
        if depth + 1 >= rr_min_depth and pmax < rr_threshold * p_ref:
            q = pmax / (rr_threshold * p_ref)
            if uniform(key, ctr + np.uint64(1)) >= q:
                for c in range(C):
                    ledger[jl, L_RR, c] += pw[i, c]
                    pw[i, c] = 0.0
                continue
            for c in range(C):
                boost = pw[i, c] / q - pw[i, c]
                ledger[jl, L_RR, c] -= boost
                pw[i, c] += boost

        # depth limit
        if last_bounce:
            for c in range(C):
                ledger[jl, L_MAXD, c] += pw[i, c]
                pw[i, c] = 0.0
            continue

        # compaction: the survivor moves to row w
        wo[w, 0], wo[w, 1], wo[w, 2] = ox, oy, oz
        wd[w, 0], wd[w, 1], wd[w, 2] = wx, wy, wz
        o32[w, 0], o32[w, 1], o32[w, 2] = ox, oy, oz
        d32[w, 0], d32[w, 1], d32[w, 2] = wx, wy, wz
        if w != i:
            for c in range(C):
                pw[w, c] = pw[i, c]
            pref[w] = pref[i]
            wflags[w] = wflags[i]
            wkeys[w] = wkeys[i]
            wlid[w] = wlid[i]
            if track:
                for q in range(K):
                    hist[w, q] = hist[i, q]
                nev[w] = nev[i]
        w += 1
    return w, r, e


@njit(cache=True, inline="always")
def _path_step(hist, nev, i, k, kind, side, front, ior, d, ns, ng):
    """Append ray ``i``'s event on triangle ``k`` to its path: diffuse, mirror reflection,
    refraction (``side`` < 0) or, on glass, Fresnel reflection or total internal
    reflection (no refracted ray: sin²θₜ ≥ 1 about the shading or the geometric normal).
    The first ``hist.shape[1]`` events are kept; ``nev`` counts up to 255."""
    ev = EV_REFLECT
    if kind == DIFFUSE:
        ev = EV_DIFFUSE
    elif kind == DIELECTRIC:
        if side < 0.0:
            ev = EV_REFRACT
        else:
            eta = 1.0 / ior if front else ior
            ci = -(d[0] * ns[0] + d[1] * ns[1] + d[2] * ns[2])
            cg = -(d[0] * ng[0] + d[1] * ng[1] + d[2] * ng[2])
            if (eta * eta * (1.0 - ci * ci) >= 1.0
                    or eta * eta * (1.0 - cg * cg) >= 1.0):
                ev = EV_TIR
    n = nev[i]
    if n < hist.shape[1]:
        hist[i, n] = np.int32(k * 4 + ev)
    if n < 255:
        nev[i] = n + np.uint8(1)


@njit(cache=True, nogil=True, boundscheck=False)
def _start(o, d, power, weight, keys, lo, hi, base):
    """The wavefront's own arrays for photons lo..hi in one pass: flux (``power``, times
    ``weight`` unless that is empty), roulette reference (largest channel), flags, keys,
    photon indices (base + i), float32 rays for embree."""
    n = hi - lo
    C = power.shape[1]
    pw = np.empty((n, C))
    p_ref = np.empty(n)
    flags = np.zeros(n, np.uint8)
    kk = np.empty(n, np.uint64)
    lid = np.empty(n, np.int64)
    o32 = np.empty((n, 3), np.float32)
    d32 = np.empty((n, 3), np.float32)
    weighted = weight.shape[0] > 0
    for i in range(n):
        best = -np.inf
        for c in range(C):
            v = power[lo + i, c] * weight[lo + i] if weighted else power[lo + i, c]
            pw[i, c] = v
            best = v if c == 0 else max(best, v)
        p_ref[i] = best
        kk[i] = keys[lo + i]
        lid[i] = base + i
        for q in range(3):
            o32[i, q] = o[i, q]
            d32[i, q] = d[i, q]
    return pw, p_ref, flags, kk, lid, o32, d32


@njit(cache=True, nogil=True)
def near_hits(prim, tfar, bound):
    """Indices of hits closer than ``bound`` (m): candidates for false self-hits."""
    out = np.empty(prim.shape[0], np.int64)
    n = 0
    for i in range(prim.shape[0]):
        if prim[i] >= 0 and tfar[i] < bound:
            out[n] = i
            n += 1
    return out[:n]


@njit(cache=True, nogil=True)
def false_hits(near, o, d, prim, tfar, eps_floor, tri, fn):
    """Of the rays ``near`` (:func:`near_hits`), those whose hit is closer than their
    origin offset t_min = 4 · 2⁻¹⁸ · (|o|∞ + eps_floor) while they move away from the hit
    face's plane on their origin's side (false self-hits), and their t_min."""
    close = np.empty(near.shape[0], np.int64)
    step = np.empty(near.shape[0])
    n = 0
    for q in range(near.shape[0]):
        i = near[q]
        k = prim[i]
        if k < 0:
            continue
        t_min = 4 * 3.814697265625e-06 * (max(abs(o[i, 0]), abs(o[i, 1]), abs(o[i, 2]))
                                          + eps_floor)
        if not float(tfar[i]) < t_min:
            continue
        # the dot products summed as (x₀y₀ + x₂y₂) + x₁y₁, like NumPy's einsum of
        # 3-vectors that this replaced (bit for bit: an origin on the face's plane gives
        # a tiny side of either sign, and the sign decides)
        s0 = o[i, 0] - tri[k, 0, 0]
        s1 = o[i, 1] - tri[k, 0, 1]
        s2 = o[i, 2] - tri[k, 0, 2]
        side = (s0 * fn[k, 0] + s2 * fn[k, 2]) + s1 * fn[k, 1]
        moving = (d[i, 0] * fn[k, 0] + d[i, 2] * fn[k, 2]) + d[i, 1] * fn[k, 1]
        if side * moving > 0:
            close[n] = i
            step[n] = t_min
            n += 1
    return close[:n], step[:n]


@njit(cache=True, nogil=True)
def _add_ledger(ledger, group, power, weight, lo, out, emitted):
    """Photons lo.. (their per-photon ledger rows (n, len(LEDGER) · C), groups, flux
    ``power`` × ``weight`` unless that is empty) added to ``out`` (n_groups,
    len(LEDGER) · C) and ``emitted`` per group in photon order, as ``np.bincount`` sums;
    the rows are zeroed as they are read (the buffer is used again). Rows as one axis:
    8.9 against 20.9 ns per photon with the (n, 7, C) loops (C = 1)."""
    weighted = weight.shape[0] > 0
    G = out.shape[0]
    Q = ledger.shape[1]
    for i in range(ledger.shape[0]):
        g = group[lo + i]
        if g < 0 or g >= G:
            raise ValueError("tracer: a photon's group is outside 0 .. n_groups - 1")
        for q in range(Q):
            out[g, q] += ledger[i, q]
            ledger[i, q] = 0.0
        for c in range(emitted.shape[1]):
            v = power[lo + i, c] * weight[lo + i] if weighted else power[lo + i, c]
            emitted[g, c] += v


class _TraceLedger:
    """A trace's per-group ledgers (one per batch) and emitted flux, summed in photon
    order from the chunks' per-photon rows as the chunks finish, by whichever thread
    finishes one (chunk k is added once chunks 0..k−1 are): the same additions in the same
    order as one pass over the photons after the trace, and no serial pass on the main
    thread."""

    def __init__(self, group, power, weight, n_groups: int, channels: int,
                 pool: _LedgerPool) -> None:
        self.group, self.power, self.weight, self.pool = group, power, weight, pool
        self.n_groups, self.channels = n_groups, channels
        self.emitted = np.zeros((n_groups, channels))
        self.chunks: list[tuple[int, np.ndarray]] = []  # (first photon, batch's ledger)
        self.next = 0
        self.ready: dict[int, np.ndarray] = {}
        self.lock = threading.Lock()
        self.adding = threading.Lock()

    def add_batch(self, bounds: list[int]) -> tuple[int, np.ndarray]:
        """Chunks lo..hi of the next batch (absolute photon bounds, in photon order): the
        index of its first chunk and the batch's per-group ledger."""
        out = np.zeros((self.n_groups, len(LEDGER), self.channels))
        with self.lock:
            first = len(self.chunks)
            self.chunks.extend((a, out) for a in bounds[:-1])
        return first, out

    def done(self, k: int, rows: np.ndarray) -> None:
        """Chunk k's rows are final: add every chunk whose turn it is (or leave them to
        the thread adding now)."""
        with self.lock:
            self.ready[k] = rows
        while self.adding.acquire(blocking=False):
            try:
                while True:
                    with self.lock:
                        rows = self.ready.pop(self.next, None)
                        if rows is not None:
                            lo, out = self.chunks[self.next]
                    if rows is None:
                        break
                    _add_ledger(rows.reshape(len(rows), -1), self.group, self.power,
                                self.weight, lo, out.reshape(len(out), -1), self.emitted)
                    self.pool.put(rows)
                    self.next += 1
            finally:
                self.adding.release()
            with self.lock:  # a chunk may have come in after the last look
                if self.next not in self.ready:
                    return

    def check(self, upto: int) -> None:
        if self.next < upto:
            raise RuntimeError("tracer: a chunk's ledger was not summed")


class _LedgerPool:
    """Zeroed per-photon ledger buffers (rows, len(LEDGER), C) handed to chunks and
    returned zeroed by :func:`_add_ledger`: no fresh pages per batch."""

    def __init__(self, channels: int) -> None:
        self.channels = channels
        self.free: list[np.ndarray] = []
        self.lock = threading.Lock()

    def get(self, n: int) -> np.ndarray:
        with self.lock:
            for i, buf in enumerate(self.free):
                if len(buf) >= n:
                    return self.free.pop(i)[:n]
        return np.zeros((max(n, 1), len(LEDGER), self.channels))[:n]

    def put(self, rows: np.ndarray) -> None:
        base = rows if rows.base is None else rows.base
        with self.lock:
            if len(self.free) < 64:
                self.free.append(base)


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
    path : (n, K) int32 or None
        With path signatures (``path_length`` K > 0): the first K surface events of the
        photon's path before this record, each ``triangle · 4 + event`` (:data:`EVENTS`),
        −1 past the last.
    events : (n,) uint8 or None
        With path signatures: how many events the path had (up to 255; more than K: the
        path is longer than ``path`` shows).
    """

    position: np.ndarray
    normal: np.ndarray
    power: np.ndarray
    part: np.ndarray
    flags: np.ndarray
    source: np.ndarray
    path: np.ndarray | None = None
    events: np.ndarray | None = None

    @classmethod
    def empty(cls, channels: int) -> PhotonRecords:
        return cls(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32),
                   np.zeros((0, channels), np.float32), np.zeros(0, np.int32),
                   np.zeros(0, np.uint8), np.zeros(0, np.int64))

    @classmethod
    def concatenate(cls, parts: list[PhotonRecords], channels: int,
                    pool: ThreadPoolExecutor | None = None) -> PhotonRecords:
        """The parts' records in order; with a ``pool``, the fields are concatenated on its
        threads (NumPy copies without the GIL: the new arrays' page faults and copies of
        a large trace run in parallel instead of on one core after the trace)."""
        if not parts:
            return cls.empty(channels)
        fields = ("position", "normal", "power", "part", "flags", "source")
        paths = all(p.path is not None for p in parts)
        if pool is None or len(parts) == 1:
            out = cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in fields))
        else:
            order = ("position", "normal", "source", "power", "part", "flags")  # largest first
            fut = {f: pool.submit(np.concatenate, [getattr(p, f) for p in parts])
                   for f in order}
            out = cls(*(fut[f].result() for f in fields))
        if paths:
            out.path = np.concatenate([p.path for p in parts])
            out.events = np.concatenate([p.events for p in parts])
        return out

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


@njit(cache=True, nogil=True)
def sort_by_source(position, normal, power, part, flags, source, n_sources, first=0):
    """The records in stable order of ``source`` (a counting sort; ``source`` in
    [first, first + n_sources)): the same arrays as gathering every array through
    ``np.argsort(source, kind="stable")``."""
    n = source.shape[0]
    start = np.zeros(n_sources + 1, np.int64)
    for i in range(n):
        start[source[i] - first + 1] += 1
    for s in range(n_sources):
        start[s + 1] += start[s]
    C = power.shape[1]
    pos = np.empty((n, 3), position.dtype)
    nrm = np.empty((n, 3), normal.dtype)
    pw = np.empty((n, C), power.dtype)
    pt = np.empty(n, part.dtype)
    fl = np.empty(n, flags.dtype)
    src = np.empty(n, source.dtype)
    for i in range(n):
        s = source[i]
        k = start[s - first]
        start[s - first] = k + 1
        for a in range(3):
            pos[k, a] = position[i, a]
            nrm[k, a] = normal[i, a]
        for c in range(C):
            pw[k, c] = power[i, c]
        pt[k] = part[i]
        fl[k] = flags[i]
        src[k] = s
    return pos, nrm, pw, pt, fl, src


@njit(cache=True, nogil=True)
def sort_paths_by_source(path, events, source, n_sources, first=0):
    """``path`` and ``events`` of records in the stable order of ``source``, as
    :func:`sort_by_source` orders the other fields."""
    n = source.shape[0]
    start = np.zeros(n_sources + 1, np.int64)
    for i in range(n):
        start[source[i] - first + 1] += 1
    for s in range(n_sources):
        start[s + 1] += start[s]
    K = path.shape[1]
    pt = np.empty((n, K), path.dtype)
    ev = np.empty(n, events.dtype)
    for i in range(n):
        k = start[source[i] - first]
        start[source[i] - first] = k + 1
        for q in range(K):
            pt[k, q] = path[i, q]
        ev[k] = events[i]
    return pt, ev


def _path_buffer(rows: int, K: int) -> tuple[np.ndarray, np.ndarray]:
    """Empty path-signature record arrays (rows, max(K, 1)) int32 and (rows,) uint8."""
    return np.empty((rows, max(K, 1)), np.int32), np.empty(rows, np.uint8)


def _record_buffer(rows: int, C: int) -> RecordBuffer:
    """Empty record arrays of ``rows`` rows."""
    return RecordBuffer(np.empty((rows, 3), np.float32), np.empty((rows, 3), np.float32),
                        np.empty((rows, C), np.float32), np.empty(rows, np.int32),
                        np.empty(rows, np.uint8), np.empty(rows, np.int64))


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


def scene_caster(scene, threads: int | None = None) -> RayCaster:
    """A new ray caster of ``scene`` built the way :class:`PhotonTracer` builds its own
    (the wall outside embree when it can be), for callers that share one embree scene
    between tracers (the plan's pilot and the run's photon sets)."""
    return _caster_for(scene, None, threads)


class PhotonTracer:
    """Traces photon batches through a scene (see the module docstring for parameters)."""

    def __init__(self, scene, *, max_depth: int = 32, rr_threshold: float = 0.05,
                 rr_min_depth: int = 3, record: str = "wall", threads: int | None = None,
                 batch: int = 262144, caster: RayCaster | None = None,
                 min_chunk: int = 8192, path_length: int = 0) -> None:
        if record not in ("wall", "all"):
            raise ValueError("record must be 'wall' or 'all'")
        self.scene = scene
        self.max_depth = int(max_depth)
        self.rr_threshold = float(rr_threshold)
        self.rr_min_depth = int(rr_min_depth)
        self.record_all = record == "all"
        if not 0 <= int(path_length) <= 64:
            raise ValueError("path_length must be in 0..64")
        #: surface events a record keeps of its photon's path (0: no path signatures)
        self.path_length = int(path_length)
        self.batch = int(batch)
        self.caster = _caster_for(scene, caster, threads)
        self.emitters = EmitterMix.from_scene(scene)
        mats = scene.materials
        self.channels = mats.channels
        prev = getattr(caster, "geometry", None) if caster is not None else None
        of = getattr(caster, "geometry_of", None)  # the parts ``prev`` was packed from
        if prev is not None and of is not None and len(of) == len(scene.parts) and all(
                a is b for a, b in zip(of, scene.parts)):
            self.geometry = prev  # the very same parts (the plan's pilot and the run)
        elif (prev is not None and self.caster.exact_wall and self.caster is not caster
                and len(prev.tri_part) == self.caster.n_triangles):
            self.geometry = prev.with_wall_of(scene)  # same lamp, the wall moved
        else:
            self.geometry = Geometry.from_scene(scene)
        # the packed lamp rides with its embree scene: a tracer reusing this caster
        # (only the wall or materials changed) reuses the lamp's rows too
        self.caster.geometry = self.geometry
        if caster is not None and prev is None:  # the shared caster too, for the next
            caster.geometry, caster.geometry_of = self.geometry, tuple(scene.parts)
        #: the traced triangles as the bounce kernel reads them (:class:`Geometry`), with
        #: the exact wall of this tracer's caster (the bounce intersects the wall)
        self.geometry = self.geometry.for_caster(self.caster)
        self._mats = mats.arrays
        self.eps_floor = 0.01 * scene.scale
        self._params = TraceParams(self.eps_floor, self.rr_threshold, self.rr_min_depth,
                                   self.record_all)
        self.scene_extent = scene.extent  # no ray origin lies farther out than the geometry
        self.threads = self.caster.threads
        self.min_chunk = int(min_chunk)
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        self._ledgers = _LedgerPool(self.channels)
        #: seconds per stage ("emit", "start", "cast", "bounce") summed over all chunks
        #: and threads when set to a dict (a profile: :func:`stage_seconds`); None: off
        self.stages: dict[str, float] | None = None
        self._stages_lock = threading.Lock()

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
                     record_escaped: bool = False, by_source: bool = False) -> TraceResult:
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
        by_source : bool
            Records in photon order (each photon's in bounce order: a stable sort by
            ``source``, done per chunk on the tracer's threads) instead of bounce-major.
        """
        points = np.ascontiguousarray(points, dtype=np.float64)
        # photon power Φ · weight, made per chunk by the kernels (no (n, C) array here)
        power = np.broadcast_to(np.full(self.channels, float(self.emitters.flux_lm)),
                                (len(points), self.channels))
        weight = (np.zeros(0) if weight is None
                  else np.ascontiguousarray(weight, dtype=np.float64).reshape(len(points)))

        def source(lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
            return self.emitters.sample(points[lo:hi])  # photon i from point i only

        return self._trace(source, len(points), power, weight, keys, group, n_groups,
                           record_escaped, by_source)

    def trace(self, origins: np.ndarray, directions: np.ndarray, power: np.ndarray,
              keys: np.ndarray, group: np.ndarray | None = None, n_groups: int = 1,
              record_escaped: bool = False, by_source: bool = False) -> TraceResult:
        """Trace photons given their origins (m), unit directions and powers (n, C).

        The ledger is (n_groups, len(LEDGER), C); per group it is summed in photon order,
        so a set's bookkeeping is bit-identical however sets are batched together.
        ``by_source``: records in photon order, as :meth:`trace_points`.
        """
        def source(lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
            # copies: the tracer moves its rays in place
            return (np.array(origins[lo:hi], dtype=np.float64),
                    np.array(directions[lo:hi], dtype=np.float64))

        power = np.asarray(power, dtype=np.float64).reshape(len(origins), self.channels)
        return self._trace(source, len(origins), power, np.zeros(0), keys, group, n_groups,
                           record_escaped, by_source)

    def _trace(self, source, n: int, power: np.ndarray, weight: np.ndarray, keys: np.ndarray,
               group: np.ndarray | None, n_groups: int, record_escaped: bool,
               by_source: bool = False) -> TraceResult:
        """Photon i: emitted by ``source``, flux ``power[i]`` × ``weight[i]`` (``weight``
        empty: ``power[i]``); ``by_source``: records in photon order (each chunk's sorted
        on its thread, the chunks in photon order)."""
        C = self.channels
        keys = np.asarray(keys, dtype=np.uint64)
        group = np.zeros(n, np.int64) if group is None else np.asarray(group, np.int64)
        parts: list[PhotonRecords] = []
        ledger = np.zeros((n_groups, len(LEDGER), C))
        esc_d, esc_p = [], []
        caustic_source = np.zeros(n, dtype=np.bool_)  # marked by the bounce kernel
        sums = _TraceLedger(group, power, weight, n_groups, C, self._ledgers)
        rays = 0
        # two batches in flight: the next batch's chunks are queued before a batch is
        # collected, so no thread idles at a batch's tail (memory: two batch ledgers)
        pending: list = []
        done = []
        for lo in range(0, n, self.batch):
            hi = min(n, lo + self.batch)
            pending.append(self._submit_batch(source, lo, hi, power, weight, keys,
                                              record_escaped, sums, caustic_source, hi == n,
                                              by_source))
            if len(pending) > 1:
                done.append(self._collect_batch(pending.pop(0)))
        done.extend(self._collect_batch(b) for b in pending)
        for recs, led, nrays, ed, ep in done:
            parts.extend(recs)
            ledger += led
            rays += nrays
            if record_escaped:
                esc_d.append(ed)
                esc_p.append(ep)
        sums.check(len(sums.chunks))
        return TraceResult(PhotonRecords.concatenate(parts, C, self._pool), sums.emitted,
                           ledger, rays,
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
        prim, tfar, bu, bv = self.caster.cast_lamp(o32, d32)  # the wall: in _bounce
        # a cheap global bound first: only rays that hit very close need the per-ray test
        bound = 4 * 3.814697265625e-06 * (self.scene_extent + self.eps_floor)
        near = near_hits(prim, tfar, bound)
        if len(near) == 0:
            return Hits(prim, tfar, bu, bv)
        tri, fn = self.geometry.tri_v, self.geometry.face_n
        for _ in range(3):
            close, step = false_hits(near, o, d, prim, tfar, self.eps_floor, tri, fn)
            if len(close) == 0:
                break
            p2, t2, u2, v2 = self.caster.cast_lamp(
                np.ascontiguousarray(o[close] + step[:, None] * d[close], dtype=np.float32),
                np.ascontiguousarray(d32[close]))
            prim[close], tfar[close], bu[close], bv[close] = p2, t2 + step, u2, v2
        return Hits(prim, tfar, bu, bv)

    def _trace_chunk(self, source, lo: int, hi: int, power, weight, keys, ledger, base,
                     caustic, record_escaped, by_source=False):
        """Trace photons lo..hi to the end in this thread: emit, then per bounce one embree
        cast and one fused interaction + compaction kernel. ``source(lo, hi)`` returns new
        arrays of origins and directions (they become the wavefront); photon lo + i is
        photon base + i of the trace (its records' source), its ledger row is
        ``ledger[i]``. Returns per-bounce records (with ``by_source`` one part, sorted by
        photon: :func:`sort_by_source`), escaped photons and the ray count."""
        n = hi - lo
        C = self.channels
        clock = time.perf_counter if self.stages is not None else None
        t_emit = t_start = t_cast = t_bounce = 0.0
        t0 = clock() if clock else 0.0
        origins, directions = source(lo, hi)  # fresh arrays: traced in place
        o = np.ascontiguousarray(origins, dtype=np.float64).reshape(n, 3)
        d = np.ascontiguousarray(directions, dtype=np.float64).reshape(n, 3)
        if clock:
            t1 = clock()
            t_emit = t1 - t0
        pw, p_ref, flags, kk, lid, o32, d32 = _start(o, d, power, weight, keys, lo, hi, base)
        if clock:
            t_start = clock() - t1
        wf = Wavefront(o, d, pw, p_ref, flags, kk, lid)
        K = self.path_length
        # path signatures: the rays' events so far and the records' copies (none: 0 rows)
        hist = np.full((n if K else 0, max(K, 1)), -1, np.int32)
        nev = np.zeros(n if K else 0, np.uint8)
        pbuf = _path_buffer(n if K else 0, K)
        recs: list[PhotonRecords] = []
        escs: list[tuple[np.ndarray, np.ndarray]] = []
        rays = 0
        m = n
        # one record buffer for the chunk, each bounce writing after the last: with
        # record="wall" a photon records once (the wall ends it), so n rows hold them all;
        # a buffer per bounce kept m rows alive for the few records most bounces make
        buf = _record_buffer(n, C)
        r0 = 0
        for depth in range(self.max_depth):
            if m == 0:
                break
            if clock:
                t0 = clock()
            hits = self._cast(o[:m], d[:m], o32[:m], d32[:m])
            if clock:
                t1 = clock()
                t_cast += t1 - t0
            rays += m
            if len(buf.source) - r0 < m:  # record="all": a bounce may record every ray
                buf, r0 = _record_buffer(max(2 * len(buf.source), m), C), 0  # parts kept
                pbuf = _path_buffer(len(buf.source) if K else 0, K)
            rb = RecordBuffer(*(a[r0:] for a in buf))
            esc = ((np.empty((m, 3), np.float32), np.empty((m, C))) if record_escaped
                   else (np.empty((0, 3), np.float32), np.empty((0, C))))
            m, r, e = _bounce(wf, m, hits, self.geometry, self._mats, self._params, depth,
                              depth == self.max_depth - 1, rb, ledger, base, caustic, o32,
                              d32, esc[0], esc[1], record_escaped, hist, nev,
                              pbuf[0][r0:] if K else pbuf[0], pbuf[1][r0:] if K else pbuf[1])
            if clock:
                t_bounce += clock() - t1
            recs.append(PhotonRecords(*(a[r0:r0 + r] for a in buf)))
            if K:
                recs[-1].path, recs[-1].events = pbuf[0][r0:r0 + r], pbuf[1][r0:r0 + r]
            r0 += r
            escs.append((esc[0][:e], esc[1][:e]))
        if by_source and recs:  # one part: the chunk's records in photon order
            if r0 == sum(map(len, recs)):  # one buffer: its prefix, no copy
                whole = PhotonRecords(*(a[:r0] for a in buf))
                if K:
                    whole.path, whole.events = pbuf[0][:r0], pbuf[1][:r0]
            else:  # buffers replaced: join them
                whole = PhotonRecords.concatenate(recs, C)
            recs = [PhotonRecords(*sort_by_source(
                whole.position, whole.normal, whole.power, whole.part, whole.flags,
                whole.source, n, base))]
            if K:
                recs[0].path, recs[0].events = sort_paths_by_source(
                    whole.path, whole.events, whole.source, n, base)
        if clock:
            with self._stages_lock:
                for k, v in (("emit", t_emit), ("start", t_start), ("cast", t_cast),
                             ("bounce", t_bounce)):
                    self.stages[k] = self.stages.get(k, 0.0) + v
        return recs, escs, rays

    def _submit_batch(self, source, lo, hi, power, weight, keys, record_escaped, sums,
                      caustic, last, by_source=False):
        """Queue one batch's chunks on the threads (or trace them here without a pool);
        :meth:`_collect_batch` waits for them. Each chunk books into its own per-photon
        ledger rows, summed per group in photon order as the chunks finish
        (:class:`_TraceLedger`). The trace's last batch ends in smaller chunks (each a
        share of what is left), so the threads finish about together."""
        n = hi - lo
        T = self.threads
        step = max(self.min_chunk, -(-n // (4 * T)))
        if last and T > 1:
            bounds, a = [0], 0
            while a < n:
                a = min(n, a + max(self.min_chunk, min(step, -(-(n - a) // (2 * T)))))
                bounds.append(a)
        else:
            bounds = list(range(0, n, step)) + [n]
        first, led = sums.add_batch([lo + a for a in bounds])
        w = weight[lo:hi] if len(weight) else weight

        def work(k: int):
            a, b = bounds[k], bounds[k + 1]
            rows = self._ledgers.get(b - a)
            out = self._trace_chunk(lambda x, y: source(lo + x, lo + y), a, b,
                                    power[lo:hi], w, keys[lo:hi], rows, lo + a, caustic,
                                    record_escaped, by_source)
            sums.done(first + k, rows)
            return out

        if self._pool is None or len(bounds) <= 2:
            chunks = [work(k) for k in range(len(bounds) - 1)]
        else:
            chunks = [self._pool.submit(work, k) for k in range(len(bounds) - 1)]
        return led, chunks

    def _collect_batch(self, batch):
        """One batch's records in (bounce, photon) order (a list of the chunks' bounces,
        concatenated once per trace by :meth:`_trace`; with ``by_source`` every chunk has
        one part, so they come in chunk order, which is photon order) and its per-group
        ledger (final once every earlier chunk of the trace is summed:
        :meth:`_TraceLedger.check`)."""
        led, chunks = batch
        chunks = [c.result() if hasattr(c, "result") else c for c in chunks]
        C = self.channels
        # bounce-major like one wavefront: bounce 0 of every chunk, then bounce 1, …
        depth = max((len(c[0]) for c in chunks), default=0)
        recs = [c[0][k] for k in range(depth) for c in chunks if k < len(c[0])]
        escs = [c[1][k] for k in range(depth) for c in chunks if k < len(c[1])]
        rays = sum(c[2] for c in chunks)
        ed = np.concatenate([e[0] for e in escs]) if escs else np.zeros((0, 3), np.float32)
        ep = np.concatenate([e[1] for e in escs]) if escs else np.zeros((0, C))
        return recs, led, rays, ed, ep
