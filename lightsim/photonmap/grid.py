"""Uniform grid photon map (Günther, Wald & Slusallek 2004, section 5.3), hashed when large.

Photons are sorted into a cell-ordered array (a counting sort by cell, equivalent to the
paper's recursive binning along x, y, z); a start table of int32 (4 bytes per cell) gives
each cell's first slot, the next cell's start its end. A kNN query visits cells in shells
of growing Chebyshev distance around the query's cell and stops as soon as the searched
block covers the ball of the current k-th distance, so the result is exact. Cells are
numbered with the longest axis varying fastest, so a run of cells along it is one
contiguous slot range (scanned in one go).

When the grid would have more than ``max_cells`` cells, cells are *hashed* into a table of
``2^⌈log₂ 2n⌉`` buckets (at most ``max_cells``); a run of cells along the longest axis still
maps to consecutive buckets, and each slot keeps its cell key so photons of colliding
cells are filtered out (queries stay exact).

The cell size h follows from a target number of photons per cell, assuming the photons
fill their bounding box in as many dimensions as it has non-negligible extent (3, 2 for a
wall, 1 for a line). As the paper notes, the best value depends on the photon
distribution and on k; the two presets of its Table 5 are:

==========  ===================  ======================================================
preset      photons_per_cell     meaning
==========  ===================  ======================================================
``lo``      32                   low resolution: few, full cells (k = 64 ≈ 2 cells)
``hi``      4                    high resolution: many small cells, tighter search
==========  ===================  ======================================================

Parameters (constructor)
------------------------
====================  =====  ========  ================================================
name                  unit   default   meaning
====================  =====  ========  ================================================
``positions``         m      None      (n, 3) photon positions (NaN/inf rejected)
``normals``           —      None      (n, 3) photon normals (for the normal filter)
``powers``            lm     None      (n, C) photon powers Φ
``photons_per_cell``  —      4         target mean photons per occupied cell
``cell_size``         m      None      explicit cell size h (overrides the target)
``max_cells``         —      2²²       above this many cells the grid is hashed
``channels``          —      1         number of power channels C
====================  =====  ========  ================================================
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, parallel_chunksize, prange

from lightsim.errors import InputError
from lightsim.photonmap.common import (
    QUERY_CHUNK,
    Estimate,
    PhotonIndex,
    as_queries,
    block_size,
    check_radius,
    counting_sort,
    finish_query,
    hint_bound,
    kernel_code,
    kernel_norm,
    query_normals,
    query_outputs,
    query_scratch,
    scan_knn,
    scan_radius,
    take_rows,
)

#: photons per cell of the paper's two grid presets (Table 5: "grid lo", "grid hi")
GRID_PRESETS: dict[str, float] = {"lo": 32.0, "hi": 4.0}
DEFAULT_MAX_CELLS = 2**22
#: cells per axis are capped so that linear cell keys fit in int64 without overflow
MAX_CELLS_PER_AXIS = 2**20
# multipliers of the cell hash (odd, < 2^31: products with indices < 2^20 fit in int64)
_H0 = 1_640_531_527
_H1 = 805_459_861


# =========================================================================== geometry
def choose_cell_size(lo: np.ndarray, hi: np.ndarray, n: int, photons_per_cell: float) -> float:
    """Cell size h (m) giving ≈ ``photons_per_cell`` photons per cell for uniform photons.

    The photons are assumed to fill their bounding box in d = 3, 2 or 1 dimensions: the
    largest d whose thinnest used extent is still at least one cell wide.
    """
    ext = np.sort(np.asarray(hi, np.float64) - np.asarray(lo, np.float64))[::-1]
    if n == 0 or ext[0] <= 0.0:
        return 1.0
    h = ext[0]
    for d in (3, 2, 1):
        if ext[d - 1] <= 0.0:
            continue
        h = (photons_per_cell * float(np.prod(ext[:d])) / n) ** (1.0 / d)
        if h <= ext[d - 1]:
            return float(h)
    return float(h)


@njit(cache=True)
def _cell_of(x: float, origin: float, inv_h: float, n: int) -> int:
    """Cell index of coordinate x along one grid axis, clamped to [0, n-1]."""
    t = (x - origin) * inv_h
    if t < 0.0:
        return 0
    if t >= n:
        return n - 1
    return int(t)


@njit(cache=True)
def _cell_unclamped(x: float, origin: float, inv_h: float) -> int:
    """Cell index of a query coordinate (may lie outside the grid; clamped to ±2^50)."""
    t = (x - origin) * inv_h  # clamp first: floor(±inf) has no integer value
    if t < -1.125899906842624e15:
        t = -1.125899906842624e15
    elif t > 1.125899906842624e15:
        t = 1.125899906842624e15
    return math.floor(t)


@njit(cache=True)
def _row_base(i0: int, i1: int, hashed: bool, n1: int, n2: int) -> int:
    """Key (dense) or hashed bucket offset (hashed) of cell (i0, i1, 0)."""
    if hashed:
        return (i0 * _H0) ^ (i1 * _H1)
    return (i0 * n1 + i1) * n2


@njit(cache=True)
def _cell_keys(pts: np.ndarray, origin: np.ndarray, inv_h: float, dims: np.ndarray,
               ax: np.ndarray, hashed: bool, mask: int) -> tuple[np.ndarray, np.ndarray]:
    """Linear cell key (longest axis fastest) and bucket of every photon."""
    n = pts.shape[0]
    keys = np.empty(n, np.int64)
    bucket = np.empty(n, np.int64)
    n0, n1, n2 = dims[0], dims[1], dims[2]
    for i in range(n):
        i0 = _cell_of(pts[i, ax[0]], origin[0], inv_h, n0)
        i1 = _cell_of(pts[i, ax[1]], origin[1], inv_h, n1)
        i2 = _cell_of(pts[i, ax[2]], origin[2], inv_h, n2)
        keys[i] = (i0 * n1 + i1) * n2 + i2
        if hashed:
            bucket[i] = (_row_base(i0, i1, True, n1, n2) + i2) & mask
        else:
            bucket[i] = keys[i]
    return keys, bucket


# =========================================================================== query kernels
@njit(cache=True)
def _axis_gap(g: float, i: int, h: float) -> float:
    """Distance (m) along one axis from coordinate g (grid frame) to cell i's slab."""
    a = i * h
    if g < a:
        return a - g
    b = a + h
    if g > b:
        return g - b
    return 0.0


