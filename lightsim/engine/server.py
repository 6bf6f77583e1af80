"""The server loop: plan, broadcast changes, run frames on the clients, assemble, log error.

A :class:`Session` is the Python API of lightsim (the CLI is a thin layer over it)::

    session = Session(scene, RunConfig(frame_photons=200_000))
    session.frame()                      # interaction mode: shoot + render
    session.update(material=("lens", {"ior": 1.55}))   # discards photons, next frame is immediate
    session.walkthrough()                # queries only (no shooting)
    result = session.run(photons=2_000_000, target_error=0.02)

Backends (``workers``): 0 → clients in this process; N ≥ 1 → N Ray actors on a private
local Ray instance; ``address`` → actors on an existing Ray cluster, N of them or, without
``workers``, one per CPU of the cluster (at most one per interleave set). Results are
bit-identical between backends for the same seed and photon count, because every set's
photons depend only on (seed, set, index) and the server combines sets in set order.

:meth:`Session.run` is the paper's loop in named stages, one frame at a time: shoot →
insert (:meth:`~Session.shoot`), estimate at the probes or on the written map
(:meth:`~Session.estimate_at_probes`, :meth:`~Session.final_image`), the error figure and
the stopping rule (a :class:`StoppingRule`; :class:`MapErrorRule` for a target error),
and after the last frame the final image (:meth:`~Session.final_image`: the written map,
:mod:`lightsim.render.written_map`).

====================  =====  ==========  =============================================
parameter             unit   default     meaning
====================  =====  ==========  =============================================
``min_frames``        –      3           frames before a target error may stop a run
``growth``            –      2           photons between two error estimates grow ≤
                                         this
``aim``               –      0.98        a target-error stop is aimed at this × the
                                         target
``STOP_ALPHA``        –      0.1         a target-error stop ends above the target at
                                         most this often (the error budget of its
                                         looks)
``EXPONENT_RANGE``    –      0.35 … 1    the error law's exponent p (e ∝ N^-p) is
                                         clamped to this range
``LAW_POINTS``        –      3           estimates the error law is fitted to
``MAP_CHECK_PIXELS``  –      4           walls with at most this many pixels per grid
                                         probe judge every estimate on the written map
====================  =====  ==========  =============================================

A target error stops the run when the written map's error figure is at most the target
at confidence 1 − :data:`STOP_ALPHA`: the figure's upper bound √(noise² + blur² + z·se)
(:func:`stop_level`; se the standard error of the squared-blur estimate, which dominates
the figure's own uncertainty) at most the target, with z growing with every look at a
written map so the chances of a wrong stop over all looks sum to at most the budget
(:class:`MapErrorRule`). The schedule places the looks where the error law predicts the
bound meets the target (:class:`ErrorSchedule`), so a run takes few of them.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from statistics import NormalDist
from typing import Any, Protocol

import numpy as np

from lightsim.engine import memory
from lightsim.engine.backend import Backend
from lightsim.engine.client import apply_changes
from lightsim.engine.config import RunConfig
from lightsim.engine.estimator import effective_radii, normalise_flux
from lightsim.engine.guiding import run_targets, target_rows
from lightsim.engine.local import LocalBackend
from lightsim.engine.numba_start import lazy_target_setup
from lightsim.engine.plan import Plan, make_plan
from lightsim.engine.ray_backend import RayBackend, actor_count, connect
from lightsim.engine.results import (
    Estimate,
    FrameResult,
    MemoryStop,
    RenderRequest,
    SetFrames,
    ShootResult,
)
from lightsim.errors import InputError
from lightsim.persource import PerSourceMaps, group_names
from lightsim.render.frame import (
    ErrorEstimate,
    ProbeStats,
    assemble_interleaved,
    luminous,
    pool_full_images,
    probe_error,
    probe_grid,
    probe_stats,
)
from lightsim.render.interleave import InterleavePattern
from lightsim.render.written_map import MapEstimator
from lightsim.scene import Scene
from lightsim.tracer import LEDGER, scene_caster

__all__ = ["Estimate", "FrameResult", "MapErrorRule", "Session", "StoppingRule"]


#: the error law's exponent p (e ∝ N^-p) fitted between two estimates is clamped to this
#: range: noise alone gives 0.5, an unresolved blur falls slower, a resolved one faster
EXPONENT_RANGE = (0.35, 1.0)
#: estimates the law is fitted to (the last ones of the same figure)
LAW_POINTS = 3
#: a target-error stop is wrong (true error above the target) at most this often: the
#: error budget α spent over the looks, α·2^-j at look j (Σ = α)
STOP_ALPHA = 0.1
#: a frame shot to land a look where the error law places the stop has at least this
#: share of a whole frame's photons
MIN_PARTIAL = 0.1
#: the stop is judged on the written map at every estimate when the wall has at most
#: this many pixels per grid probe (the map's figure then costs about the probes')
MAP_CHECK_PIXELS = 4


def look_z(look: int, alpha: float = STOP_ALPHA) -> float:
    """The one-sided normal quantile of look ``look`` (1, 2, …): its share α·2^-look of
    the error budget, z = Φ⁻¹(1 − α·2^-look) (1.64, 1.96, 2.24, 2.50, … for α = 0.1)."""
    if not (0 < alpha < 1) or look < 1:
        raise ValueError(f"look {look} with budget {alpha}: need look ≥ 1, 0 < α < 1")
    return -NormalDist().inv_cdf(alpha * 2.0 ** -min(look, 200))  # Φ⁻¹(1 − p) = −Φ⁻¹(p)


def stop_level(error: ErrorEstimate | None, z: float = 0.0) -> float | None:
    """What a target-error stop compares with the target (a fraction): the error figure's
    upper confidence bound √(noise² + max(blur², 0) + z·se) — blur² the unbiased
    squared-blur estimate, se its standard error — or the figure itself (``total``) where
    no blur is measured (binning, one set). A negative blur² estimate is noise (the true
    one is ≥ 0) and must not eat the margin z·se; ``z`` = 0 gives the figure
    (``total``). None without a figure."""
    if error is None:
        return None
    if error.bias2 is None or error.bias2_se is None:
        return error.total
    return math.sqrt(error.noise**2 + max(error.bias2, 0.0) + z * max(error.bias2_se, 0.0))


class StoppingRule(Protocol):
    """When a run has what it was run for, besides its photon, time and memory budgets.

    :meth:`Session.run` asks the rule at every estimate: first of the probes' estimate
    (a frame between images) and, when that satisfies it, of the written map, which
    has the last word — or of the written map alone where the schedule measures it
    (:meth:`ErrorSchedule.measure`). The run stops on the first written map that
    satisfies the rule, and returns it.
    """

    def satisfied(self, est: FrameResult, frames: int) -> bool:
        """Whether the estimate ``est`` (the probes' or the written map's), made after
        ``frames`` frames, lets the run stop."""
        ...


@dataclass
class MapErrorRule:
    """The target-error rule (``--target-error``): the written map's error figure is at
    most ``target_error`` at confidence 1 − ``alpha``, after at least ``min_frames``
    frames.

    A judgement of a written map whose figure (``total``) is at most the target is a
    *look*; look j tests the upper bound :func:`stop_level` with z = :func:`look_z` (j),
    one-sided at level α·2^-j. A run stops wrongly — its true error above the target —
    only if one of its looks does, and those chances sum to at most Σ α·2^-j = α however
    many looks the run takes and wherever it places them (Bonferroni over the looks):
    valid under repeated looks. A map whose figure is above the target cannot stop the
    run at any z, so it is no test and spends nothing. The schedule
    (:class:`ErrorSchedule`) places the looks where the error law predicts the bound
    reaches the target, and the run shoots a partial frame to land there
    (:meth:`Session.frame_photons`), so a run takes one or two looks. The probes' figure
    proposes a stop at the z of the next look; it spends nothing (only the written map
    decides).

    ================  =====  =======  ================================================
    parameter         unit   default  meaning
    ================  =====  =======  ================================================
    ``target_error``  –      –        relative error (a fraction) the run stops at
    ``min_frames``    –      3        frames before the rule may stop a run
    ``alpha``         –      0.1      error budget: the share of runs allowed to stop
                                      above the target (:data:`STOP_ALPHA`)
    ================  =====  =======  ================================================
    """

    target_error: float
    min_frames: int = 3
    alpha: float = STOP_ALPHA
    looks: int = 0  # written maps judged so far

    def level(self, error: ErrorEstimate | None) -> float | None:
        """:func:`stop_level` at the z of the next look."""
        return stop_level(error, look_z(self.looks + 1, self.alpha))

    def satisfied(self, est: FrameResult, frames: int) -> bool:
        """A :class:`StoppingRule`: the bound (:meth:`level`) at most the target after
        ``min_frames`` frames; never without a figure. A written map (``est.lux`` set)
        whose figure is at most the target spends a look."""
        if est.error is None or frames < self.min_frames:
            return False
        ok = self.level(est.error) <= self.target_error
        if est.lux is not None and est.error.total <= self.target_error:
            self.looks += 1
        return ok


@dataclass
class ErrorSchedule:
    """When the run loop estimates the error: the figure costs about as much as a frame
    of tracing, so it runs where it can change a decision, not every frame.

    Without a target error the estimates (the error-vs-time log) are spaced by a factor
    ``growth`` in photons. With one, the next estimate comes where the error law measured
    so far says the stop's level (``level``: the rule's bound at its next look,
    :meth:`MapErrorRule.level`; the figure itself, :func:`stop_level`, without a rule)
    reaches ``aim`` × target: e ∝ N^-p, with
    p fitted to the last estimates of the same figure (clamped to
    :data:`EXPONENT_RANGE`; 0.5, the noise's, with one estimate), at the frame nearest
    to that photon count (``due``), at most ``growth`` × N and at least the next frame.
    ``stop_expected`` says the next estimate is placed to stop the run (the loop then
    measures the written map itself there, see :meth:`Session.run`). The probes' figure
    can sit well above or below the written map's (on the shipped headlight ~2× above):
    :meth:`calibrate` measures their ratio once, and the probes' figure is scaled by it
    before the law places the stop. Deterministic: it depends on photons and estimates
    only, never on the clock. :meth:`measure` says what an estimate measures.

    ================  =====  =======  ================================================
    parameter         unit   default  meaning
    ================  =====  =======  ================================================
    ``target_error``  –      None     relative error the estimates are aimed at
    ``growth``        –      2        photons between two estimates grow ≤ this factor
    ``aim``           –      0.98     the stop is aimed at this fraction of the target
    ``map_is_cheap``  –      False    the written map's figure costs about the probes'
                                      (:meth:`Session.map_check_is_cheap`)
    ``min_frames``    –      3        frames before the written map is calibrated
    ``level``         –      None     the stop's level of an error figure (None:
                                      :func:`stop_level`, the figure)
    ================  =====  =======  ================================================
    """

    target_error: float | None = None
    growth: float = 2.0
    aim: float = 0.98
    map_is_cheap: bool = False
    min_frames: int = 3
    level: Callable[[ErrorEstimate | None], float | None] | None = None
    next_photons: float = 0.0
    stop_expected: bool = False
    history: dict[str, list[tuple[int, float]]] = field(default_factory=dict)
    probe_scale: float = 1.0  # the written map's figure over the probes' (calibrate)
    calibrated: bool = False
    _step: float = 0.0  # photons of the last frame (the nearest-frame rule of ``due``)
    _last_seen: int = 0

    def due(self, photons: int) -> bool:
        """Whether the frame that brought the run to ``photons`` should estimate: the
        first frame past ``next_photons``, or the one before it when that is nearer (with
        a target and an estimate placed by the error law)."""
        if photons > self._last_seen:
            self._step = float(photons - self._last_seen)
            self._last_seen = photons
        if photons >= self.next_photons:
            return True
        return self.stop_expected and photons + 0.5 * self._step >= self.next_photons

    def measure(self, frames: int) -> str:
        """What the estimate due after ``frames`` frames measures: ``"map"`` — the written
        map itself, where the error law places the stop or where it costs about the
        probes' figure (``map_is_cheap``); ``"calibrate"`` — the probes and, once after
        ``min_frames`` frames, the written map beside them (:meth:`calibrate`);
        ``"probes"`` — the probes alone (always, without a target error)."""
        if self.target_error is None:
            return "probes"
        if self.map_is_cheap or self.stop_expected:
            return "map"
        if not self.calibrated and frames >= self.min_frames:
            return "calibrate"
        return "probes"

    def exponent(self, kind: str) -> float:
        """The error law's exponent p: a least-squares line through the last
        :data:`LAW_POINTS` estimates of figure ``kind`` in log N, log e (one estimate's
        scatter moves it less than a two-point slope), clamped to :data:`EXPONENT_RANGE`."""
        pts = self.history.get(kind, [])[-LAW_POINTS:]
        if len(pts) < 2:  # the other figure's law, if it has one, else the noise's
            other = self.history.get("probes" if kind == "map" else "map", [])
            return self.exponent("probes" if kind == "map" else "map") if (
                len(other) >= 2) else 0.5
        x = np.log([n for n, _ in pts])
        y = np.log([e for _, e in pts])
        dx = x - x.mean()
        if not np.any(dx > 0):
            return 0.5
        p = -float(np.dot(dx, y - y.mean()) / np.dot(dx, dx))
        return min(max(p, EXPONENT_RANGE[0]), EXPONENT_RANGE[1])

    def estimated(self, photons: int, est: FrameResult, kind: str = "probes") -> None:
        """Place the next estimate after an estimate ``est`` of figure ``kind`` (the
        probes' or the written map's) at ``photons``."""
        self._last_seen = max(self._last_seen, photons)
        factor = self.growth
        self.stop_expected = False
        if self.target_error is not None and est.error is not None:
            e = self.stop_level(est.error)
            if e is not None and math.isfinite(e) and e > 0:
                self.history.setdefault(kind, []).append((photons, e))
                level = e * (self.probe_scale if kind == "probes" else 1.0)
                ratio = (level / (self.aim * self.target_error)) ** (1.0 / self.exponent(kind))
                factor = min(self.growth, ratio)
                self.stop_expected = ratio <= self.growth
            else:  # no usable figure (0 or not finite): look again after the next frame
                factor = 1.0
        self.next_photons = photons * max(1.0, factor)

    def stop_level(self, error: ErrorEstimate | None) -> float | None:
        """The stop's level of ``error`` (``level``, or :func:`stop_level`)."""
        return stop_level(error) if self.level is None else self.level(error)

    def calibrate(self, probes: FrameResult, written: FrameResult) -> None:
        """The ratio of the written map's figure to the probes' at the same photons
        (kept as ``probe_scale``; 1 when either has no usable figure)."""
        self.calibrated = True
        a, b = self.stop_level(probes.error), self.stop_level(written.error)
        if a and b and math.isfinite(a) and math.isfinite(b) and a > 0:
            self.probe_scale = b / a


