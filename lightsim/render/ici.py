"""The written map's radius rule: intersection of confidence intervals over a radius ladder.

A density estimate at a pixel trades blur for noise through its radius. kNN picks the
radius from the photon density alone (r_k), so next to a cut-off or a beam edge it reaches
across the step, and with the radius held between fixed bounds its error stops falling
(issue 12: 2.2–2.9 % from 2 M to 16 M photons on the paraboloid while binning fell as
1/√N). Here every pixel has a ladder of nested estimates from the same photons

    rung 0: the photons in the pixel itself (dh × dv) — unbiased for the pixel mean;
    rung j: the photons in the square of j + 1 pixels a side centred on it (j = 1 … J,
            the largest with the area of the disk of radius r_max: 4 × 4 by default),

each with a standard error σ_j, and the radius is the largest rung whose confidence
interval [E_j − Γσ_j, E_j + Γσ_j] still overlaps those of all smaller rungs (the ICI rule
of Goldenshluger & Nemirovski 1997 / Katkovnik 1999, a form of Lepski's method). Where E is
smooth the rungs agree and the largest, least noisy one wins; where a larger disk's
blur exceeds the noise of the smaller ones it is rejected. As photons accumulate every σ_j
falls as 1/√N, so ever smaller blur is rejected: the radius shrinks where — and only
where — blur would show, the bias of the chosen rung stays below ≈ 2Γσ, and the map
converges to the pixel means at the 1/√N rate of the rung it ends on, without a floor.

σ_j is the compound-Poisson standard error of the pooled estimate (all sets, N photons),

    σ_j² = max(E_j, E_J) · q / (N A_j),  q = ΣΦ² / ΣΦ of the wall photons (lm),

with the largest rung's (least noisy) value standing in for an empty small rung; for
quasi-random photons it is conservative (their counts scatter less than Poisson).

The windows are sums over a half-pixel lattice of photon power that every set keeps
(windows of any whole number of pixels are then centred on the pixel), read from its
summed-area table: O(1) per pixel and rung whatever the photon count, where disk queries
on the photon map cost in proportion to the photons inside the largest disk. A few queries
(a frame's grid probes) sum their windows' cells directly instead (:func:`_direct_sums`):
no pass over the whole lattice per frame.

On the whole wall raster :func:`written_map` also makes the fused directional map of
:mod:`lightsim.render.directional` (one-sided windows that reach inwards next to an edge,
LPA-ICI) and writes it where its own, cross-fitted figure is clearly the lower.

===============  =====  ========  ========================================================
parameter        unit   default   meaning
===============  =====  ========  ========================================================
``r_max``        m      4 r_pix   the largest window has at most this disk's area
                                  (``RunConfig.max_radius``; auto: 4 × the radius of the
                                  disk with one pixel's area → 4 × 4 pixels)
``gamma``        –      2.0       interval half-width Γ in standard errors
                                  (``RunConfig.ici_gamma``)
``q``            lm     –         power-weighted mean photon power ΣΦ²/ΣΦ (all sets)
``CERTIFY``      –      0.25      the blur estimate's standard error may be at most this
                                  × the squared error the figure reports
``MIX_STEPS``    –      40        steps of the counts' weight α in the written map
``FUSED_MARGIN`` –      0.9       the fused map is written below this × the centred
                                  map's figure
``TILE``         px     8         a region's blur standard error: batch means over tiles
                                  of this side (``TILES_MIN`` = 16 tiles at least)
===============  =====  ========  ========================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any

import numpy as np
from numba import njit

from lightsim.render.frame import ErrorEstimate, luminous
from lightsim.render.region import Restrict
from lightsim.threads import helper_thread

MAX_RUNGS = 8  # window sides 1 … 8 pixels at most


def rung_sides(pixel_size: tuple[float, float], r_max: float) -> np.ndarray:
    """Window sides (pixels) of the rungs: 1, 2, … m_max, the largest window no larger in
    area than the disk of radius ``r_max`` (m; infinite: 4 pixels a side)."""
    dh, dv = pixel_size
    if not math.isfinite(r_max):
        m_max = 4
    else:
        m_max = math.floor(math.sqrt(math.pi * r_max * r_max / (dh * dv)) + 1e-9)
    return np.arange(1, min(MAX_RUNGS, max(1, m_max)) + 1)


SHRINK_START = 256.0  # photons per pixel (all sets) where the largest window starts to shrink


def shrink_sides(sides: np.ndarray, photons_per_pixel: float) -> np.ndarray:
    """The rungs still allowed at Λ photons per pixel (all sets): sides 1 … m(Λ),

    m(Λ) = ⌊m_cap (Λ₀/Λ)^(1/6)⌋ clipped to [1, m_cap] for Λ > Λ₀ = :data:`SHRINK_START`.
    h ∝ Λ^(−1/6) is the bandwidth that balances a second-order kernel's blur (∝ h²)
    against its noise (∝ 1/(h √Λ)) in two dimensions, so even where the ICI test cannot
    see the blur of the largest window it shrinks towards the pixel itself: the estimate
    is consistent everywhere, not only where blur is detectable.
    """
    sides = np.asarray(sides)
    m_cap = int(sides.max()) if sides.size else 1
    if not photons_per_pixel > SHRINK_START:
        return sides
    m = math.floor(m_cap * (SHRINK_START / photons_per_pixel) ** (1.0 / 6.0) + 1e-9)
    return sides[sides <= max(1, m)]


def power_moment(moments: dict[int, np.ndarray]) -> float:
    """q = ΣΦ² / ΣΦ (lm) over every set's luminous wall photons; 0 without photons."""
    tot = np.zeros(2)
    for s in sorted(moments):
        tot += np.asarray(moments[s], dtype=np.float64)[:2]
    return float(tot[1] / tot[0]) if tot[0] > 0 else 0.0


def wall_photons(moments: dict[int, np.ndarray]) -> float:
    """Photons on the wall over all sets (the third moment, a count)."""
    return float(sum(float(np.asarray(moments[s])[2]) for s in sorted(moments)))


def lattice_index(h: np.ndarray, v: np.ndarray, frame) -> tuple[np.ndarray, np.ndarray]:
    """(flat index into the (2H, 2W) half-pixel lattice, inside mask) of wall points (m).

    Row 0 is the top (v = v_max) as in the image; a pixel (row, col) covers half-pixel rows
    2row, 2row+1 and columns 2col, 2col+1, so its centre is a lattice corner.
    """
    W, H = frame.resolution
    dh, dv = frame.pixel_size_m
    col = np.floor(2.0 * (h - frame.h_range_m[0]) / dh).astype(np.int64)
    row = np.floor(2.0 * (frame.v_range_m[1] - v) / dv).astype(np.int64)
    ok = (col >= 0) & (col < 2 * W) & (row >= 0) & (row < 2 * H)
    return row * (2 * W) + col, ok