@njit(cache=True, inline="always")
def _grid_frame(qx: float, qy: float, qz: float, origin: np.ndarray, ax: np.ndarray,
                ) -> tuple[float, float, float]:
    """The query's coordinates along the grid axes (longest last), from the origin (m)."""
    q3 = (qx, qy, qz)
    return q3[ax[0]] - origin[0], q3[ax[1]] - origin[1], q3[ax[2]] - origin[2]


@njit(cache=True)
def _row_ranges(i0: int, i1: int, t0: int, t1: int, dims: np.ndarray, hashed: bool,
                mask: int, start: np.ndarray) -> tuple[int, int, int, int, int, int]:
    """Slot ranges of the cells (i0, i1, t0 … t1): (s0, s1, s2, s3, key_lo, key_hi).

    Dense grids give one range [s0, s1) and an empty second one; hashed grids may wrap
    around the table into a second range [s2, s3), and keys filter other cells out.
    """
    n1 = dims[1]
    n2 = dims[2]
    key0 = (i0 * n1 + i1) * n2 + t0
    key1 = key0 + (t1 - t0) + 1
    if not hashed:
        return int(start[key0]), int(start[key1]), 0, 0, key0, key1
    n_b = mask + 1
    length = t1 - t0 + 1
    if length >= n_b:
        return int(start[0]), int(start[n_b]), 0, 0, key0, key1
    b0 = (_row_base(i0, i1, True, n1, n2) + t0) & mask
    if b0 + length <= n_b:
        return int(start[b0]), int(start[b0 + length]), 0, 0, key0, key1
    return (int(start[b0]), int(start[n_b]), int(start[0]), int(start[b0 + length - n_b]),
            key0, key1)


