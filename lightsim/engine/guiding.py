"""Importance-driven emission: photons sent where the wall apertures still need them.

A uniform run spends photons in proportion to flux, so a dim test point next to a bright
cut-off collects a handful of photons long after the map is good. The guide learns, set
by set and from the set's own earlier photons only, which emission samples reach given
wall apertures ("targets", rectangles in wall degrees) and draws more of them.

What is guided. Every emitter turns a sample point u ∈ [0, 1)⁵ into a photon
(:mod:`lightsim.emitters`), each carrying Φ/N. The guide is a piecewise-constant density
p(u) over a grid of cells in (u₂, u₀, u₁) — the source/triangle choice, then the
direction (a goniometric table's plane and polar angles, a mesh emitter's direction, a ray
file's ray in direction order) — so it works for every emitter without knowing its
geometry. The Halton point is carried through p's inverse cumulative (marginal in u₂,
then u₀ given u₂, then u₁ given both: continuous and monotone, so the points stay
stratified) and the photon's power is multiplied by 1 / p(u). The estimate of any
quantity is then Σ Φ f(u)/(N p(u)) with u ~ p: unbiased for ∫ f — the map, the far
field, every aperture — whatever p is, as long as p > 0 wherever f ≠ 0.

The density is a *defensive mixture* (Hesterberg 1995): p = α + (1 − α)·g, with α
(= 1 − ``share``) uniform and g the learned part, normalised to 1 over the cells. So p ≥
α everywhere, every photon weighs at most 1/α (the heaviest photon the count intervals
allow for, :func:`heaviest_weight`) and no region is ever starved.

What is learned (photon-map importance, Peter & Pietrek 1998; a learned sampling density
as in Müller et al. 2017, on a fixed grid). For each target t the guide sums, per cell,
the luminous power (lm, weights included: an unbiased estimate of the flux that cell
sends there) of the set's wall photons that landed (a) in the target's rectangle and
(b) in a wider window around it (``window_deg``; found sooner where photons are still
rare). Target t's distribution h_t is (a) once it holds ``MIN_LEARNED`` photons, else
(b): proportional to each cell's flux into the target — the zero-variance choice for that
target alone. g = Σ_t imp_t h_t / Σ_t imp_t over the *open* targets: each gets an equal
(importance-weighted) share of the guided photons, however dim it is.

A target closes (draws no more guided photons) once the set's effective photon count in
its rectangle, (Σw)²/Σw², reaches ``goal`` / (number of sets): the pooled count that
makes its interval about ±1.96/√goal. Importance 0 closes it at once — how a stopping
rule that knows which verdicts are decided turns them off.

Independence and determinism. A set's guide is learned from that set's own photons of
earlier frames, and applied to its next frame: set s's photons are a function of its
own scramble and its own past only, so the sets stay independent and identically
distributed (their spread stays an honest error) and every photon stays a function of
(seed, set, index, frames shot) — a lost client or a resumed run replays its frames to
the same guide. Targets may change between frames: they are rows (first frame, h₀, h₁,
v₀, v₁, importance) of the run's configuration, so the history travels with checkpoints.
They may be chosen from what all sets showed so far (``--until decided`` aims them at the
rules still open, :meth:`~lightsim.luminaires.regulations.sequential.VerdictRule.steer`):
every frame's density is still fixed before the frame is shot, so given the past each
frame adds an unbiased estimate to each set, drawn independently of the other sets' —
the sets' estimates stay unbiased and uncorrelated, and their spread an honest error.

Parameters
----------
==================  =====  ========  ====================================================
name                unit   default   meaning
==================  =====  ========  ====================================================
``share``           –      0.5       (1 − α) share of photons drawn from the learned part
``goal``            –      400       pooled effective photons per target at which it closes
``window_deg``      deg    1.0       side of the learning window around each target
``shape``           –      (1,64,64) cells in (u₂, u₀, u₁); per emitter (:func:`guide_shape`)
``MIN_LEARNED``     –      8         photons in a target's own rectangle before its own
                                     histogram replaces the window's
==================  =====  ========  ====================================================
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from lightsim.emitters.mesh import MeshEmitter
from lightsim.emitters.mixture import EmitterMix
from lightsim.errors import InputError

GUIDE_MODES = ("off", "points")
#: photons in a target's own rectangle before its histogram replaces the window's
MIN_LEARNED = 8
#: columns of a target row: first frame, H₀, H₁, V₀, V₁ (deg), importance
ROW = 6


def guide_shape(emitters) -> tuple[int, int, int]:
    """Cells (n₂, n₀, n₁) of the guide grid over (u₂, u₀, u₁) for an emitter.

    A single goniometric source reads u₀, u₁ only (one cell in u₂); a ray file reads u₀
    only (its rays in direction order, :meth:`~lightsim.emitters.rayfile.RaySource.
    direction_order`, through :func:`guide_remap`: 4096 cells along u₀); triangles and
    mixtures read u₂ too (the triangle or source, 4 cells) at a coarser direction grid,
    so the tables stay small.
    """
    mesh = emitters.mesh if isinstance(emitters, EmitterMix) else (
        emitters if isinstance(emitters, MeshEmitter) else None)
    sources = emitters.sources if isinstance(emitters, EmitterMix) else []
    if mesh is None and len(sources) == 1:
        if hasattr(sources[0], "file_sample"):
            return (1, 4096, 1)
        return (1, 64, 64)
    return (4, 32, 32)


def guide_remap(emitters):
    """A single ray file's map from u₀ in direction order to u₀ in file order
    (:meth:`~lightsim.emitters.rayfile.RaySource.file_sample`), applied after the warp so
    that the guide's u₀ cells are direction ranges; None for every other emitter. The
    map keeps every ray's probability (∝ its flux), so the weights stay 1/p."""
    sources = emitters.sources if isinstance(emitters, EmitterMix) else []
    mesh = emitters.mesh if isinstance(emitters, EmitterMix) else emitters
    if isinstance(emitters, EmitterMix) and mesh is None and len(sources) == 1 and hasattr(
            sources[0], "file_sample"):
        return sources[0].file_sample
    return None


