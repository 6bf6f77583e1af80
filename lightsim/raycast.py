"""Ray casting with embree (embreex): the only place rays meet triangles.

One embree scene is built per geometry (``embree_scene``: the corners copied by NumPy into
embree's buffers; build once per geometry change, never per frame). ``run()`` of embreex is
single-threaded but releases the GIL, so a batch is split over a pool of Python threads.

The measuring wall can be kept out of the embree scene (``wall`` mask): its few triangles
are then intersected exactly (float64 Möller–Trumbore) after embree's closest hit, and
:meth:`RayCaster.with_wall` places the wall anew while sharing the lamp's embree scene —
aiming the lamp (the wall moved the opposite way about the lamp) or changing the wall
distance costs no BVH rebuild. Hits keep the indices of the full triangle soup.

=============  =====  ========================  ==========================================
parameter      unit   default                   meaning
=============  =====  ========================  ==========================================
``threads``    –      all cores (``os.cpu_count``)  threads casting one batch in parallel
``min_chunk``  rays   8192                      smallest batch piece given to one thread
``wall``       –      none                      (T,) bool: triangles intersected exactly,
                                                outside embree (at most WALL_MAX_TRIANGLES)
=============  =====  ========================  ==========================================
"""

from __future__ import annotations

import ctypes
import functools
import glob
import os
from concurrent.futures import ThreadPoolExecutor

import embreex
import numpy as np
from embreex import rtcore as rtc
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh
from numba import njit

WALL_MAX_TRIANGLES = 64  # a wall with more triangles stays in the embree scene
_MISS_T = np.float32(1e37)  # embree's tfar of a miss

# embree 4's enums (rtcore_common.h, rtcore_buffer.h, rtcore_geometry.h)
_RTC_GEOMETRY_TYPE_TRIANGLE = 0
_RTC_BUFFER_TYPE_INDEX, _RTC_BUFFER_TYPE_VERTEX = 0, 1
_RTC_FORMAT_UINT3, _RTC_FORMAT_FLOAT3 = 0x5003, 0x9003


def embree_scene(triangles: np.ndarray, fast: bool = True):
    """An embreex ``EmbreeScene`` holding one triangle mesh (uncommitted).

    embreex's ``TriangleMesh`` copies the corners into embree's buffers one Python-level
    indexing at a time (~2 µs per triangle: 0.25 s for the 131 k triangles of the peer
    bench's mirror). With ``fast``, the same embree calls are made through ctypes on the
    library embreex loaded and the corners are copied by NumPy; this needs the scene's
    embree handles, read from the ``EmbreeScene`` object's C layout, which is checked
    first (``embree_handles``). Where the check fails (another embreex build) the slow
    path is taken, so the result is always the same mesh.

    Parameters
    ----------
    triangles : (T, 3, 3) float32
        Corners (m), C-contiguous.
    fast : bool
        Try the ctypes path first.
    """
    device = rtc.EmbreeDevice()
    scene = rtcs.EmbreeScene(device)
    if fast and len(triangles) and _fill_fast(scene, device, triangles):
        return scene
    TriangleMesh(scene, triangles)
    return scene


@functools.lru_cache(maxsize=1)
def _embree_lib():
    """The libembree4 embreex's extension modules are linked against (ctypes), or None
    (looked up once)."""
    try:
        return _load_embree_lib()
    except Exception:  # any failure means: use embreex's own path
        return None


def _load_embree_lib():
    root = os.path.dirname(os.path.abspath(embreex.__file__))
    for pattern in ("../embreex.libs/libembree4*.so*", ".dylibs/libembree4*.dylib",
                    "libembree4*.so*", "../embreex.libs/embree4*.dll", "embree4*.dll"):
        found = sorted(glob.glob(os.path.join(root, pattern)))
        if found:
            try:
                lib = ctypes.CDLL(found[0])
            except OSError:
                return None
            vp, u32, sz = ctypes.c_void_p, ctypes.c_uint, ctypes.c_size_t
            for name, res, args in (
                    ("rtcNewGeometry", vp, [vp, ctypes.c_int]),
                    ("rtcSetNewGeometryBuffer", vp, [vp, ctypes.c_int, u32, ctypes.c_int,
                                                     sz, sz]),
                    ("rtcCommitGeometry", None, [vp]),
                    ("rtcAttachGeometry", u32, [vp, vp]),
                    ("rtcReleaseGeometry", None, [vp]),
                    ("rtcGetSceneDevice", vp, [vp]),
                    ("rtcReleaseDevice", None, [vp])):
                fn = getattr(lib, name, None)
                if fn is None:
                    return None
                fn.restype, fn.argtypes = res, args
            return lib
    return None


