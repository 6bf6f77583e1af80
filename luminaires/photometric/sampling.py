"""Use a photometric file (IES/LDT) as a point light source: sample emission directions.

The intensity of a grid (:class:`~lightsim.luminaires.photometric.candela.CandelaGrid`,
Type C, or :class:`~lightsim.luminaires.photometric.hvgrid.HVGrid`, Types A/B) is the
bilinear interpolant of its table, and directions are drawn **exactly** from it: the density
of a sampled direction is ``pdf = I(direction)/Φ`` (1/sr) with ``I = grid.intensity_towards``
and ``Φ = grid.total_flux()`` (the interpolant's exact integral). ``u1`` picks the plane angle
from its marginal, ``u2`` the polar angle from the conditional distribution (see
:func:`~lightsim.emitters.polar.sample_table`); the map is continuous and
monotone in each of u1, u2, so stratified or low-discrepancy inputs (Halton) stay well
distributed. Each photon carries ``Φ/n`` lm — the luminaire's output, which is the file's
lumens for absolute photometry (for relative photometry, lamp lumens × light output ratio) —
so an N-photon emission converges to the grid's own interpolated intensities and its flux.

Parameters
----------
====  =====  =======  ==================================================
name  unit   default  meaning
====  =====  =======  ==================================================
grid  –      –        CandelaGrid or HVGrid (e.g. from ``read_ies``)
u1    1      –        (n,) uniform numbers in [0, 1]: plane-angle choice
u2    1      –        (n,) uniform numbers in [0, 1]: polar-angle choice
====  =====  =======  ==================================================
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lightsim.emitters.polar import sample_table
from lightsim.errors import InputError

__all__ = ["sample_directions"]


def sample_directions(grid: Any, u1: ArrayLike, u2: ArrayLike) -> tuple[NDArray, NDArray]:
    """Emission directions distributed exactly like the grid's interpolated intensity.

    Parameters
    ----------
    grid : CandelaGrid or HVGrid
        Intensity distribution (cd); must emit some flux.
    u1, u2 : array_like, shape (n,)
        Uniform random or quasi-random numbers in [0, 1].

    Returns
    -------
    dirs : ndarray, shape (n, 3)
        Unit world directions (lamp axes: +Z ahead, +Y up; see ``candela``/``hvgrid``).
    pdf : ndarray, shape (n,)
        Density of each direction in 1/sr, ``I(direction)/Φ``.
    """
    a = np.asarray(u1, dtype=float).reshape(-1)
    b = np.asarray(u2, dtype=float).reshape(-1)
    if a.shape != b.shape:
        raise InputError(f"sample_directions: u1 and u2 differ in shape {a.shape} vs {b.shape}")
    if a.size and not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise InputError("sample_directions: u1 and u2 must be finite")
    if a.size and (a.min() < 0 or a.max() > 1 or b.min() < 0 or b.max() > 1):
        raise InputError("sample_directions: u1 and u2 must lie in [0, 1]")
    table = grid.table
    total = table.total_flux()
    if not total > 0:
        raise InputError("sample_directions: the intensity distribution emits no flux")
    _, _, dirs, cd = sample_table(table, a, b)
    return dirs, cd / total
