"""The angles a far-field file lists, and its intensities on them.

A file holds the run's intensity (:class:`~.runfield.RunField`) on a table of angles:

* **auto** (``--ies-step``/``--ldt-step`` not given): uneven angle lists, fine where the
  intensity changes fast (the cut-off, the hot spot), coarse where it does not. Each axis
  keeps a subset of the field's own node angles (:func:`select_nodes`): starting from the
  angles a file must list, the interval whose straight line misses the field by most
  (relative to ``REL_TOL`` × the intensity there, or ``ABS_TOL`` × the peak) gets its
  worst node, until every interval is within tolerance, no gap exceeds ``MAX_GAP_DEG``, or
  the format's count is reached. LM-63-2002 allows uneven angle lists for Types A, B, C;
  EULUMDAT allows uneven C-planes (Dc = 0) and γ angles (Dg = 0) but at most 721 C-planes
  and 361 γ angles, and a file without symmetry (Isym 0) lists C 0°, 90°, 180° and 270°.
* **a step** (deg): equal steps over the whole file, as before.

With equal steps the intensities are the field's flux handed to the file's nodes with
bilinear weights (:func:`regrid`, the deposit of :func:`~.farfield.farfield_from_photons`);
auto files that met the tolerance take the field's values at their nodes, and the flux the
straight lines between them gain or lose goes to the nodes next to a left-out angle. Either
way the file's interpolant integrates to the field's flux exactly.

Parameters
----------
==================  =====  =======  =========================================================
name                unit   default  meaning
==================  =====  =======  =========================================================
REL_TOL             1      0.01     largest deviation between kept nodes, relative to the
                                    intensity there
ABS_TOL             1      0.0005   … or relative to the peak intensity
MAX_GAP_DEG         deg    5        largest step between listed angles (auto)
LDT_MAX_PLANES      1      721      EULUMDAT's largest number of C-planes Mc
LDT_MAX_GAMMA       1      361      EULUMDAT's largest number of γ angles Ng
IES_MAX_PLANES      1      1441     auto's largest horizontal-angle count in IES files
IES_MAX_POLAR       1      721      auto's largest vertical-angle count in IES files
==================  =====  =======  =========================================================
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from lightsim.errors import InputError

from .candela import CandelaGrid, directions_from_angles
from .farfield import farfield_from_photons, symmetric_axis, uniform_axes
from .hvgrid import HVGrid
from .runfield import RunField

__all__ = ["ABS_TOL", "IES_MAX_PLANES", "IES_MAX_POLAR", "LDT_MAX_GAMMA", "LDT_MAX_PLANES",
           "MAX_GAP_DEG", "REL_TOL", "auto_axes", "check_step", "file_axes", "regrid",
           "select_nodes", "step_axes"]

REL_TOL = 0.01
"""Largest deviation between kept nodes, relative to the intensity there."""
ABS_TOL = 0.0005
"""… or relative to the field's peak intensity (dark regions)."""
MAX_GAP_DEG = 5.0
"""Largest step (deg) between the angles an auto file lists."""
LDT_MAX_PLANES = 721
"""EULUMDAT: at most 721 C-planes (Mc)."""
LDT_MAX_GAMMA = 361
"""EULUMDAT: at most 361 γ angles (Ng)."""
IES_MAX_PLANES = 1441
"""Largest horizontal-angle count of an auto IES file (LM-63-2002 sets none)."""
IES_MAX_POLAR = 721
"""Largest vertical-angle count of an auto IES file."""


