"""When the live session draws the pooled map, and on how many numba threads it traces.

:class:`PooledSchedule` — the pooled full-resolution map (what ``simulate`` writes) costs
M² times an interleaved image, so the session draws it where it shows something new: first
where the scene's error law predicts 5 %, then where the figure is expected to cross the
next of :data:`ERROR_LEVELS` (noise ∝ 1/√N beside a blur that does not fall), otherwise
each time the photons have doubled with its cost kept to ``pooled_share`` of the time.

:class:`ThreadChoice` — numba threads of the session thread: the warm-up's choice for
interaction frames and accumulation batches, revised by the still scene's batches (one in
:data:`THREAD_TRIAL` runs at the other count; moving average of the rates).

=====================  =====  =======  ========================================================
constant               unit   value    meaning
=====================  =====  =======  ========================================================
``ERROR_LEVELS``       –      5 % …    error figures at which the next pooled map is scheduled
``LEVEL_AIM``          –      0.93     a level's pooled map is aimed this far below it
``FIRST_AIM``          –      0.9      … the first after an edit further below
``LAW_MIN_PHOTONS``    –      2·10⁵    maps with fewer photons do not set the error law
``THREAD_TRIAL``       –      8        one still batch in this many runs at the other count
``RATE_WEIGHT``        –      0.3      weight of a batch's rate in the moving average
=====================  =====  =======  ========================================================
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

# error figures at which the next pooled map is scheduled (where it is expected to cross)
ERROR_LEVELS = (0.05, 0.02, 0.01, 0.005)
LEVEL_AIM = 0.93  # a level's pooled map is aimed this far below it (the law's scatter) …
FIRST_AIM = 0.9  # … the first after an edit further: e √N moves ~10 % from edit to edit
LAW_MIN_PHOTONS = 200_000  # maps with fewer photons do not set the error law
THREAD_TRIAL = 8  # one still batch in this many runs at the other numba thread count
RATE_WEIGHT = 0.3  # weight of a batch's rate in the moving average per thread count


def finite_or_none(x: float | None) -> float | None:
    """``x`` as a float, or None when it is None, NaN or infinite (JSON-safe figures)."""
    return None if x is None or not np.isfinite(x) else float(x)


def blur_estimate(e: Any) -> tuple[float, float] | None:
    """(blur², its standard error), relative², of an error figure
    (:class:`~lightsim.render.frame.ErrorEstimate`): ``bias_upper``² = blur² + 2 se, and a
    negative blur² estimate reads as 0; None without the figure's parts."""
    bias = None if e is None else finite_or_none(e.bias)
    upper = None if e is None else finite_or_none(e.bias_upper)
    if bias is None or upper is None:
        return None
    return bias * bias, max(upper * upper - bias * bias, 0.0) / 2.0


