"""Far-field intensity (cd) of a lamp from the photons that leave it.

Every photon that escapes the lamp carries a flux ΔΦ (lm) in a direction. It is deposited
on the four grid nodes around its direction with its bilinear weights ("cloud in cell"),
and a node's intensity is ``I = Σ w·ΔΦ / Ω`` (cd) with Ω the node's share of the solid angle
(:meth:`~lightsim.emitters.polar.PolarTable.node_weights`). Because the
weights of every direction sum to 1 and ``total_flux = Σ I·Ω`` is the exact integral of the
grid's bilinear interpolant, the grid's :meth:`total_flux` equals the binned flux exactly.
A pole node (γ = 0°/180°, or V = ±90° in Type A) is one direction: it gets one value for
every plane (the pooled flux over the pooled Ω). Grids: Type C (default) over the whole
sphere, or Type A (H, V from −90° to 90°) over the front hemisphere — photons heading
backwards are then reported as ``metadata["flux_outside_lm"]``.

Statistical error: the emitted photons are independent samples, photon k adding
``X_k = w_k·ΔΦ_k`` to a node (0 if it is absorbed or lands elsewhere); the standard error of
a node's flux is ``sqrt(n/(n−1)·(ΣX² − (ΣX)²/n))`` with ``n = n_emitted``.

Parameters
----------
============  =====  ==========  ======================================================
name          unit   default     meaning
============  =====  ==========  ======================================================
directions    1      –           (n, 3) world directions of the escaping photons
powers        lm     –           (n,) flux carried by each photon (Σ over all emitted =
                                 lamp flux)
n_emitted     1      –           number of photons emitted to produce these records
dc_deg        deg    1.0         C step (C from 0 to 360 − dc; Type A: the H step)
dgamma_deg    deg    1.0         γ step (γ from 0 to 180; Type A: the V step)
c_deg         deg    None        explicit C-plane angles (Type A: H angles)
gamma_deg     deg    None        explicit γ angles from 0 to 180 (Type A: V angles)
lamp_lumens   lm     None        rated lamp flux to record in the grid
photometric_  –      "C"         "C" or "A" (headlamps)
type
============  =====  ==========  ======================================================
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lightsim.errors import InputError

from .candela import CandelaGrid
from .hvgrid import HVGrid

__all__ = ["farfield_from_photons", "symmetric_axis", "uniform_axes"]


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
                          return_error: bool = False, photometric_type: str = "C"
                          ) -> CandelaGrid | HVGrid | tuple[CandelaGrid | HVGrid, NDArray]:
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
        Also return the standard error (cd) of every node.
    photometric_type : {"C", "A"}, default "C"
        "A": a Type A (H, V) grid, H and V from −90° to 90° in steps ``dc_deg`` and
        ``dgamma_deg`` (or the nodes ``c_deg``/``gamma_deg`` as H/V); photons heading
        backwards (outside H = ±90°) are not in it (``metadata["flux_outside_lm"]``).

    Returns
    -------
    CandelaGrid or HVGrid
        With ``total_flux()`` equal to ``sum(powers)`` of the photons inside the grid; or
        ``(grid, stderr_cd)``.
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
    if photometric_type not in ("C", "A"):
        raise InputError(f"farfield: photometric type must be 'C' or 'A', got "
                         f"{photometric_type!r}")
    if photometric_type == "A":
        step_h, step_v = dc_deg, dgamma_deg
        h_nodes = (np.asarray(c_deg, dtype=float) if c_deg is not None
                   else symmetric_axis(step_h, "H"))
        v_nodes = (np.asarray(gamma_deg, dtype=float) if gamma_deg is not None
                   else symmetric_axis(step_v, "V"))
        shell: CandelaGrid | HVGrid = HVGrid(h_nodes, v_nodes,
                                             np.zeros((h_nodes.size, v_nodes.size)), "A")
    else:
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
    table = shell.table
    n_phi, n_theta = table.candela.shape

    j, jn, s_, i, t = table.locate(*table.angles(d))
    inside = j >= 0
    outside_lm = float(p[~inside].sum())
    j, jn, s_, i, t, pin = j[inside], jn[inside], s_[inside], i[inside], t[inside], p[inside]
    flux = np.zeros(n_phi * n_theta)
    flux2 = np.zeros(n_phi * n_theta)
    for rows, ws in ((j, 1 - s_), (jn, s_)):  # bilinear ("cloud in cell") deposit
        for cols, wt in ((i, 1 - t), (i + 1, t)):
            w = ws * wt * pin
            np.add.at(flux, rows * n_theta + cols, w)
            np.add.at(flux2, rows * n_theta + cols, w * w)
    flux = flux.reshape(n_phi, n_theta)
    flux2 = flux2.reshape(n_phi, n_theta)
    omega = table.node_weights()
    pooled = [k for k in (0, n_theta - 1) if table.theta_deg[k] in (0.0, 180.0)]
    for k in pooled:  # a pole is one direction: one value for every plane
        flux[:, k] = flux[:, k].sum() * omega[:, k] / omega[:, k].sum()
        flux2[:, k] = flux2[:, k].sum() * omega[:, k] / omega[:, k].sum()
    candela = flux / omega

    meta = dict(metadata or {})
    meta.setdefault("photons_emitted", str(n_emitted))
    meta.setdefault("photons_escaped", str(len(p)))
    meta.setdefault("flux_outside_lm", format(outside_lm, ".9g"))
    if photometric_type == "A":
        grid: CandelaGrid | HVGrid = HVGrid(h_nodes, v_nodes, candela, "A", lamp_lumens, meta)
    else:
        grid = CandelaGrid(c_nodes, g_nodes, candela, lamp_lumens, meta)
    if not return_error:
        return grid
    n = float(n_emitted)
    var = np.maximum(flux2 - flux * flux / n, 0.0) * (n / max(n - 1.0, 1.0))
    return grid, np.sqrt(var) / omega


def symmetric_axis(step: float, name: str) -> NDArray:
    """Angles −90, −90 + step, …, 90 in degrees (step must divide 180°)."""
    if not step > 0:
        raise InputError(f"far-field {name} step must be > 0 degrees")
    n = round(180.0 / step)
    if abs(n * step - 180.0) > 1e-6:
        raise InputError(f"far-field {name} step must divide 180°, got {step}°")
    return np.linspace(-90.0, 90.0, n + 1)