def select_nodes(x: NDArray, values: NDArray, tol: NDArray, required: NDArray, budget: int,
                 max_gap: float = MAX_GAP_DEG) -> NDArray:
    """Indices of the nodes of axis ``x`` a table needs (see the module docstring).

    Parameters
    ----------
    x : ndarray, shape (n,)
        Candidate angles (deg), increasing.
    values : ndarray, shape (m, n)
        The field along the axis, one row per node of the other axis.
    tol : ndarray, shape (m, n)
        Allowed deviation of the straight line between kept nodes at every node.
    required : ndarray of bool, shape (n,)
        Nodes the table must list (the first and the last among them).
    budget : int
        Largest number of nodes.
    max_gap : float
        Largest step (deg) between kept nodes.

    Returns
    -------
    keep : ndarray of int
        Kept indices, increasing.
    residual : float
        The largest deviation left, in units of ``tol`` (≤ 1 unless the budget ran out).
    """
    x = np.asarray(x, dtype=np.float64)
    chosen = set(np.flatnonzero(required).tolist()) | {0, len(x) - 1}

    def worst(a: int, b: int) -> tuple[float, int]:
        if b - a < 2:
            return 0.0, -1
        k = np.arange(a + 1, b)
        if x[b] - x[a] > max_gap:  # too wide: split near the middle first
            return math.inf, int(k[np.argmin(np.abs(x[k] - 0.5 * (x[a] + x[b])))])
        t = (x[k] - x[a]) / (x[b] - x[a])
        line = values[:, a, None] * (1.0 - t) + values[:, b, None] * t
        err = (np.abs(values[:, k] - line) / tol[:, k]).max(axis=0)
        j = int(np.argmax(err))
        return float(err[j]), int(k[j])

    heap: list[tuple[float, int, int, int]] = []
    ordered = sorted(chosen)
    for a, b in itertools.pairwise(ordered):
        e, k = worst(a, b)
        heapq.heappush(heap, (-e, a, b, k))
    while heap and len(chosen) < budget:
        e, a, b, k = heapq.heappop(heap)
        if -e <= 1.0 or k < 0:
            heapq.heappush(heap, (e, a, b, k))
            break
        chosen.add(k)
        for lo, hi in ((a, k), (k, b)):
            e2, k2 = worst(lo, hi)
            heapq.heappush(heap, (-e2, lo, hi, k2))
    residual = -heap[0][0] if heap else 0.0
    return np.array(sorted(chosen), dtype=np.int64), float(residual)


def _tolerance(values: NDArray, peak: float) -> NDArray:
    return np.maximum(REL_TOL * np.abs(values), max(ABS_TOL * peak, 1e-12))


def auto_axes(field: RunField, kind: str, budget: tuple[int, int]
              ) -> tuple[NDArray, NDArray, bool]:
    """Uneven angle lists of a Type A (H, V) or Type C (C, γ) file (module docstring).

    ``budget`` is the largest (horizontal/C, vertical/γ) count. The flag says whether both
    lists meet the tolerance (False: a count ran out first).
    """
    g = field.grid
    cd = g.candela
    peak = float(cd.max()) if cd.size else 0.0
    gamma = g.gamma_deg
    if kind == "C":
        c = np.concatenate([g.c_deg, [360.0]])  # the 0° plane closes the circle
        plane_values = np.vstack([cd, cd[:1]]).T
        required = np.isin(np.round(c, 9), (0.0, 90.0, 180.0, 270.0, 360.0))
        keep, left = select_nodes(c, plane_values, _tolerance(plane_values, peak), required,
                                  budget[0] + 1)
        planes = c[keep][:-1]
        rows = slice(None)
        polar = gamma
    elif kind == "A":
        h = -np.where(g.c_deg > 180.0, g.c_deg - 360.0, g.c_deg)
        front = np.flatnonzero(np.abs(h) <= 90.0 + 1e-9)
        order = front[np.argsort(h[front])]
        hx = h[order]
        plane_values = cd[order].T
        required = np.isin(np.round(hx, 9), (-90.0, 0.0, 90.0))
        keep, left = select_nodes(hx, plane_values, _tolerance(plane_values, peak), required,
                                  budget[0])
        planes = hx[keep]
        rows = order
        polar = gamma - 90.0
    else:
        raise InputError(f"far-field file type must be 'A' or 'C', got {kind!r}")
    values = cd[rows]
    required = np.isin(np.round(gamma, 9), (0.0, 90.0, 180.0))
    keep, left_polar = select_nodes(polar, values, _tolerance(values, peak), required,
                                    budget[1])
    return planes, polar[keep], max(left, left_polar) <= 1.0


def check_step(step: float, kind: str, what: str) -> None:
    """Raise :class:`InputError` unless ``step`` (deg) makes a table of ``kind``:
    "ldt" needs 90° divided evenly (C 0°, 90°, 180°, 270° listed), IES 180°."""
    span = 90.0 if kind == "ldt" else 180.0
    n = round(span / step) if step > 0 else 0
    if n < 1 or abs(n * step - span) > 1e-6:
        raise InputError(f"{what} must divide {span:g}° into equal steps, got {step:g}°")


def step_axes(kind: str, step: float) -> tuple[NDArray, NDArray]:
    """Equal steps (deg): Type A H and V from −90° to 90°, Type C C in [0, 360), γ 0…180°."""
    if kind == "A":
        return symmetric_axis(step, "H"), symmetric_axis(step, "V")
    return uniform_axes(step, step)