@njit(cache=True, inline="always")
def _grid_knn_one(qx: float, qy: float, qz: float, qnx: float, qny: float, qnz: float,
                  origin: np.ndarray, h: float, dims: np.ndarray, ax: np.ndarray,
                  hashed: bool, mask: int, start: np.ndarray, keys: np.ndarray,
                  pts: np.ndarray, nrm: np.ndarray, use_nrm: bool, ncos: float,
                  k: int, cd: np.ndarray, cs: np.ndarray, bound: float,
                  rlo: float, kernel: int, pw: np.ndarray, acc: np.ndarray,
                  ) -> tuple[int, int]:
    """Exact kNN of one query by shells of cells; returns (candidates, photons ≤ rlo)."""
    n = 0
    cnt_lo = 0
    rlo2 = rlo * rlo if rlo > 0.0 else -1.0
    g0, g1, g2 = _grid_frame(qx, qy, qz, origin, ax)
    inv_h = 1.0 / h
    c0 = _cell_unclamped(g0, 0.0, inv_h)
    c1 = _cell_unclamped(g1, 0.0, inv_h)
    c2 = _cell_unclamped(g2, 0.0, inv_h)
    n0 = dims[0]
    n1 = dims[1]
    n2 = dims[2]
    # the first shell that reaches the grid
    m = 0
    for c, nn in ((c0, n0), (c1, n1), (c2, n2)):
        if c < 0 and -c > m:
            m = -c
        elif c > nn - 1 and c - (nn - 1) > m:
            m = c - (nn - 1)
    while True:
        lim = bound if bound > rlo2 else rlo2
        lo0 = max(c0 - m, 0)
        hi0 = min(c0 + m, n0 - 1)
        lo1 = max(c1 - m, 0)
        hi1 = min(c1 + m, n1 - 1)
        lo2 = max(c2 - m, 0)
        hi2 = min(c2 + m, n2 - 1)
        for i0 in range(lo0, hi0 + 1):
            e0 = _axis_gap(g0, i0, h)
            e0 *= e0
            if e0 > lim:
                continue
            on0 = i0 == c0 - m or i0 == c0 + m
            for i1 in range(lo1, hi1 + 1):
                e1 = _axis_gap(g1, i1, h)
                e01 = e0 + e1 * e1
                if e01 > lim:
                    continue
                # on the shell: the whole row (trimmed to the ball of the current bound);
                # inside it: only the two end cells c2 ± m (the rest was searched before)
                whole = on0 or i1 == c1 - m or i1 == c1 + m
                for seg in range(1 if whole else 2):
                    if whole:
                        rr = math.sqrt(lim - e01)
                        t0 = max(lo2, _cell_unclamped(g2 - rr, 0.0, inv_h))
                        t1 = min(hi2, _cell_unclamped(g2 + rr, 0.0, inv_h))
                    else:
                        t0 = c2 - m if seg == 0 else c2 + m
                        t1 = t0
                        if t0 < 0 or t0 >= n2:
                            continue
                        e2 = _axis_gap(g2, t0, h)
                        if e01 + e2 * e2 > lim:
                            continue
                    if t0 > t1:
                        continue
                    s0, s1, s2, s3, ka, kb = _row_ranges(i0, i1, t0, t1, dims, hashed, mask,
                                                         start)
                    for part in range(2):
                        a = s0 if part == 0 else s2
                        z = s1 if part == 0 else s3
                        if z > a:
                            n, bound, cnt_lo = scan_knn(a, z, qx, qy, qz, qnx, qny, qnz, pts,
                                                        nrm, use_nrm, ncos, keys, ka, kb, k,
                                                        cd, cs, n, bound, rlo2, rlo, kernel,
                                                        pw, acc, cnt_lo)
                    lim = bound if bound > rlo2 else rlo2
        # radius of the ball around the query that the searched block covers: photons
        # beyond a face of the block are at least that far; clipped faces hide nothing
        cov = np.inf
        for g, c, nn in ((g0, c0, n0), (g1, c1, n1), (g2, c2, n2)):
            if c - m > 0:
                cov = min(cov, g - (c - m) * h)
            if c + m < nn - 1:
                cov = min(cov, (c + m + 1) * h - g)
        lim = bound if bound > rlo2 else rlo2
        if cov == np.inf or cov * cov > lim:
            return n, cnt_lo
        m += 1