def run_targets(config) -> tuple:
    """The guide target rows of a run (:class:`~lightsim.engine.config.RunConfig`): its
    ``guide_targets`` where set (:meth:`Session.guide <lightsim.engine.server.Session.
    guide>`), else with ``guide="points"`` every test-point aperture of the run (the
    requested rule sets' points and zone samples, and H-V), from frame 0; else none.

    Raises
    ------
    InputError
        ``guide="points"`` in a run without test-point apertures.
    """
    if config.guide_targets:
        return tuple(config.guide_targets)
    if config.guide != "points":
        return ()
    if not config.apertures:
        raise InputError("--guide points aims at the regulation's test points: give "
                         "--regulation (with --aperture > 0)")
    hv = np.asarray(config.apertures, np.float64).reshape(-1, 2)
    return target_rows(aperture_rects(hv[:, 0], hv[:, 1], config.aperture_deg))


def heaviest_weight(config) -> float:
    """The largest weight 1/p a guided photon can carry (1 when the run is unguided)."""
    if not (config.guide_targets or config.guide == "points"):
        return 1.0
    return 1.0 / (1.0 - float(config.guide_share))


def targets_at(rows: tuple, frame: int) -> NDArray:
    """The targets in force at frame ``frame`` (0-based): the rows with the latest first
    frame ≤ ``frame``, as (K, 5) float64 (H₀, H₁, V₀, V₁ in deg, importance)."""
    r = np.asarray(rows, dtype=np.float64).reshape(-1, ROW)
    live = r[r[:, 0] <= frame]
    if not len(live):
        return np.zeros((0, 5))
    return live[live[:, 0] == live[:, 0].max(), 1:]


