"""Exact Euclidean distance transform of a raster (Felzenszwalb & Huttenlocher 2012,
"Distance Transforms of Sampled Functions": the lower envelope of parabolas, one 1-D
pass down the columns, then one along the rows; O(H·W), cells of any aspect).

============  ====  ==========================================================
parameter     unit  meaning
============  ====  ==========================================================
``dv``, ``dh``  m   distance between row centres and between column centres
============  ====  ==========================================================
"""

from __future__ import annotations

import numpy as np
from numba import njit

_FAR = 1e300  # squared distance of a cell with no seed in its row/column pass


@njit(cache=True, nogil=True)
def _dt_1d(f: np.ndarray, step: float, out: np.ndarray, v: np.ndarray, z: np.ndarray) -> None:
    """Squared distance transform of one line: out[q] = min_p ((q − p)·step)² + f[p]
    (the lower envelope of parabolas; ``v``, ``z`` are work arrays of n and n + 1)."""
    n = f.shape[0]
    k = 0
    v[0] = 0
    z[0] = -np.inf
    z[1] = np.inf
    for q in range(1, n):
        xq = q * step
        while True:
            xp = v[k] * step
            s = ((f[q] + xq * xq) - (f[v[k]] + xp * xp)) / (2.0 * (xq - xp))
            if s <= z[k] and k > 0:
                k -= 1
                continue
            break
        if s <= z[k]:  # k == 0: parabola q lies below parabola v[0] everywhere left of it
            v[0] = q
            z[1] = np.inf
            continue
        k += 1
        v[k] = q
        z[k] = s
        z[k + 1] = np.inf
    k = 0
    for q in range(n):
        xq = q * step
        while z[k + 1] < xq:
            k += 1
        d = xq - v[k] * step
        out[q] = d * d + f[v[k]]


@njit(cache=True, nogil=True)
def squared_distance(unlit: np.ndarray, dv: float, dh: float) -> np.ndarray:
    """(H, W) squared distance (m²) from every cell centre to the nearest unlit one
    (rows ``dv`` apart, columns ``dh``); ≥ :data:`_FAR` where there is none."""
    H, W = unlit.shape
    g = np.empty((H, W))
    n = max(H, W)
    f = np.empty(n)
    out = np.empty(n)
    v = np.empty(n, np.int64)
    z = np.empty(n + 1)
    for c in range(W):  # down every column
        for r in range(H):
            f[r] = 0.0 if unlit[r, c] else _FAR
        _dt_1d(f[:H], dv, out[:H], v[:H], z[:H + 1])
        for r in range(H):
            g[r, c] = out[r]
    d2 = np.empty((H, W))
    for r in range(H):  # then along every row
        _dt_1d(g[r], dh, out[:W], v[:W], z[:W + 1])
        for c in range(W):
            d2[r, c] = out[c]
    return d2