@njit(cache=True)
def _grid_query_block(q0: int, q1: int, queries: np.ndarray, qnrm: np.ndarray,
                      use_nrm: bool, ncos: float, k: int, max_r2: float, rlo: float,
                      kernel: int, fused: bool, origin: np.ndarray, h: float,
                      dims: np.ndarray, ax: np.ndarray, hashed: bool, mask: int,
                      start: np.ndarray, keys: np.ndarray, pts: np.ndarray, nrm: np.ndarray,
                      pw: np.ndarray, perm: np.ndarray, out_d: np.ndarray, out_i: np.ndarray,
                      out_e: np.ndarray, out_r: np.ndarray, out_n: np.ndarray) -> None:
    """Queries q0 … q1-1 of :func:`_grid_query` (as ``kdtree._tree_query_block``)."""
    cd, cs, sort_stack, acc = query_scratch(k, out_e.shape[1])
    prev_rk2 = -1.0
    for q in range(q0, q1):
        bound = hint_bound(queries, qnrm, use_nrm, q, q0, prev_rk2, max_r2)
        while True:
            acc[:] = 0.0
            n, cnt_lo = _grid_knn_one(queries[q, 0], queries[q, 1], queries[q, 2], qnrm[q, 0],
                                      qnrm[q, 1], qnrm[q, 2], origin, h, dims, ax, hashed,
                                      mask, start, keys, pts, nrm, use_nrm, ncos, k, cd, cs,
                                      bound, rlo, kernel, pw, acc)
            if n >= k or bound >= max_r2:
                break
            bound = max_r2
        prev_rk2 = finish_query(q, fused, cd, cs, n, k, max_r2, rlo, kernel, pw, acc, cnt_lo,
                                perm, sort_stack, out_d, out_i, out_e, out_r, out_n)


