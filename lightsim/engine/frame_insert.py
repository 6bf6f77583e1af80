"""Compiled passes of a frame's insertion (:meth:`PhotonSets.shoot`): counting sorts and
per-cell sums instead of ``argsort`` / ``np.unique`` / one ``bincount`` per window offset.

Every kernel reproduces the NumPy definition it replaces bit for bit (the same float64
operations in the same order, each cell's photons summed from 0 in photon order and then
added to the store once), so the stores do not change: ``tests/test_frame_insert.py``
compares them with the per-set NumPy path (:meth:`PhotonSets.insert`).

=======================  =====================================================
kernel                   replaces
=======================  =====================================================
:func:`sort_by_source`   ``np.argsort(source, kind="stable")`` and six gathers
:func:`wall_hits`        ``np.isin(part, ids)``, ``flatnonzero`` and the wall's h, v
:func:`add_windows`      one ``bincount`` per window offset and channel
:func:`add_lattice`      ``np.unique`` over (set, cell) and one ``bincount`` per channel
=======================  =====================================================
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def sort_by_source(position, normal, power, part, flags, source, n_sources):
    """The records in stable order of ``source`` (a counting sort; ``source`` in
    [0, n_sources)): the same arrays as gathering every array through
    ``np.argsort(source, kind="stable")``."""
    n = source.shape[0]
    start = np.zeros(n_sources + 1, np.int64)
    for i in range(n):
        start[source[i] + 1] += 1
    for s in range(n_sources):
        start[s + 1] += start[s]
    C = power.shape[1]
    pos = np.empty((n, 3), position.dtype)
    nrm = np.empty((n, 3), normal.dtype)
    pw = np.empty((n, C), power.dtype)
    pt = np.empty(n, part.dtype)
    fl = np.empty(n, flags.dtype)
    src = np.empty(n, source.dtype)
    for i in range(n):
        s = source[i]
        k = start[s]
        start[s] = k + 1
        for a in range(3):
            pos[k, a] = position[i, a]
            nrm[k, a] = normal[i, a]
        for c in range(C):
            pw[k, c] = power[i, c]
        pt[k] = part[i]
        fl[k] = flags[i]
        src[k] = s
    return pos, nrm, pw, pt, fl, src


@njit(cache=True, nogil=True)
def wall_hits(part, wall_ids, position, centre, h_axis, v_axis):
    """(record indices, h, v in m) of the records on a wall part: ``d = position − centre``
    in float64, ``h = d·h_axis``, ``v = d·v_axis`` summed x, y, z in that order."""
    n = part.shape[0]
    on = np.zeros(n, np.bool_)
    m = 0
    for i in range(n):
        for w in wall_ids:
            if part[i] == w:
                on[i] = True
                m += 1
                break
    index = np.empty(m, np.int64)
    h = np.empty(m)
    v = np.empty(m)
    k = 0
    for i in range(n):
        if on[i]:
            index[k] = i
            d0 = np.float64(position[i, 0]) - centre[0]
            d1 = np.float64(position[i, 1]) - centre[1]
            d2 = np.float64(position[i, 2]) - centre[2]
            h[k] = d0 * h_axis[0] + d1 * h_axis[1] + d2 * h_axis[2]
            v[k] = d0 * v_axis[0] + d1 * v_axis[1] + d2 * v_axis[2]
            k += 1
    return index, h, v


_BIG = 2.0 ** 62  # |u| beyond it: no window can hold the photon (and no int64 overflow)


@njit(cache=True, nogil=True)
def add_windows(windows, bounds, h, v, power, index, geometry, reach):
    """Add wall photons to the pixel windows at the grid probes of every set.

    ``windows`` (S, G, C) float64, set g's wall photons ``bounds[g]:bounds[g+1]`` of ``h``,
    ``v`` (m) with powers ``power[index[k]]``; ``geometry`` = (h0, v0, pitch_h, pitch_v,
    half_dh, half_dv), ``reach`` = (i0, i1, j0, j1, nh, nv): the window offsets i0…i1,
    j0…j1 around the nearest cell centre. Per offset (i, j), in that order, every cell's
    photons are summed from 0 and the sum added to the store: what one ``bincount`` per
    offset does.
    """
    S, G, C = windows.shape
    h0, v0, pitch_h, pitch_v, half_dh, half_dv = geometry
    i0, i1, j0, j1, nh, nv = reach
    ni, nj = i1 - i0 + 1, j1 - j0 + 1
    scratch = np.zeros((ni * nj, G, C))
    for g in range(S):
        lo, hi = bounds[g], bounds[g + 1]
        if hi == lo:
            continue
        for k in range(lo, hi):
            uh = (h[k] - h0) / pitch_h - 0.5
            uv = (v[k] - v0) / pitch_v - 0.5
            if not (abs(uh) < _BIG and abs(uv) < _BIG):
                continue
            rh = np.int64(np.rint(uh))
            rv = np.int64(np.rint(uv))
            r = index[k]
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
                            scratch[slot, cell, c] += np.float64(power[r, c])
        for slot in range(ni * nj):
            for cell in range(G):
                for c in range(C):
                    windows[g, cell, c] += scratch[slot, cell, c]
                    scratch[slot, cell, c] = 0.0


@njit(cache=True, nogil=True)
def add_lattice(lattice, bounds, h, v, power, index, geometry, shape, scratch, touched,
                cells):
    """Add wall photons to every set's half-pixel lattice (ICI windows).

    ``lattice`` (S, 4HW, C) float64; set g's wall photons ``bounds[g]:bounds[g+1]``;
    ``geometry`` = (h0, v1, dh, dv), ``shape`` = (W, H). A photon's cell is
    ``row · 2W + col`` with ``col = ⌊2(h − h0)/dh⌋``, ``row = ⌊2(v1 − v)/dv⌋`` (photons
    off the lattice are left out); each cell's photons are summed from 0 in order and the
    sum added once, as ``np.unique`` + ``bincount`` do. ``scratch`` (4HW, C) float64 zeros,
    ``touched`` (4HW,) False and ``cells`` (4HW,) int64 are work arrays kept by the caller
    (left zero / False: only the cells a frame touched are visited, never the whole
    image). Returns the positions (in the wall arrays) of the photons on the lattice, in
    order, and each set's share of them (S + 1 bounds).
    """
    S = lattice.shape[0]
    C = lattice.shape[2]
    h0, v1, dh, dv = geometry
    W, H = shape
    ok_index = np.empty(h.shape[0], np.int64)
    ok_bounds = np.zeros(S + 1, np.int64)
    m = 0
    for g in range(S):
        n_touched = 0
        for k in range(bounds[g], bounds[g + 1]):
            fc = np.floor(2.0 * (h[k] - h0) / dh)
            fr = np.floor(2.0 * (v1 - v[k]) / dv)
            if not (fc >= 0 and fc < 2 * W and fr >= 0 and fr < 2 * H):
                continue
            cell = np.int64(fr) * (2 * W) + np.int64(fc)
            if not touched[cell]:
                touched[cell] = True
                cells[n_touched] = cell
                n_touched += 1
            r = index[k]
            for c in range(C):
                scratch[cell, c] += np.float64(power[r, c])
            ok_index[m] = k
            m += 1
        ok_bounds[g + 1] = m
        for t in range(n_touched):
            cell = cells[t]
            for c in range(C):
                lattice[g, cell, c] += scratch[cell, c]
                scratch[cell, c] = 0.0
            touched[cell] = False
    return ok_index[:m], ok_bounds
