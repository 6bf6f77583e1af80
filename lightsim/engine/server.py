"""The server loop: plan, broadcast changes, run frames on the clients, assemble, log error.

A :class:`Session` is the Python API of lightsim (the CLI is a thin layer over it)::

    session = Session(scene, RunConfig(frame_photons=200_000))
    session.frame()                      # interaction mode: shoot + render
    session.update(material=("lens", {"ior": 1.55}))   # discards photons, next frame is immediate
    session.walkthrough()                # queries only (no shooting)
    result = session.run(photons=2_000_000, target_error=0.02)

Backends (``workers``): 0 → clients in this process; N ≥ 1 → N Ray actors on a local Ray
runtime; ``address`` → the same actors on an existing Ray cluster. Results are
bit-identical between backends for the same seed and photon count, because every set's
photons depend only on (seed, set, index) and the server combines sets in set order.

:meth:`Session.run` is the paper's loop in named steps: :meth:`~Session.shoot` (shoot →
insert), :meth:`~Session.estimate_at_probes` (estimates at the probes, the error figure),
:meth:`~Session.error_low_enough` (the stopping rule), :meth:`~Session.final_image`.

==================  =====  =======  ================================================
parameter           unit   default  meaning
==================  =====  =======  ================================================
``min_frames``      –      3        frames before a target error may stop a run
``growth``          –      2        photons between two error estimates grow ≤ this
``aim``             –      0.98     a target-error stop is aimed at this × the target
==================  =====  =======  ================================================

A target error stops the run on the error *figure* itself (``ErrorEstimate.total``, the
point estimate √(noise² + blur²), what the run reports), not on its upper bound: the
figure tracks the true error of the lit pixels closely, the bound sits 10–20 % above it
and stopped runs that far under the target. The bound still guards the stop: it may
exceed the target by at most :data:`UPPER_SLACK` (a blur the photons cannot resolve yet
keeps the run going). :func:`stop_level` is the one number both the rule and the
schedule read.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lightsim.engine.backend import Backend
from lightsim.engine.client import apply_changes
from lightsim.engine.config import RunConfig
from lightsim.engine.estimator import effective_radii, normalise_flux
from lightsim.engine.plan import Plan, make_plan
from lightsim.engine.results import (
    Estimate,
    FrameResult,
    MemoryStop,
    RenderRequest,
    SetFrames,
    ShootResult,
)
from lightsim.errors import InputError
from lightsim.render.frame import (
    ErrorEstimate,
    ProbeStats,
    assemble_interleaved,
    estimate_error,
    luminous,
    pool_full_images,
    probe_grid,
    probe_stats,
)
from lightsim.render.interleave import InterleavePattern
from lightsim.render.region import Restrict, restriction
from lightsim.scene import Scene
from lightsim.tracer import LEDGER

__all__ = ["Estimate", "FrameResult", "Session", "lux_channel"]


#: the error law's exponent p (e ∝ N^-p) fitted between two estimates is clamped to this
#: range: noise alone gives 0.5, an unresolved blur falls slower, a resolved one faster
EXPONENT_RANGE = (0.35, 1.0)
#: estimates the law is fitted to (the last ones of the same figure)
LAW_POINTS = 3
#: a target-error stop allows the figure's upper bound (blur + 2 s.e.) this × the target
UPPER_SLACK = 1.25
#: the stop is judged on the written map at every estimate when the wall has at most
#: this many pixels per grid probe (the map's figure then costs about the probes')
MAP_CHECK_PIXELS = 4


def stop_level(error: ErrorEstimate | None) -> float | None:
    """What a target-error stop compares with the target (a fraction): the error figure
    (``total``) or its upper bound over :data:`UPPER_SLACK`, whichever is larger; None
    without a figure. The run stops when this is ≤ the target: the figure at the target,
    its bound within ``UPPER_SLACK`` × the target."""
    if error is None:
        return None
    return max(error.total, error.upper / UPPER_SLACK)


@dataclass
class ErrorSchedule:
    """When the run loop estimates the error: the figure costs about as much as a frame
    of tracing, so it runs where it can change a decision, not every frame.

    Without a target error the estimates (the error-vs-time log) are spaced by a factor
    ``growth`` in photons. With one, the next estimate comes where the error law measured
    so far says the stop's level (:func:`stop_level`: the figure, its upper bound
    allowed :data:`UPPER_SLACK` × the target) reaches ``aim`` × target: e ∝ N^-p, with
    p fitted to the last estimates of the same figure (clamped to
    :data:`EXPONENT_RANGE`; 0.5, the noise's, with one estimate), at the frame nearest
    to that photon count (``due``), at most ``growth`` × N and at least the next frame.
    ``stop_expected`` says the next estimate is placed to stop the run (the loop then
    measures the written map itself there, see :meth:`Session.run`). The probes' figure
    can sit well above or below the written map's (on the shipped headlight ~2× above):
    :meth:`calibrate` measures their ratio once, and the probes' figure is scaled by it
    before the law places the stop. Deterministic: it depends on photons and estimates
    only, never on the clock.

    ==============  =====  =======  ==================================================
    parameter       unit   default  meaning
    ==============  =====  =======  ==================================================
    ``growth``      –      2        photons between two estimates grow ≤ this factor
    ``aim``         –      0.98     the stop is aimed at this fraction of the target
    ==============  =====  =======  ==================================================
    """

    target_error: float | None = None
    growth: float = 2.0
    aim: float = 0.98
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
            e = stop_level(est.error)
            if math.isfinite(e) and e > 0:
                self.history.setdefault(kind, []).append((photons, e))
                level = e * (self.probe_scale if kind == "probes" else 1.0)
                ratio = (level / (self.aim * self.target_error)) ** (1.0 / self.exponent(kind))
                factor = min(self.growth, ratio)
                self.stop_expected = ratio <= self.growth
            else:  # no usable figure (0 or not finite): look again after the next frame
                factor = 1.0
        self.next_photons = photons * max(1.0, factor)

    def calibrate(self, probes: FrameResult, written: FrameResult) -> None:
        """The ratio of the written map's figure to the probes' at the same photons
        (kept as ``probe_scale``; 1 when either has no usable figure)."""
        self.calibrated = True
        a, b = stop_level(probes.error), stop_level(written.error)
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
        0: in-process clients; N ≥ 1: N Ray actors.
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
                 plan: Plan | None = None, checkpoint: dict | None = None) -> None:
        if scene.wall is None:
            raise InputError("the scene has no measurement wall")
        from lightsim.engine.numba_start import lazy_target_setup

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
            from lightsim.tracer import scene_caster

            caster = scene_caster(scene, threads=self.config.threads)
        self.plan = plan or make_plan(scene, self.config, camera=camera, farfield=farfield,
                                      regulation=regulation, caster=caster)
        W, H = scene.wall.resolution
        if W < 1 or H < 1:
            raise InputError(f"resolution must be at least 1x1, got {W}x{H}")
        self.pattern = InterleavePattern(self.config.interleave, W, H)
        grid = probe_grid(scene.wall.h_range_m, scene.wall.v_range_m, self.config.probe_grid)
        extra = np.zeros((0, 2)) if extra_probes is None else np.asarray(extra_probes, float)
        self.grid_count = len(grid)
        self.probes_hv = np.vstack([grid, extra.reshape(-1, 2)])
        n_clients = max(1, workers) if (workers or address) else 1
        n_clients = min(n_clients, self.pattern.n_sets)
        self.assignment = self.pattern.assign(n_clients)
        self.backend: Backend
        if workers or address:
            from lightsim.engine.ray_backend import RayBackend

            self.backend = RayBackend(scene, self.config, self.plan, self.assignment,
                                      self.probes_hv, address=address)
        else:
            from lightsim.engine.local import LocalBackend

            self.backend = LocalBackend(scene, self.config, self.plan, self.assignment,
                                        self.probes_hv, caster=caster)
        self.log: list[dict[str, Any]] = []
        self.shoot_totals = ShootTotals()
        # the memory check of open-ended runs (:meth:`memory_full`): only where the photon
        # maps live on this machine (a cluster's nodes have memories of their own)
        self.memory_checked = address is None
        self.memory_stop: MemoryStop | None = None  # set when a run stopped for memory
        self.frame_records = 0  # photon records of the largest frame so far
        self.frames = 0
        self.partial: dict[int, int] = {}  # frame index → photons of a partial frame
        self._t0: float | None = None
        self._elapsed_before = 0.0
        self.last: FrameResult | None = None
        # the whole raster's ICI window areas, keyed by what they depend on (the wall's
        # pixels and the ladder's sides): made once, not once per written map
        self._raster_areas: tuple[tuple, np.ndarray, tuple[int, int] | None] | None = None
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
        """Estimate at probes → error → image: the server's half of a frame."""
        timings = {} if timings is None else timings
        t0 = time.perf_counter()
        emitted = self.emitted_per_set()
        lux, raw, rungs, map_error = self.image(frames, emitted, image_step)
        error = map_error if map_error is not None else self.ici_error(frames, emitted)
        cam_img = self.camera_image(frames, camera)
        timings["assemble"] = time.perf_counter() - t0
        probes = frames.collect("probes")
        stats = probe_stats(probes, frames.collect("window")) if probes else None
        if error is None and not self._has_ici_rungs(frames, emitted):
            error = (estimate_error(stats, self.grid_count, restrict=self._grid_region())
                     if stats is not None else None)
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

    # -- the server's half: error and images ----------------------------------------------
    def _has_ici_rungs(self, frames: SetFrames, emitted: dict[int, int]) -> bool:
        rungs = frames.collect("probe_rungs")
        return bool(rungs) and len(rungs) == len(emitted)

    def ici_error(self, frames: SetFrames, emitted: dict[int, int]) -> ErrorEstimate | None:
        """The written map's error figure from the ICI rungs at the grid probes (None
        without rungs from every set; see :meth:`_ici_error`)."""
        if not self._has_ici_rungs(frames, emitted):
            return None
        return self._ici_error(frames.collect("probe_rungs"), frames.collect("moments"),
                               emitted)

    def image(self, frames: SetFrames, emitted: dict[int, int], image_step: int = 1
              ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None,
                         ErrorEstimate | None]:
        """The wall image of a frame: (lux, raw, ICI rungs, the written map's error figure
        over every pixel), each None if not rendered.

        Interleaved sub-images are scattered and box-filtered (the paper's frame); the
        written ICI map mixes each pixel's chosen rung with its count
        (:func:`lightsim.render.ici.written_map`); pooled full images are averaged with
        the sets' photon counts as weights.
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
            lux, rungs, error = self._ici_image(full_rungs, frames.collect("moments"),
                                                emitted)
            return lux, lux, rungs, error
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

    def _ici_areas(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(J+1, Q) window areas (m²) of the ICI rungs at pixels (clipped to the wall)."""
        from lightsim.render import ici

        frame = self.scene.wall
        dh, dv = frame.pixel_size_m
        W, H = frame.resolution
        sides = ici.rung_sides((dh, dv), effective_radii(self.config, frame, "pooled")[1])
        return ici.window_cells(H, W, rows, cols, sides) * (0.25 * dh * dv)

    def raster_areas(self) -> tuple[np.ndarray, tuple[int, int] | None]:
        """(J+1, H·W) m²: :meth:`_ici_areas` at every pixel of the wall in row order
        (read-only), and the (H, W) :func:`ici.raster_shape` recognises in them (None on
        walls too small for it); made once per wall pixel grid and ladder."""
        from lightsim.render import ici

        frame = self.scene.wall
        W, H = frame.resolution
        key = (W, H, tuple(frame.pixel_size_m),
               effective_radii(self.config, frame, "pooled")[1])
        if self._raster_areas is None or self._raster_areas[0] != key:
            rows, cols = np.divmod(np.arange(H * W), W)
            areas = self._ici_areas(rows, cols)
            areas.flags.writeable = False
            self._raster_areas = (key, areas, ici.raster_shape(areas))
        return self._raster_areas[1], self._raster_areas[2]

    def _ici_rungs_now(self, n_rungs: int, moments: dict[int, np.ndarray]) -> int:
        """How many rungs the ladder has at the photons so far (:func:`ici.shrink_sides`)."""
        from lightsim.render import ici

        W, H = self.scene.wall.resolution
        return len(ici.shrink_sides(np.arange(1, n_rungs + 1),
                                    ici.wall_photons(moments) / (W * H)))

    def _ici_image(self, rungs: dict[int, np.ndarray], moments: dict[int, np.ndarray],
                   emitted: dict[int, int]
                   ) -> tuple[np.ndarray, np.ndarray, ErrorEstimate | None]:
        """The written map, every pixel at its rung (:func:`ici.written_map`), (H, W, C) lx,
        the rungs (H, W) and the map's error figure over every pixel."""
        from lightsim.render import ici

        first = next(iter(rungs.values()))
        J1, H, W, C = first.shape
        J1 = self._ici_rungs_now(J1, moments)
        flat = {s: np.asarray(v)[:J1].reshape(J1, H * W, C) for s, v in rungs.items()}
        areas, shape = self.raster_areas()  # shape: recognised once, not per map
        wm = ici.written_map(flat, emitted, ici.power_moment(moments),
                             areas, self.config.ici_gamma, shape=shape,
                             directional=self.directional_map,
                             restrict=self._pixel_region())
        self.last_map_fused = wm.fused
        return wm.lux.reshape(H, W, C), wm.choice.rung.reshape(H, W), wm.error

    def _ici_error(self, rungs: dict[int, np.ndarray], moments: dict[int, np.ndarray],
                   emitted: dict[int, int]) -> ErrorEstimate | None:
        """The error figure of the written map from the pixels under the grid probes (the
        frames between images; the image itself is measured over every pixel)."""
        from lightsim.render import ici

        grid = self.probes_hv[:self.grid_count]
        rows, cols = ici.pixel_of(self.scene.wall, grid[:, 0], grid[:, 1])
        J1 = self._ici_rungs_now(next(iter(rungs.values())).shape[0], moments)
        rungs = {s: np.asarray(v)[:J1] for s, v in rungs.items()}
        return ici.written_map(rungs, emitted, ici.power_moment(moments),
                               self._ici_areas(rows, cols), self.config.ici_gamma,
                               restrict=self._grid_region()).error

    def _pixel_region(self) -> Restrict | None:
        """The error figure's region (``config.error_region``) over the wall's pixels
        (None for ``lit``)."""
        W, H = self.scene.wall.resolution
        dh, dv = self.scene.wall.pixel_size_m
        return restriction(self.config.error_region, (H, W), (dv, dh))

    def _grid_region(self) -> Restrict | None:
        """The error figure's region over the grid probes (:func:`probe_grid`: a regular
        raster of cell centres over the wall, in row order; None for ``lit``)."""
        wall = self.scene.wall
        nh, nv = self.config.probe_grid
        cell = (float(np.ptp(wall.v_range_m)) / nv, float(np.ptp(wall.h_range_m)) / nh)
        return restriction(self.config.error_region, (nv, nh), cell)

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

    # -- accounting ----------------------------------------------------------------------
    @property
    def radii_m(self) -> tuple[float, float]:
        """(min, max) density-estimation radius in use (m)."""
        return effective_radii(self.config, self.scene.wall)

    def emitted_per_set(self) -> dict[int, int]:
        return {s: st["emitted"] for s, st in self.backend.stats().items()}

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
            should_stop: Callable[[], bool] | None = None, probes: bool = True
            ) -> FrameResult:
        """Shoot frames until a budget is met, then render the final image.

        Stops at whichever comes first: exactly ``photons`` emitted (total over sets; the
        last frame is partial, except with Selective Photon Tracing, whose passes are whole),
        ``seconds`` elapsed, or the estimated relative error ≤ ``target_error`` — the
        figure itself, with its upper bound (blur + 2 s.e.) at most :data:`UPPER_SLACK` ×
        the target, so an unresolved blur cannot stop a run early (after at least
        ``min_frames`` frames; :func:`stop_level`), first at the probes and then
        confirmed on the written map itself. With no budget at all, one frame is shot.
        Before every frame after the first the kept photons are measured against the
        memory (:meth:`memory_full`): a run that would outgrow it stops there with its
        final image, and :attr:`memory_stop` says so (None otherwise).
        ``probes=False`` leaves the probe estimates (``FrameResult.probes``) out of the
        final image when the caller does not read them (the error figure of an ICI map
        does not need them).

        The loop is the paper's: shoot → insert (:meth:`shoot`), estimate at the probes
        and the error (:meth:`estimate_at_probes`), the stopping rule
        (:meth:`error_low_enough`), and after it the final image (:meth:`final_image`).
        The estimate runs on :class:`ErrorSchedule`'s photon counts, not every frame;
        frames that only shoot report to ``callback`` with the latest error
        (:meth:`progress`). The last frame goes straight to the final image. With a
        target, the estimate the error law places at the stop measures the written map
        itself (on a small wall, :meth:`map_check_is_cheap`, every estimate does), so the
        run stops on the figure it reports, near the target rather than below it.
        """
        if photons is None and seconds is None and target_error is None:
            photons = self.config.frame_photons
        if target_error is not None and not (0 < target_error < 1):
            raise InputError(f"target error must lie in (0, 1), got {target_error}")
        self.start_clock()
        schedule = ErrorSchedule(target_error)
        cheap_map = self.map_check_is_cheap()
        self.memory_stop = None
        budget = self.photon_budget()
        while not self.budget_spent(photons, seconds, should_stop):
            if budget is not None and self.memory_full(budget):
                break  # the final image of the photons kept so far, and memory_stop says so
            t0 = time.perf_counter()
            self.shoot(self.frame_photons(photons))
            timings = {"shoot": time.perf_counter() - t0}
            if self.budget_spent(photons, seconds):
                break  # the final image estimates everything once more
            done = sum(self.emitted_per_set().values())
            if not schedule.due(done):
                if callback is not None:
                    callback(self.progress(timings))
                continue
            if target_error is not None and (cheap_map or schedule.stop_expected):
                # where the law places the stop (or always, when the written map costs
                # about what the probes' figure does) the written map itself is measured:
                # its figure is what the run reports, the probes' would miss its level
                final = self.final_image(probes)
                schedule.estimated(done, final, "map")
                if callback is not None:
                    callback(final)
                if self.error_low_enough(final, target_error, min_frames):
                    return final
                continue
            est = self.estimate_at_probes(timings)
            if (target_error is not None and not schedule.calibrated
                    and self.frames >= min_frames):
                # once: how the written map's figure stands to the probes' (the map is
                # what the run reports; the probes' figure alone may sit 2× off it)
                final = self.final_image(probes)
                schedule.calibrate(est, final)
                schedule.estimated(done, est)
                if callback is not None:
                    callback(final)
                if self.error_low_enough(final, target_error, min_frames):
                    return final
                continue
            schedule.estimated(done, est)
            if callback is not None:
                callback(est)
            if self.error_low_enough(est, target_error, min_frames):
                # The frame's figure comes from the grid probes; the written map (every
                # pixel, held-out blur) is what the run delivers, so it has the last word.
                final = self.final_image(probes)
                if self.error_low_enough(final, target_error, min_frames):
                    return final
                schedule.estimated(done, final, "map")
        return self.final_image(probes)

    def kept_photons(self) -> int:
        """Photon records the sets' maps keep (0 for the ``bin`` estimator's bins)."""
        if self.config.estimator == "bin":
            return 0
        return sum(int(st.get("records", 0)) for st in self.backend.stats().values())

    def photon_budget(self) -> float | None:
        """Bytes the photon maps may take in all (:func:`~lightsim.engine.memory.
        photon_budget`: this machine's available memory, capped by
        ``LIGHTSIM_MEMORY_LIMIT``, plus what the kept photons hold already, by the
        model); None where it is not checked (a cluster, the ``bin`` estimator, memory not
        known)."""
        from lightsim.engine.memory import available_bytes, photon_budget, stored_photon_bytes

        if not self.memory_checked:
            return None
        avail = available_bytes()
        if avail is not None:
            per = stored_photon_bytes(self.plan.channels or 1, self.config.n_sets)
            avail += int(self.kept_photons() * per)
        return photon_budget(self.scene.wall.resolution, self.config,
                             self.plan.channels or 1, available=avail)

    def memory_full(self, budget: float) -> bool:
        """Whether another frame's photons (as many as the largest frame so far) would take
        the kept photons past ``budget`` bytes; sets :attr:`memory_stop` when so. The
        first frame always runs (``simulate`` checked one frame before it started)."""
        from lightsim.engine.memory import kept_photon_bytes

        if self.frames == 0:
            return False
        per = kept_photon_bytes(self.plan.channels or 1, self.config.n_sets)
        kept = self.kept_photons()
        if (kept + self.frame_records) * per <= budget:
            return False
        self.memory_stop = MemoryStop(sum(self.emitted_per_set().values()), kept, kept * per,
                                      budget)
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
        if photons is not None and sum(self.emitted_per_set().values()) >= photons:
            return True
        if seconds is not None and self.elapsed >= seconds and self.frames > 0:
            return True
        return should_stop is not None and should_stop()

    def frame_photons(self, photons: int | None) -> int | None:
        """Photons (over all sets) of the next frame: None for a whole frame; the rest of
        a ``photons`` budget when it is smaller (an SPT pass is always whole)."""
        if photons is None or self.plan.spt:
            return None
        rest = photons - sum(self.emitted_per_set().values())
        return rest if rest < self.config.photons_per_set * self.config.n_sets else None

    def progress(self, timings: dict[str, float] | None = None) -> FrameResult:
        """A frame that estimated nothing: photons and time now, the error of the last
        estimate (at ``error_photons``)."""
        last = self.last
        return FrameResult(None, None, None, None if last is None else last.rel_error,
                           sum(self.emitted_per_set().values()), self.elapsed,
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

    def error_low_enough(self, est: FrameResult, target_error: float | None,
                         min_frames: int) -> bool:
        """The stopping rule: :func:`stop_level` (the error figure; its upper bound
        allowed :data:`UPPER_SLACK` × the target) is at most ``target_error`` after at
        least ``min_frames`` frames."""
        if target_error is None or est.error is None:
            return False
        return self.frames >= min_frames and stop_level(est.error) <= target_error

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


def lux_channel(lux: np.ndarray) -> np.ndarray:
    """(H, W, C) → (H, W) luminous illuminance (lx)."""
    return luminous(lux)

