"""Far-field intensity (cd) of a lamp from the photons that leave it.

Every photon that escapes the lamp carries a flux ΔΦ (lm) in a direction; binned on a
Type C grid the intensity of a cell is ``I = ΣΔΦ / ΔΩ`` (cd). The cells are those of
:class:`~lightsim.luminaires.photometric.candela.CandelaGrid` (halfway between nodes, polar
caps at γ = 0° and 180°), so the grid's :meth:`total_flux` equals the escaped flux exactly.
The two polar caps are split among the C-planes in the binning but reported with one
intensity (their cap's flux over the cap's solid angle) for every C, as a nodal grid needs.

Statistical error: the emitted photons are independent samples, photon k adding
``X_k = ΔΦ_k`` to the cell it lands in (0 if it is absorbed or lands elsewhere); the standard
error of a cell's flux is ``sqrt(n/(n−1)·(ΣX² − (ΣX)²/n))`` with ``n = n_emitted``.

Parameters
----------
============  =====  ==========  ======================================================
name          unit   default     meaning
============  =====  ==========  ======================================================
directions    1      –           (n, 3) world directions of the escaping photons
powers        lm     –           (n,) flux carried by each photon (Σ over all emitted =
                                 lamp flux)
n_emitted     1      –           number of photons emitted to produce these records
dc_deg        deg    1.0         C step (C from 0 to 360 − dc) when c_deg is not given
dgamma_deg    deg    1.0         γ step (γ from 0 to 180) when gamma_deg is not given
c_deg         deg    None        explicit C-plane angles
gamma_deg     deg    None        explicit γ angles (must run from 0 to 180)
lamp_lumens   lm     None        rated lamp flux to record in the grid
============  =====  ==========  ======================================================
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lightsim.errors import InputError

from .candela import CandelaGrid, angles_from_directions

__all__ = ["farfield_from_photons", "uniform_axes"]


def uniform_axes(dc_deg: float = 1.0, dgamma_deg: float = 1.0) -> tuple[NDArray, NDArray]:
    """C angles ``0, dc, …, 360 − dc`` and γ angles ``0, dγ, …, 180`` in degrees."""
    if not (dc_deg > 0 and dgamma_deg > 0):
        raise InputError("grid steps must be > 0 degrees")
    nc = round(360.0 / dc_deg)
    ng = round(180.0 / dgamma_deg)
    if abs(nc * dc_deg - 360.0) > 1e-6 or abs(ng * dgamma_deg - 180.0) > 1e-6:
        raise InputError(f"grid steps must divide 360° and 180°, got dc={dc_deg}°, "
                         f"dγ={dgamma_deg}°")
    return np.arange(nc) * (360.0 / nc), np.linspace(0.0, 180.0, ng + 1)


def farfield_from_photons(directions: ArrayLike, powers: ArrayLike, n_emitted: int, *,
                          dc_deg: float = 1.0, dgamma_deg: float = 1.0,
                          c_deg: ArrayLike | None = None, gamma_deg: ArrayLike | None = None,
                          lamp_lumens: float | None = None,
                          metadata: Mapping[str, str] | None = None,
                          return_error: bool = False
                          ) -> CandelaGrid | tuple[CandelaGrid, NDArray]:
    """Bin escaping photons into a Type C far-field intensity grid (cd).

    Parameters
    ----------
    directions : array_like, shape (n, 3)
        World directions of the photons leaving the lamp (normalised or not).
    powers : array_like, shape (n,)
        Flux of each photon in lm.
    n_emitted : int
        Photons emitted in total (≥ n); used for the error estimate and recorded.
    dc_deg, dgamma_deg : float, default 1.0
        Uniform grid steps in degrees when ``c_deg``/``gamma_deg`` are not given.
    c_deg, gamma_deg : array_like, optional
        Explicit node angles in degrees (γ must start at 0 and end at 180 so that every
        direction falls into a cell).
    lamp_lumens : float, optional
        Rated lamp flux (lm) to record (None: absolute photometry).
    metadata : mapping, optional
        Descriptive fields stored in the grid.
    return_error : bool, default False
        Also return the standard error (cd) of every cell.

    Returns
    -------
    CandelaGrid
        With ``total_flux()`` equal to ``sum(powers)``; or ``(grid, stderr_cd)``.
    """
    d = np.asarray(directions, dtype=float)
    p = np.asarray(powers, dtype=float).reshape(-1)
    if d.ndim != 2 or d.shape[1] != 3 or d.shape[0] != p.shape[0]:
        raise InputError(f"farfield: directions must be (n, 3) and powers (n,), got "
                         f"{d.shape} and {p.shape}")
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(p))) or np.any(p < 0):
        raise InputError("farfield: directions and powers must be finite, powers ≥ 0 lm")
    if d.size and not np.all(np.linalg.norm(d, axis=1) > 0):
        raise InputError("farfield: a photon direction is the zero vector")
    n_emitted = int(n_emitted)
    if n_emitted < max(1, len(p)):
        raise InputError(f"farfield: n_emitted ({n_emitted}) is smaller than the number of "
                         f"escaping photons ({len(p)})")
    if c_deg is None or gamma_deg is None:
        cu, gu = uniform_axes(dc_deg, dgamma_deg)
        c_nodes = cu if c_deg is None else np.asarray(c_deg, dtype=float)
        g_nodes = gu if gamma_deg is None else np.asarray(gamma_deg, dtype=float)
    else:
        c_nodes = np.asarray(c_deg, dtype=float)
        g_nodes = np.asarray(gamma_deg, dtype=float)
    if g_nodes.size < 2 or abs(g_nodes[0]) > 1e-9 or abs(g_nodes[-1] - 180.0) > 1e-9:
        raise InputError("farfield: gamma_deg must run from 0 to 180 degrees")
    shell = CandelaGrid(c_nodes, g_nodes, np.zeros((c_nodes.size, g_nodes.size)))
    ce = shell.c_edges_deg()
    ge = shell.gamma_edges_deg()
    nc, ng = shell.shape

    c, g = angles_from_directions(d)
    gi = np.clip(np.searchsorted(ge, g, side="right") - 1, 0, ng - 1)
    rel = (c - ce[0]) % 360.0
    ci = np.clip(np.searchsorted(ce - ce[0], rel, side="right") - 1, 0, nc - 1)
    flat = ci * ng + gi
    flux = np.bincount(flat, weights=p, minlength=nc * ng).reshape(nc, ng)
    flux2 = np.bincount(flat, weights=p * p, minlength=nc * ng).reshape(nc, ng)

    omega = shell.solid_angles()
    for k in (0, ng - 1):  # polar caps: one value for every C-plane
        flux[:, k] = flux[:, k].sum() * omega[:, k] / omega[:, k].sum()
        flux2[:, k] = flux2[:, k].sum() * omega[:, k] / omega[:, k].sum()
    candela = flux / omega

    meta = dict(metadata or {})
    meta.setdefault("photons_emitted", str(n_emitted))
    meta.setdefault("photons_escaped", str(len(p)))
    grid = CandelaGrid(c_nodes, g_nodes, candela, lamp_lumens, meta)
    if not return_error:
        return grid
    n = float(n_emitted)
    var = np.maximum(flux2 - flux * flux / n, 0.0) * (n / max(n - 1.0, 1.0))
    return grid, np.sqrt(var) / omega
