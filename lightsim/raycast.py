"""Ray casting with embree (embreex): the only place rays meet triangles.

One embree scene is built per geometry (building copies the vertices, which is slow for
large meshes: build once per geometry change, never per frame). ``run()`` of embreex is
single-threaded but releases the GIL, so a batch is split over a pool of Python threads.

=============  =====  ========================  ==========================================
parameter      unit   default                   meaning
=============  =====  ========================  ==========================================
``threads``    –      all cores (``os.cpu_count``)  threads casting one batch in parallel
``min_chunk``  rays   8192                      smallest batch piece given to one thread
=============  =====  ========================  ==========================================
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np


class RayCaster:
    """Closest-hit queries against a fixed triangle soup.

    Parameters
    ----------
    triangles : (T, 3, 3) array
        Triangle corners (m); converted to float32 for embree.
    threads : int, optional
        Threads per batch (default: all cores).
    """

    def __init__(self, triangles: np.ndarray, threads: int | None = None,
                 min_chunk: int = 8192) -> None:
        self.n_triangles = len(triangles)
        self.threads = max(1, int(threads or os.cpu_count() or 1))
        self.min_chunk = int(min_chunk)
        self._scene = None
        if self.n_triangles:
            from embreex import rtcore_scene as rtcs
            from embreex.mesh_construction import TriangleMesh

            self._scene = rtcs.EmbreeScene()
            TriangleMesh(self._scene, np.ascontiguousarray(triangles, dtype=np.float32))
            # commit now, in one thread: embreex commits lazily on the first run()
            self._scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None

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
        if n == 0 or self._scene is None:
            return prim, t, u, v
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)

        def run(lo: int, hi: int) -> None:
            res = self._scene.run(o[lo:hi], d[lo:hi], output=1)
            prim[lo:hi] = res["primID"]
            t[lo:hi] = res["tfar"]
            u[lo:hi] = res["u"]
            v[lo:hi] = res["v"]

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
        if n == 0 or self._scene is None:
            return (np.full(n, -1, dtype=np.int32), np.full(n, np.inf, dtype=np.float32),
                    np.zeros(n, dtype=np.float32), np.zeros(n, dtype=np.float32))
        res = self._scene.run(origins, directions, output=1)
        return res["primID"], res["tfar"], res["u"], res["v"]

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None

    def __del__(self) -> None:  # pragma: no cover - best effort
        self.close()
