"""Compiled passes of a frame's insertion (:meth:`PhotonSets.shoot`): counting sorts and
per-cell sums instead of ``argsort`` / ``np.unique`` / one ``bincount`` per window offset.

Every kernel reproduces the NumPy definition it replaces bit for bit (the same float64
operations in the same order, each cell's photons summed from 0 in photon order and then
added to the store once), so the stores do not change: ``tests/engine/test_frame_insert.py``
compares them with the per-set NumPy path (:meth:`PhotonSets.insert`).

=======================  =====================================================
kernel                   replaces
=======================  =====================================================
:func:`sort_by_source`   ``np.argsort(source, kind="stable")`` and six gathers
                         (:mod:`lightsim.tracer`'s, which sorts each chunk's
                         records with it when asked: ``by_source``)
:func:`insert_wall`      ``np.isin(part, ids)`` and the wall's h, v; one
                         ``bincount`` per window offset and channel (probe
                         windows); ``np.unique`` over (set, cell) and one
                         ``bincount`` per channel (ICI lattice) — one pass
=======================  =====================================================
"""

from __future__ import annotations

import numpy as np
from numba import njit

from lightsim.tracer import sort_by_source

__all__ = ["insert_wall", "sort_by_source"]


_BIG = 2.0 ** 62  # |u| beyond it: no window can hold the photon (and no int64 overflow)


@njit(cache=True, nogil=True)
def insert_wall(part, wall_ids, position, power, bounds, axes, windows, win_geometry,
                reach, win_scratch, lattice, lat_geometry, shape, lat_work, need_hv):
    """The wall photons of a frame's sorted records into every set's probe windows and
    half-pixel lattice, in one pass over the records.

    Records ``bounds[g]:bounds[g+1]`` are set g's (in photon order). A record is a wall
    photon when its ``part`` is one of ``wall_ids``; its wall coordinates are
    ``d = position − centre`` in float64, ``h = d·h_axis``, ``v = d·v_axis`` summed x, y,
    z in that order (``axes`` = (centre, h_axis, v_axis) as a (3, 3) array).

    *Windows* ``windows`` (S, G, C): ``win_geometry`` = (h0, v0, pitch_h, pitch_v,
    half_dh, half_dv), ``reach`` = (i0, i1, j0, j1, nh, nv) the window offsets around the
    nearest cell centre; per offset (i, j), in that order, each cell's photons are summed
    from 0 (in ``win_scratch``, (n_offsets, G, C) zeros) and the sum added to the store:
    what one ``bincount`` per offset does.

    *Lattice* ``lattice`` (S, 4HW, C), or (0, 0, C) for none: ``lat_geometry`` = (h0, v1,
    dh, dv), ``shape`` = (W, H); a photon's cell is ``row · 2W + col`` with
    ``col = ⌊2(h − h0)/dh⌋``, ``row = ⌊2(v1 − v)/dv⌋`` (photons off it are left out); each
    cell's photons are summed from 0 (in a compact per-set array, in photon order) and
    the sum added once, as ``np.unique`` + ``bincount`` do. ``lat_work`` = (slot of each
    cell (4HW,) int32, all −1), kept by the caller and left at −1: only the cells a frame
    touches are visited, never the whole image, and the sums stay compact (a lattice row
    of a large wall does not fit in cache).

    Returns (wall photons per set (S,), the lattice photons' record indices in order and
    each set's share of them (S + 1 bounds), and with ``need_hv`` the wall photons'
    record indices, h and v (m), else empty arrays).
    """
    S, G, C = windows.shape
    centre, ha, va = axes[0], axes[1], axes[2]
    h0, v0, pitch_h, pitch_v, half_dh, half_dv = win_geometry
    i0, i1, j0, j1, nh, nv = reach
    nj = j1 - j0 + 1
    n_slots = (i1 - i0 + 1) * nj
    use_lattice = lattice.shape[0] > 0
    lh0, lv1, dh, dv = lat_geometry
    W, H = shape
    slot_of = lat_work
    n = part.shape[0]
    counts = np.zeros(S, np.int64)
    ok_rec = np.empty(n if use_lattice else 0, np.int64)
    ok_bounds = np.zeros(S + 1, np.int64)
    m_hv = n if need_hv else 0
    index = np.empty(m_hv, np.int64)
    hs = np.empty(m_hv)
    vs = np.empty(m_hv)
    n_ok = 0
    n_wall = 0
    most = 0
    for g in range(S):
        most = max(most, bounds[g + 1] - bounds[g])
    acc = np.zeros((most if use_lattice else 0, C))  # a set's per-cell sums, compact
    cells = np.empty(most if use_lattice else 0, np.int64)
    for g in range(S):
        n_touched = 0
        for k in range(bounds[g], bounds[g + 1]):
            on = False
            for w in wall_ids:
                if part[k] == w:
                    on = True
                    break
            if not on:
                continue
            counts[g] += 1
            d0 = np.float64(position[k, 0]) - centre[0]
            d1 = np.float64(position[k, 1]) - centre[1]
            d2 = np.float64(position[k, 2]) - centre[2]
            h = d0 * ha[0] + d1 * ha[1] + d2 * ha[2]
            v = d0 * va[0] + d1 * va[1] + d2 * va[2]
            if need_hv:
                index[n_wall] = k
                hs[n_wall] = h
                vs[n_wall] = v
            n_wall += 1
            uh = (h - h0) / pitch_h - 0.5
            uv = (v - v0) / pitch_v - 0.5
            if abs(uh) < _BIG and abs(uv) < _BIG:
                rh = np.int64(np.rint(uh))
                rv = np.int64(np.rint(uv))
                for i in range(i0, i1 + 1):
                    ci = rh + i
                    oh = (uh - ci) * pitch_h
                    if not (ci >= 0 and ci < nh and oh >= -half_dh and oh < half_dh):
                        continue
                    for j in range(j0, j1 + 1):
                        cj = rv + j
                        ov = (uv - cj) * pitch_v
                        if cj >= 0 and cj < nv and ov >= -half_dv and ov < half_dv:
                            slot = (i - i0) * nj + (j - j0)
                            cell = cj * nh + ci
                            for c in range(C):
                                win_scratch[slot, cell, c] += np.float64(power[k, c])
            if use_lattice:
                fc = np.floor(2.0 * (h - lh0) / dh)
                fr = np.floor(2.0 * (lv1 - v) / dv)
                if fc >= 0 and fc < 2 * W and fr >= 0 and fr < 2 * H:
                    cell = np.int64(fr) * (2 * W) + np.int64(fc)
                    t = slot_of[cell]
                    if t < 0:
                        t = n_touched
                        slot_of[cell] = t
                        cells[t] = cell
                        n_touched += 1
                    for c in range(C):
                        acc[t, c] += np.float64(power[k, c])
                    ok_rec[n_ok] = k
                    n_ok += 1
        ok_bounds[g + 1] = n_ok
        if counts[g] == 0:
            continue
        for slot in range(n_slots):
            for cell in range(G):
                for c in range(C):
                    windows[g, cell, c] += win_scratch[slot, cell, c]
                    win_scratch[slot, cell, c] = 0.0
        for t in range(n_touched):
            cell = cells[t]
            for c in range(C):
                lattice[g, cell, c] += acc[t, c]
                acc[t, c] = 0.0
            slot_of[cell] = -1
    return counts, ok_rec[:n_ok], ok_bounds, index[:n_wall], hs[:n_wall], vs[:n_wall]