def file_axes(field: RunField, kind: str, step: float | None, budget: tuple[int, int]
              ) -> tuple[NDArray, NDArray, bool]:
    """The angle lists of a file — auto (``step`` None) or equal steps — and whether the
    file should take the field's values at its nodes (auto lists that met the tolerance:
    see :func:`regrid`)."""
    if step is None:
        return auto_axes(field, kind, budget)
    return (*step_axes(kind, step), False)


def regrid(field: RunField, kind: str, planes: NDArray, polar: NDArray, *,
           lamp_lumens: float | None = None, metadata: Mapping[str, str] | None = None,
           sample: bool = False) -> CandelaGrid | HVGrid:
    """The field on a file's angles.

    The field's node fluxes are handed to the file's nodes with bilinear weights, so the
    file integrates to the field's flux exactly. With ``sample`` (auto angles, a subset
    of the field's) the file takes the field's own values at its nodes instead — a
    deposit would average across the kinks the auto angles were placed at — and the
    flux the straight lines between them gain or lose is given back on the nodes next to
    a left-out angle only (a node whose neighbours the file keeps too holds the field's
    value either way).

    Parameters
    ----------
    field : RunField
    kind : {"A", "C"}
        Type A (``planes`` = H, ``polar`` = V, front hemisphere; the flux behind is
        ``metadata["flux_outside_lm"]``) or Type C (C, γ).
    planes, polar : ndarray
        The file's angles (deg).
    lamp_lumens : float, optional
    metadata : mapping, optional
    sample : bool
        Take the field's values at the file's nodes (``planes``, ``polar`` among the
        field's angles).
    """
    g = field.grid
    power = (g.candela * g.node_solid_angles()).ravel()
    cc, gg = np.meshgrid(g.c_deg, g.gamma_deg, indexing="ij")
    dirs = directions_from_angles(cc, gg).reshape(-1, 3)
    lit = power > 0
    meta = dict(metadata or {})
    grid = farfield_from_photons(dirs[lit], power[lit], max(1, int(lit.sum())), c_deg=planes,
                                 gamma_deg=polar, lamp_lumens=lamp_lumens, metadata=meta,
                                 photometric_type=kind)
    # the deposit counts the field's nodes as photons: only the caller's counts are kept
    kept = {k: v for k, v in grid.metadata.items()
            if k in meta or k not in ("photons_emitted", "photons_escaped")}
    grid = replace(grid, metadata=kept)
    if not sample:
        return grid
    pp, qq = np.meshgrid(planes, polar, indexing="ij")
    if kind == "A":
        cd = g.intensity((-pp) % 360.0, qq + 90.0)
        field_planes = np.sort(-np.where(g.c_deg > 180.0, g.c_deg - 360.0, g.c_deg))
        field_polar = g.gamma_deg - 90.0
    else:
        cd = g.intensity(pp, qq)
        field_planes, field_polar = g.c_deg, g.gamma_deg
    dense = (_dense(field_planes, planes, kind == "C")[:, None]
             & _dense(field_polar, polar, False)[None, :])
    omega = grid.node_solid_angles()
    lost = grid.total_flux() - float(np.sum(cd * omega))
    sparse_flux = float(np.sum(np.where(dense, 0.0, cd * omega)))
    if sparse_flux > 0 and sparse_flux + lost > 0:
        cd = np.where(dense, cd, cd * ((sparse_flux + lost) / sparse_flux))
    else:  # nothing to give it to: the whole file
        cd = cd * (grid.total_flux() / max(float(np.sum(cd * omega)), 1e-300))
    return replace(grid, candela=cd)


def _dense(field_axis: NDArray, axis: NDArray, periodic: bool) -> NDArray:
    """Which of ``axis``'s angles keep both their neighbours of ``field_axis``."""
    f = np.round(np.asarray(field_axis, dtype=np.float64), 9)
    k = np.searchsorted(f, np.round(np.asarray(axis, dtype=np.float64), 9))
    k = np.clip(k, 0, len(f) - 1)
    member = np.zeros(len(f) + 2, dtype=bool)
    member[k + 1] = True
    if periodic:
        member[0], member[-1] = member[len(f)], member[1]
    else:
        member[0] = member[-1] = True  # the ends have no outer neighbour
    return member[k] & member[k + 2]