def embree_handles(scene, device) -> tuple[int, int] | None:
    """(RTCScene, RTCDevice) pointers of an embreex scene made with ``device``, or None.

    embreex declares ``EmbreeScene`` as {RTCScene scene_i; public int is_committed;
    EmbreeDevice device} and ``EmbreeDevice`` as {RTCDevice device}, after the object
    header. The layout is trusted only if the object sizes match, the ``device`` slot
    holds this very ``device`` object and ``is_committed`` reads back what was set.
    """
    head = object.__basicsize__  # PyObject header: refcount and type
    ptr = ctypes.sizeof(ctypes.c_void_p)
    if (type(scene).__basicsize__ != head + 3 * ptr
            or type(device).__basicsize__ != head + ptr):
        return None
    base = id(scene)
    if ctypes.c_void_p.from_address(base + head + 2 * ptr).value != id(device):
        return None
    saved = scene.is_committed
    scene.is_committed = 0x2BAD5EED
    ok = ctypes.c_int.from_address(base + head + ptr).value == 0x2BAD5EED
    scene.is_committed = saved
    if not ok:
        return None
    return (ctypes.c_void_p.from_address(base + head).value,
            ctypes.c_void_p.from_address(id(device) + head).value)


def _fill_fast(scene, device, tri: np.ndarray) -> bool:
    """Attach ``tri`` to ``scene`` through ctypes (see :func:`embree_scene`); False where
    that cannot be done safely (nothing attached then)."""
    lib = _embree_lib()
    handles = None if lib is None else embree_handles(scene, device)
    if handles is None or not handles[0] or not handles[1]:
        return False
    rtc_scene, rtc_device = handles
    owner = lib.rtcGetSceneDevice(rtc_scene)  # a second check: the scene is the device's
    if owner:
        lib.rtcReleaseDevice(owner)
    if owner != rtc_device:
        return False
    nt = len(tri)
    geom = lib.rtcNewGeometry(rtc_device, _RTC_GEOMETRY_TYPE_TRIANGLE)
    if not geom:
        return False
    vb = lib.rtcSetNewGeometryBuffer(geom, _RTC_BUFFER_TYPE_VERTEX, 0, _RTC_FORMAT_FLOAT3,
                                     16, 3 * nt)
    ib = lib.rtcSetNewGeometryBuffer(geom, _RTC_BUFFER_TYPE_INDEX, 0, _RTC_FORMAT_UINT3,
                                     12, nt)
    if not vb or not ib:
        lib.rtcReleaseGeometry(geom)
        return False
    # the vertex buffer's stride is 16 bytes (x, y, z, pad), as embreex's Vertex
    verts = np.ctypeslib.as_array((ctypes.c_float * (12 * nt)).from_address(vb))
    verts.reshape(3 * nt, 4)[:, :3] = tri.reshape(3 * nt, 3)
    index = np.ctypeslib.as_array((ctypes.c_uint * (3 * nt)).from_address(ib))
    index[:] = np.arange(3 * nt, dtype=np.uint32)
    lib.rtcCommitGeometry(geom)
    lib.rtcAttachGeometry(rtc_scene, geom)
    lib.rtcReleaseGeometry(geom)
    return True


@njit(cache=True, nogil=True, inline="always")
def _tri_hit(ox, oy, oz, dx, dy, dz, tri):
    """Möller–Trumbore in float64, both sides: (t, u, v), t = inf for a miss."""
    e1x, e1y, e1z = tri[1, 0] - tri[0, 0], tri[1, 1] - tri[0, 1], tri[1, 2] - tri[0, 2]
    e2x, e2y, e2z = tri[2, 0] - tri[0, 0], tri[2, 1] - tri[0, 1], tri[2, 2] - tri[0, 2]
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return np.inf, 0.0, 0.0
    inv = 1.0 / det
    sx, sy, sz = ox - tri[0, 0], oy - tri[0, 1], oz - tri[0, 2]
    u = (sx * px + sy * py + sz * pz) * inv
    if u < 0.0 or u > 1.0:
        return np.inf, 0.0, 0.0
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < 0.0 or u + v > 1.0:
        return np.inf, 0.0, 0.0
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if not t > 0.0:
        return np.inf, 0.0, 0.0
    return t, u, v


