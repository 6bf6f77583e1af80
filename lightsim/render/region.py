"""The region the error figure covers: every lit query, or the beam's interior.

A density estimate blurs a beam's edge, so the error of a map is largest in a thin band
along the edges of the lit region; the beam's body converges faster. ``--error-region``
lets the figure (and so ``--target-error``'s stop) cover either:

============  ====  =======  =============================================================
parameter     unit  default  meaning
============  ====  =======  =============================================================
``kind``      –     lit      ``lit``: every lit query (the map's level ≥ ``lit_fraction`` ×
                             its maximum, :mod:`lightsim.render.ici`); ``interior``: the lit
                             queries at least ``inset`` × R_eq inside the lit region's edge
``inset``     –     0.2      depth of the interior as a fraction of R_eq = √(A_lit/π), the
                             radius of a disk with the lit area: on a round beam the interior
                             is the inner 1 − inset = 80 % of its radius
============  ====  =======  =============================================================

The queries are the cells of a raster (the wall's pixels, or the grid probes), in row
order. A lit cell's depth is its distance to the nearest unlit cell centre (an exact
Euclidean distance transform, Felzenszwalb & Huttenlocher's two 1-D passes,
:mod:`lightsim.render.edt`, cells of
any aspect) less half a cell: the edge lies between the two centres. The wall's own
border is not an edge (a beam cut by the wall continues beyond it). Where no cell is that
deep (a beam a few cells wide) the interior falls back to every lit cell: the figure then
covers more, never less.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from lightsim.render.edt import squared_distance

REGIONS = ("lit", "interior")
INSET = 0.2

#: a lit mask (Q,) bool → the mask the figure reads (Q,) bool
Restrict = Callable[[np.ndarray], np.ndarray]


def interior(lit: np.ndarray, shape: tuple[int, int], cell: tuple[float, float],
             inset: float = INSET) -> np.ndarray:
    """The lit cells at least ``inset`` × R_eq inside the lit region's edge.

    Parameters
    ----------
    lit : (H·W,) bool
        Lit cells of an H × W raster, in row order.
    shape : (H, W)
        The raster.
    cell : (dv, dh) float
        Distance between row and between column centres (m).
    inset : float
        Depth as a fraction of R_eq = √(A_lit/π), A_lit = lit cells × dv·dh.

    Returns
    -------
    (H·W,) bool
        The interior; ``lit`` itself when no cell is unlit or none is that deep.
    """
    H, W = shape
    lit = np.asarray(lit, dtype=np.bool_).reshape(-1)
    if len(lit) != H * W:
        raise ValueError(f"interior: {len(lit)} lit flags for a {H} x {W} raster")
    dv, dh = float(cell[0]), float(cell[1])
    n_lit = int(lit.sum())
    if n_lit == 0 or n_lit == lit.size or not (dv > 0 and dh > 0):
        return lit.copy()
    # in cell units of the finer side, so that 1e-30 m or 1e30 m pixels square alike
    unit = min(dv, dh)
    d2 = squared_distance(~lit.reshape(H, W), dv / unit, dh / unit).reshape(-1)
    r_eq = math.sqrt(n_lit * (dv / unit) * (dh / unit) / math.pi)
    depth = np.sqrt(d2) - 0.5 * math.sqrt((dv / unit) * (dh / unit))
    out = lit & (depth >= inset * r_eq)
    return out if out.any() else lit.copy()


def restriction(kind: str, shape: tuple[int, int], cell: tuple[float, float],
                inset: float = INSET) -> Restrict | None:
    """The mask function of region ``kind`` over an H × W raster of cells ``cell`` =
    (dv, dh) m apart, queries in row order (None for ``lit``: every lit query)."""
    if kind not in REGIONS:
        raise ValueError(f"error region must be one of {', '.join(REGIONS)}, got {kind!r}")
    if kind == "lit":
        return None

    def restrict(lit: np.ndarray) -> np.ndarray:
        return interior(lit, shape, cell, inset)

    return restrict
