"""kNN estimates at fixed wall points in memory that does not grow with the photons.

A run whose outputs read kNN estimates only at points known before it starts (the
cut-off scans' sample points, the error grid) does not need every photon: each set
accumulates, frame by frame, just what its estimates at those points will read, and
drops the rest. For a point q the estimate (:mod:`lightsim.photonmap.density`) reads

* r_lo-sums: ΣΦ·w and the count of the photons within r_lo (the radius floor) — once at
  least k photons lie within r_lo the estimate is ΣΦ·w / (π r_lo²) (box kernel) for ever
  after: the k-th neighbour only comes closer as photons arrive. These sums are added
  per frame and the photons dropped (the "resolved" points; progressive photon mapping's
  per-point statistics, with the radius already at its floor);
* otherwise the k nearest photons within r_max: kept in a pool of candidates (the
  photons within r_max of a point not yet resolved), cut back to each unresolved point's
  k nearest whenever it has doubled — at most k photons per unresolved point.

So the estimates are those of a map of every photon: the same photons enter the same
sums (float64 sums of float32 powers, exact in practice, so bit for bit in the tests);
only the order of additions differs. Memory: P points × (C + 1) numbers, plus the pool
(≤ 2 k photons per unresolved point), whatever the photon count.

Parameters
----------
==================  =====  =========  ===============================================
name                unit   default    meaning
==================  =====  =========  ===============================================
``points``          m      —          (P, 3) world points on the wall (the registered
                                      points; estimates anywhere else are refused)
``normal``          —      —          (3,) the wall's normal (the normal filter)
``k``               —      64         photons per estimate
``max_radius``      m      —          r_max: photons farther never count
``min_radius``      m      —          r_lo: the radius floor
``kernel``          —      ``box``    ``box``, ``cone`` or ``epanechnikov``
``normal_cos``      —      0.5        photons with n · n_wall below this are ignored
``POOL_SLACK``      —      2          the pool is cut back when it has grown this much
==================  =====  =========  ===============================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lightsim.errors import InputError
from lightsim.photonmap.common import R_FLOOR_REL, Estimate, as_unit_normals
from lightsim.photonmap.density import PhotonMap

POOL_SLACK = 2.0
#: photons the pool may gain before it is cut back (per set; 0.9 MB of pool). Small
#: enough that a run's first cut comes early (the README lamp's sets pool ~16 000
#: photons each per 10 M shot), so the pool's peak is the same at 50 M and 500 M
#: photons; each cut's kNN queries cost about one frame's insertion
POOL_MIN = 2**15
#: points whose r_lo-sums are added at once: bounds the (point, photon) pairs in memory
SUM_POINTS = 512
#: bytes one pooled photon takes (position, normal, power per channel: float32)
POOL_PHOTON_BYTES = 24
KERNELS = ("box", "cone", "epanechnikov")


def kernel_weight(kernel: str, d2: np.ndarray, r: float) -> np.ndarray:
    """Unnormalised weights (as the density kernels compute them) of photons at squared
    distances ``d2`` (m²) for radius ``r`` (m)."""
    if kernel == "box":
        return np.ones_like(d2)
    w = 1.0 - np.sqrt(d2) / r if kernel == "cone" else 1.0 - d2 / (r * r)
    return np.maximum(w, 0.0)


def kernel_norm(kernel: str, r: float) -> float:
    """1 / kernel integral (1/m²) for radius ``r`` (m), as the density kernels compute it."""
    if kernel == "box":
        return 1.0 / (math.pi * r * r)
    if kernel == "cone":
        return 3.0 / (math.pi * r * r)
    return 2.0 / (math.pi * r * r)


def floor_holds(min_radius: float, scale_m: float) -> bool:
    """Whether ``min_radius`` (m) is at least the density floor of any photon map of a
    scene whose coordinates stay within ``scale_m`` (m): then the floor is r_lo itself,
    known before any photon, and the r_lo-sums can be added frame by frame."""
    return float(min_radius) >= R_FLOOR_REL * max(1.0, float(scale_m)) * (1.0 + 1e-9)


class PointStore:
    """One set's kNN statistics at fixed points, photons dropped after each frame (see
    the module docstring). Takes the place of a photon map: :meth:`add` per frame,
    :meth:`estimate` at registered points, ``len()`` the photons added."""

    def __init__(self, points: np.ndarray, normal: np.ndarray, channels: int, *, k: int,
                 max_radius: float, min_radius: float, kernel: str = "box",
                 normal_cos: float = 0.5) -> None:
        if kernel not in KERNELS:
            raise InputError(f"unknown kernel {kernel!r}; choose one of {', '.join(KERNELS)}")
        # as a photon map sees them: float32 query points and a float32 normal made unit
        # in float64 (the estimator hands both over as float32)
        self.points = np.asarray(points, dtype=np.float32).reshape(-1, 3).astype(np.float64)
        self._normal32 = np.asarray(normal, np.float32).reshape(1, 3)
        self.normal = as_unit_normals(self._normal32, 1, np.float64, "wall normal")[0]
        self.channels = int(channels)
        self.k, self.kernel, self.normal_cos = int(k), kernel, float(normal_cos)
        self.max_radius, self.min_radius = float(max_radius), float(min_radius)
        self.r_lo = min(self.min_radius, self.max_radius)
        P = len(self.points)
        self.acc = np.zeros((P, self.channels))  # ΣΦ·w within r_lo (lm)
        self.count = np.zeros(P, np.int64)  # photons within r_lo
        self._tree = None
        if P:  # scipy.spatial pulls scipy.linalg in: only runs that register points pay it
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self.points)
        self._cells: dict[float, tuple] = {}  # reach → (lo, cell, shape, mask, box)
        # pooled photons: positions, normals, powers, already in the r_lo-sums
        self._pool: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._open = P > 0  # some point not yet resolved (at the last cut)
        self._pool_n = 0
        self._pool_cut = 0  # pool size after its last cut
        self.added = 0  # photons added in all

    def __len__(self) -> int:
        return self.added

    @property
    def resolved(self) -> np.ndarray:
        """(P,) bool: points whose estimate is their r_lo-sum for good."""
        return self.count >= self.k

    @property
    def kept(self) -> int:
        """Photons held in the pool (the store's only part that moves with photons)."""
        return self._pool_n

    def nbytes(self) -> int:
        """Bytes of the store's arrays (sums, counts, pool)."""
        pool = sum(sum(a.nbytes for a in part) for part in self._pool)
        return int(self.acc.nbytes + self.count.nbytes + pool)

    # -- a frame's photons ----------------------------------------------------------------
    def near(self, positions: np.ndarray) -> np.ndarray:
        """Indices (ascending) of the photons at ``positions`` (m, (n, 3) float32) that
        may lie within r_max of a point: a superset, for :meth:`add` of any store with
        the same points (one lookup for a whole frame of several sets)."""
        pos = np.asarray(positions, dtype=np.float32).reshape(-1, 3)
        if self._tree is None:
            return np.zeros(0, np.int64)
        return self._near_cells(pos, self.max_radius * (1 + 1e-6) + 1e-9)

    def add(self, positions: np.ndarray, normals: np.ndarray, powers: np.ndarray,
            near: np.ndarray | None = None) -> None:
        """Add a frame's photons (positions m float32 (n, 3), unit normals (n, 3), powers
        lm (n, C)): those near a point join the pool, the rest are dropped at once. The
        pool is summed and cut back (:meth:`compact`) whenever it has grown
        ``POOL_SLACK`` times, and at least by ``POOL_MIN`` photons. ``near``: the
        photons' indices :meth:`near` gave, when already known."""
        n = len(positions)
        self.added += n
        if n == 0 or self._tree is None:
            return
        pos = np.asarray(positions, dtype=np.float32).reshape(-1, 3)
        reach = self.max_radius if self._open else self.r_lo
        # a photon in a cell next to a point's (cells of the reach's size: a photon within
        # reach of a point lies in its cell or a neighbour); most photons of a frame are
        # far from every point and cost one lookup
        if near is None:
            cand = self._near_cells(pos, reach * (1 + 1e-6) + 1e-9)
        else:
            cand = np.asarray(near, dtype=np.int64)
            if reach < self.max_radius and len(cand):  # every point resolved: r_lo only
                cand = cand[self._near_cells(pos[cand], reach * (1 + 1e-6) + 1e-9)]
        if len(cand) == 0:
            return
        nrm = as_unit_normals(np.asarray(normals).reshape(-1, 3)[cand], len(cand))
        pw = np.asarray(powers, dtype=np.float32).reshape(n, self.channels)[cand]
        self._pool.append((pos[cand], nrm, pw, np.zeros(len(cand), np.bool_)))
        self._pool_n += len(cand)
        if self._pool_n > max(POOL_SLACK * self._pool_cut, self._pool_cut + POOL_MIN):
            self.compact()

    def compact(self) -> None:
        """Add the pool's new photons to the r_lo-sums of every point, then keep of the
        pool only each unresolved point's k nearest photons within r_max: all its
        estimate can ever read of them (later photons only push them out)."""
        pm, pts, nrm, pw = self._sum_pool()
        open_ = np.flatnonzero(~self.resolved)
        self._open = len(open_) > 0
        if not self._open or pm is None:
            self._pool, self._pool_n = [], 0
        else:
            _, idx = pm.query(self.points[open_], self.k, max_radius=self.max_radius,
                              normals=np.broadcast_to(self._normal32, (len(open_), 3)),
                              normal_cos=self.normal_cos)
            keep = np.unique(idx[idx >= 0])  # ascending: insertion order
            self._pool = ([(pts[keep], nrm[keep], pw[keep], np.ones(len(keep), np.bool_))]
                          if len(keep) else [])
            self._pool_n = len(keep)
        self._pool_cut = self._pool_n

    def _sum_pool(self) -> tuple:
        """Add the pool's photons not yet summed to the r_lo-sums; the pool becomes one
        block, all summed. Returns (photon map of the pool, positions, normals, powers),
        or Nones for an empty pool."""
        if self._pool_n == 0:
            return None, None, None, None
        pts, nrm, pw, summed = (np.concatenate(parts) for parts in zip(*self._pool,
                                                                       strict=True))
        pm = PhotonMap("middle", channels=self.channels)
        pm.add(pts, nrm, pw)
        new = np.flatnonzero(~summed)
        if len(new) == len(pts):  # the pool's map serves the sums too
            self._sum_within_r_lo(pm, pts, pw)
        elif len(new):
            sub = PhotonMap("middle", channels=self.channels)
            sub.add(pts[new], nrm[new], pw[new])
            self._sum_within_r_lo(sub, pts[new], pw[new])
        self._pool = [(pts, nrm, pw, np.ones(len(pts), np.bool_))]
        return pm, pts, nrm, pw

    def _near_cells(self, pos: np.ndarray, reach: float) -> np.ndarray:
        """Indices of the photons at ``pos`` in a cell (side ≥ ``reach``, m) holding or
        next to a point: the only ones that can lie within ``reach`` of one (ascending).
        The cells are made once per reach (r_max, and r_lo once every point is
        resolved)."""
        if reach not in self._cells:
            lo = self.points.min(axis=0) - 2 * reach
            span = self.points.max(axis=0) + 2 * reach - lo
            cell = max(reach, float(span.max()) / 256.0)  # at most 256³ cells
            shape = np.maximum(np.ceil(span / cell).astype(np.int64), 1) + 1
            ijk = np.floor((self.points - lo) / cell).astype(np.int64)
            mask = np.zeros(tuple(shape), np.bool_)
            for off in np.ndindex(3, 3, 3):
                at = np.clip(ijk + np.array(off) - 1, 0, shape - 1)
                mask[at[:, 0], at[:, 1], at[:, 2]] = True
            # float32 bounds a little wider than the cells' reach around the points
            box = np.concatenate([self.points.min(axis=0) - 1.5 * reach,
                                  self.points.max(axis=0) + 1.5 * reach]).astype(np.float32)
            self._cells[reach] = (lo, cell, shape, mask, box)
        lo, cell, shape, mask, box = self._cells[reach]
        # the points' box first (six compares a photon: most of a frame lies outside it)
        x, y, z = pos[:, 0], pos[:, 1], pos[:, 2]
        idx = np.flatnonzero((x >= box[0]) & (x < box[3]) & (y >= box[1]) & (y < box[4])
                             & (z >= box[2]) & (z < box[5]))
        c = np.floor((pos[idx] - lo) / cell).astype(np.int64)
        c = np.minimum(np.maximum(c, 0), shape - 1)  # the box is inside the cells
        return idx[mask[c[:, 0], c[:, 1], c[:, 2]]]

    def _sum_within_r_lo(self, pm: PhotonMap, pts: np.ndarray, pw: np.ndarray) -> None:
        """Add the photons of ``pm`` (positions ``pts``, powers ``pw``, in its insertion
        order) to the r_lo-sums of every point (the density kernels' test: the photon
        map's radius search, d² ≤ r_lo², the normal filter). Points go in blocks of
        ``SUM_POINTS``, so the (point, photon) pairs held at once stay bounded whatever
        the pool; each point's sum is added in the same order either way."""
        P = len(self.points)
        for i0 in range(0, P, SUM_POINTS):
            at = self.points[i0:i0 + SUM_POINTS]
            nb = pm.query_radius(at, self.r_lo,
                                 normals=np.broadcast_to(self._normal32, at.shape),
                                 normal_cos=self.normal_cos)
            if len(nb.indices) == 0:
                continue
            qi = np.repeat(np.arange(len(at)), np.diff(nb.offsets))
            pj = nb.indices
            if self.kernel == "box":
                w = None
            else:  # the weight from the float64 distance, as the estimate computes it
                dx = pts[pj].astype(np.float64) - at[qi]
                w = kernel_weight(self.kernel, dx[:, 0] * dx[:, 0] + dx[:, 1] * dx[:, 1]
                                  + dx[:, 2] * dx[:, 2], self.r_lo)
            for c in range(self.channels):
                pc = pw[pj, c].astype(np.float64)
                self.acc[i0:i0 + len(at), c] += np.bincount(
                    qi, pc if w is None else w * pc, minlength=len(at))
            self.count[i0:i0 + len(at)] += np.bincount(qi, minlength=len(at))

    # -- estimates --------------------------------------------------------------------------
    def lookup(self, points: np.ndarray) -> np.ndarray:
        """Indices of the registered points at ``points`` (m, (Q, 3)); raises
        :class:`InputError` for a point that was not registered."""
        q = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(q) == 0:
            return np.zeros(0, np.int64)
        if self._tree is None:
            raise InputError("no photons were kept for estimates at these points: run "
                             "with --keep-photons")
        scale = max(1.0, float(np.abs(self.points).max()))
        d, i = self._tree.query(q, k=1, distance_upper_bound=1e-9 * scale)
        if not np.all(np.isfinite(d)):
            raise InputError(f"{int((~np.isfinite(d)).sum())} of {len(q)} estimate points "
                             "were not known before the run and its photons were not kept: "
                             "run with --keep-photons")
        return i.astype(np.int64)

    def estimate(self, points: np.ndarray, normals: np.ndarray | None, *, k: int = 64,
                 max_radius: float = np.inf, min_radius: float = 0.0,
                 kernel: str = "box") -> Estimate:
        """The density estimate (power per m², :class:`~lightsim.photonmap.common.
        Estimate`) a map of every photon added would give at registered points, with the
        settings the store was made for (others are refused)."""
        same = (int(k) == self.k and float(max_radius) == self.max_radius
                and float(min_radius) == self.min_radius and kernel == self.kernel)
        if not same:
            raise InputError("these estimates need photons that were not kept (other "
                             "radii, k or kernel): run with --keep-photons")
        idx = self.lookup(points)
        pm, _, _, _ = self._sum_pool()  # every photon in the sums (no cut: not needed)
        E = np.zeros((len(idx), self.channels))
        r = np.full(len(idx), self.r_lo)
        count = self.count[idx].copy()
        done = self.resolved[idx]
        E[done] = self.acc[idx[done]] * kernel_norm(self.kernel, self.r_lo)
        rest = np.flatnonzero(~done)
        if len(rest) and pm is not None:
            at = self.points[idx[rest]]
            res = pm.estimate(
                at.astype(np.float32), np.broadcast_to(self._normal32, at.shape),
                k=self.k, max_radius=self.max_radius, min_radius=self.min_radius,
                kernel=self.kernel)
            E[rest], r[rest], count[rest] = res.E, res.r, res.count
        elif len(rest):  # no photon near any unresolved point
            r[rest] = self.max_radius if self.max_radius < np.inf else 0.0
            count[rest] = 0
        return Estimate(E, r, count)


@dataclass(frozen=True)
class PointSpec:
    """What a set's :class:`PointStore` is made with: the registered points (world m,
    (P, 3)), the wall normal and the estimate's settings (k, radii in m, kernel)."""

    points: np.ndarray
    normal: np.ndarray
    k: int
    max_radius: float
    min_radius: float
    kernel: str = "box"

    def store(self, channels: int) -> PointStore:
        """A new, empty store for one set."""
        return PointStore(self.points, self.normal, channels, k=self.k,
                          max_radius=self.max_radius, min_radius=self.min_radius,
                          kernel=self.kernel)

    def peak_bytes(self, channels: int = 1) -> float:
        """Most bytes one set's store can hold (:func:`store_peak_bytes`)."""
        return store_peak_bytes(len(self.points), self.k, channels)


def store_peak_bytes(points: int, k: int, channels: int = 1) -> float:
    """Most bytes one set's store at ``points`` points can hold: sums and counts per
    point, and a pool of at most ``POOL_SLACK`` × k photons per point (a bound, whatever
    the photons; the pool is far smaller where points share their nearest photons)."""
    return points * (8.0 * channels + 8.0) + POOL_SLACK * k * points * (
        POOL_PHOTON_BYTES + 4.0 * channels)