def target_rows(rects: NDArray, importance: NDArray | None = None, frame: int = 0) -> tuple:
    """Rows for :attr:`~lightsim.engine.config.RunConfig.guide_targets`: rectangles
    (K, 4) (H₀, H₁, V₀, V₁ in deg) with importance (K,) (default 1) from ``frame`` on."""
    rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
    imp = (np.ones(len(rects)) if importance is None
           else np.asarray(importance, dtype=np.float64).reshape(-1))
    if len(imp) != len(rects):
        raise ValueError("one importance per guide target")
    if not (np.all(np.isfinite(rects)) and np.all(np.isfinite(imp)) and np.all(imp >= 0)):
        raise ValueError("guide targets must be finite, importance ≥ 0")
    if np.any(rects[:, 1] <= rects[:, 0]) or np.any(rects[:, 3] <= rects[:, 2]):
        raise ValueError("a guide target needs H₀ < H₁ and V₀ < V₁")
    if np.any(np.abs(rects) >= 89.0):
        raise ValueError("guide targets must lie within ±89°")
    return tuple((float(frame), *map(float, r), float(i)) for r, i in zip(rects, imp,
                                                                          strict=True))


@njit(cache=True, nogil=True)
def _warp(points, marg, rows, cols, shape, out, weight, cells):
    """Carry points through the inverse cumulative of the cell density (module docstring).

    ``marg`` (n₂+1), ``rows`` (n₂, n₀+1), ``cols`` (n₂, n₀, n₁+1): cumulative
    probabilities; ``out`` gets the warped points, ``weight`` 1/p (p relative to the
    uniform density), ``cells`` the flat cell index of each photon."""
    n2, n0, n1 = shape[0], shape[1], shape[2]
    top = 1.0 - 1.1102230246251565e-16
    for i in range(points.shape[0]):
        for d in range(points.shape[1]):
            out[i, d] = points[i, d]
        # u₂: the slab
        x = points[i, 2]
        k = 0
        while k < n2 - 1 and marg[k + 1] <= x:
            k += 1
        pk = marg[k + 1] - marg[k]
        t = min(max((x - marg[k]) / pk, 0.0), top) if pk > 0 else 0.5
        out[i, 2] = min((k + t) / n2, top)
        # u₀ given the slab: the row (binary search: up to 4096 rows)
        x = points[i, 0]
        lo, hi = 0, n0 - 1
        while lo < hi:
            mid = (lo + hi) // 2
            if rows[k, mid + 1] <= x:
                lo = mid + 1
            else:
                hi = mid
        r = lo
        pr = rows[k, r + 1] - rows[k, r]
        t = min(max((x - rows[k, r]) / pr, 0.0), top) if pr > 0 else 0.5
        out[i, 0] = min((r + t) / n0, top)
        # u₁ given both: the column
        x = points[i, 1]
        lo, hi = 0, n1 - 1
        while lo < hi:
            mid = (lo + hi) // 2
            if cols[k, r, mid + 1] <= x:
                lo = mid + 1
            else:
                hi = mid
        c = lo
        pc = cols[k, r, c + 1] - cols[k, r, c]
        t = min(max((x - cols[k, r, c]) / pc, 0.0), top) if pc > 0 else 0.5
        out[i, 1] = min((c + t) / n1, top)
        p = pk * pr * pc * (n2 * n0 * n1)
        weight[i] = 1.0 / p
        cells[i] = (k * n0 + r) * n1 + c


def cell_of(points: NDArray, shape: tuple[int, int, int]) -> NDArray:
    """Flat guide cell of sample points (n, ≥ 3) in [0, 1) (int64)."""
    n2, n0, n1 = shape
    k = np.minimum((points[:, 2] * n2).astype(np.int64), n2 - 1)
    r = np.minimum((points[:, 0] * n0).astype(np.int64), n0 - 1)
    c = np.minimum((points[:, 1] * n1).astype(np.int64), n1 - 1)
    return (k * n0 + r) * n1 + c


