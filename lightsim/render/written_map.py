"""The written map: the final estimate on the wall and its error figure.

The run writes one lux map of the wall, made on the server from every interleave set's
ICI rungs (:mod:`lightsim.render.ici`: rung 0 the pixel's own photons, then centred
squares 2, 3, … pixels a side). At every pixel ICI picks the largest rung that the
smaller ones do not contradict; the map is that choice mixed with the pixel counts
(weight α, :func:`written_map`), and on the whole wall raster the fusion with eight
directional ladders (:mod:`lightsim.render.directional`) is written instead where its
own figure is clearly the lower. Its error figure is measured from the sets themselves:

- noise: the spread of the S sets' values at the chosen rungs;
- blur: per set D = chosen − rung 0 (rung 0, the pixel's count, is unbiased for the
  pixel mean), held out from the choice (:func:`~lightsim.render.ici.held_out_blur`, or
  cross-fitted for the fused map), so D̄² − se_D² is unbiased for the squared blur;
- both over the lit pixels, each half of the sets over the pixels the other half calls
  lit, and over the region ``--error-region`` keeps of them
  (:func:`lightsim.render.region.restriction`).

:class:`MapEstimator` is what the run loop (:class:`~lightsim.engine.server.Session`)
calls: given every set's rungs, the sets' wall-photon moments and the wall, it returns
the map (:meth:`MapEstimator.image`) or, between images, the same figure from the rungs
at the grid probes (:meth:`MapEstimator.error_at_probes`). :class:`MapInputs` is what a
map is made from (kept for studies that remake it: :attr:`MapEstimator.keep_inputs`).

================  =====  ========  =======================================================
parameter         unit   default   meaning
================  =====  ========  =======================================================
``gamma``         –      2.0       ICI interval half-width Γ in standard errors
                                   (``RunConfig.ici_gamma``)
``lit_fraction``  –      0.1       lit: rung 0's mean and the map ≥ this × the map's
                                   maximum
``CERTIFY``       –      0.25      the blur estimate's standard error may be at most this
                                   × the squared error the figure reports
``MIX_STEPS``     –      40        steps of the counts' weight α in the written map
``FUSED_MARGIN``  –      0.9       the fused map is written below this × the centred
                                   map's figure
``DIRECTIONAL``   –      True      the fused map may be written at all (studies: False)
``TILE``          px     8         a region's blur standard error: batch means over tiles
                                   of this side (``TILES_MIN`` = 16 tiles at least)
================  =====  ========  =======================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from lightsim.render.directional import fused_map
from lightsim.render.frame import ErrorEstimate, luminous
from lightsim.render.ici import (
    IciChoice,
    add_scaled,
    choose,
    chosen_per_set,
    halves,
    held_out_blur,
    pixel_of,
    power_moment,
    raster_shape,
    set_weights,
    shrink_sides,
    stack_sets,
    wall_photons,
    window_cells,
)
from lightsim.render.region import Restrict, restriction
from lightsim.threads import second_thread
from lightsim.wall import WallFrame

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
    of the sets, to use instead of D̄² − se_D² (:func:`~lightsim.render.ici.held_out_blur`
    over the halves, for
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
        return ErrorFigure(ErrorEstimate(math.hypot(noise, bias), noise, bias, upper, b2, se),
                           b2, se, self.lit)


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
    calls lit (``blur``: (2, Q) from :func:`~lightsim.render.ici.held_out_blur` over
    :func:`~lightsim.render.ici.halves`, or None).

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
    vals, win, groups, masks = lits
    S = vals.shape[0]
    parts = []
    for h, (own, lit) in enumerate(zip(groups, masks, strict=True)):
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
    groups = halves(S) if S >= 4 else [np.arange(S)]
    thr = lit_fraction * vals.mean(axis=0).max()
    masks = []
    for h, own in enumerate(groups):
        other = groups[1 - h] if len(groups) == 2 else own
        masks.append((_rows(win, other).mean(axis=0) >= thr)
                     & (_rows(vals, other).mean(axis=0) >= thr))
    return vals, win, groups, masks


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
    half the spread (tests/render/test_region.py). A blur that varies over the region only
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
    its figure cannot state (the ICI figure read 0.65–1.05 × the actual error on the
    shield at 250 k photons, from seed to seed). Mixing in the counts with weight α
    scales the blur and its standard error by (1 − α)² and trades it for count noise, so
    the written map is (1 − α) ICI + α counts with α (in steps of 1/:data:`MIX_STEPS`)
    the lowest figure among those that are :attr:`ErrorFigure.certified`. α = 0 where the
    ICI map is both best and measurable; α → 1 where ICI keeps a blur that no single pixel
    can see but the figure, over all lit pixels, does (the curvature of a smooth beam
    inside a 4 × 4 window: the counts are then better); α = 1, the counts, is always
    certified. One number chosen from n pixels' figures adds little optimism; the blur
    part is :func:`~lightsim.render.ici.held_out_blur`, free of the per-pixel choice's.

    When the queries are the whole wall raster in row order (``shape`` = (H, W), or
    recognised from ``areas`` by :func:`~lightsim.render.ici.raster_shape`), a second map
    is made: the fusion of the centred ladder with eight directional ones
    (:mod:`lightsim.render.directional`), whose windows next to an edge reach inwards
    instead of falling back to the pixel, with a figure of its own (cross-fitted, honest
    like this one). ``directional``: None (default, :data:`DIRECTIONAL`) writes the fused
    map where its certified figure is below :data:`FUSED_MARGIN` × the centred map's —
    where the pattern is smooth enough for its wider support (the paraboloid:
    0.75–0.8 ×) — and the centred one elsewhere (the headlight at 320 × 128: 0.96–1.0 ×,
    where the fused map's true error is the higher); True the fused map, False the
    centred map alone.

    ``rungs`` {set: (J+1, Q, C)} already cut to the ladder allowed at these photons
    (:func:`~lightsim.render.ici.shrink_sides`); ``restrict``: the queries the figure
    covers within the lit ones (:func:`lightsim.render.region.restriction`; None: every
    lit query): the map is chosen on the lit queries and only its figure is measured over
    the region (:func:`_in_region`); the other parameters as in
    :func:`~lightsim.render.ici.choose`.
    """
    if directional is None and not DIRECTIONAL:
        directional = False
    if directional is not False and shape is None:
        shape = raster_shape(areas)
    choice = choose(rungs, emitted, q, areas, gamma)
    fused = win = fused_lits = None  # win: every set's luminous rung 0, once made
    pending = None
    if directional is not False and shape is not None and \
            np.asarray(rungs[next(iter(rungs))]).shape[0] >= 2:
        win = stack_sets(rungs, sorted(rungs), lum=True, rung=0)  # (S, Q)

        def fused_branch() -> tuple[Any, WrittenMap]:
            fmap = fused_map(rungs, emitted, q, areas, gamma, shape, lit_fraction,
                             guide=choice, win=win)
            # every set's luminous rung 0 is win: the lit masks need not convert it again
            lits = _lit_masks(rungs, fmap.choice, lit_fraction, fmap.vals, win)
            wm = _mixed(rungs, emitted, fmap.choice, fmap.vals, None, lits, lit_fraction)
            wm.fused = True
            return lits, wm

        if directional:
            fused_lits, fused = fused_branch()
            return _in_region(fused, rungs, None, fused_lits, restrict, lit_fraction, shape)
        # the fused map and the centred map's figure share nothing but the choice and
        # every set's rung 0: one on a second thread while the other runs here (their
        # NumPy passes and compiled kernels run without the GIL; the same values either
        # way)
        pending = second_thread().submit(fused_branch)
    try:
        centred, blur, lits = _centred(rungs, emitted, q, areas, gamma, choice,
                                       lit_fraction, win)
    finally:
        if pending is not None:
            fused_lits, fused = pending.result()
    if fused is not None and fused.figure is not None and (
            centred.figure is None
            or fused.figure.error.total < FUSED_MARGIN * centred.figure.error.total):
        return _in_region(fused, rungs, None, fused_lits, restrict, lit_fraction, shape)
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
        read = _lit_queries(lits)
        blur = held_out_blur(rungs, emitted, q, areas, gamma, halves(len(rungs)),
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
    vals, win, groups, masks = lits
    tiles = None if shape is None else tile_labels(shape)
    mix = _mix_parts(rungs, wm.choice, lit_fraction, blur,
                     (vals, win, groups, [restrict(m) for m in masks]), tiles)
    return replace(wm, figure=None if mix is None else mix.figure(wm.alpha))


def tile_labels(shape: tuple[int, int], tile: int = TILE) -> np.ndarray:
    """(H·W,) int: the tile of every pixel of an H × W raster in row order, tiles of
    ``tile`` × ``tile`` pixels from the top-left corner (the last row and column of tiles
    may be cut)."""
    H, W = shape
    rows, cols = np.divmod(np.arange(H * W, dtype=np.int64), W)
    return (rows // tile) * (-(-W // tile)) + cols // tile


def _lit_queries(lits) -> np.ndarray:
    """Indices of the queries either half's figure reads (see :func:`_lit_masks`)."""
    return (np.flatnonzero(lits[3][0] | lits[3][1]) if lits is not None
            else np.zeros(0, np.int64))


def _mixed(rungs: dict[int, np.ndarray], emitted: dict[int, int], choice: IciChoice,
           vals: np.ndarray | None, blur: np.ndarray | None, lits, lit_fraction: float
           ) -> WrittenMap:
    """The written map of a choice: the counts' weight α with the lowest certified figure
    (``vals``: every set's luminous map values if not at ``choice.rung``)."""
    order = sorted(rungs)
    w = set_weights(emitted, order)
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


# -- the run's interface ------------------------------------------------------------------
@dataclass(frozen=True)
class MapInputs:
    """What a written map is made from: every set's rungs at every pixel of the wall.

    Attributes
    ----------
    rungs : {set: (J+1, H·W, C) lx}
        Every set's centred rungs in row order, cut to the ladder allowed at these photons
        (:func:`~lightsim.render.ici.shrink_sides`).
    emitted : {set: photons}
    q : float
        ΣΦ²/ΣΦ (lm) of the wall photons over all sets.
    areas : (J'+1, H·W) m²
        The windows' areas of the whole ladder (read-only).
    gamma : float
        ICI interval half-width in standard errors.
    shape : (H, W)
        The wall's pixels.
    raster : (H, W) or None
        ``shape`` where :func:`~lightsim.render.ici.raster_shape` recognises it in
        ``areas`` (None on a wall too small for the directional map).
    """

    rungs: dict[int, np.ndarray]
    emitted: dict[int, int]
    q: float
    areas: np.ndarray
    gamma: float
    shape: tuple[int, int]
    raster: tuple[int, int] | None

    def make(self, directional: bool | None = None, restrict: Restrict | None = None,
             lit_fraction: float = 0.1) -> WrittenMap:
        """:func:`written_map` of these inputs (``directional``: None lets the figures
        choose, True the fused map, False the centred one; ``restrict``: the figure's
        region)."""
        return written_map(self.rungs, self.emitted, self.q, self.areas, self.gamma,
                           lit_fraction, shape=self.raster, directional=directional,
                           restrict=restrict)


@dataclass(frozen=True)
class MapImage:
    """The written map of a wall.

    Attributes
    ----------
    lux : (H, W, C) float64
        Illuminance (lx).
    rung : (H, W) int
        The ICI rung of every pixel (the heaviest ladder's where fused).
    error : ErrorEstimate or None
        Its error figure over the region (None with one set or nothing lit).
    fused : bool
        Whether the directional fusion was written.
    """

    lux: np.ndarray
    rung: np.ndarray
    error: ErrorEstimate | None
    fused: bool


class MapEstimator:
    """The server's half of the written map: the map and its error figure from every
    set's ICI rungs (see the module docstring).

    Parameters
    ----------
    gamma : float
        ICI interval half-width in standard errors (``RunConfig.ici_gamma``).
    error_region : str
        ``lit`` or ``interior`` (``RunConfig.error_region``): the pixels the figure covers.
    grid_hv : (G, 2) array
        Wall coordinates (h, v in m) of the grid probes, a regular raster in row order
        (:func:`~lightsim.render.frame.probe_grid`).
    grid_shape : (nh, nv)
        The grid's columns and rows (``RunConfig.probe_grid``).
    """

    def __init__(self, gamma: float, error_region: str, grid_hv: np.ndarray,
                 grid_shape: tuple[int, int]) -> None:
        self.gamma = gamma
        self.error_region = error_region
        self.grid_hv = np.asarray(grid_hv, dtype=np.float64).reshape(-1, 2)
        self.grid_shape = (int(grid_shape[0]), int(grid_shape[1]))
        #: keep the last image's :class:`MapInputs` in :attr:`last_inputs` (studies that
        #: remake the map from the same rungs)
        self.keep_inputs = False
        self.last_inputs: MapInputs | None = None
        # the whole raster's window areas, keyed by what they depend on (the wall's
        # pixels and the ladder): made once, not once per map
        self._raster: tuple[tuple, np.ndarray, tuple[int, int] | None] | None = None

    # -- geometry -----------------------------------------------------------------------
    @staticmethod
    def window_areas(wall: WallFrame, rows: np.ndarray, cols: np.ndarray, n_rungs: int
                     ) -> np.ndarray:
        """(J+1, Q) m²: the areas of the windows 1 … ``n_rungs`` pixels a side at pixels
        (rows, cols), clipped to the wall."""
        dh, dv = wall.pixel_size_m
        W, H = wall.resolution
        return window_cells(H, W, rows, cols, np.arange(1, n_rungs + 1)) * (0.25 * dh * dv)

    def raster_areas(self, wall: WallFrame, n_rungs: int
                     ) -> tuple[np.ndarray, tuple[int, int] | None]:
        """:meth:`window_areas` at every pixel of the wall in row order (read-only) and
        the (H, W) :func:`~lightsim.render.ici.raster_shape` recognises in them (None on
        walls too small for it); made once per wall pixel grid and ladder."""
        W, H = wall.resolution
        key = (W, H, tuple(wall.pixel_size_m), n_rungs)
        if self._raster is None or self._raster[0] != key:
            rows, cols = np.divmod(np.arange(H * W), W)
            areas = self.window_areas(wall, rows, cols, n_rungs)
            areas.flags.writeable = False
            self._raster = (key, areas, raster_shape(areas))
        return self._raster[1], self._raster[2]

    @staticmethod
    def rungs_now(wall: WallFrame, n_rungs: int, moments: dict[int, np.ndarray]) -> int:
        """How many of ``n_rungs`` the ladder keeps at the photons so far
        (:func:`~lightsim.render.ici.shrink_sides`)."""
        W, H = wall.resolution
        return len(shrink_sides(np.arange(1, n_rungs + 1), wall_photons(moments) / (W * H)))

    def pixel_region(self, wall: WallFrame) -> Restrict | None:
        """The figure's region over the wall's pixels (None for ``lit``)."""
        W, H = wall.resolution
        dh, dv = wall.pixel_size_m
        return restriction(self.error_region, (H, W), (dv, dh))

    def grid_region(self, wall: WallFrame) -> Restrict | None:
        """The figure's region over the grid probes (a regular raster of cell centres over
        the wall, in row order; None for ``lit``)."""
        nh, nv = self.grid_shape
        cell = (float(np.ptp(wall.v_range_m)) / nv, float(np.ptp(wall.h_range_m)) / nh)
        return restriction(self.error_region, (nv, nh), cell)

    # -- the map --------------------------------------------------------------------------
    def inputs(self, wall: WallFrame, rungs: dict[int, np.ndarray],
               moments: dict[int, np.ndarray], emitted: dict[int, int]) -> MapInputs:
        """The :class:`MapInputs` of every set's rungs {set: (J+1, H, W, C) lx} at every
        pixel, their wall-photon moments {set: (ΣΦ, ΣΦ², count)} and photons emitted."""
        J1, H, W, C = next(iter(rungs.values())).shape
        n = self.rungs_now(wall, J1, moments)
        flat = {s: np.asarray(v)[:n].reshape(n, H * W, C) for s, v in rungs.items()}
        areas, raster = self.raster_areas(wall, J1)  # raster: recognised once, not per map
        return MapInputs(flat, emitted, power_moment(moments), areas, self.gamma, (H, W),
                         raster)

    def image(self, wall: WallFrame, rungs: dict[int, np.ndarray],
              moments: dict[int, np.ndarray], emitted: dict[int, int],
              directional: bool | None = None) -> MapImage:
        """The written map of the wall, every pixel at its rung (:func:`written_map`), and
        its error figure over every pixel of the region (arguments as in :meth:`inputs`;
        ``directional`` as in :meth:`MapInputs.make`)."""
        inputs = self.inputs(wall, rungs, moments, emitted)
        if self.keep_inputs:
            self.last_inputs = inputs
        wm = inputs.make(directional, restrict=self.pixel_region(wall))
        H, W = inputs.shape
        return MapImage(wm.lux.reshape(H, W, wm.lux.shape[-1]), wm.choice.rung.reshape(H, W),
                        wm.error, wm.fused)

    def error_at_probes(self, wall: WallFrame, rungs: dict[int, np.ndarray],
                        moments: dict[int, np.ndarray], emitted: dict[int, int]
                        ) -> ErrorEstimate | None:
        """The written map's error figure from every set's rungs {set: (J+1, G, C) lx} at
        the grid probes' pixels (the frames between images; an image is measured over
        every pixel)."""
        rows, cols = pixel_of(wall, self.grid_hv[:, 0], self.grid_hv[:, 1])
        J1 = next(iter(rungs.values())).shape[0]
        n = self.rungs_now(wall, J1, moments)
        cut = {s: np.asarray(v)[:n] for s, v in rungs.items()}
        return written_map(cut, emitted, power_moment(moments),
                           self.window_areas(wall, rows, cols, J1), self.gamma,
                           restrict=self.grid_region(wall)).error