@dataclass(frozen=True)
class WindowGeometry:
    """The clipped half-pixel bounds of every window (per side: r0, r1, c0, c1) and their
    cell counts (J, Q): the same for every set, so computed once per query set."""

    bounds: tuple[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], ...]
    cells: np.ndarray
    raster: bool = False  # every pixel in row order: summed by :func:`_raster_sums`
    direct: bool = False  # few queries: their windows summed cell by cell (_direct_sums)
    stacked: np.ndarray | None = None  # bounds as one (J, 4, Q) int64 array (_bounded_sums)

    def __post_init__(self) -> None:
        if self.stacked is None:  # derived from the bounds when not given
            n = len(self.bounds[0][0]) if self.bounds else 0
            object.__setattr__(self, "stacked", np.array(
                self.bounds, dtype=np.int64).reshape(len(self.bounds), 4, n))

    @classmethod
    def of(cls, H: int, W: int, rows: np.ndarray, cols: np.ndarray, sides: np.ndarray
           ) -> WindowGeometry:
        rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
        raster = bool(len(rows) == H * W and np.array_equal(rows, np.repeat(np.arange(H), W))
                      and np.array_equal(cols, np.tile(np.arange(W), H)))
        # the summed-area table reads every cell of the lattice twice, the direct sums
        # the largest window of every query once: direct where that reads fewer cells
        # (the grid probes of a frame's error figure: 2 048 × 8² cells against 2 × 2H × 2W)
        m = int(np.max(sides)) if len(sides) else 0
        direct = not raster and len(rows) * (2 * m) ** 2 <= 2 * (2 * H) * (2 * W)
        return cls(tuple(_bounds(2 * H, 2 * W, rows, cols, sides)),
                   window_cells(H, W, rows, cols, sides), raster, direct)


@lru_cache(maxsize=4)
def raster_queries(H: int, W: int, sides: tuple[int, ...]
                   ) -> tuple[np.ndarray, np.ndarray, WindowGeometry]:
    """(rows, cols, geometry) of every pixel of an H × W wall in row order for the
    window ``sides``: the written map's queries, made once per wall and ladder rather
    than once per session and set (read-only arrays)."""
    rows, cols = np.divmod(np.arange(H * W, dtype=np.int64), W)
    geometry = WindowGeometry.of(H, W, rows, cols, np.asarray(sides, np.int64))
    for a in (rows, cols, geometry.cells):
        a.flags.writeable = False
    return rows, cols, geometry