@dataclass
class PooledSchedule:
    """When the next pooled map is due (see the module docstring).

    Attributes
    ----------
    first_pooled_seconds, first_cap_seconds, pooled_share
        The settings of the same names (:class:`~lightsim.view.settings.ViewSettings`).
    traced_s : float
        Seconds of tracing since the last change (s).
    traced_at_pooled : float
        ``traced_s`` at the last pooled map (s).
    pooled_cost : float
        Seconds of the last pooled map (kept across changes: the next scene's first map
        costs about as much).
    written : (figure, photons) or None
        The last pooled map's own error figure (None: not finite) and photons since the
        last change; None before the first.
    law : (photons, total, noise, blur) or None
        The scene's error law from the last pooled map with ≥ ``LAW_MIN_PHOTONS`` (kept
        across changes: e √N moves ~10 % from edit to edit).
    law_5 : (photons, figure) or None
        The pooled map whose figure was nearest 5 % so far (kept across changes).
    blurs : list of (blur², se)
        The blur of every pooled map since the last change (:func:`blur_estimate`).
    """

    first_pooled_seconds: float = 1.0
    first_cap_seconds: float = 30.0
    pooled_share: float = 0.1
    traced_s: float = 0.0
    traced_at_pooled: float = 0.0
    pooled_cost: float = 0.0
    written: tuple[float | None, int] | None = None
    law: tuple[int, float, float, float] | None = None
    law_5: tuple[int, float] | None = None
    blurs: list[tuple[float, float]] = field(default_factory=list)

    def reset(self) -> None:
        """A change: the photons start afresh (the law and the map's cost are kept)."""
        self.traced_s = self.traced_at_pooled = 0.0
        self.written = None
        self.blurs = []

    def note_map(self, est: Any, cost: float) -> None:
        """A pooled map ``est`` (:class:`~lightsim.engine.results.FrameEstimate`) drawn in
        ``cost`` seconds: its figure, and the scene's error law from it."""
        self.pooled_cost = cost
        self.traced_at_pooled = self.traced_s
        self.written = (finite_or_none(est.rel_error), int(est.photons))
        e = est.error
        if self.written[0] is not None and est.photons >= LAW_MIN_PHOTONS:
            # the error law of this scene: where the next maps (and the next edit's first
            # map) are due; a warm-up-sized map is not yet in the 1/√N regime
            noise = finite_or_none(e.noise) if e is not None else None
            blur = (finite_or_none(e.bias) or 0.0) if e is not None else 0.0
            self.law = (int(est.photons), self.written[0],
                        self.written[0] if noise is None else noise, blur)
            measured = blur_estimate(e)
            if measured is not None:
                self.blurs.append(measured)
            near = self.law_5
            if near is None or abs(math.log(self.written[0] / ERROR_LEVELS[0])) <= \
                    abs(math.log(near[1] / ERROR_LEVELS[0])):
                self.law_5 = (int(est.photons), self.written[0])

    def photons_for(self, level: float) -> float | None:
        """Photons at which the written map's figure is expected to reach ``level``
        (aimed ``LEVEL_AIM`` below it) from the last map's noise (∝ 1/√N) and the blur
        (kept: :meth:`blur2`); None where the blur alone is above it."""
        if self.law is None:
            return None
        n, _, noise, _ = self.law
        room = (LEVEL_AIM * level) ** 2 - self.blur2()
        return None if room <= 0 else n * noise ** 2 / room

    def blur2(self) -> float:
        """The written map's squared blur (relative²) for the prediction: the maps of
        this scene each measure the same blur (the rungs' windows do not shrink with the
        photons), so their estimates are pooled by their precision (1/se²): one map's
        blur² scatters by its se, at 1–4 M photons on the shipped headlight by as much as
        the blur² itself (blur 0.4–1.8 % from map to map, 1.4–1.5 % at 8–16 M)."""
        if self.law is None:
            return 0.0
        ok = [(b2, se) for b2, se in self.blurs if se > 0]
        if not ok:
            return self.law[3] ** 2
        w = [1.0 / (se * se) for _, se in ok]
        return sum(wi * b2 for wi, (b2, _) in zip(w, ok, strict=True)) / sum(w)

    def due(self, photons_now: Callable[[], int]) -> bool:
        """Whether the next pooled map (M² times an image's work) is due at the photons
        ``photons_now()`` (asked only when needed: a Ray session's count is a round trip).

        The first: where the scene's error law (the map nearest 5 % so far: e √N)
        predicts 5 % (aimed ``FIRST_AIM`` below it), after at least the map's own cost of
        tracing — or, with no law yet, after ``first_pooled_seconds`` of tracing. Then
        where the figure is expected to cross the next level (noise ∝ 1/√N beside the
        blur), otherwise at twice the photons with its cost ≤ ``pooled_share`` of the
        time — unless the crossing is due before that."""
        if self.written is None:
            first = max(self.first_pooled_seconds, self.pooled_cost)
            if self.law_5 is None:
                return self.traced_s >= first
            n, e = self.law_5
            n5 = n * (e / (FIRST_AIM * ERROR_LEVELS[0])) ** 2
            return (self.traced_s >= self.pooled_cost and photons_now() >= n5) or \
                self.traced_s >= max(self.first_cap_seconds, 2.0 * self.pooled_cost)
        err, n_last = self.written
        photons = photons_now()
        if err is not None:
            below = [lv for lv in ERROR_LEVELS if lv < err]
            due = self.photons_for(below[0]) if below else None
            if due is not None and photons >= due:
                return True
            if due is not None and due <= 2 * photons:
                return False  # the next level's map comes before a doubled one would
        share = self.pooled_share
        return photons >= 2 * n_last and (self.traced_s - self.traced_at_pooled
                                          >= self.pooled_cost * (1 - share) / share)


