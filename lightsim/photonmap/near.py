"""Photons near a few query points: all that an estimate with a finite radius reads.

A density estimate capped at ``max_radius`` r (kNN or fixed radius) reads only photons
within r of its query point. At a few points — the cut-off scans' 6 765 points, the
regulation test points — the estimates from the photons within r of any of them are
therefore the estimates from all photons, and a map of those few is built in a fraction
of the time a map of every photon takes (a run that never queried its maps would
otherwise build all of them, 16 trees over every stored photon, for a probe at the end).

The photons are found in one pass: the queries' cells of a grid with cells at least r
wide are marked together with their 26 neighbours, and a photon is kept when its cell is
marked — a superset of the photons within r of a query (a photon within r ≤ cell of a
query lies in its cell or a neighbouring one), in their original order.

=============  =====  ========  ========================================================
parameter      unit   default   meaning
=============  =====  ========  ========================================================
``radius``     m      –         the estimate's largest radius (finite, > 0)
``MAX_CELLS``  –      2²²       cells of the marking grid at most: cells grow (by
                                doubling, from r) until the queries' box fits
``MARGIN``     –      10⁻⁶      relative widening of the cells (rounding at the edge)
=============  =====  ========  ========================================================
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

MAX_CELLS = 1 << 22
MARGIN = 1e-6


class NearGrid:
    """The marked cells around query points (see the module docstring).

    Parameters
    ----------
    queries : (Q, 3) array_like
        Query points (m), finite.
    radius : float
        Largest distance (m) at which a photon can count at a query; finite, > 0.
    """

    def __init__(self, queries: np.ndarray, radius: float) -> None:
        q = np.ascontiguousarray(queries, dtype=np.float64).reshape(-1, 3)
        r = float(radius)
        if not (0.0 < r < math.inf) or len(q) == 0 or not np.all(np.isfinite(q)):
            raise ValueError("NearGrid: finite queries and a finite radius > 0")
        qlo, qhi = q.min(axis=0), q.max(axis=0)
        extent = qhi - qlo
        cell = r * (1.0 + MARGIN)
        while np.prod(np.floor(extent / cell) + 5.0) > MAX_CELLS:
            cell *= 2.0
        # two cells of room below the lowest query cell, and above the highest
        self.cell = cell
        self.lo = qlo - 2.0 * cell
        self.dims = (np.floor((qhi - self.lo) / cell) + 3.0).astype(np.int64)
        self.marked = np.zeros(int(np.prod(self.dims)), np.bool_)
        _mark(q, self.lo, 1.0 / cell, self.dims, self.marked)

    def select(self, positions: np.ndarray, bounds: np.ndarray) -> np.ndarray:
        """Indices (int64, ascending) of the photons in marked cells: every photon within
        ``radius`` of a query, and some farther. ``bounds`` (6,) float64, [min xyz, max
        xyz], is widened to hold every photon of ``positions`` (the whole map's bounds,
        which its density floor reads)."""
        pos = np.ascontiguousarray(positions, dtype=np.float32).reshape(-1, 3)
        out = np.empty(len(pos), np.int64)
        n = _select(pos, self.lo, 1.0 / self.cell, self.dims, self.marked, out, bounds)
        return out[:n]


@njit(cache=True, nogil=True)
def _mark(q, lo, inv, dims, marked):
    """Mark each query's cell and its 26 neighbours."""
    ny, nz = dims[1], dims[2]
    for i in range(q.shape[0]):
        cx = int((q[i, 0] - lo[0]) * inv)
        cy = int((q[i, 1] - lo[1]) * inv)
        cz = int((q[i, 2] - lo[2]) * inv)
        for a in range(cx - 1, cx + 2):
            for b in range(cy - 1, cy + 2):
                for c in range(cz - 1, cz + 2):
                    if 0 <= a < dims[0] and 0 <= b < ny and 0 <= c < nz:
                        marked[(a * ny + b) * nz + c] = True


@njit(cache=True, nogil=True)
def _select(pos, lo, inv, dims, marked, out, bounds):
    """Write the indices of photons in marked cells to ``out``; return their count.
    Widens ``bounds`` to every photon. A cell coordinate outside the grid (or not a
    number: a coordinate beyond float64's range after scaling) is not marked."""
    fx, fy, fz = float(dims[0]), float(dims[1]), float(dims[2])
    ny, nz = dims[1], dims[2]
    n = 0
    for i in range(pos.shape[0]):
        x, y, z = float(pos[i, 0]), float(pos[i, 1]), float(pos[i, 2])
        bounds[0] = min(bounds[0], x)
        bounds[1] = min(bounds[1], y)
        bounds[2] = min(bounds[2], z)
        bounds[3] = max(bounds[3], x)
        bounds[4] = max(bounds[4], y)
        bounds[5] = max(bounds[5], z)
        gx = (x - lo[0]) * inv
        gy = (y - lo[1]) * inv
        gz = (z - lo[2]) * inv
        if not (0.0 <= gx < fx and 0.0 <= gy < fy and 0.0 <= gz < fz):
            continue
        if marked[(int(gx) * ny + int(gy)) * nz + int(gz)]:
            out[n] = i
            n += 1
    return n
