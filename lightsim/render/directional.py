"""The written map near edges: directional (one-sided) windows fused by inverse variance.

The centred ICI ladder (:mod:`lightsim.render.ici`) has one weakness: next to a beam edge
or a cut-off every centred window larger than the pixel straddles the step, ICI rejects
them all and the pixel falls back to rung 0 — its own count, the noisiest estimate there
is — so the photons a run needs are set by its edge pixels. This module adds the
directional windows of LPA-ICI (Katkovnik, Foi, Egiazarian, Astola, "Directional varying
scale approximations for anisotropic signal processing", EUSIPCO 2004; Katkovnik,
Egiazarian, Astola, *Local Approximation Techniques in Signal and Image Processing*, SPIE
Press 2006: the ICI rule run per direction over one-sided/sector windows, the directional estimates
fused by their inverse variances). Here, for every pixel, K = 9 ladders share rung 0 (the
pixel itself):

    ladder 0      the centred squares of :mod:`lightsim.render.ici` (from the clients);
    ladders 1–4   squares of side m with the pixel at a corner (NW, NE, SW, SE);
    ladders 5–8   rectangles m deep × (2⌊m/2⌋ + 1) wide with the pixel at the middle of an
                  edge (N, S, W, E), m = 2 … m_max,

each run through the ICI rule with the same Γ and the same compound-Poisson σ as the
centred ladder; the K chosen estimates are fused with weights w_k ∝ 1/σ_k² (σ_k the
standard error of ladder k's chosen rung, at the pixel's one intensity: w_k ∝ the
window's area; weights ∝ 1/E_k of each window's own value would favour the dimmer,
Poisson-low windows and bias the map down). Next to an edge the ladders reaching inwards
stay unbiased and keep large windows, so the pixel is no longer left with rung 0; where
the pixel itself is crossed by the edge, every ladder that leaves it disagrees with
rung 0 and is cut back to it, so rung 0 stays. In a smooth region opposite one-sided
windows cancel each other's first-order blur, and the centred ladder is one of the nine.

The directional windows consist of whole pixels, so they are sums of rung 0 (the pixel
values every set already sends) over pixel rectangles, read from one summed-area table
per set: O(1) per pixel and rung, from the same data the centred map uses, only for the
whole wall raster (queries at scattered probes have no neighbours: they keep the centred
map). Directional windows that would leave the wall end their ladder.

The error figure stays the written map's
(:func:`lightsim.render.written_map.written_map`: noise plus blur, mixed with the counts
by α) and stays honest by **cross-fitting**: each half of the interleave sets is read at
the fusion chosen from the other half, so a set's value depends on its own photons only
through the windows it sums. Its scatter is then the
map's noise, and D̄² − se_D² of a half (D = value − rung 0, rung 0 unbiased for the pixel
mean) is unbiased for the squared blur of the other half's choice. (A choice made from the
same photons, with nine ladders to pick from, prefers windows whose noise happens to agree
with the pixel; even the held-out pairs of :func:`~lightsim.render.ici.held_out_blur`,
which leave the pair's photons out of the choice but not out of the map, read 0.75 × the
actual error on the paraboloid at 250 k photons.)

===============  =====  ========  ========================================================
parameter        unit   default   meaning
===============  =====  ========  ========================================================
``m_max``        px     ladder's  largest directional window side: the centred ladder's
                                  (after :func:`~lightsim.render.ici.shrink_sides`)
``gamma``        –      2.0       ICI interval half-width Γ in standard errors
                                  (``RunConfig.ici_gamma``)
``q``            lm     –         ΣΦ²/ΣΦ of the wall photons (all sets)
``n``            –      –         photons emitted, all sets
``a_pix``        m²     dh dv     pixel area (the σ of a window of c pixels uses c a_pix)
``GUIDE``        –      0.5       pixels fused: the centred map ≥ GUIDE × the lit fraction
                                  × its maximum (the rest keep the centred value)
===============  =====  ========  ========================================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from lightsim.render.frame import luminous
from lightsim.render.ici import IciChoice, add_scaled, halves, set_weights, stack_sets

#: (dy, dx) of the directional ladders 1 … 8: rows grow downwards, columns to the right.
DIRECTIONS = np.array([(-1, -1), (-1, 1), (1, -1), (1, 1), (-1, 0), (1, 0), (0, -1), (0, 1)],
                      dtype=np.int64)
GUIDE = 0.5  # pixels fused: centred map ≥ GUIDE × the lit fraction × its maximum


def pixel_sat(img: np.ndarray) -> np.ndarray:
    """(…, H+1, W+1) summed-area table of (…, H, W) pixel values, zero first row/column:
    NumPy's two ``cumsum`` passes (down the columns, then along the rows), for a stack
    of images one compiled pass per image on the cores (the same additions in the same
    order, so the same table)."""
    img = np.asarray(img, dtype=np.float64)
    sat = np.zeros((*img.shape[:-2], img.shape[-2] + 1, img.shape[-1] + 1))
    if img.ndim == 3 and img.flags.c_contiguous and img.size:
        _sat_stack(img, sat)
        return sat
    np.cumsum(img, axis=-2, out=sat[..., 1:, 1:])
    np.cumsum(sat[..., 1:, 1:], axis=-1, out=sat[..., 1:, 1:])
    return sat


@njit(cache=True, parallel=True, nogil=True)
def _sat_stack(img: np.ndarray, sat: np.ndarray) -> None:
    """:func:`pixel_sat` of every image of (S, H, W) into the zeroed (S, H+1, W+1)."""
    S, H, W = img.shape
    for s in prange(S):
        for c in range(W):  # cumsum down the columns: the first row as it is
            sat[s, 1, c + 1] = img[s, 0, c]
        for r in range(1, H):
            for c in range(W):
                sat[s, r + 1, c + 1] = sat[s, r, c + 1] + img[s, r, c]
        for r in range(H):  # then along each row, in place
            for c in range(1, W):
                sat[s, r + 1, c + 1] = sat[s, r + 1, c] + sat[s, r + 1, c + 1]


@njit(cache=True, inline="always")
def _extent(p, d, m, n):
    """[lo, hi) of a window of side m along one axis of n pixels, pixel p, direction d;
    (−1, −1) when it would leave the wall."""
    if d > 0:
        lo, hi = p, p + m
    elif d < 0:
        lo, hi = p - m + 1, p + 1
    else:
        k = m // 2
        lo, hi = p - k, p + k + 1
    if lo < 0 or hi > n:
        return -1, -1
    return lo, hi


@njit(cache=True, inline="always")
def _rect(sat, r0, r1, c0, c1):
    return sat[r1, c1] - sat[r0, c1] - sat[r1, c0] + sat[r0, c0]


@njit(cache=True)
def _ladders(sat, H, W, Ec, Ac, r, c, dirs, a_pix, E, A, J):
    """Fill E (K, J+1) and A (K, J+1) with the ladders' values (lx) and areas (m²) at
    pixel (r, c) of an H × W wall from a pooled SAT and the centred rungs Ec (J+1,),
    Ac (J+1,); a window leaving the wall has A = 0 (its ladder ends there). Returns nothing."""
    K = E.shape[0]
    for j in range(J + 1):
        E[0, j] = Ec[j]
        A[0, j] = Ac[j]
    for k in range(1, K):
        E[k, 0] = Ec[0]
        A[k, 0] = Ac[0]
        dy = dirs[k - 1, 0]
        dx = dirs[k - 1, 1]
        for j in range(1, J + 1):
            m = j + 1
            r0, r1 = _extent(r, dy, m, H)
            c0, c1 = _extent(c, dx, m, W)
            if r0 < 0 or c0 < 0:
                A[k, j] = 0.0
                E[k, j] = 0.0
                continue
            cnt = (r1 - r0) * (c1 - c0)
            E[k, j] = _rect(sat, r0, r1, c0, c1) / cnt
            A[k, j] = cnt * a_pix


@njit(cache=True)
def _choose(E, A, J, scale, gamma, jk, wk):
    """ICI per ladder on E, A (K, J+1) with σ² = max(E_j, E_top, 0) · scale / A_j
    (scale = q/n); fills the chosen rungs jk (K,) and normalised fusion weights wk (K,)
    ∝ A_j: 1/σ² at the pixel's one intensity (see :func:`fused_map`)."""
    K = E.shape[0]
    for k in range(K):
        top = 0
        for j in range(1, J + 1):
            if A[k, j] > 0:
                top = j
            else:
                break
        et = E[k, top]
        lo = -np.inf
        hi = np.inf
        best = 0
        for j in range(top + 1):
            base = max(E[k, j], et, 0.0)
            s = gamma * np.sqrt(base * scale / A[k, j]) if scale > 0 else 0.0
            lo = max(lo, E[k, j] - s)
            hi = min(hi, E[k, j] + s)
            if lo <= hi:
                best = j
            else:
                break
        jk[k] = best
        wk[k] = A[k, best]
    tot = 0.0
    for k in range(K):
        tot += wk[k]
    for k in range(K):
        wk[k] /= tot