def window_sums(sub: np.ndarray, rows: np.ndarray, cols: np.ndarray, sides: np.ndarray,
                geometry: WindowGeometry | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Power in square windows centred on pixels, from the half-pixel lattice
    (``geometry``: :meth:`WindowGeometry.of` these rows, cols and sides, if known).

    Parameters
    ----------
    sub : (2H, 2W, C) float64
        Power (lm) per half-pixel cell.
    rows, cols : (Q,) int
        Pixels.
    sides : (J,) int
        Window sides in pixels; a window of side m spans half-pixel cells
        2row + 1 − m … 2row + m (likewise in columns), clipped to the wall.

    Returns
    -------
    sums : (J, Q, C) float64 (lm)
    cells : (J, Q) float64
        Half-pixel cells inside each clipped window (area = cells · dh dv / 4).
    """
    H2, W2, C = sub.shape
    if geometry is None:
        geometry = WindowGeometry.of(H2 // 2, W2 // 2, rows, cols, sides)
    if geometry.raster:  # every pixel: one compiled pass, no temporaries
        sums = np.empty((len(sides), len(rows), C))
        _raster_sums(np.ascontiguousarray(sub, dtype=np.float64),
                     np.asarray(sides, np.int64), sums)
        return sums, geometry.cells
    if geometry.direct:  # few queries: no pass over the whole lattice
        sums = np.empty((len(sides), len(rows), C))
        _direct_sums(np.ascontiguousarray(sub, dtype=np.float64),
                     np.asarray(rows, np.int64), np.asarray(cols, np.int64),
                     np.asarray(sides, np.int64), sums)
        return sums, geometry.cells
    sums = np.empty((len(sides), len(rows), C))
    _bounded_sums(_summed_area(np.ascontiguousarray(sub, dtype=np.float64)),
                  geometry.stacked, sums)
    return sums, geometry.cells


@njit(cache=True, nogil=True)
def _summed_area(sub: np.ndarray) -> np.ndarray:
    """(2H + 1, 2W + 1, C) summed-area table of a lattice (2H, 2W, C), zero first row and
    column: NumPy's ``cumsum`` down the columns and then along the rows, the same
    additions in the same order (bit for bit), in one pass a row at a time (the columns'
    running sums in one row of their own). Each running sum starts from 0.0, so a −0.0
    cell reads +0.0 where ``cumsum`` would copy it (a lattice sums non-negative powers;
    :func:`lightsim.render.directional.pixel_sat` keeps NumPy's −0.0 and its own loop)."""
    H2, W2, C = sub.shape
    sat = np.empty((H2 + 1, W2 + 1, C))
    for c in range(W2 + 1):
        for k in range(C):
            sat[0, c, k] = 0.0
    col = np.zeros((W2, C))  # the column sums down to the current row
    for r in range(H2):
        for k in range(C):
            sat[r + 1, 0, k] = 0.0
            acc = 0.0
            for c in range(W2):
                x = col[c, k] + sub[r, c, k]
                col[c, k] = x
                acc += x
                sat[r + 1, c + 1, k] = acc
    return sat


@njit(cache=True, nogil=True)
def _bounded_sums(sat: np.ndarray, bounds: np.ndarray, out: np.ndarray) -> None:
    """out[j, q] = the sum of the window ``bounds[j, :, q]`` (r0, r1, c0, c1) read from
    the summed-area table ``sat``: its four corners as NumPy's fancy indexing reads them,
    in the same order."""
    J, _, Q = bounds.shape
    for j in range(J):
        for q in range(Q):
            r0, r1 = bounds[j, 0, q], bounds[j, 1, q]
            c0, c1 = bounds[j, 2, q], bounds[j, 3, q]
            for k in range(sat.shape[2]):
                out[j, q, k] = sat[r1, c1, k] - sat[r0, c1, k] - sat[r1, c0, k] + sat[r0, c0, k]


@njit(cache=True, nogil=True)
def _raster_sums(sub: np.ndarray, sides: np.ndarray, out: np.ndarray, emitted: float = 0.0,
                 area: float = 1.0) -> None:
    """:func:`window_sums` at every pixel of the raster, in row order, into ``out``
    (J, H·W, C): the summed-area table as NumPy's two ``cumsum`` passes make it (down the
    columns, then along the rows: the same additions in the same order) and the four
    corners of each window as its fancy indexing reads them, so the sums are NumPy's bit
    for bit; no (H, W) temporaries per corner and side (the written map's largest cost
    on a 640 × 256 wall). Both sums are made in one pass a row at a time (the columns'
    running sums in one row of their own), and a row's windows that the wall does not
    clip share one divisor, so that loop runs without per-pixel bounds (it vectorises):
    2.1 against 6.1 ms a set at 640 × 256 (the earlier two-pass form). Serial: ``prange``
    (thread start-up per call, 16 calls per map) was slower.

    ``emitted`` > 0: each sum is written normalised instead, ``sum / ((emitted ·
    max(cells, 1)) · area)`` — :func:`~lightsim.engine.estimator.normalise_flux` of the
    sums with the window's half-pixel cells, in its order — and in ``out``'s dtype
    (float32 for the wire: the same rounding as ``astype``), with no (J, H·W, C) float64
    sums and quotient in between (:func:`raster_lux`)."""
    H2, W2, C = sub.shape
    H, W = H2 // 2, W2 // 2
    sat = _summed_area(sub)
    for r in range(H):
        for j in range(sides.shape[0]):
            m = sides[j]
            r0, r1 = max(2 * r + 1 - m, 0), min(2 * r + 1 + m, H2)
            # columns ca … cb − 1: the window 2c + 1 ± m lies inside the wall
            ca = min(m // 2, W)
            cb = max(min((W2 - 1 - m) // 2 + 1, W), ca)
            for c in range(ca):
                _clipped_window(sat, out, j, r, c, m, r0, r1, W, W2, emitted, area)
            den = 1.0  # x / 1.0 is x: the raw sums where not normalised
            if emitted > 0:
                den = (emitted * max(np.float64((r1 - r0) * (2 * m)), 1.0)) * area
            q0 = r * W
            if C == 1:
                for c in range(ca, cb):
                    c0 = 2 * c + 1 - m
                    c1 = c0 + 2 * m
                    out[j, q0 + c, 0] = (sat[r1, c1, 0] - sat[r0, c1, 0] - sat[r1, c0, 0]
                                         + sat[r0, c0, 0]) / den
            else:
                for c in range(ca, cb):
                    c0 = 2 * c + 1 - m
                    c1 = c0 + 2 * m
                    for k in range(C):
                        out[j, q0 + c, k] = (sat[r1, c1, k] - sat[r0, c1, k]
                                             - sat[r1, c0, k] + sat[r0, c0, k]) / den
            for c in range(cb, W):
                _clipped_window(sat, out, j, r, c, m, r0, r1, W, W2, emitted, area)


@njit(cache=True, nogil=True, inline="always")
def _clipped_window(sat, out, j, r, c, m, r0, r1, W, W2, emitted, area):
    """:func:`_raster_sums`' window of side ``m`` at pixel (r, c), clipped to the wall."""
    c0, c1 = max(2 * c + 1 - m, 0), min(2 * c + 1 + m, W2)
    q = r * W + c
    den = 1.0
    if emitted > 0:
        den = (emitted * max(np.float64((r1 - r0) * (c1 - c0)), 1.0)) * area
    for k in range(out.shape[2]):
        out[j, q, k] = (sat[r1, c1, k] - sat[r0, c1, k] - sat[r1, c0, k]
                        + sat[r0, c0, k]) / den


def raster_lux(sub: np.ndarray, sides: np.ndarray, emitted: int, area: float,
               dtype: type = np.float32) -> np.ndarray:
    """(J, H·W, C) lx in ``dtype``: the windows' sums at every pixel of the raster
    (:func:`window_sums`) normalised by :func:`~lightsim.engine.estimator.normalise_flux`
    (``emitted`` photons, > 0; window areas ``cells · area``, ``area`` m² a half-pixel
    cell) and cast — the same numbers, in one pass and one array (a set's part of the
    written map)."""
    H2, W2, C = sub.shape
    out = np.empty((len(sides), (H2 // 2) * (W2 // 2), C), dtype)
    _raster_sums(np.ascontiguousarray(sub, dtype=np.float64), np.asarray(sides, np.int64),
                 out, float(emitted), float(area))
    return out


@njit(cache=True, nogil=True)
def _direct_sums(sub: np.ndarray, rows: np.ndarray, cols: np.ndarray, sides: np.ndarray,
                 out: np.ndarray) -> None:
    """:func:`window_sums` at a few pixels, cell by cell, into ``out`` (J, Q, C): each
    cell of a query's largest window is added to the ring of the smallest side that holds
    it, and the rings are summed outwards (a window of side m is the rings 1 … m). Reads
    (2 m_max)² cells a query, whatever the wall's size; no summed-area table, so no
    cancellation between its corners either."""
    H2, W2, C = sub.shape
    M = 0
    for j in range(sides.shape[0]):
        M = max(M, sides[j])
    ring = np.empty((M + 1, C))
    for q in range(rows.shape[0]):
        r2, c2 = 2 * rows[q] + 1, 2 * cols[q] + 1  # the pixel centre: a lattice corner
        ring[:] = 0.0
        for a in range(max(r2 - M, 0), min(r2 + M, H2)):
            # side m holds row a when r2 − m ≤ a < r2 + m
            mr = r2 - a if a < r2 else a - r2 + 1
            for b in range(max(c2 - M, 0), min(c2 + M, W2)):
                mc = c2 - b if b < c2 else b - c2 + 1
                m = max(mr, mc)
                for k in range(C):
                    ring[m, k] += sub[a, b, k]
        for m in range(2, M + 1):
            for k in range(C):
                ring[m, k] += ring[m - 1, k]
        for j in range(sides.shape[0]):
            for k in range(C):
                out[j, q, k] = ring[sides[j], k]


def _bounds(H2: int, W2: int, rows: np.ndarray, cols: np.ndarray, sides: np.ndarray):
    rows = np.asarray(rows, np.int64)
    cols = np.asarray(cols, np.int64)
    for m in np.asarray(sides, np.int64):
        yield (np.clip(2 * rows + 1 - m, 0, H2), np.clip(2 * rows + 1 + m, 0, H2),
               np.clip(2 * cols + 1 - m, 0, W2), np.clip(2 * cols + 1 + m, 0, W2))


def window_cells(H: int, W: int, rows: np.ndarray, cols: np.ndarray, sides: np.ndarray
                 ) -> np.ndarray:
    """(J, Q) half-pixel cells inside each window clipped to an H × W-pixel wall."""
    out = np.zeros((len(sides), len(rows)))
    for j, (r0, r1, c0, c1) in enumerate(_bounds(2 * H, 2 * W, rows, cols, sides)):
        out[j] = (r1 - r0) * (c1 - c0)
    return out


def pixel_of(frame, h: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the wall pixels containing points (m), clipped to the wall."""
    W, H = frame.resolution
    dh, dv = frame.pixel_size_m
    col = np.floor((np.asarray(h) - frame.h_range_m[0]) / dh).astype(np.int64)
    row = np.floor((frame.v_range_m[1] - np.asarray(v)) / dv).astype(np.int64)
    return np.clip(row, 0, H - 1), np.clip(col, 0, W - 1)


@dataclass
class IciChoice:
    """The rung chosen at every query and the pooled values.

    Attributes
    ----------
    rung : (Q,) int
        Chosen rung (0 = the pixel's own count).
    lux : (Q, C) float64
        Pooled estimate at the chosen rung (lx).
    """

    rung: np.ndarray
    lux: np.ndarray


def _weights(emitted: dict[int, int], order: list[int]) -> np.ndarray:
    w = np.array([emitted[s] for s in order], dtype=np.float64)
    return w / w.sum() if w.sum() > 0 else np.full(len(order), 1.0 / max(len(order), 1))


def _stack64(rungs: dict[int, np.ndarray], order: list[int], lum: bool = False,
             rung: int | None = None, pixels: np.ndarray | None = None) -> np.ndarray:
    """The sets' rungs in ``order`` as one float64 array (S, J+1, Q, C) — or, with
    ``lum``, their luminous values (S, J+1, Q) — filled in place: the same values as
    ``np.stack`` of float64 copies, without the copies (the wire brings float32).
    ``rung`` keeps that rung only (no J+1 axis), ``pixels`` those queries only: the same
    values as indexing the whole stack, without making it."""
    def part(r: np.ndarray) -> np.ndarray:
        if rung is not None:
            r = r[rung]
        return r if pixels is None else r[..., pixels, :]

    first = part(np.asarray(rungs[order[0]]))
    shape = first.shape[:-1] if lum else first.shape
    out = np.empty((len(order), *shape))
    for i, s in enumerate(order):
        r = part(np.asarray(rungs[s]))
        if not lum:
            out[i] = r
        elif r.shape[-1] == 1:
            out[i] = r[..., 0]
        else:
            out[i] = luminous(np.asarray(r, np.float64))
    return out


def choose(rungs: dict[int, np.ndarray], emitted: dict[int, int], q: float,
           areas: np.ndarray, gamma: float) -> IciChoice:
    """ICI over the pooled rungs.

    Parameters
    ----------
    rungs : {set: (J+1, Q, C) lx}
        Every set's rung estimates.
    emitted : {set: photons}
    q : float
        ΣΦ²/ΣΦ (lm) of the wall photons over all sets.
    areas : (J+1,) or (J+1, Q) m²
        Window areas.
    gamma : float
        Half-width of the intervals in standard errors (Γ).
    """
    order = sorted(rungs)
    w = _weights(emitted, order)
    # the weighted sum set by set: no (S, J+1, Q, C) float64 stack (105 MB at 640 × 256)
    pooled = np.zeros(np.asarray(rungs[order[0]]).shape)
    for wi, s in zip(w, order, strict=True):
        add_scaled(pooled, rungs[s], wi)
    areas = np.asarray(areas, dtype=np.float64)[:pooled.shape[0]]
    n = sum(emitted[s] for s in order)
    E = luminous(pooled.reshape(-1, pooled.shape[-1])).reshape(pooled.shape[:2])  # (J+1, Q)
    rung = ici_rungs(E, n, q, areas, gamma)
    lux = np.take_along_axis(pooled, rung[None, :, None], 0)[0]
    return IciChoice(rung, lux)


def ici_rungs(E: np.ndarray, n: float, q: float, areas: np.ndarray, gamma: float
              ) -> np.ndarray:
    """(Q,) the ICI rung of luminous rung estimates E (J+1, Q) lx from n photons."""
    J = E.shape[0] - 1
    if n > 0 and q > 0:
        base = np.maximum(np.maximum(E, E[-1][None, :]), 0.0)
        sig = np.sqrt(base * q / (n * (areas if areas.ndim == 2 else areas[:, None])))
    else:
        sig = np.zeros_like(E)
    lo, hi = E[0] - gamma * sig[0], E[0] + gamma * sig[0]
    alive = np.ones(E.shape[1], bool)
    rung = np.zeros(E.shape[1], np.int64)
    for j in range(1, J + 1):
        lo = np.maximum(lo, E[j] - gamma * sig[j])
        hi = np.minimum(hi, E[j] + gamma * sig[j])
        alive &= lo <= hi
        rung[alive] = j
    return rung


def held_out_blur(rungs: dict[int, np.ndarray], emitted: dict[int, int], q: float,
                  areas: np.ndarray, gamma: float, groups: list[np.ndarray] | None = None,
                  queries: np.ndarray | None = None) -> np.ndarray:
    """(G, Q) lx²: per query an unbiased estimate of the squared blur of an ICI choice,
    from the pairs of sets within each of the G ``groups`` (positions in set order;
    default one group of all sets). ``queries`` (indices): only those are computed (every
    query stands alone), the others are 0 — the figure reads only the lit ones.

    The blur of the chosen rung is measured against rung 0 by D = E_j − E_0, but the
    rung is chosen from the same photons: ICI keeps the large rung exactly where D came
    out small, so D̄² − se_D² at the chosen rungs reads low (on a synthetic step,
    0.82 × the actual error). Here every pair of sets (s, t) is left out of the choice:
    with j the ICI rung of the other S − 2 sets, E[D_s D_t] = b(j)², the squared blur of
    a choice made from (S − 2)/S of the photons (a little larger than the full choice's).
    The mean over each group's pairs is returned.
    """
    order = sorted(rungs)
    S = len(order)
    areas = np.asarray(areas, dtype=np.float64)[:np.asarray(rungs[order[0]]).shape[0]]
    if queries is not None:
        full = np.zeros((1 if groups is None else len(groups),
                         np.asarray(rungs[order[0]]).shape[1]))
        queries = np.asarray(queries, np.int64)
        if len(queries):
            full[:, queries] = held_out_blur(
                {k: np.asarray(rungs[k])[:, queries] for k in order}, emitted, q,
                areas[:, queries] if areas.ndim == 2 else areas, gamma, groups)
        return full
    R = _stack64(rungs, order, lum=True)  # (S, J+1, Q) lx
    e = np.array([emitted[k] for k in order], dtype=np.float64)
    n_all = float(e.sum())
    groups = [np.arange(S)] if groups is None else groups
    out = np.zeros((len(groups), R.shape[2]))
    if R.shape[2] == 0:
        return out
    members = np.full((len(groups), max((len(m) for m in groups), default=0)), -1, np.int64)
    for g, m in enumerate(groups):
        members[g, :len(m)] = m
    A = np.broadcast_to(areas if areas.ndim == 2 else areas[:, None], R.shape[1:])
    _held_out_pairs(R, e, n_all, float(q), A, float(gamma), members, out)
    return out


_HELD_OUT_BLOCK = 64  # queries a pass of the pair loop holds (its arrays stay in L1)


@njit(cache=True, nogil=True)
def _held_out_pairs(R: np.ndarray, e: np.ndarray, n_all: float, q: float,
                    areas: np.ndarray, gamma: float, members: np.ndarray,
                    out: np.ndarray) -> None:
    """:func:`held_out_blur`'s pairs, a block of queries at a time: the emitted-weighted
    total Σ_s e_s R_s (summed in set order: the same on any machine, where a BLAS
    ``tensordot`` sums in an order that depends on its thread count), then for every
    pair (a, b) of a group the ICI rung j of the other sets' pooled ladder
    (``(total − e_a R_a − e_b R_b) / n``, :func:`ici_rungs`' intervals) and the product
    of the pair's blurs (R_a,j − R_a,0)(R_b,j − R_b,0), summed over the pairs in their
    order and divided by their number: the NumPy form's operations in its order (no
    contraction into fused multiply-adds), so the same numbers for finite rungs; no
    (J+1, Q) temporaries per pair (its largest cost: 56 pairs on 16 sets). The inner
    loops run over a block's queries, which the compiler vectorises (2.5× the
    query-by-query loop). Serial: it runs beside the fused map's branch
    (:func:`written_map`), whose kernels have the other core."""
    S, J1, Q = R.shape
    G, M = members.shape
    B = _HELD_OUT_BLOCK
    weighted = n_all > 0
    total = np.empty((J1, B))
    E = np.empty((J1, B))
    lo = np.empty(B)
    hi = np.empty(B)
    rung = np.empty(B, np.int64)
    alive = np.empty(B, np.bool_)
    acc = np.empty(B)
    for c0 in range(0, Q, B):
        nb = min(B, Q - c0)
        for j in range(J1):
            for p in range(nb):
                total[j, p] = 0.0
            for s in range(S):
                w = e[s]
                for p in range(nb):
                    total[j, p] += w * R[s, j, c0 + p] if weighted else R[s, j, c0 + p]
        for g in range(G):
            for p in range(nb):
                acc[p] = 0.0
            pairs = 0
            for i in range(M):
                a = members[g, i]
                if a < 0:
                    break
                for k in range(i + 1, M):
                    b = members[g, k]
                    if b < 0:
                        break
                    n = n_all - e[a] - e[b]
                    if n <= 0:
                        continue
                    ea, eb = e[a], e[b]
                    for j in range(J1):
                        for p in range(nb):
                            E[j, p] = (total[j, p] - ea * R[a, j, c0 + p]
                                       - eb * R[b, j, c0 + p]) / n
                    # ici_rungs at these queries: σ_j from max(E_j, E_J, 0), the
                    # intervals' running intersection, the last rung still alive
                    for j in range(J1):
                        for p in range(nb):
                            sig = 0.0
                            if q > 0:
                                x, last = E[j, p], E[J1 - 1, p]
                                base = x if x >= last else last
                                base = base if base >= 0.0 else 0.0
                                sig = np.sqrt(base * q / (n * areas[j, c0 + p]))
                            lj, hj = E[j, p] - gamma * sig, E[j, p] + gamma * sig
                            if j == 0:
                                lo[p], hi[p], alive[p], rung[p] = lj, hj, True, 0
                            else:
                                lj = lo[p] if lo[p] >= lj else lj
                                hj = hi[p] if hi[p] <= hj else hj
                                lo[p], hi[p] = lj, hj
                                ok = alive[p] and lj <= hj
                                alive[p] = ok
                                rung[p] = j if ok else rung[p]
                    for p in range(nb):
                        r, c = rung[p], c0 + p
                        acc[p] += (R[a, r, c] - R[a, 0, c]) * (R[b, r, c] - R[b, 0, c])
                    pairs += 1
            for p in range(nb):
                out[g, c0 + p] = acc[p] / max(pairs, 1)


def chosen_per_set(rungs: dict[int, np.ndarray], rung: np.ndarray) -> np.ndarray:
    """(S, Q, C) every set's value at the chosen rungs (set order), float64."""
    order = sorted(rungs)
    first = np.asarray(rungs[order[0]])
    out = np.empty((len(order), *first.shape[1:]))
    rung = np.ascontiguousarray(rung, dtype=np.int64)
    for i, s in enumerate(order):
        _take_rung(np.asarray(rungs[s]), rung, out[i])
    return out


@njit(cache=True, nogil=True)
def _take_rung(r: np.ndarray, rung: np.ndarray, out: np.ndarray) -> None:
    """out[q, k] = r[rung[q], q, k] as float64 (``take_along_axis`` and ``astype`` in one
    pass)."""
    for q in range(rung.shape[0]):
        j = rung[q]
        for k in range(out.shape[1]):
            out[q, k] = np.float64(r[j, q, k])


def add_scaled(acc: np.ndarray, x: np.ndarray, w: float) -> np.ndarray:
    """``acc += w · float64(x)`` in place, in one pass (NumPy's ``acc += w * x`` makes a
    float64 copy of x and the product first: two temporaries as large as the rungs): the
    same product and sum per element, so the same numbers. Returns ``acc``."""
    x = np.asarray(x)
    if x.shape != acc.shape:
        x = np.broadcast_to(x, acc.shape)
    if not (acc.flags.c_contiguous and x.flags.c_contiguous):
        acc += w * np.asarray(x, np.float64)
        return acc
    _add_scaled(acc.reshape(-1), x.reshape(-1), float(w))
    return acc


@njit(cache=True, nogil=True)
def _add_scaled(acc: np.ndarray, x: np.ndarray, w: float) -> None:
    for i in range(acc.shape[0]):
        acc[i] += w * np.float64(x[i])


CERTIFY = 0.25  # largest standard error of the blur estimate, × the squared error it certifies
#: a region's blur standard error is the batch-means one over square tiles of this many
#: pixels a side (twice the largest window's: queries a window apart share no photons)
TILE = 8
#: ... from this many tiles on (fewer: the Gaussian formula; a spread from a handful of
#: tiles is itself too noisy)
TILES_MIN = 16


@dataclass(frozen=True)
class ErrorFigure:
    """The error figure of a map at given rungs, with the precision of its blur part.

    All in units of the mean lit illuminance (dimensionless; squares where named so).

    Attributes
    ----------
    error : ErrorEstimate
        noise, blur and their sum as :class:`~lightsim.render.frame.ErrorEstimate`.
    bias2 : float
        Unbiased estimate of the mean squared blur (may be negative: noise).
    bias2_se : float
        Its standard error from the sets' scatter (the pixels are the whole region, not a
        sample of it: only the noise of the estimate counts).
    lit : int
        Pixels (or probes) averaged.
    """

    error: ErrorEstimate
    bias2: float
    bias2_se: float
    lit: int

    @property
    def certified(self) -> bool:
        """Whether the blur estimate is precise enough to sign the figure: its standard
        error is at most :data:`CERTIFY` × the squared error it reports (the figure then
        scatters by about half that, ±12 %)."""
        return self.bias2_se <= CERTIFY * self.error.total**2


def error_figure(rungs: dict[int, np.ndarray], choice: IciChoice, lit_fraction: float = 0.1,
                 alpha: float = 0.0, blur: np.ndarray | None = None) -> ErrorFigure | None:
    """Noise and blur of the map ``choice`` over the lit queries (pixels or probes), mixed
    with weight ``alpha`` with the pixel counts (rung 0): (1 − α) chosen + α rung 0.
    ``blur`` (2, Q) lx²: per-query squared-blur estimates of the unmixed map from each half
    of the sets, to use instead of D̄² − se_D² (:func:`held_out_blur` over the halves, for
    a choice made from these photons).

    Noise: the spread of the S sets' values at the chosen rungs, se² = s²/S per query.
    Blur: per set D = chosen − rung 0 (rung 0, the pixel window, is unbiased for the pixel
    mean), so E[D̄² − se_D²] = b² at each query and their mean over the lit queries is an
    unbiased estimate of the mean squared bias (0 where rung 0 was chosen). Its variance
    is Σ (2 v² + 4 b² v) / n² with v = Var(D̄) (estimated by se_D², v² by
    se_D⁴ (S − 1)/(S + 1), b² by the mean): for a window of A pixels v ≈ σ₀² (1 − 1/A),
    the noise of the pixel's own count, which bounds how well any blur can be measured
    (:attr:`ErrorFigure.certified`).

    Lit: rung 0's mean and the map ≥ ``lit_fraction`` × the map's maximum; relative to
    rung 0's mean over the lit queries, which is unbiased for the exact mean there (the
    map's own mean is blurred). None with one set or nothing lit.
    """
    mix = _mix_parts(rungs, choice, lit_fraction, blur)
    return None if mix is None else mix.figure(alpha)


@dataclass(frozen=True)
class _MixParts:
    """The parts of :func:`error_figure` that depend on the counts' weight α only through
    (1 − α)² (blur and its standard error) or a quadratic (noise): means over the lit
    queries of the chosen values' variance ``a``, the counts' ``b`` and their covariance
    ``c`` (each /S, relative²), the blur² ``b2`` and its standard error ``se`` at α = 0."""

    a: float
    b: float
    c: float
    b2: float
    se: float
    lit: int

    def figure(self, alpha: float) -> ErrorFigure | None:
        k = (1.0 - alpha) ** 2
        n2 = k * self.a + 2.0 * alpha * (1.0 - alpha) * self.c + alpha * alpha * self.b
        noise = math.sqrt(max(n2, 0.0))
        b2, se = k * self.b2, k * self.se
        if not all(math.isfinite(x) for x in (noise, b2, se)):
            return None
        bias = math.sqrt(max(b2, 0.0))
        upper = math.sqrt(max(b2 + 2.0 * se, 0.0))
        return ErrorFigure(ErrorEstimate(math.hypot(noise, bias), noise, bias, upper), b2, se,
                           self.lit)


def _halves(S: int) -> list[np.ndarray]:
    """Two halves of the sets (positions in set order): even and odd."""
    return [np.arange(0, S, 2), np.arange(1, S, 2)]


def _rows(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[idx]`` — as a strided view where ``idx`` is an increasing arithmetic run (the
    halves): the same values in the same order without copying (S/2, Q) rows, whose
    fresh pages cost more than the reductions that read them on this VM."""
    idx = np.asarray(idx)
    if idx.ndim == 1 and len(idx) >= 1:
        step = int(idx[1] - idx[0]) if len(idx) > 1 else 1
        if step > 0 and np.array_equal(idx, np.arange(idx[0], idx[-1] + 1, step)):
            return a[int(idx[0]):int(idx[-1]) + 1:step]
    return a[idx]


def _mix_parts(rungs: dict[int, np.ndarray], choice: IciChoice, lit_fraction: float,
               blur: np.ndarray | None, lits: tuple | None = None,
               tiles: np.ndarray | None = None) -> _MixParts | None:
    """The figure's parts, each half of the sets measured over the pixels the other half
    calls lit (``blur``: (2, Q) from :func:`held_out_blur` over :func:`_halves`, or None).

    Lit — the pixel's own count and the map both ≥ ``lit_fraction`` × the map's maximum —
    is decided by data the half does not use: decided and measured on the same photons,
    dim pixels that caught a stray photon come in exactly when they scatter most (on the
    paraboloid 36 such pixels tripled the noise figure).

    ``tiles`` (Q,) int: every query's tile (:func:`tile_labels`); the blur's standard
    error is then the batch-means one over them (:func:`_half_parts`), for a region's
    figure.
    """
    lits = lits if lits is not None else _lit_masks(rungs, choice, lit_fraction)
    if lits is None:
        return None
    vals, win, halves, masks = lits
    S = vals.shape[0]
    parts = []
    for h, (own, lit) in enumerate(zip(halves, masks, strict=True)):
        p = _half_parts(_rows(vals, own)[:, lit], _rows(win, own)[:, lit], S,
                        None if blur is None else np.asarray(blur)[h][lit],
                        None if tiles is None else tiles[lit])
        if p is not None:
            parts.append(p)
    if not parts:
        return None
    k = len(parts)
    return _MixParts(*(sum(getattr(p, f) for p in parts) / k for f in ("a", "b", "c", "b2")),
                     math.sqrt(sum(p.se**2 for p in parts)) / k,
                     round(sum(p.lit for p in parts) / k))


def _lit_masks(rungs: dict[int, np.ndarray], choice: IciChoice, lit_fraction: float,
               vals: np.ndarray | None = None, win: np.ndarray | None = None):
    """(vals (S, Q), counts (S, Q), halves, lit mask of each half) for :func:`_mix_parts`:
    half h is measured over the queries the *other* half calls lit; None with fewer than
    two sets or nothing lit. ``vals``: every set's luminous value of the map (S, Q), if
    not each set's value at ``choice.rung``; ``win``: their rung 0 (S, Q), if known.
    (A region within the lit queries is applied to these masks by :func:`_in_region`.)"""
    if len(rungs) < 2:
        return None
    if vals is None:
        vals = luminous(chosen_per_set(rungs, choice.rung))  # (S, Q)
    if win is None:  # every set's luminous pixel count (rung 0), (S, Q)
        win = luminous(np.stack([np.asarray(rungs[s][0], np.float64) for s in sorted(rungs)]))
    S = vals.shape[0]
    if vals.shape[1] == 0 or not np.any(vals.mean(axis=0) > 0):
        return None
    halves = _halves(S) if S >= 4 else [np.arange(S)]
    thr = lit_fraction * vals.mean(axis=0).max()
    masks = []
    for h, own in enumerate(halves):
        other = halves[1 - h] if len(halves) == 2 else own
        masks.append((_rows(win, other).mean(axis=0) >= thr)
                     & (_rows(vals, other).mean(axis=0) >= thr))
    return vals, win, halves, masks


def _half_parts(v_l: np.ndarray, w_l: np.ndarray, S: int, blur: np.ndarray | None,
                tiles: np.ndarray | None = None) -> _MixParts | None:
    """Parts from some of the sets (rows) over the lit queries (columns) for the pooled
    map of all S sets.

    The blur's standard error is √(Σ (2 v² + 4 b² v)) / n, the spread of D̄² − se_D² for
    Gaussian D̄. With ``tiles`` ((n,) int, the queries' tiles, at least :data:`TILES_MIN`
    of them) it is the batch-means standard error of the n per-query terms t instead,

        se² = K/(K − 1) Σ_k (Σ_{q in tile k} (t_q − t̄))² / n²   (K tiles),

    which assumes no distribution and takes in the correlation of neighbouring queries
    (their windows share photons, a QMC set's counts are stratified). Measured over the
    interior of the peer bench's two scenes (20 seeds each, 0.39–0.8 M photons): the
    formula read 1.05–1.8 × the seed-to-seed spread of the blur estimate, the batch-means
    error 0.91–1.33 ×; with counts correlated over 3 × 3 pixels the formula reads about
    half the spread (tests/test_error_region.py). A blur that varies over the region only
    adds to it (conservative)."""
    s_h, n = v_l.shape
    if n == 0 or s_h < 2:
        return None
    mean_lit = float(w_l.mean())
    if not mean_lit > 0:
        return None
    dv, dw = v_l - v_l.mean(axis=0), w_l - w_l.mean(axis=0)
    norm = (s_h - 1) * S * n * mean_lit**2  # sample (co)variance / S, mean over lit, relative
    a, b, c = (float(np.sum(x * y)) / norm for x, y in ((dv, dv), (dw, dw), (dv, dw)))
    d = v_l - w_l
    d_mean, v = d.mean(axis=0), d.var(axis=0, ddof=1) / s_h  # v: Var(D̄) of these sets
    terms = d_mean**2 - v if blur is None else np.asarray(blur, np.float64)
    b2 = float(np.mean(terms)) / mean_lit**2
    # Σ 4 b² v with the mean b² (one query's b² estimate is mostly noise, and its positive
    # part would double the variance at a few photons per pixel)
    var = float(np.sum(2.0 * v * v * (s_h - 1) / (s_h + 1))
                + 4.0 * max(b2, 0.0) * mean_lit**2 * np.sum(v))
    se = math.sqrt(max(var, 0.0)) / n / mean_lit**2
    if tiles is not None:
        labels, tile = np.unique(tiles, return_inverse=True)
        K = len(labels)
        if K >= TILES_MIN:  # batch means: each tile's summed deviation from the mean
            dev = np.bincount(tile, weights=terms - float(np.mean(terms)), minlength=K)
            se = math.sqrt(float(np.sum(dev * dev)) * K / (K - 1)) / n / mean_lit**2
    if not all(math.isfinite(x) for x in (a, b, c, b2, se)):
        return None
    return _MixParts(a, b, c, b2, se, n)


def estimate_error(rungs: dict[int, np.ndarray], choice: IciChoice, lit_fraction: float = 0.1
                   ) -> ErrorEstimate | None:
    """The :class:`~lightsim.render.frame.ErrorEstimate` of :func:`error_figure`."""
    fig = error_figure(rungs, choice, lit_fraction)
    return None if fig is None else fig.error


MIX_STEPS = 40  # the weight of the pixel counts is searched in steps of 1/40
#: whether :func:`written_map` (``directional=None``) may write the fused directional map
#: of a whole raster; studies set it False to compare with the centred map
DIRECTIONAL = True
#: the fused map replaces the centred one only with a figure below this × the centred's:
#: the two figures scatter by several per cent, and a choice between near-equal figures
#: would pick the one that happens to read low (optimism), for no real gain
FUSED_MARGIN = 0.9


@dataclass
class WrittenMap:
    """The map the run writes, its error figure and its weight on the pixel counts.

    Attributes
    ----------
    choice : IciChoice
        The ICI rungs and their pooled values.
    lux : (Q, C) float64
        The written values (lx): (1 − α) ``choice.lux`` + α rung 0.
    alpha : float
        Weight α of the pixel counts (0: the ICI map, 1: the counts).
    figure : ErrorFigure or None
    fused : bool
        True for the fusion of the directional ladders, False for the centred one.
    """

    choice: IciChoice
    lux: np.ndarray
    alpha: float
    figure: ErrorFigure | None
    fused: bool = False

    @property
    def error(self) -> ErrorEstimate | None:
        return None if self.figure is None else self.figure.error


def written_map(rungs: dict[int, np.ndarray], emitted: dict[int, int], q: float,
                areas: np.ndarray, gamma: float, lit_fraction: float = 0.1,
                shape: tuple[int, int] | None = None, directional: bool | None = None,
                restrict: Restrict | None = None) -> WrittenMap:
    """The ICI map mixed with the pixel counts: the lowest error that can be signed.

    A window's blur is measured against the pixel's own count, whose noise σ₀ does not
    fall with the window: the blur estimate's standard error is ≈ √2 σ₀² / √n over n lit
    pixels whatever the map, so a map whose error is below ≈ (2/n)^¼ σ₀ carries an error
    its figure cannot state (issue 12: the ICI figure read 0.65–1.05 × the actual error on
    the shield at 250 k photons, from seed to seed). Mixing in the counts with weight α
    scales the blur and its standard error by (1 − α)² and trades it for count noise, so
    the written map is (1 − α) ICI + α counts with α (in steps of 1/:data:`MIX_STEPS`)
    the lowest figure among those that are :attr:`ErrorFigure.certified`. α = 0 where the
    ICI map is both best and measurable; α → 1 where ICI keeps a blur that no single pixel
    can see but the figure, over all lit pixels, does (the curvature of a smooth beam
    inside a 4 × 4 window: the counts are then better); α = 1, the counts, is always
    certified. One number chosen from n pixels' figures adds little optimism; the blur
    part is :func:`held_out_blur`, free of the per-pixel choice's.

    When the queries are the whole wall raster in row order (``shape`` = (H, W), or
    recognised from ``areas`` by :func:`raster_shape`), a second map is made: the fusion
    of the centred ladder with eight directional ones (:mod:`lightsim.render.directional`),
    whose windows next to an edge reach inwards instead of falling back to the pixel,
    with a figure of its own (cross-fitted, honest like this one). ``directional``: None
    (default, :data:`DIRECTIONAL`) writes the fused map where its certified figure is
    below :data:`FUSED_MARGIN` × the centred map's — where the pattern is smooth enough
    for its wider support (the paraboloid: 0.75–0.8 ×) — and the centred one elsewhere
    (the headlight at 320 × 128: 0.96–1.0 ×, where the fused map's true error is the
    higher); True the fused map, False the centred map alone.

    ``rungs`` {set: (J+1, Q, C)} already cut to the ladder allowed at these photons
    (:func:`shrink_sides`); ``restrict``: the queries the figure covers within the lit
    ones (:func:`lightsim.render.region.restriction`; None: every lit query): the map is
    chosen on the lit queries and only its figure is measured over the region
    (:func:`_in_region`); the other parameters as in :func:`choose`.
    """
    if directional is None and not DIRECTIONAL:
        directional = False
    if directional is not False and shape is None:
        shape = raster_shape(areas)
    choice = choose(rungs, emitted, q, areas, gamma)
    fused = win = fm = None  # win: every set's luminous rung 0, once made
    pending = None
    if directional is not False and shape is not None and \
            np.asarray(rungs[next(iter(rungs))]).shape[0] >= 2:
        from lightsim.render.directional import fused_map

        win = _stack64(rungs, sorted(rungs), lum=True, rung=0)  # (S, Q)

        def fused_branch() -> tuple[Any, WrittenMap]:
            fmap = fused_map(rungs, emitted, q, areas, gamma, shape, lit_fraction,
                             guide=choice, win=win)
            wm = _mixed(rungs, emitted, fmap.choice, fmap.vals, None, fmap.lits,
                        lit_fraction)
            wm.fused = True
            return fmap, wm

        if directional:
            fm, fused = fused_branch()
            return _in_region(fused, rungs, None, fm.lits, restrict, lit_fraction, shape)
        # the fused map and the centred map's figure share nothing but the choice and
        # every set's rung 0: one on a second thread while the other runs here (their
        # NumPy passes and compiled kernels run without the GIL; the same values either
        # way)
        pending = helper_thread().submit(fused_branch)
    try:
        centred, blur, lits = _centred(rungs, emitted, q, areas, gamma, choice,
                                       lit_fraction, win)
    finally:
        if pending is not None:
            fm, fused = pending.result()
    if fused is not None and fused.figure is not None and (
            centred.figure is None
            or fused.figure.error.total < FUSED_MARGIN * centred.figure.error.total):
        return _in_region(fused, rungs, None, fm.lits, restrict, lit_fraction, shape)
    if restrict is not None and shape is None:
        shape = raster_shape(areas)
    return _in_region(centred, rungs, blur, lits, restrict, lit_fraction, shape)


def _centred(rungs: dict[int, np.ndarray], emitted: dict[int, int], q: float,
             areas: np.ndarray, gamma: float, choice: IciChoice, lit_fraction: float,
             win: np.ndarray | None) -> tuple[WrittenMap, np.ndarray | None, Any]:
    """The centred map of ``choice`` with its figure: (map, held-out blur, lit masks)."""
    blur = None
    lits = _lit_masks(rungs, choice, lit_fraction, win=win)
    if len(rungs) >= 4:  # the blur of the queries the figure reads (lit for either half)
        read = lit_queries(lits)
        blur = held_out_blur(rungs, emitted, q, areas, gamma, _halves(len(rungs)),
                             queries=read)
    return _mixed(rungs, emitted, choice, None, blur, lits, lit_fraction), blur, lits


def _in_region(wm: WrittenMap, rungs: dict[int, np.ndarray], blur: np.ndarray | None,
               lits, restrict: Restrict | None, lit_fraction: float,
               shape: tuple[int, int] | None = None) -> WrittenMap:
    """``wm`` with its figure measured over the region ``restrict`` keeps of the lit
    queries (unchanged without one).

    The map itself — its counts' weight α and the centred/fused choice — stays the one
    chosen on the lit queries: chosen on a smaller region, the lowest *certified* figure
    is more often the counts' (a blur estimate from fewer queries is certified only at a
    larger error), which on the paraboloid made the interior 1.75 × worse at the same
    photons. The region's figure of that fixed map need not be certified; its upper bound
    (blur + 2 s.e.) is what the stopping rule checks, so on a raster (``shape`` (H, W))
    the blur's standard error is the batch-means one over :data:`TILE`-pixel tiles
    (:func:`_half_parts`), which measures what the Gaussian per-pixel formula assumes
    (it overstated the spread over the bench's interiors by up to 1.8 × and understates
    it where neighbouring counts are correlated)."""
    if restrict is None or lits is None:
        return wm
    vals, win, halves, masks = lits
    tiles = None if shape is None else tile_labels(shape)
    mix = _mix_parts(rungs, wm.choice, lit_fraction, blur,
                     (vals, win, halves, [restrict(m) for m in masks]), tiles)
    return replace(wm, figure=None if mix is None else mix.figure(wm.alpha))


def tile_labels(shape: tuple[int, int], tile: int = TILE) -> np.ndarray:
    """(H·W,) int: the tile of every pixel of an H × W raster in row order, tiles of
    ``tile`` × ``tile`` pixels from the top-left corner (the last row and column of tiles
    may be cut)."""
    H, W = shape
    rows, cols = np.divmod(np.arange(H * W, dtype=np.int64), W)
    return (rows // tile) * (-(-W // tile)) + cols // tile


def lit_queries(lits) -> np.ndarray:
    """Indices of the queries either half's figure reads (see :func:`_lit_masks`)."""
    return (np.flatnonzero(lits[3][0] | lits[3][1]) if lits is not None
            else np.zeros(0, np.int64))


def _mixed(rungs: dict[int, np.ndarray], emitted: dict[int, int], choice: IciChoice,
           vals: np.ndarray | None, blur: np.ndarray | None, lits, lit_fraction: float
           ) -> WrittenMap:
    """The written map of a choice: the counts' weight α with the lowest certified figure
    (``vals``: every set's luminous map values if not at ``choice.rung``)."""
    order = sorted(rungs)
    w = _weights(emitted, order)
    counts = np.zeros_like(choice.lux)
    for wi, s in zip(w, order, strict=True):
        add_scaled(counts, np.asarray(rungs[s])[0], wi)
    mix = None if lits is None else _mix_parts(rungs, choice, lit_fraction, blur, lits)
    fig, alpha = None, 0.0
    if mix is not None:
        figs = [(mix.figure(k / MIX_STEPS), k / MIX_STEPS) for k in range(MIX_STEPS + 1)]
        ok = [(f.error.total, a, f) for f, a in figs if f is not None and f.certified]
        if ok:
            _, alpha, fig = min(ok, key=lambda t: (t[0], t[1]))
    return WrittenMap(choice, (1.0 - alpha) * choice.lux + alpha * counts, alpha, fig)


def raster_shape(areas: np.ndarray) -> tuple[int, int] | None:
    """(H, W) when window areas (J+1, Q) m² are those of every pixel of an H × W wall in
    row order (:func:`window_cells` × a quarter pixel, checked exactly), else None.

    The side-2 window is clipped to 9 of its 16 half-pixel cells at the wall's four
    corners only, which fixes W; the check against :func:`window_cells` then rules out any
    other query set.
    """
    areas = np.asarray(areas, dtype=np.float64)
    if areas.ndim != 2 or areas.shape[0] < 2 or areas.shape[1] < 4:
        return None
    a0 = areas[0]
    if not (a0[0] > 0 and np.all(a0 == a0[0])):
        return None
    corner = np.flatnonzero(np.isclose(areas[1] / a0[0], 2.25, rtol=1e-9, atol=0))
    if len(corner) != 4:
        return None
    W = int(corner[1]) + 1
    Q = areas.shape[1]
    if W < 2 or Q % W or Q // W < 2:
        return None
    H = Q // W
    rows, cols = np.divmod(np.arange(Q), W)
    sides = np.arange(1, areas.shape[0] + 1)
    cells = window_cells(H, W, rows, cols, sides) * (0.25 * a0[0])
    return (H, W) if np.allclose(cells, areas, rtol=1e-9, atol=0) else None