@dataclass
class ShootTotals:
    """Sums of the clients' :class:`~lightsim.engine.results.ShootResult` over a session's
    frames (photons, rays; seconds: all of shooting, the sample points, the tracer —
    client-side, summed over clients)."""

    photons: int = 0
    rays: int = 0
    seconds: float = 0.0
    sample_s: float = 0.0
    trace_s: float = 0.0

    def add(self, r: ShootResult) -> None:
        self.photons += int(r.photons)
        self.rays += int(r.rays)
        self.seconds += float(r.seconds)
        self.sample_s += float(r.sample_s)
        self.trace_s += float(r.trace_s)


class Session:
    """Distributed photon-mapping session (see the module docstring).

    Parameters
    ----------
    scene : Scene
    config : RunConfig
    workers : int
        0: in-process clients (with ``address``: one Ray actor per CPU of the cluster);
        N ≥ 1: N Ray actors.
    address : str, optional
        Ray cluster address (``HOST:PORT`` or ``auto``); implies Ray.
    camera, farfield, regulation :
        Stages the plan must include.
    extra_probes : (n, 2) array, optional
        More probe points (h, v in m) every set estimates, e.g. regulation test points.
    """

    def __init__(self, scene: Scene, config: RunConfig | None = None, *, workers: int = 0,
                 address: str | None = None, camera: bool = False, farfield: bool = False,
                 regulation: str | None = None, extra_probes: np.ndarray | None = None,
                 plan: Plan | None = None, checkpoint: dict | None = None,
                 per_source: bool = False) -> None:
        if scene.wall is None:
            raise InputError("the scene has no measurement wall")
        lazy_target_setup()  # before the first kernel load: cache loads set up no compiler
        self.config = config or RunConfig()
        # the written map's directional fusion: None lets its figure decide (both maps are
        # made), True/False only that one (a caller that redraws the same scene's map can
        # keep the first map's choice, :attr:`last_map_fused`, and halve the cost; reset
        # by :meth:`update`)
        self.directional_map: bool | None = None
        self.last_map_fused = False
        self.scene = scene
        caster = None
        if not (workers or address):  # one embree scene for the pilot and the run
            caster = scene_caster(scene, threads=self.config.threads)
        self.plan = plan or make_plan(scene, self.config, camera=camera, farfield=farfield,
                                      regulation=regulation, caster=caster)
        if per_source:  # every emitter group's wall map too (lightsim.persource)
            self.plan = replace(self.plan, per_source=True)
        W, H = scene.wall.resolution
        if W < 1 or H < 1:
            raise InputError(f"resolution must be at least 1x1, got {W}x{H}")
        self.pattern = InterleavePattern(self.config.interleave, W, H)
        grid = probe_grid(scene.wall.h_range_m, scene.wall.v_range_m, self.config.probe_grid)
        extra = np.zeros((0, 2)) if extra_probes is None else np.asarray(extra_probes, float)
        self.grid_count = len(grid)
        self.probes_hv = np.vstack([grid, extra.reshape(-1, 2)])
        # the written map and its error figure from the sets' ICI rungs
        self.map_estimator = MapEstimator(self.config.ici_gamma, self.config.error_region,
                                          grid, self.config.probe_grid)
        self.backend: Backend
        if workers or address:  # as many actors as asked, or the cluster's CPUs
            cluster = connect(address, workers or 1)
            n_clients, notes = actor_count(cluster, workers, self.pattern.n_sets)
            scene.warnings.extend(notes)
            self.assignment = self.pattern.assign(n_clients)
            self.backend = RayBackend(scene, self.config, self.plan, self.assignment,
                                      self.probes_hv, cluster=cluster)
        else:
            self.assignment = self.pattern.assign(1)
            self.backend = LocalBackend(scene, self.config, self.plan, self.assignment,
                                        self.probes_hv, caster=caster)
        self.log: list[dict[str, Any]] = []
        self.shoot_totals = ShootTotals()
        # the memory check of open-ended runs (:meth:`memory_full`): only where the photon
        # maps live on this machine (a cluster's nodes have memories of their own)
        self.memory_checked = address is None
        self.memory_stop: MemoryStop | None = None  # set when a run stopped for memory
        self.memory_estimate: memory.MemoryEstimate | None = None  # simulate's pre-flight
        self.frame_records = 0  # photon records of the largest frame so far
        self.frames = 0
        self.partial: dict[int, int] = {}  # frame index → photons of a partial frame
        self._t0: float | None = None
        self._elapsed_before = 0.0
        self.last: FrameResult | None = None
        if checkpoint is not None:
            self._restore(checkpoint)

    # -- clock ---------------------------------------------------------------------------
    def start_clock(self) -> None:
        if self._t0 is None:
            self._t0 = time.perf_counter()

    @property
    def elapsed(self) -> float:
        return self._elapsed_before + (0.0 if self._t0 is None
                                       else time.perf_counter() - self._t0)

    # -- the steps of a frame -------------------------------------------------------------
    def shoot(self, photons: int | None = None) -> None:
        """Shoot → insert: every set shoots one frame of photons and adds them to its
        stores (``photons`` over all sets makes the frame partial)."""
        if photons is not None:
            self.partial[self.frames] = int(photons)
        records = 0
        for r in self.backend.shoot(photons):  # where the shooting time went (bench pipeline)
            self.shoot_totals.add(r)
            records += int(r.records)
        self.frame_records = max(self.frame_records, records)
        self.frames += 1

    def request(self, image: bool, mode: str = "interleaved", camera=None,
                probes: bool | str = True, image_step: int = 1) -> RenderRequest:
        """What a frame asks every set for: the binning estimator and ``pooled`` frames
        want every pixel of every set, ``interleaved`` frames each set's own pixels.
        ``probes``: True = probe estimates and what the error figure needs; ``"ici"`` =
        only the error figure's ICI rungs (no kNN probe queries); False = neither."""
        full = self.config.estimator == "bin" or mode == "pooled"
        return RenderRequest(image=image and not full, full_image=image and full,
                             probes=probes is True, error=probes is not False, camera=camera,
                             image_step=max(1, int(image_step)))

    def render(self, request: RenderRequest) -> SetFrames:
        """Every set's estimates for ``request`` (lx), keyed by set."""
        return SetFrames.gather(self.backend.render(request))

    def assemble(self, frames: SetFrames, timings: dict[str, float] | None = None,
                 camera=None, image_step: int = 1) -> FrameResult:
        """Estimate at probes → error → image: the server's half of a frame.

        The error figure is the written map's own where the frame made it (over every
        pixel); else, from every set's ICI rungs at the grid probes, the same figure there
        (:meth:`~lightsim.render.written_map.MapEstimator.error_at_probes`); else (kNN
        and binning) the probes' (:func:`~lightsim.render.frame.probe_error`)."""
        timings = {} if timings is None else timings
        t0 = time.perf_counter()
        emitted = self.emitted_per_set()
        wall = self.scene.wall
        lux, raw, rungs, error = self.image(frames, emitted, image_step)
        probe_rungs = frames.collect("probe_rungs")
        ici_figure = bool(probe_rungs) and len(probe_rungs) == len(emitted)  # every set's
        if error is None and ici_figure:
            error = self.map_estimator.error_at_probes(wall, probe_rungs,
                                                       frames.collect("moments"), emitted)
        cam_img = self.camera_image(frames, camera)
        timings["assemble"] = time.perf_counter() - t0
        probes = frames.collect("probes")
        stats = probe_stats(probes, frames.collect("window")) if probes else None
        if error is None and not ici_figure and stats is not None:
            error = probe_error(stats, self.grid_count,
                                restrict=self.map_estimator.grid_region(wall))
        n = sum(emitted.values())
        return FrameResult(lux, raw, stats, None if error is None else error.total, n,
                           self.elapsed, timings, camera=cam_img, error=error, rungs=rungs,
                           error_photons=n)

    def frame(self, image: bool = True, shoot: bool = True, camera=None,
              mode: str = "interleaved", photons: int | None = None,
              probes: bool | str = True, image_step: int = 1) -> FrameResult:
        """One frame: every client shoots (unless ``shoot`` is False) and renders.

        ``mode`` ``interleaved`` is the paper's frame (each set its own pixels, then the box
        filter); ``pooled`` asks every set for every pixel (the final, full-resolution lux
        map; M² times the queries). The binning estimator always pools. ``camera`` (a
        :class:`~lightsim.render.camera.PinholeCamera`) adds an interleaved luminance
        image (cd/m²) in ``FrameResult.camera``; the plan must include the camera pass.
        ``photons`` (over all sets) makes the frame partial, e.g. the last of a budget.
        ``probes=False`` skips the probe estimates (no error figure, ``probes`` None): an
        interaction frame that only draws the image (``lightsim view``); ``probes="ici"``
        (with the ICI bandwidth) only the rung sums the error figure needs, no kNN probe
        queries (``probes`` None). ``image_step`` > 1 renders the interleaved image at
        every ``image_step``-th pixel (⌈W/step⌉ × ⌈H/step⌉ over the same wall, step² times
        fewer queries: ``lightsim view``'s interaction frames).
        """
        if mode not in ("interleaved", "pooled"):
            raise ValueError(f"mode must be 'interleaved' or 'pooled', got {mode!r}")
        if camera is not None and not self.plan.camera:
            raise InputError("this session was planned without a camera view "
                             "(create it with camera=True)")
        self.start_clock()
        timings: dict[str, float] = {}
        if shoot:
            t0 = time.perf_counter()
            self.shoot(photons)
            timings["shoot"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        frames = self.render(self.request(image, mode, camera, probes, image_step))
        timings["render"] = time.perf_counter() - t1
        est = self.assemble(frames, timings, camera, image_step)
        self.last = est
        if shoot:
            self.log.append({**est.error_entry(), "frames": self.frames})
        return est

    def accumulate(self, batches: int = 1) -> None:
        """Shoot ``batches`` frames of photons into every set without estimating anything.

        Accumulation between displayed frames (``lightsim view``): the probe estimates
        and the error figure of :meth:`frame` are then paid once per displayed frame, not
        once per batch. Deterministic like :meth:`frame` (the same photons in the same
        order).
        """
        self.start_clock()
        for _ in range(max(0, int(batches))):
            self.shoot()

    def walkthrough(self, camera=None) -> FrameResult:
        """A frame without shooting: the camera/view may change, the photons stay."""
        return self.frame(image=True, shoot=False, camera=camera)

    # -- the server's half: images ------------------------------------------------------
    def image(self, frames: SetFrames, emitted: dict[int, int], image_step: int = 1
              ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None,
                         ErrorEstimate | None]:
        """The wall image of a frame: (lux, raw, ICI rungs, the written map's error figure
        over every pixel), each None if not rendered.

        Interleaved sub-images are scattered and box-filtered (the paper's frame); the
        written ICI map mixes each pixel's chosen rung with its count
        (:meth:`lightsim.render.written_map.MapEstimator.image`); pooled full images are
        averaged with the sets' photon counts as weights.
        """
        subs = frames.collect("sub_image")
        full_rungs = frames.collect("full_rungs")
        fulls = frames.collect("full_image")
        if subs:
            pattern = self.pattern
            if image_step > 1:  # the image at every image_step-th pixel
                W, H = self.scene.wall.resolution
                pattern = InterleavePattern(self.config.interleave, -(-W // image_step),
                                            -(-H // image_step))
            lux, raw = assemble_interleaved(pattern, subs, self.config.filter_n)
            return lux, raw, None, None
        if full_rungs:
            m = self.map_estimator.image(self.scene.wall, full_rungs, frames.collect("moments"),
                                         emitted, directional=self.directional_map)
            self.last_map_fused = m.fused
            return m.lux, m.lux, m.rung, m.error
        if fulls:
            lux = pool_full_images(fulls, emitted)
            return lux, lux, None, None
        return None, None, None, None

    def camera_image(self, frames: SetFrames, camera) -> np.ndarray | None:
        """The camera view's luminance (cd/m²), interleaved and box-filtered."""
        cams = frames.collect("camera")
        if camera is None or not cams:
            return None
        W, H = camera.resolution
        img, _ = assemble_interleaved(InterleavePattern(self.config.interleave, W, H), cams,
                                      self.config.filter_n)
        return img

    def probe(self, points_hv: np.ndarray) -> ProbeStats:
        """Estimates of every set at wall points (h, v in m): mean, standard error, values."""
        return probe_stats(self.backend.probe(np.asarray(points_hv, dtype=np.float64)))

    # -- interaction ---------------------------------------------------------------------
    def update(self, *, scene: Scene | None = None,
               material: tuple[str, dict[str, Any]] | None = None,
               part_transform: tuple[str, np.ndarray] | None = None,
               light_transform: np.ndarray | None = None,
               wall_transform: np.ndarray | None = None) -> None:
        """Interaction mode: change the scene and discard the accumulated photons.

        ``material=(part, {"ior": 1.55})`` or ``{"reflectance": 0.8}``/``{"albedo": …}``/
        ``{"sigma": …}`` changes a material; ``light_transform`` (4×4) moves every emitter —
        both keep the embree scene; ``wall_transform`` (4×4) moves the wall and its pixel
        frame (aiming the lamp by R is ``wall_transform=R⁻¹``; the wall lies outside the
        embree scene, which is kept); ``part_transform=(part, 4×4)`` moves a part and
        ``scene`` replaces everything (both rebuild it). Only the change travels to the
        clients (a whole scene goes to Ray's object store once).
        """
        changes: list[tuple] = []
        if scene is not None:
            changes.append(("scene", scene))
        if material is not None:
            changes.append(("material", material[0], dict(material[1])))
        if part_transform is not None:
            changes.append(("transform", part_transform[0], np.asarray(part_transform[1])))
        if light_transform is not None:
            changes.append(("light", np.asarray(light_transform)))
        if wall_transform is not None:
            changes.append(("wall", np.asarray(wall_transform)))
        self.scene, _ = apply_changes(self.scene, changes)  # validates before sending
        self.backend.apply(changes)
        self.frames = 0
        self.frame_records = 0
        self.partial = {}
        self.directional_map = None  # a new scene: its first map chooses again
        self.log.append({"event": "update", "seconds": self.elapsed})

    def guide(self, rects: np.ndarray, importance: np.ndarray | None = None) -> None:
        """Send photons towards wall apertures from the next frame on
        (:mod:`lightsim.engine.guiding`): ``rects`` (K, 4) H₀, H₁, V₀, V₁ in degrees,
        ``importance`` (K,) ≥ 0 (default 1; 0 = decided, draws no more photons). Replaces
        the targets; the photons are kept, and the history goes into checkpoints."""
        try:
            rows = target_rows(rects, importance, self.frames)
        except ValueError as exc:
            raise InputError(f"guide targets: {exc}") from None
        kept = tuple(r for r in run_targets(self.config) if r[0] < self.frames)
        self.config = self.config.with_(guide_targets=kept + rows)
        self.backend.apply([("guide", self.config.guide_targets)])

    # -- accounting ----------------------------------------------------------------------
    @property
    def radii_m(self) -> tuple[float, float]:
        """(min, max) density-estimation radius in use (m)."""
        return effective_radii(self.config, self.scene.wall)

    def per_source(self) -> PerSourceMaps | None:
        """Every emitter group's wall map after the photons so far (a run started with
        ``per_source=True``; None otherwise)."""
        parts = [p for p in self.backend.per_source() if p is not None]
        if not parts:
            return None
        power = np.sum([p[0] for p in parts], axis=0) if len(parts) > 1 else parts[0][0]
        square = np.sum([p[1] for p in parts], axis=0) if len(parts) > 1 else parts[0][1]
        sets = {s: sums for p in parts for s, sums in p[2].items()}
        return PerSourceMaps.from_sums(group_names(self.scene), power, square,
                                       self.photons_emitted(), self.scene.wall,
                                       all_on=self._binned_map(sets))

    def _binned_map(self, sets: dict[int, np.ndarray]) -> np.ndarray:
        """(H, W) float32 lx: the map a plain ``--estimator bin`` run of the same photons
        writes, from every set's pixel sums (H, W, C) by the same operations — each set's
        estimate at the pixel centres in float32, pooled with the sets' photon counts,
        luminous — so it equals that run's ``wall_lux.exr`` bit for bit."""
        frame = self.scene.wall
        emitted = self.emitted_per_set()
        dh, dv = frame.pixel_size_m
        h_all, v_all = frame.pixel_centres()
        hh, vv = np.meshgrid(h_all, v_all)
        h, v = frame.to_hv(frame.to_world(hh, vv).reshape(-1, 3))
        row, col = frame.pixel_index(h, v, clip=True)
        W, H = frame.resolution
        C = next(iter(sets.values())).shape[-1] if sets else 1
        fulls = {}
        for s in emitted:
            bins = sets.get(s)
            full = (np.zeros((H, W, C)) if emitted[s] == 0 or bins is None else
                    normalise_flux(bins[row, col], emitted[s], dh, dv).reshape(H, W, C))
            fulls[s] = full.astype(np.float32)  # as a set's frame travels (SetFrame.for_wire)
        return luminous(pool_full_images(fulls, emitted)).astype(np.float32)

    def emitted_per_set(self) -> dict[int, int]:
        """Photons each set has emitted, keyed by set."""
        return {s: st["emitted"] for s, st in self.backend.stats().items()}

    def photons_emitted(self) -> int:
        """Photons emitted over all sets."""
        return sum(self.emitted_per_set().values())

    def energy(self) -> dict[str, float]:
        """Energy bookkeeping in lm (luminous), summed over sets, normalised by photons."""
        stats = self.backend.stats()
        n = sum(st["emitted"] for st in stats.values())
        if n == 0:
            return {"emitted": 0.0, **{k: 0.0 for k in LEDGER}}
        ledger = sum(st["ledger"] for _, st in sorted(stats.items()))
        emitted = sum(st["emitted_power"] for _, st in sorted(stats.items()))
        out = {"emitted": float(normalise_flux(luminous(emitted[None, :])[0], n))}
        for i, k in enumerate(LEDGER):
            out[k] = float(normalise_flux(luminous(ledger[i][None, :])[0], n))
        return out

    def caustic_yield(self) -> float:
        stats = self.backend.stats()
        n = sum(st["emitted"] for st in stats.values())
        return sum(st["caustic"] for st in stats.values()) / n if n else 0.0

    # -- the batch loop ------------------------------------------------------------------
    def run(self, photons: int | None = None, seconds: float | None = None,
            target_error: float | None = None, min_frames: int = 3,
            callback: Callable[[FrameResult], None] | None = None,
            should_stop: Callable[[], bool] | None = None, probes: bool = True,
            rule: StoppingRule | None = None) -> FrameResult:
        """Shoot frames until a budget is met or the stopping rule is satisfied, then
        render the final image.

        Stops at whichever comes first: exactly ``photons`` emitted (total over sets; the
        last frame is partial, except with Selective Photon Tracing, whose passes are whole),
        ``seconds`` elapsed, or the stopping ``rule`` satisfied — by default, with a
        ``target_error``, :class:`MapErrorRule`: the estimated relative error ≤ the
        target at its confidence (the figure's upper bound at the look's z, after at
        least ``min_frames`` frames; :func:`stop_level`), first at the probes and then
        confirmed on the written map itself. With no budget at all, one
        frame is shot. Before every frame after the first the kept photons are measured
        against the memory (:meth:`memory_full`): a run that would outgrow it stops there
        with its final image, and :attr:`memory_stop` says so (None otherwise).
        ``probes=False`` leaves the probe estimates (``FrameResult.probes``) out of the
        final image when the caller does not read them (the error figure of an ICI map
        does not need them).

        The loop is the paper's, one frame at a time: shoot → insert (:meth:`shoot`),
        estimate at the probes or on the written map, the error figure and the stopping
        rule (:meth:`_estimate_and_judge`), and after the last frame the final image
        (:meth:`final_image`). The estimate runs on :class:`ErrorSchedule`'s photon
        counts, not every frame; frames that only shoot report to ``callback`` with the
        latest error (:meth:`progress`). The last frame of a budget goes straight to the
        final image. With a target, the estimate the error law places at the stop
        measures the written map itself (on a small wall, :meth:`map_check_is_cheap`,
        every estimate does), so the run stops on the figure it reports, near the target
        rather than below it.
        """
        if photons is None and seconds is None and target_error is None:
            photons = self.config.frame_photons
        if target_error is not None and not (0 < target_error < 1):
            raise InputError(f"target error must lie in (0, 1), got {target_error}")
        if rule is None and target_error is not None:
            rule = MapErrorRule(target_error, min_frames)
        self.start_clock()
        schedule = ErrorSchedule(target_error, map_is_cheap=self.map_check_is_cheap(),
                                 min_frames=min_frames,
                                 level=getattr(rule, "level", None))
        self.memory_stop = None
        budget = self.photon_budget()
        stop: FrameResult | None = None  # the written map the stopping rule accepted
        last_frame = False  # the budget is spent: the final image estimates everything
        while not (last_frame or stop is not None
                   or self.budget_spent(photons, seconds, should_stop)
                   or self.memory_full(budget)):  # memory_stop says so
            t0 = time.perf_counter()
            self.shoot(self.frame_photons(photons, schedule))  # shoot → insert
            timings = {"shoot": time.perf_counter() - t0}
            last_frame = self.budget_spent(photons, seconds)
            if not last_frame:  # estimate → error → stopping rule
                stop = self._estimate_and_judge(schedule, rule, timings, callback, probes)
        return stop if stop is not None else self.final_image(probes)

    def _estimate_and_judge(self, schedule: ErrorSchedule, rule: StoppingRule | None,
                            timings: dict[str, float],
                            callback: Callable[[FrameResult], None] | None,
                            probes: bool) -> FrameResult | None:
        """One frame's estimate, error figure and stopping rule in :meth:`run`: the
        written map when the rule lets the run stop here, else None.

        A frame the schedule does not estimate reports progress only. An estimate
        measures the probes, the written map (:meth:`ErrorSchedule.measure`) or both;
        its figure places the next estimate; a stop the probes propose is decided on the
        written map (every pixel, held-out blur), which is what the run delivers.
        """
        done = self.photons_emitted()
        if not schedule.due(done):
            if callback is not None:
                callback(self.progress(timings))
            return None

        def satisfied(est: FrameResult) -> bool:
            return rule is not None and rule.satisfied(est, self.frames)

        what = schedule.measure(self.frames)
        est = None if what == "map" else self.estimate_at_probes(timings)
        written = None if what == "probes" else self.final_image(probes)
        if what == "calibrate":
            schedule.calibrate(est, written)
        if est is not None:
            schedule.estimated(done, est)
        else:
            schedule.estimated(done, written, "map")
        if callback is not None:
            callback(written if written is not None else est)
        if written is None and satisfied(est):  # the probes propose, the map decides
            written = self.final_image(probes)
            schedule.estimated(done, written, "map")  # read only if the map refuses
        return written if written is not None and satisfied(written) else None

    def kept_photons(self) -> int:
        """Photon records the sets' maps keep now (0 for the ``bin`` estimator's bins; a
        point store's pool when no photon is kept)."""
        if self.config.estimator == "bin":
            return 0
        return sum(int(st.get("kept", 0)) for st in self.backend.stats().values())

    def photon_budget(self) -> float | None:
        """Bytes the photon maps may take in all (:func:`~lightsim.engine.memory.
        photon_budget`: this machine's available memory, capped by
        ``LIGHTSIM_MEMORY_LIMIT``, plus what the kept photons hold already, by the
        model); None where it is not checked (a cluster, the ``bin`` estimator, memory not
        known)."""
        if not self.memory_checked:
            return None
        avail = memory.available_bytes()
        if avail is not None:
            per = memory.stored_photon_bytes(self.plan.channels or 1, self.config.n_sets)
            avail += int(self.kept_photons() * per)
        return memory.photon_budget(self.scene.wall.resolution, self.config,
                                    self.plan.channels or 1, available=avail)

    def memory_full(self, budget: float | None) -> bool:
        """Whether another frame's photons (as many as the largest frame so far) would take
        the kept photons past ``budget`` bytes; sets :attr:`memory_stop` when so. The
        first frame always runs (``simulate`` checked one frame before it started), and
        every frame without a budget (None: :meth:`photon_budget` does not check)."""
        if budget is None or self.frames == 0:
            return False
        per = memory.kept_photon_bytes(self.plan.channels or 1, self.config.n_sets)
        kept = self.kept_photons()
        if (kept + self.frame_records) * per <= budget:
            return False
        self.memory_stop = MemoryStop(self.photons_emitted(), kept, kept * per, budget)
        return True

    def map_check_is_cheap(self) -> bool:
        """Whether the written map's own figure costs about what the probes' does: a
        wall of at most :data:`MAP_CHECK_PIXELS` × the grid probes (every set's rungs at
        every pixel instead of at the probes' pixels)."""
        W, H = self.scene.wall.resolution
        return W * H <= MAP_CHECK_PIXELS * max(self.grid_count, 1)

    def budget_spent(self, photons: int | None, seconds: float | None,
                     should_stop: Callable[[], bool] | None = None) -> bool:
        """Whether ``photons`` are emitted, ``seconds`` elapsed (after a frame) or the
        caller asks to stop."""
        if photons is not None and self.photons_emitted() >= photons:
            return True
        if seconds is not None and self.elapsed >= seconds and self.frames > 0:
            return True
        return should_stop is not None and should_stop()

    def frame_photons(self, photons: int | None,
                      schedule: ErrorSchedule | None = None) -> int | None:
        """Photons (over all sets) of the next frame: None for a whole frame; the rest of
        a ``photons`` budget when it is smaller; with a ``schedule`` that places a stop
        (``stop_expected``) inside the next frame, the photons up to it, at least
        :data:`MIN_PARTIAL` of a frame (the look lands where the error law puts the
        target, not up to a frame beyond it). An SPT pass is always whole."""
        if self.plan.spt:
            return None
        whole = self.config.photons_per_set * self.config.n_sets
        done = self.photons_emitted()
        n = whole
        if photons is not None:
            n = min(n, photons - done)
        if schedule is not None and schedule.stop_expected and self.frames > 0:
            to_stop = math.ceil(schedule.next_photons - done)
            if 0 < to_stop < n:
                n = max(to_stop, math.ceil(MIN_PARTIAL * whole))
        return n if n < whole else None

    def progress(self, timings: dict[str, float] | None = None) -> FrameResult:
        """A frame that estimated nothing: photons and time now, the error of the last
        estimate (at ``error_photons``)."""
        last = self.last
        return FrameResult(None, None, None, None if last is None else last.rel_error,
                           self.photons_emitted(), self.elapsed,
                           {} if timings is None else timings,
                           error=None if last is None else last.error,
                           error_photons=None if last is None else last.error_photons)

    def estimate_at_probes(self, timings: dict[str, float] | None = None) -> FrameResult:
        """Every set's estimates at the probe points and the error figure they give
        (no image); logged as a point of the error-vs-time curve."""
        timings = {} if timings is None else timings
        t0 = time.perf_counter()
        # the ICI figure reads the lattice windows at the grid probes, not the probes'
        # kNN estimates: those are left for the final image
        request = RenderRequest(probes=not self.config.uses_ici, error=True)
        frames = self.render(request)
        timings["render"] = time.perf_counter() - t0
        est = self.assemble(frames, timings)
        self.last = est
        self.log.append({**est.error_entry(), "frames": self.frames})
        return est

    def final_image(self, probes: bool = True) -> FrameResult:
        """The written map (``config.final``: pooled or interleaved) from every photon,
        with its error (and probe estimates, with ``probes`` or without ICI: the kNN and
        binning figures need them); logged unless the last log point is this one."""
        probes = probes or not self.config.uses_ici
        self.start_clock()
        t0 = time.perf_counter()
        frames = self.render(self.request(True, self.config.final, probes=probes))
        timings = {"render": time.perf_counter() - t0}
        final = self.assemble(frames, timings)
        self.last = final
        if self.frames and (not self.log or self.log[-1].get("photons") != final.photons):
            self.log.append({**final.error_entry(), "frames": self.frames})
        return final

    # -- checkpoints ---------------------------------------------------------------------
    def checkpoint(self) -> dict[str, Any]:
        """Everything needed to continue this run to the same result (see resume)."""
        return {"config": self.config.to_dict(), "frames": self.frames,
                "elapsed": self.elapsed, "log": list(self.log),
                "counters": self.backend.counters(),
                "partial": {str(k): v for k, v in self.partial.items()}}

    def _restore(self, ckpt: dict[str, Any]) -> None:
        self.partial = {int(k): int(v) for k, v in ckpt.get("partial", {}).items()}
        self.backend.replay(ckpt["counters"], self.partial)
        self.frames = int(ckpt["frames"])
        self.log = list(ckpt["log"])
        self._elapsed_before = float(ckpt["elapsed"])

    def close(self) -> None:
        self.backend.close()

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

