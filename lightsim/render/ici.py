"""The written map's radius rule: intersection of confidence intervals over a radius ladder.

A density estimate at a pixel trades blur for noise through its radius. kNN picks the
radius from the photon density alone (r_k), so next to a cut-off or a beam edge it reaches
across the step, and with the radius held between fixed bounds its error stops falling
(2.2–2.9 % from 2 M to 16 M photons on the paraboloid while binning fell as 1/√N). Here
every pixel has a ladder of nested estimates from the same photons

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

This module holds the primitives: the ladder (:func:`rung_sides`, :func:`shrink_sides`),
the windows (:class:`WindowGeometry`, :func:`window_sums`, :func:`raster_lux`,
:func:`window_cells`, :func:`raster_shape`), the ICI choice (:func:`choose`,
:func:`ici_rungs`, :class:`IciChoice`), the held-out blur (:func:`held_out_blur`) and the
per-set functions the maps share (:func:`stack_sets`, :func:`set_weights`, :func:`halves`,
:func:`chosen_per_set`, :func:`add_scaled`). The map the run writes and its error figure
are :mod:`lightsim.render.written_map`'s; the directional windows are
:mod:`lightsim.render.directional`'s.

===============  =====  ========  ========================================================
parameter        unit   default   meaning
===============  =====  ========  ========================================================
``r_max``        m      4 r_pix   the largest window has at most this disk's area
                                  (``RunConfig.max_radius``; auto: 4 × the radius of the
                                  disk with one pixel's area → 4 × 4 pixels)
``gamma``        –      2.0       interval half-width Γ in standard errors
                                  (``RunConfig.ici_gamma``)
``q``            lm     –         power-weighted mean photon power ΣΦ²/ΣΦ (all sets)
``MAX_RUNGS``    px     8         window sides 1 … this at most
``SHRINK_START`` –      256       photons per pixel (all sets) where the largest window
                                  starts to shrink (:func:`shrink_sides`)
===============  =====  ========  ========================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from lightsim.render.frame import luminous

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
    2.1 against 6.1 ms a set at 640 × 256 for two passes. Serial: ``prange`` (thread
    start-up per call, 16 calls per map) is slower.

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


def set_weights(emitted: dict[int, int], order: list[int]) -> np.ndarray:
    """The sets' weights in ``order``: their emitted photons over the total (equal weights
    while no set has emitted)."""
    w = np.array([emitted[s] for s in order], dtype=np.float64)
    return w / w.sum() if w.sum() > 0 else np.full(len(order), 1.0 / max(len(order), 1))


def stack_sets(rungs: dict[int, np.ndarray], order: list[int], lum: bool = False,
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
    w = set_weights(emitted, order)
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
    R = stack_sets(rungs, order, lum=True)  # (S, J+1, Q) lx
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
    (:func:`lightsim.render.written_map.written_map`), whose kernels have the other
    core."""
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


def halves(S: int) -> list[np.ndarray]:
    """Two halves of the sets (positions in set order): even and odd."""
    return [np.arange(0, S, 2), np.arange(1, S, 2)]


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