@njit(cache=True, nogil=True, inline="always")
def merge_wall_hit(i, o, d, prim, tfar, u, v, wall_tri, wall_index):
    """Ray i of float32 rays o, d: let a nearer hit on the wall's triangles replace the
    (soup-indexed) hit in prim/tfar/u/v — the wall half of :meth:`RayCaster.cast`."""
    best = np.inf if prim[i] < 0 else float(tfar[i])
    ox, oy, oz = float(o[i, 0]), float(o[i, 1]), float(o[i, 2])
    dx, dy, dz = float(d[i, 0]), float(d[i, 1]), float(d[i, 2])
    for w in range(wall_tri.shape[0]):
        t, bu, bv = _tri_hit(ox, oy, oz, dx, dy, dz, wall_tri[w])
        if t < best:
            best = t
            prim[i] = wall_index[w]
            tfar[i] = t
            u[i] = bu
            v[i] = bv


@njit(cache=True, nogil=True)
def _merge_wall(o, d, prim, tfar, u, v, lamp_index, wall_tri, wall_index):
    """Map embree's primitive ids to the full soup and let a nearer wall hit win.

    ``lamp_index`` (E,) maps embree ids to soup indices (empty: identity); ``wall_tri``
    (W, 3, 3) float64 and ``wall_index`` (W,) are the wall's triangles and soup indices.
    Updates ``prim``/``tfar``/``u``/``v`` in place.
    """
    remap = lamp_index.shape[0] > 0
    for i in range(prim.shape[0]):
        k = prim[i]
        if k >= 0 and remap:
            prim[i] = lamp_index[k]  # a soup index, ≥ 0 exactly when embree hit
        merge_wall_hit(i, o, d, prim, tfar, u, v, wall_tri, wall_index)