@njit(cache=True, parallel=True, nogil=True)
def choose_fused(sat, Ec, Ac, rows, cols, dirs, a_pix, scale, gamma):
    """The fused choice at every query: (jk (Q, K) int64, wk (Q, K) float64).

    sat (H+1, W+1) pooled luminous SAT; Ec, Ac (J+1, Q) pooled centred rungs (lx) and
    their areas (m²)."""
    J = Ec.shape[0] - 1
    Q = rows.shape[0]
    K = dirs.shape[0] + 1
    H = sat.shape[0] - 1
    W = sat.shape[1] - 1
    jk = np.zeros((Q, K), np.int64)
    wk = np.zeros((Q, K))
    chunk = 256  # queries per work item: the scratch arrays are made once per item
    for b in prange((Q + chunk - 1) // chunk):
        E = np.empty((K, J + 1))
        A = np.empty((K, J + 1))
        ec = np.empty(J + 1)
        ac = np.empty(J + 1)
        for i in range(b * chunk, min(Q, (b + 1) * chunk)):
            for j in range(J + 1):
                ec[j] = Ec[j, i]
                ac[j] = Ac[j, i]
            _ladders(sat, H, W, ec, ac, rows[i], cols[i], dirs, a_pix, E, A, J)
            _choose(E, A, J, scale, gamma, jk[i], wk[i])
    return jk, wk


@njit(cache=True, parallel=True, nogil=True)
def apply_fused(sats, Ecs, which, rows, cols, dirs, jk, wk):
    """(len(which), Q) the fused values of the images ``which`` of sats (S, H+1, W+1) and
    centred rungs Ecs (S, J+1, Q) at the choice (jk, wk) of :func:`choose_fused`."""
    Q = rows.shape[0]
    K = jk.shape[1]
    T = which.shape[0]
    out = np.zeros((T, Q))
    # one parallel region for all images (one per image cost a thread barrier each: on a
    # loaded machine ~4x the work on a 64 × 64 map); each thread's block of (t, i) still
    # walks one image after another, so its SAT stays in cache
    for ti in prange(T * Q):
        t = ti // Q
        i = ti - t * Q
        s = which[t]
        sat = sats[s]
        H = sat.shape[0] - 1
        W = sat.shape[1] - 1
        r = rows[i]
        c = cols[i]
        v = wk[i, 0] * Ecs[s, jk[i, 0], i]
        for k in range(1, K):
            w = wk[i, k]
            j = jk[i, k]
            if w == 0.0:
                continue
            if j == 0:
                v += w * Ecs[s, 0, i]
                continue
            r0, r1 = _extent(r, dirs[k - 1, 0], j + 1, H)
            c0, c1 = _extent(c, dirs[k - 1, 1], j + 1, W)
            v += w * _rect(sat, r0, r1, c0, c1) / ((r1 - r0) * (c1 - c0))
        out[t, i] = v
    return out


@dataclass
class FusedChoice(IciChoice):
    """:class:`~lightsim.render.ici.IciChoice` of the fused map: ``rung`` is the rung of
    the ladder with the largest weight (the centred rung where a pixel is not fused);
    ``ladder_rungs`` (P, K) and ``weights`` (P, K) the whole choice at the fused pixels
    ``pixels`` (P,) (ladder 0 the centred one, then :data:`DIRECTIONS`)."""

    ladder_rungs: np.ndarray | None = None
    weights: np.ndarray | None = None
    pixels: np.ndarray | None = None


@dataclass
class FusedMap:
    """What :func:`lightsim.render.written_map.written_map` needs of the fused map: the
    choice and every set's luminous values (S, Q) (no held-out blur: the map's own
    D̄² − se_D² is unbiased, see :func:`fused_map`)."""

    choice: FusedChoice
    vals: np.ndarray


def _combine(out: np.ndarray, stack: np.ndarray, which, weights) -> np.ndarray:
    """Σ weights · stack[which] into ``out`` (in place: no copies of the stack)."""
    out[:] = 0.0
    for wi, k in zip(weights, which, strict=True):
        add_scaled(out, stack[k], wi)
    return out


def fused_map(rungs: dict[int, np.ndarray], emitted: dict[int, int], q: float,
              areas: np.ndarray, gamma: float, shape: tuple[int, int],
              lit_fraction: float = 0.1, guide: IciChoice | None = None,
              win: np.ndarray | None = None) -> FusedMap:
    """The fused directional map over the whole H × W raster (``shape``), cross-fitted.

    With S ≥ 4 sets each half of them (:func:`lightsim.render.ici.halves`) is read at
    the choice made from the *other* half; the map is the emitted-weighted mean of every
    set's value. Each set's value then depends on its own photons only through the
    windows it sums, not through the choice, so its scatter is the map's noise and
    D̄² − se_D² of a half (D = value − rung 0) is an unbiased estimate of the squared blur
    of the other half's choice; their mean bounds the map's (mean of the two choices')
    squared blur from above. (With nine ladders to pick from, a choice made from the same
    photons favours windows whose noise happens to agree with the pixel: on the
    paraboloid at 250 k photons the held-out pairs of :func:`~lightsim.render.ici.
    held_out_blur` then read 0.75 × the actual error; this split removes that.) Fewer
    than four sets: one choice from all of them and no blur estimate of its own.

    Parameters
    ----------
    rungs : {set: (J+1, H·W, C) lx}
        Every set's centred rungs at every pixel in row order (rung 0: the pixel).
    emitted : {set: photons}
    q : float
        ΣΦ²/ΣΦ (lm) of the wall photons over all sets.
    areas : (J+1, H·W) m²
        The centred windows' areas.
    gamma : float
        ICI interval half-width in standard errors.
    guide : IciChoice, optional
        The centred map (:func:`lightsim.render.ici.choose`): only pixels at ≥
        :data:`GUIDE` × ``lit_fraction`` × its luminous maximum are fused; the others, far
        below what the figure reads, keep the centred value and rung (a headlight's wall
        is mostly dark: several times less work).
    win : (S, Q) lx, optional
        Every set's luminous rung 0 in set order, if the caller has made it
        (:func:`lightsim.render.ici.stack_sets` with ``lum=True, rung=0``).
    """
    H, W = shape
    order = sorted(rungs)
    e = np.array([emitted[s] for s in order], dtype=np.float64)
    # every set's luminous rung 0 at every pixel (the windows' SATs, the lit masks); the
    # other rungs only at the fused pixels below (no (S, J+1, H·W) stack: 84 MB on the
    # shipped headlight's wall, of which a tenth is fused)
    R0 = stack_sets(rungs, order, lum=True, rung=0) if win is None else win  # (S, Q)
    S, Q = R0.shape
    J1 = np.asarray(rungs[order[0]]).shape[0]
    if Q != H * W:
        raise ValueError(f"fused_map: {Q} queries are not a {H} × {W} raster")
    areas = np.ascontiguousarray(np.broadcast_to(
        np.asarray(areas, np.float64)[:J1].reshape(J1, -1), (J1, Q)))
    a_pix = float(areas[0, 0])
    rows_all, cols_all = np.divmod(np.arange(Q, dtype=np.int64), W)
    sats = pixel_sat(R0.reshape(S, H, W))
    C = np.asarray(rungs[order[0]]).shape[-1]
    # the fused pixels: all, or those the centred map shows near or above the lit level
    if guide is not None and Q:
        g = luminous(np.asarray(guide.lux, np.float64))
        sel = np.flatnonzero(g >= GUIDE * lit_fraction * float(g.max()))
    else:
        sel = np.arange(Q, dtype=np.int64)
    rows, cols = rows_all[sel], cols_all[sel]
    Rs = stack_sets(rungs, order, lum=True, pixels=sel)  # (S, J+1, Qs)
    As = np.ascontiguousarray(areas[:, sel])
    Qs = len(sel)
    everyone = np.arange(S)
    # (sets read, sets that choose): each half at the other's choice, or all at their own
    plan = ([(h, g) for h, g in zip(halves(S), halves(S)[::-1], strict=True)]
            if S >= 4 else [(everyone, everyone)])
    choices = []
    pooled_sat = np.empty_like(sats[0])
    pooled_c = np.empty((J1, Qs))
    w_all = set_weights(emitted, order)
    one = np.zeros(1, np.int64)
    means = []  # each half's mean fused value (what the lit masks read), (Qs,)
    lux1 = np.zeros(Qs)
    for read, chooser in plan:
        w = set_weights({k: emitted[order[k]] for k in chooser}, list(chooser))
        n = float(e[chooser].sum())
        scale = q / n if n > 0 and q > 0 else 0.0
        jk, wk = choose_fused(_combine(pooled_sat, sats, chooser, w),
                              _combine(pooled_c, Rs, chooser, w), As, rows, cols,
                              DIRECTIONS, a_pix, scale, gamma)
        flat = np.full(len(read), 1.0 / len(read))
        means.append(apply_fused(_combine(pooled_sat, sats, read, flat)[None],
                                 _combine(pooled_c, Rs, read, flat)[None], one, rows, cols,
                                 DIRECTIONS, jk, wk)[0])
        if C == 1:  # the map itself: linear in the sets, so from their weighted sum
            lux1 += apply_fused(_combine(pooled_sat, sats, read, w_all[read])[None],
                                _combine(pooled_c, Rs, read, w_all[read])[None], one, rows,
                                cols, DIRECTIONS, jk, wk)[0]
        choices.append((read, jk, wk))
    # every set's value is needed only where the figure may read it (lit for either
    # half: a half's mean ≥ the threshold); 0 elsewhere leaves the lit masks as they are
    vals = np.zeros((S, Q))
    if Qs:
        overall = sum(len(r) * m for (r, _), m in zip(plan, means, strict=True)) / S
        thr = lit_fraction * float(overall.max()) * (1.0 - 1e-9)
        cand = np.flatnonzero(np.any(np.stack(means) >= thr, axis=0))
        Rc = np.ascontiguousarray(Rs[:, :, cand])
        for read, jk, wk in choices:
            vals[np.ix_(read, sel[cand])] = apply_fused(
                sats, Rc, np.asarray(read, np.int64), rows[cand], cols[cand], DIRECTIONS,
                np.ascontiguousarray(jk[cand]), np.ascontiguousarray(wk[cand]))
    lux = np.zeros((Q, C))
    if guide is not None:  # the pixels not fused keep the centred map's value
        lux[:] = np.asarray(guide.lux, np.float64)
    if C == 1:
        lux[sel, 0] = lux1
    else:  # every channel fused with the luminous choice of its half
        lux[sel] = 0.0
        for read, jk, wk in choices:
            part = np.zeros((J1, Q, C))
            for k in read:
                part += w_all[k] * np.asarray(rungs[order[k]], np.float64)
            pc = np.ascontiguousarray(np.moveaxis(part, -1, 0))  # (C, J+1, Q)
            lux[sel] += apply_fused(pixel_sat(pc[:, 0].reshape(C, H, W)),
                                    np.ascontiguousarray(pc[:, :, sel]),
                                    np.arange(C, dtype=np.int64), rows, cols, DIRECTIONS,
                                    jk, wk).T
    # the pixels not fused keep the centred rung (their one ladder, weight 1); the fused
    # ones the rung of their heaviest ladder (no (Q, K) arrays for the whole wall)
    rung = (np.array(guide.rung, dtype=np.int64) if guide is not None
            else np.zeros(Q, np.int64))
    jk0 = wk0 = None
    if choices:
        jk0, wk0 = choices[0][1], choices[0][2]
        rung[sel] = jk0[np.arange(len(sel)), np.argmax(wk0, axis=1)]
    return FusedMap(FusedChoice(rung, lux, jk0, wk0, sel if choices else None), vals)