@njit(parallel=True, cache=True)
def _grid_query(queries: np.ndarray, qnrm: np.ndarray, use_nrm: bool, ncos: float, k: int,
                max_r2: float, rlo: float, kernel: int, fused: bool, origin: np.ndarray,
                h: float, dims: np.ndarray, ax: np.ndarray, hashed: bool, mask: int,
                start: np.ndarray, keys: np.ndarray, pts: np.ndarray, nrm: np.ndarray,
                pw: np.ndarray, perm: np.ndarray, block: int,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """kNN or fused density estimate of every query (as ``kdtree._tree_query``)."""
    nq = queries.shape[0]
    out_d, out_i, out_e, out_r, out_n = query_outputs(nq, k, fused, pw.shape[1])
    n_blocks = (nq + block - 1) // block
    for b in prange(n_blocks):
        _grid_query_block(b * block, min(nq, (b + 1) * block), queries, qnrm, use_nrm, ncos,
                          k, max_r2, rlo, kernel, fused, origin, h, dims, ax, hashed, mask,
                          start, keys, pts, nrm, pw, perm, out_d, out_i, out_e, out_r, out_n)
    return out_d, out_i, out_e, out_r, out_n


@njit(cache=True)
def _grid_radius_one(qx: float, qy: float, qz: float, qnx: float, qny: float, qnz: float,
                     origin: np.ndarray, h: float, dims: np.ndarray, ax: np.ndarray,
                     hashed: bool, mask: int, start: np.ndarray, keys: np.ndarray,
                     pts: np.ndarray, nrm: np.ndarray, use_nrm: bool, ncos: float,
                     r: float, out_i: np.ndarray, out_d: np.ndarray, pos: int, write: bool,
                     kernel: int, pw: np.ndarray, acc: np.ndarray) -> int:
    """All photons within radius r (m) of one query: count/write them, sum into ``acc``."""
    g0, g1, g2 = _grid_frame(qx, qy, qz, origin, ax)
    inv_h = 1.0 / h
    r2 = r * r
    lo0 = max(_cell_unclamped(g0 - r, 0.0, inv_h), 0)
    hi0 = min(_cell_unclamped(g0 + r, 0.0, inv_h), dims[0] - 1)
    lo1 = max(_cell_unclamped(g1 - r, 0.0, inv_h), 0)
    hi1 = min(_cell_unclamped(g1 + r, 0.0, inv_h), dims[1] - 1)
    for i0 in range(lo0, hi0 + 1):
        e0 = _axis_gap(g0, i0, h)
        e0 *= e0
        if e0 > r2:
            continue
        for i1 in range(lo1, hi1 + 1):
            e1 = _axis_gap(g1, i1, h)
            e01 = e0 + e1 * e1
            if e01 > r2:
                continue
            rr = math.sqrt(r2 - e01)
            t0 = max(_cell_unclamped(g2 - rr, 0.0, inv_h), 0)
            t1 = min(_cell_unclamped(g2 + rr, 0.0, inv_h), dims[2] - 1)
            if t0 > t1:
                continue
            s0, s1, s2, s3, ka, kb = _row_ranges(i0, i1, t0, t1, dims, hashed, mask, start)
            for part in range(2):
                a = s0 if part == 0 else s2
                z = s1 if part == 0 else s3
                if z > a:
                    pos = scan_radius(a, z, qx, qy, qz, qnx, qny, qnz, pts, nrm, use_nrm,
                                      ncos, keys, ka, kb, r2, out_i, out_d, pos, write, r,
                                      kernel, pw, acc)
    return pos


@njit(cache=True)
def _grid_radius(queries: np.ndarray, qnrm: np.ndarray, use_nrm: bool, ncos: float,
                 r: float, origin: np.ndarray, h: float, dims: np.ndarray, ax: np.ndarray,
                 hashed: bool, mask: int, start: np.ndarray, keys: np.ndarray,
                 pts: np.ndarray, nrm: np.ndarray, pw: np.ndarray, perm: np.ndarray,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fixed-radius neighbours of every query as CSR (offsets, indices, d² float32).

    Serial, as ``kdtree._tree_radius``; the fixed-radius *density* is parallel.
    """
    nq = queries.shape[0]
    offsets = np.zeros(nq + 1, np.int64)
    acc = np.zeros(0, np.float64)
    no_i = np.zeros(0, np.int64)
    no_d = np.zeros(0, np.float32)
    for q in range(nq):
        offsets[q + 1] = offsets[q] + _grid_radius_one(
            queries[q, 0], queries[q, 1], queries[q, 2], qnrm[q, 0], qnrm[q, 1], qnrm[q, 2],
            origin, h, dims, ax, hashed, mask, start, keys, pts, nrm, use_nrm, ncos, r, no_i,
            no_d, 0, False, 0, pw, acc)
    out_i = np.empty(offsets[nq], np.int64)
    out_d = np.empty(offsets[nq], np.float32)
    for q in range(nq):
        _grid_radius_one(queries[q, 0], queries[q, 1], queries[q, 2], qnrm[q, 0], qnrm[q, 1],
                         qnrm[q, 2], origin, h, dims, ax, hashed, mask, start, keys, pts, nrm,
                         use_nrm, ncos, r, out_i, out_d, offsets[q], True, 0, pw, acc)
    for j in range(out_i.shape[0]):
        out_i[j] = perm[out_i[j]]
    return offsets, out_i, out_d


@njit(parallel=True, cache=True)
def _grid_radius_estimate(queries: np.ndarray, qnrm: np.ndarray, use_nrm: bool, ncos: float,
                          r: float, kernel: int, origin: np.ndarray, h: float,
                          dims: np.ndarray, ax: np.ndarray, hashed: bool, mask: int,
                          start: np.ndarray, keys: np.ndarray, pts: np.ndarray,
                          nrm: np.ndarray, pw: np.ndarray, block: int,
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-radius density estimate: E (Q, C) = ΣΦ·w(d, r)·norm(r), photons used (Q,)."""
    nq = queries.shape[0]
    n_ch = pw.shape[1]
    out_e = np.zeros((nq, n_ch), np.float64)
    out_n = np.zeros(nq, np.int64)
    dummy_i = np.zeros(0, np.int64)
    dummy_d = np.zeros(0, np.float32)
    norm = kernel_norm(kernel, r)
    n_blocks = (nq + block - 1) // block
    for b in prange(n_blocks):
        acc = np.zeros(n_ch, np.float64)
        for q in range(b * block, min(nq, (b + 1) * block)):
            acc[:] = 0.0
            out_n[q] = _grid_radius_one(queries[q, 0], queries[q, 1], queries[q, 2],
                                        qnrm[q, 0], qnrm[q, 1], qnrm[q, 2], origin, h, dims,
                                        ax, hashed, mask, start, keys, pts, nrm, use_nrm,
                                        ncos, r, dummy_i, dummy_d, 0, False, kernel, pw, acc)
            for c in range(n_ch):
                out_e[q, c] = acc[c] * norm
    return out_e, out_n


# =========================================================================== class
class UniformGrid(PhotonIndex):
    """Uniform (or hashed) grid photon map with exact kNN and fixed-radius queries.

    See the module docstring for the parameters. The grid is rebuilt by :meth:`add`
    (indices continue after the photons already stored), as a grid has no cheap
    incremental form that keeps its cell-ordered layout. Queries and kNN density
    estimates: :class:`~lightsim.photonmap.common.PhotonIndex`.
    """

    _finite_radius = True

    def __init__(self, positions: np.ndarray | None = None, normals: np.ndarray | None = None,
                 powers: np.ndarray | None = None, *, photons_per_cell: float = 4.0,
                 cell_size: float | None = None, max_cells: int = DEFAULT_MAX_CELLS,
                 channels: int = 1) -> None:
        if not photons_per_cell > 0:
            raise InputError(f"photons_per_cell must be > 0, got {photons_per_cell!r}")
        if cell_size is not None and not (0 < cell_size < np.inf):
            raise InputError(f"cell_size must be a finite length > 0 m, got {cell_size!r}")
        if int(max_cells) != max_cells or max_cells < 0:
            raise InputError(f"max_cells must be a non-negative integer, got {max_cells!r}")
        super().__init__(channels)
        self.photons_per_cell = float(photons_per_cell)
        self.fixed_cell_size = None if cell_size is None else float(cell_size)
        self.max_cells = int(max_cells)
        self._keys = np.zeros(0, np.int64)
        self._start = np.zeros(2, np.int32)
        self._origin = np.zeros(3, np.float64)
        self._dims = np.ones(3, np.int64)
        self._ax = np.arange(3, dtype=np.int64)
        self._h = 1.0
        self._hashed = False
        self._mask = 0
        self._lo = np.zeros(3, np.float32)
        self._hi = np.zeros(3, np.float32)
        if positions is not None:
            self.add(positions, normals, powers)

    # ----------------------------------------------------------------- build
    def add(self, positions: np.ndarray, normals: np.ndarray | None = None,
            powers: np.ndarray | None = None) -> None:
        """Append a batch of photons (indices continue) and rebuild the grid.

        Parameters are as for :meth:`lightsim.photonmap.kdtree.KdTree.add`.
        """
        self._add_rebuild(positions, normals, powers)

    def _build(self, pts: np.ndarray, nrm: np.ndarray, pw: np.ndarray) -> None:
        n = pts.shape[0]
        if n >= 2**31 - 1:
            raise InputError(f"a grid holds at most 2^31 - 2 photons, got {n}")
        lo = pts.min(axis=0)
        hi = pts.max(axis=0)
        ext = hi.astype(np.float64) - lo.astype(np.float64)
        h = (self.fixed_cell_size if self.fixed_cell_size is not None
             else choose_cell_size(lo, hi, n, self.photons_per_cell))
        # cap the cells per axis (int64 keys) — only matters for degenerate extents
        h = max(h, float(ext.max()) / (MAX_CELLS_PER_AXIS - 1), 1e-30)
        ax = np.argsort(ext, kind="stable").astype(np.int64)  # longest axis last = fastest
        dims = (np.floor(ext[ax] / h).astype(np.int64) + 1)
        n_cells = int(np.prod(dims.astype(np.float64)))
        hashed = n_cells > self.max_cells
        if hashed:
            n_buckets = 1 << (2 * n - 1).bit_length()  # power of two ≥ 2n
            if self.max_cells >= 2:
                n_buckets = min(n_buckets, 1 << (self.max_cells.bit_length() - 1))
            mask = n_buckets - 1
        else:
            n_buckets = n_cells
            mask = 0
        origin = lo.astype(np.float64)[ax]
        keys, bucket = _cell_keys(pts, origin, 1.0 / h, dims, ax, hashed, mask)
        start, order = counting_sort(bucket, n_buckets)
        start = start.astype(np.int32)  # 4 bytes per cell
        self._pts = take_rows(pts, order)
        self._nrm = take_rows(nrm, order) if self._has_normals else nrm
        self._pw = take_rows(pw, order)
        self._perm = order
        self._keys = keys[order] if hashed else np.zeros(0, np.int64)
        self._start = start
        self._origin = origin
        self._dims = dims
        self._ax = ax
        self._h = float(h)
        self._hashed = bool(hashed)
        self._mask = int(mask)
        self._lo = lo
        self._hi = hi

    # ----------------------------------------------------------------- info
    @property
    def cell_size(self) -> float:
        """Cell edge length h (m)."""
        return self._h

    @property
    def n_cells(self) -> int:
        """Number of grid cells (before hashing)."""
        return int(np.prod(self._dims))

    @property
    def hashed(self) -> bool:
        """Whether the cells are hashed into a table (cell count above ``max_cells``)."""
        return self._hashed

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box (lo, hi) of the stored photons (m)."""
        return self._lo.copy(), self._hi.copy()

    # ----------------------------------------------------------------- kernels
    def _grid_args(self) -> tuple:
        return (self._origin, self._h, self._dims, self._ax, self._hashed, self._mask,
                self._start, self._keys)

    def _knn(self, q: np.ndarray, qn: np.ndarray, use_nrm: bool, ncos: float, k: int,
             max_r2: float, rlo: float, kernel: int, fused: bool,
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return _grid_query(q, qn, use_nrm, ncos, k, max_r2, rlo, kernel, fused,
                           *self._grid_args(), self._pts, self._nrm, self._pw, self._perm,
                           block_size(q.shape[0]))

    def _radius(self, q: np.ndarray, qn: np.ndarray, use_nrm: bool, ncos: float, r: float,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return _grid_radius(q, qn, use_nrm, ncos, r, *self._grid_args(), self._pts,
                            self._nrm, self._pw, self._perm)

    # ----------------------------------------------------------------- queries
    def estimate_radius(self, points: np.ndarray, normals: np.ndarray | None = None, *,
                        radius: float, kernel: str = "box", normal_cos: float = 0.5,
                        ) -> Estimate:
        """Fixed-radius density estimate E = ΣΦ·w(d, R)/norm(R) with R = ``radius`` (m)."""
        q = as_queries(points)
        r = check_radius(radius, "radius", allow_inf=False)
        if r <= 0:
            raise InputError("radius must be > 0 m for a fixed-radius density estimate")
        code = kernel_code(kernel)
        qn, use_nrm = query_normals(normals, q.shape[0], self.has_normals)
        nq = q.shape[0]
        if len(self) == 0:
            return Estimate(np.zeros((nq, self.n_channels)), np.full(nq, r),
                            np.zeros(nq, np.int64))
        with parallel_chunksize(QUERY_CHUNK):
            E, count = _grid_radius_estimate(q, qn, use_nrm, float(normal_cos), r, code,
                                             *self._grid_args(), self._pts, self._nrm,
                                             self._pw, block_size(nq))
        return Estimate(E, np.full(nq, r), count)