@njit(cache=True, nogil=True)
def _learn(cells, hd, vd, lum, rects, half_window, own, window, moments):
    """Add photons (cells, wall angles in deg, luminous power) to every target whose
    window (its rectangle widened to ``half_window`` either side of its centre) or
    rectangle (H₀ ≤ H < H₁, V₀ ≤ V < V₁) holds them."""
    for t in range(rects.shape[0]):
        h0, h1, v0, v1 = rects[t, 0], rects[t, 1], rects[t, 2], rects[t, 3]
        hc, vc = 0.5 * (h0 + h1), 0.5 * (v0 + v1)
        wh = max(half_window, 0.5 * (h1 - h0))
        wv = max(half_window, 0.5 * (v1 - v0))
        for i in range(cells.shape[0]):
            if abs(hd[i] - hc) < wh and abs(vd[i] - vc) < wv:
                window[t, cells[i]] += lum[i]
                if h0 <= hd[i] < h1 and v0 <= vd[i] < v1:
                    own[t, cells[i]] += lum[i]
                    moments[t, 0] += lum[i]
                    moments[t, 1] += lum[i] * lum[i]
                    moments[t, 2] += 1.0


class EmissionGuide:
    """One interleave set's guide (module docstring).

    Parameters
    ----------
    shape : (n₂, n₀, n₁)
        Cells over (u₂, u₀, u₁) (:func:`guide_shape`).
    share : float
        Share of photons from the learned part, in (0, 1).
    goal : float
        Effective photons per target (pooled over ``n_sets``) at which it closes.
    n_sets : int
        Interleave sets of the run.
    window_deg : float
        Side of the learning window around each target (deg).
    distance_m : float
        Wall distance D (m): wall positions to degrees.

    Per target (rows in the order of :meth:`set_targets`): ``own`` and ``window``
    (K, n_cells) luminous power (lm, unnormalised) of the set's photons that landed in
    the rectangle and in the window, by emission cell; ``moments`` (K, 3) Σw, Σw²,
    count of the rectangle's photons.
    """

    def __init__(self, shape: tuple[int, int, int], share: float, goal: float, n_sets: int,
                 window_deg: float, distance_m: float) -> None:
        if not 0.0 < share < 1.0:
            raise ValueError(f"guide share must be in (0, 1), got {share}")
        self.shape = tuple(int(n) for n in shape)
        self.n_cells = int(np.prod(self.shape))
        self.share = float(share)
        self.goal_per_set = float(goal) / max(1, int(n_sets))
        self.window_deg = float(window_deg)
        self.distance_m = float(distance_m)
        self.targets = np.zeros((0, 5))
        self.own = np.zeros((0, self.n_cells))
        self.window = np.zeros((0, self.n_cells))
        self.moments = np.zeros((0, 3))
        self._learned: dict[tuple[float, ...], tuple[NDArray, NDArray, NDArray]] = {}

    # -- targets -------------------------------------------------------------------------
    def set_targets(self, targets: NDArray) -> None:
        """Use ``targets`` (K, 5): H₀, H₁, V₀, V₁ (deg), importance. What was learned about
        a rectangle already known is kept."""
        targets = np.asarray(targets, dtype=np.float64).reshape(-1, 5)
        if np.array_equal(targets, self.targets):
            return
        for i, t in enumerate(self.targets):  # keep what the old targets learned
            self._learned[tuple(t[:4].tolist())] = (self.own[i], self.window[i],
                                                    self.moments[i])
        K = len(targets)
        self.own, self.window = np.zeros((K, self.n_cells)), np.zeros((K, self.n_cells))
        self.moments = np.zeros((K, 3))
        for i, t in enumerate(targets):
            old = self._learned.get(tuple(t[:4].tolist()))
            if old is not None:
                self.own[i], self.window[i], self.moments[i] = old
        self.targets = targets

    def open_targets(self) -> NDArray:
        """Boolean (K,): targets that still draw guided photons (importance > 0 and fewer
        effective photons in the set than the goal)."""
        m = self.moments
        with np.errstate(divide="ignore", invalid="ignore"):
            n_eff = np.where(m[:, 1] > 0, m[:, 0] ** 2 / m[:, 1], 0.0)
        return (self.targets[:, 4] > 0) & (n_eff < self.goal_per_set)

    # -- the density ---------------------------------------------------------------------
    def density(self) -> NDArray | None:
        """The mixture's cell probabilities (n_cells,), summing to 1, or None when nothing
        is learned for any open target (then the set samples uniformly)."""
        is_open = self.open_targets()
        if not is_open.any():
            return None
        h = np.where((self.moments[:, 2] >= MIN_LEARNED)[:, None], self.own, self.window)
        h = h[is_open]
        s = h.sum(axis=1)
        imp = np.where(s > 0, self.targets[is_open, 4], 0.0)
        if not imp.sum() > 0:
            return None
        g = (imp / np.where(s > 0, s, 1.0)) @ h
        return (1.0 - self.share) / self.n_cells + self.share * g / imp.sum()

    def warp(self, points: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """(guided points, weights 1/p, cells) for sample points (n, 5); without a learned
        density the points themselves, weight 1."""
        points = np.ascontiguousarray(points, dtype=np.float64)
        p = self.density()
        if p is None:
            return points, np.ones(len(points)), cell_of(points, self.shape)
        return warp_points(points, p, self.shape)

    # -- learning ------------------------------------------------------------------------
    def learn(self, cells: NDArray, h_m: NDArray, v_m: NDArray, lum: NDArray) -> None:
        """Add wall photons: their emission cells, wall positions (m) and luminous power
        (lm, unnormalised, weights included)."""
        if len(cells) == 0 or not len(self.targets):
            return
        hd = np.degrees(np.arctan2(np.asarray(h_m, np.float64), self.distance_m))
        vd = np.degrees(np.arctan2(np.asarray(v_m, np.float64), self.distance_m))
        _learn(np.ascontiguousarray(cells, np.int64), hd, vd,
               np.ascontiguousarray(lum, np.float64), np.ascontiguousarray(self.targets[:, :4]),
               0.5 * self.window_deg, self.own, self.window, self.moments)


def warp_points(points: NDArray, p: NDArray, shape: tuple[int, int, int]
                ) -> tuple[NDArray, NDArray, NDArray]:
    """Points (n, ≥ 3) carried through the cell density ``p`` (n_cells,), summing to 1:
    (points, weights 1/p relative to uniform, flat cells)."""
    n2, n0, n1 = shape
    q = np.asarray(p, np.float64).reshape(n2, n0, n1)
    slab = q.sum(axis=(1, 2))
    marg = np.concatenate([[0.0], np.cumsum(slab)])
    marg /= marg[-1]
    row_p = q.sum(axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        rows = np.concatenate([np.zeros((n2, 1)), np.cumsum(row_p, axis=1)], axis=1)
        rows /= rows[:, -1:]
        cols = np.concatenate([np.zeros((n2, n0, 1)), np.cumsum(q, axis=2)], axis=2)
        cols /= cols[:, :, -1:]
    marg[-1] = 1.0
    rows[:, -1] = 1.0
    cols[:, :, -1] = 1.0
    points = np.ascontiguousarray(points, dtype=np.float64)
    out = np.empty_like(points)
    weight = np.empty(len(points))
    cells = np.empty(len(points), np.int64)
    if len(points):
        _warp(points, marg, np.ascontiguousarray(rows), np.ascontiguousarray(cols),
              np.array(shape, np.int64), out, weight, cells)
    return out, weight, cells


def aperture_rects(h_deg: NDArray, v_deg: NDArray, size_deg: float) -> NDArray:
    """Square apertures of side ``size_deg`` centred on (H, V) (deg) as rectangles
    (K, 4): H₀, H₁, V₀, V₁."""
    h = np.asarray(h_deg, np.float64).reshape(-1)
    v = np.asarray(v_deg, np.float64).reshape(-1)
    a = 0.5 * float(size_deg)
    if not (math.isfinite(a) and a > 0):
        raise ValueError(f"aperture size must be positive, got {size_deg}")
    return np.stack([h - a, h + a, v - a, v + a], axis=1)
