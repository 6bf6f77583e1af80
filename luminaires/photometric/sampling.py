"""Use a photometric file (IES/LDT) as a point light source: sample emission directions.

The intensity distribution of a :class:`~lightsim.luminaires.photometric.candela.CandelaGrid`
is taken constant over each cell (the cells of the grid's :meth:`total_flux`), so the
probability of cell (j, i) is ``I_ji·ΔΩ_ji / Φ`` with ``Φ = grid.total_flux()``. Sampling
inverts the CDFs: ``u1`` picks the C cell from the marginal distribution, ``u2`` the γ cell
from the conditional one, and the remainders of ``u1``/``u2`` place the direction uniformly
within the cell (uniform in C and in cos γ, i.e. uniform over the cell's solid angle). The
map is continuous and monotone in each of u1, u2, so stratified or low-discrepancy inputs
(Halton) stay well distributed. The density of a sampled direction is ``pdf = I/Φ`` (1/sr);
each photon carries ``Φ/n`` lm with ``Φ = grid.total_flux()`` — the luminaire's output,
which is the file's lumens for absolute photometry (for relative photometry it is the lamp
lumens times the light output ratio) — so an N-photon emission reproduces the grid's
intensities and its total flux.

Parameters
----------
====  =====  =======  ==================================================
name  unit   default  meaning
====  =====  =======  ==================================================
grid  –      –        CandelaGrid (e.g. from ``read_ies``/``read_ldt``)
u1    1      –        (n,) uniform numbers in [0, 1): C-plane choice
u2    1      –        (n,) uniform numbers in [0, 1): γ choice
====  =====  =======  ==================================================
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lightsim.errors import InputError

from .candela import CandelaGrid, directions_from_angles

__all__ = ["sample_directions"]


def sample_directions(grid: CandelaGrid, u1: ArrayLike, u2: ArrayLike
                      ) -> tuple[NDArray, NDArray]:
    """Emission directions distributed like the grid's intensity.

    Parameters
    ----------
    grid : CandelaGrid
        Intensity distribution (cd); must emit some flux.
    u1, u2 : array_like, shape (n,)
        Uniform random or quasi-random numbers in [0, 1).

    Returns
    -------
    dirs : ndarray, shape (n, 3)
        Unit world directions (lamp axes: +Z ahead, +Y up; see ``candela``).
    pdf : ndarray, shape (n,)
        Density of each direction in 1/sr, ``I(cell)/Φ``.
    """
    a = np.asarray(u1, dtype=float).reshape(-1)
    b = np.asarray(u2, dtype=float).reshape(-1)
    if a.shape != b.shape:
        raise InputError(f"sample_directions: u1 and u2 differ in shape {a.shape} vs {b.shape}")
    if a.size and (a.min() < 0 or a.max() > 1 or b.min() < 0 or b.max() > 1):
        raise InputError("sample_directions: u1 and u2 must lie in [0, 1]")
    omega = grid.solid_angles()
    w = grid.candela * omega  # flux per cell (lm)
    total = float(w.sum())
    if not total > 0:
        raise InputError("sample_directions: the intensity distribution emits no flux")
    nc, ng = grid.shape
    ce = grid.c_edges_deg()
    ge = np.radians(grid.gamma_edges_deg())
    cos_e = np.cos(ge)

    row = w.sum(axis=1)
    cdf_c = np.concatenate([[0.0], np.cumsum(row)]) / total
    cdf_c[-1] = 1.0
    j = np.clip(np.searchsorted(cdf_c, a, side="right") - 1, 0, nc - 1)
    pj = cdf_c[j + 1] - cdf_c[j]
    ta = np.clip((a - cdf_c[j]) / np.where(pj > 0, pj, 1.0), 0.0, 1.0)
    c = ce[j] + ta * (ce[j + 1] - ce[j])

    safe = np.where(row > 0, row, 1.0)
    cond = np.concatenate([np.zeros((nc, 1)), np.cumsum(w, axis=1)], axis=1) / safe[:, None]
    cond[:, -1] = 1.0
    offset = np.arange(nc, dtype=float)[:, None] * 2.0  # rows in disjoint ranges [2j, 2j+1]
    flat = (cond + offset).ravel()
    pos = np.searchsorted(flat, b + 2.0 * j, side="right") - 1
    i = np.clip(pos - j * (ng + 1), 0, ng - 1)
    pi = cond[j, i + 1] - cond[j, i]
    tb = np.clip((b - cond[j, i]) / np.where(pi > 0, pi, 1.0), 0.0, 1.0)
    cosg = cos_e[i] - tb * (cos_e[i] - cos_e[i + 1])
    gamma = np.degrees(np.arccos(np.clip(cosg, -1.0, 1.0)))

    dirs = directions_from_angles(c, gamma)
    pdf = grid.candela[j, i] / total
    return dirs, pdf