class RayCaster:
    """Closest-hit queries against a fixed triangle soup.

    Parameters
    ----------
    triangles : (T, 3, 3) array
        Triangle corners (m); converted to float32 for embree.
    threads : int, optional
        Threads per batch (default: all cores).
    wall : (T,) bool, optional
        Triangles kept out of embree and intersected exactly (the measuring wall; at most
        ``WALL_MAX_TRIANGLES``); :meth:`with_wall` moves them without a rebuild.
    """

    def __init__(self, triangles: np.ndarray, threads: int | None = None,
                 min_chunk: int = 8192, wall: np.ndarray | None = None) -> None:
        triangles = np.asarray(triangles)
        self.n_triangles = len(triangles)
        self.threads = max(1, int(threads or os.cpu_count() or 1))
        self.min_chunk = int(min_chunk)
        #: the lamp's embree scene (None without lamp triangles), shared by the casters
        #: :meth:`with_wall` makes
        self.lamp_scene = None
        mask = (np.zeros(self.n_triangles, np.bool_) if wall is None
                else np.asarray(wall, dtype=np.bool_).reshape(-1))
        if len(mask) != self.n_triangles:
            raise ValueError("wall mask: one entry per triangle")
        if mask.sum() > WALL_MAX_TRIANGLES:
            raise ValueError(f"an exactly intersected wall has at most {WALL_MAX_TRIANGLES} "
                             "triangles")
        lamp = np.flatnonzero(~mask).astype(np.int32)
        self._wall_index = np.flatnonzero(mask).astype(np.int32)
        self._wall_tri = np.ascontiguousarray(triangles[mask], dtype=np.float64).reshape(-1, 3, 3)
        # embree ids are soup ids when the wall comes last (or there is none)
        identity = len(lamp) == 0 or lamp[-1] == len(lamp) - 1
        self._lamp_index = np.zeros(0, np.int32) if identity else lamp
        self.n_lamp = len(lamp)
        if len(lamp):
            self.lamp_scene = embree_scene(np.ascontiguousarray(triangles[lamp], np.float32))
            # commit now, in one thread: embreex commits lazily on the first run()
            self.lamp_scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        self.geometry = None  # the tracer's packed triangles of this soup (set by it)

    @property
    def exact_wall(self) -> bool:
        """True if the wall is intersected outside embree (movable by :meth:`with_wall`)."""
        return len(self._wall_index) > 0

    def with_wall(self, wall_triangles: np.ndarray) -> RayCaster:
        """The same lamp (embree scene shared, not rebuilt) with the wall's triangles at
        new places.

        Parameters
        ----------
        wall_triangles : (W, 3, 3) array
            The wall's triangles (m), in the order of the ``wall`` mask this caster was
            built with (e.g. ``scene.triangles[scene.tri_is_wall]`` of a scene made by
            :meth:`~lightsim.scene.Scene.with_wall_transform`).

        Returns
        -------
        RayCaster
            A new caster with its own thread pool; this one stays valid.
        """
        tri = np.ascontiguousarray(wall_triangles, dtype=np.float64).reshape(-1, 3, 3)
        if len(tri) != len(self._wall_index) or not self.exact_wall:
            raise ValueError(f"with_wall: this caster's wall has {len(self._wall_index)} "
                             f"triangles, got {len(tri)}")
        if not np.all(np.isfinite(tri)):
            raise ValueError("with_wall: wall triangles must be finite")
        out = object.__new__(RayCaster)
        out.__dict__.update(self.__dict__)
        out._wall_tri = tri
        out._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        return out

    @property
    def wall_triangles(self) -> np.ndarray:
        """(W, 3, 3) float64 corners of the exactly intersected wall (empty if none)."""
        return self._wall_tri

    @property
    def wall_index(self) -> np.ndarray:
        """(W,) int32 soup indices of the wall's triangles."""
        return self._wall_index

    def cast_lamp(self, origins: np.ndarray, directions: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Like :meth:`cast` but without the exact wall (embree's scene only, soup
        indices): for a caller that intersects :attr:`wall_triangles` itself in its own
        pass over the rays (:func:`merge_wall_hit` gives the same answer as :meth:`cast`)."""
        n = len(origins)
        if n == 0 or self.lamp_scene is None:
            return (np.full(n, -1, dtype=np.int32), np.full(n, _MISS_T, dtype=np.float32),
                    np.zeros(n, dtype=np.float32), np.zeros(n, dtype=np.float32))
        res = self.lamp_scene.run(origins, directions, output=1)
        prim, tfar, u, v = res["primID"], res["tfar"], res["u"], res["v"]
        if len(self._lamp_index):
            _merge_wall(origins, directions, prim, tfar, u, v, self._lamp_index,
                        self._wall_tri[:0], self._wall_index[:0])
        return prim, tfar, u, v

    def _run(self, o: np.ndarray, d: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """embree's closest hits of float32 rays, merged with the exact wall."""
        n = len(o)
        if self.lamp_scene is not None:
            res = self.lamp_scene.run(o, d, output=1)
            prim, tfar, u, v = res["primID"], res["tfar"], res["u"], res["v"]
        else:
            prim = np.full(n, -1, dtype=np.int32)
            tfar = np.full(n, _MISS_T, dtype=np.float32)
            u = np.zeros(n, dtype=np.float32)
            v = np.zeros(n, dtype=np.float32)
        if len(self._wall_index) or len(self._lamp_index):
            _merge_wall(o, d, prim, tfar, u, v, self._lamp_index, self._wall_tri,
                        self._wall_index)
        return prim, tfar, u, v

    def intersect(self, origins: np.ndarray, directions: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Closest hits of rays.

        Parameters
        ----------
        origins, directions : (n, 3) arrays
            Ray origins (m) and unit directions; cast to float32.

        Returns
        -------
        prim : (n,) int32
            Triangle index, −1 for a miss.
        t : (n,) float32
            Hit distance (m); undefined for misses.
        u, v : (n,) float32
            Barycentric coordinates of the hit (weights of corners 1 and 2).
        """
        n = len(origins)
        prim = np.full(n, -1, dtype=np.int32)
        t = np.full(n, np.inf, dtype=np.float32)
        u = np.zeros(n, dtype=np.float32)
        v = np.zeros(n, dtype=np.float32)
        if n == 0 or self.n_triangles == 0:
            return prim, t, u, v
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)

        def run(lo: int, hi: int) -> None:
            prim[lo:hi], t[lo:hi], u[lo:hi], v[lo:hi] = self._run(o[lo:hi], d[lo:hi])

        pieces = min(self.threads, max(1, n // self.min_chunk))
        if pieces == 1 or self._pool is None:
            run(0, n)
        else:
            bounds = np.linspace(0, n, pieces + 1).astype(np.int64)
            list(self._pool.map(lambda k: run(bounds[k], bounds[k + 1]), range(pieces)))
        return prim, t, u, v

    def cast(self, origins: np.ndarray, directions: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Closest hits of one batch in the calling thread, as embree returns them.

        Like :meth:`intersect` without the thread pool and the copies: for callers that
        run their own threads (the photon tracer casts one wavefront chunk per thread).
        ``origins``/``directions`` must be C-contiguous (n, 3) float32.
        """
        n = len(origins)
        if n == 0 or self.n_triangles == 0:
            return (np.full(n, -1, dtype=np.int32), np.full(n, np.inf, dtype=np.float32),
                    np.zeros(n, dtype=np.float32), np.zeros(n, dtype=np.float32))
        return self._run(origins, directions)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None

    def __del__(self) -> None:  # pragma: no cover - best effort
        self.close()