@dataclass
class ThreadChoice:
    """numba threads of the session thread's work (see the module docstring).

    Attributes
    ----------
    fixed : int or None
        The ``threads`` setting when it is a number (never revised); None = auto.
    frame, accumulate : int or None
        Threads of interaction frames and of accumulation batches (the warm-up's choice).
    frame_times, batch_times : dict of threads → s
        The warm-up's best times of an interaction frame and of one batch.
    rates : dict of threads → photons/s
        Accumulation rate per thread count (the warm-up's batch, then still batches').
    still_batches : int
        Batches since the scene became still.
    """

    fixed: int | None = None
    frame: int | None = None
    accumulate: int | None = None
    frame_times: dict[int, float] = field(default_factory=dict)
    batch_times: dict[int, float] = field(default_factory=dict)
    rates: dict[int, float] = field(default_factory=dict)
    still_batches: int = 0

    def reset(self) -> None:
        """A change: the next still scene measures afresh."""
        self.still_batches = 0

    def timed(self, frame_times: dict[int, float], batch_times: dict[int, float],
              batch: int | None) -> None:
        """The warm-up's times at each thread count (``batch`` photons per batch; None:
        a whole frame, as with Selective Photon Tracing, whose passes are always whole
        and whose photons the caller does not count): the faster count for frames and
        for batches. Without ``batch`` the rates are left to the still batches, which
        then run once at each count (:meth:`for_batch`)."""
        self.frame_times.update(frame_times)
        self.batch_times.update(batch_times)
        self.frame = min(self.frame_times, key=self.frame_times.get)
        self.accumulate = min(self.batch_times, key=self.batch_times.get)
        self.rates = {} if batch is None else \
            {n: batch / t for n, t in self.batch_times.items() if t > 0}

    def for_batch(self, still: bool) -> int | None:
        """numba threads of the next accumulation batch: the faster count by the rates
        measured so far (the warm-up's batch, then the still batches'). A still scene's
        first batch and one in ``THREAD_TRIAL`` after it run at the other count: the
        warm-up times one 50 000-photon batch at start-up, and the faster count moves
        with the batch size and the machine's load. Without the warm-up's rates (whole
        frames timed), the still batches first run once at each count not yet rated."""
        rates = self.rates
        if self.fixed is not None or len(self.batch_times) < 2:
            return self.accumulate
        if len(rates) < 2:
            if not still:
                return self.accumulate
            self.still_batches += 1
            return next((n for n in sorted(self.batch_times) if n not in rates),
                        self.accumulate)
        best = max(rates, key=rates.get)
        if not still:
            return best
        self.still_batches += 1
        if self.still_batches == 1 or self.still_batches % THREAD_TRIAL == 0:
            return next(n for n in rates if n != best)
        return best

    def note_rate(self, threads: int | None, rate: float) -> None:
        """A still batch's photons/s at ``threads`` (moving average, weight
        ``RATE_WEIGHT`` on the new batch; a still scene's first two set it)."""
        if threads is None or threads not in self.batch_times:
            return
        if threads not in self.rates:  # first rated by a still batch (whole-frame warm-up)
            self.rates[threads] = rate
            return
        old = self.rates[threads]
        fresh = self.still_batches <= 2  # a still scene's first batches: now's rate
        self.rates[threads] = rate if (old <= 0 or fresh) else \
            (1.0 - RATE_WEIGHT) * old + RATE_WEIGHT * rate

    def batch_threads(self) -> int | None:
        """The accumulation's thread count as the status shows it (the faster by the
        rates, or the warm-up's choice)."""
        if self.fixed is not None or len(self.rates) < 2:
            return self.accumulate
        return max(self.rates, key=self.rates.get)
