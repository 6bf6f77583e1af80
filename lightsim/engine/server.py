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
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lightsim.engine.client import apply_changes
from lightsim.engine.config import RunConfig
from lightsim.engine.plan import Plan, make_plan
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
from lightsim.scene import Scene
from lightsim.tracer import LEDGER


@dataclass
class Estimate:
    """What the server knows after a frame.

    Attributes
    ----------
    lux : (H, W, C) float64 or None
        Filtered illuminance image (lx), if an image was rendered.
    raw : (H, W, C) float64 or None
        The assembled image before filtering.
    probes : ProbeStats
    rel_error : float or None
        Estimated relative error over the lit region: √(noise² + blur bias²) (see
        :mod:`lightsim.render.frame`); None when it cannot be estimated.
    photons : int
        Photons emitted over all sets so far.
    seconds : float
        Time since the session's clock started (s).
    """

    lux: np.ndarray | None
    raw: np.ndarray | None
    probes: ProbeStats | None
    rel_error: float | None
    photons: int
    seconds: float
    timings: dict[str, float] = field(default_factory=dict)
    camera: np.ndarray | None = None  # (H, W, C) luminance, cd/m², with a camera view
    error: ErrorEstimate | None = None  # rel_error's parts: noise and blur bias
    rungs: np.ndarray | None = None  # (H, W) ICI rung of every written pixel (0 = the pixel)

    def error_entry(self) -> dict[str, Any]:
        """The error-vs-time log entry of this estimate (fractions, s)."""
        e = self.error
        return {"seconds": self.seconds, "photons": self.photons, "rel_error": self.rel_error,
                "rel_noise": None if e is None else e.noise,
                "rel_bias": None if e is None else e.bias,
                "rel_bias_upper": None if e is None else e.bias_upper}


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
        self.config = config or RunConfig()
        self.scene = scene
        self.plan = plan or make_plan(scene, self.config, camera=camera, farfield=farfield,
                                      regulation=regulation)
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
        if workers or address:
            from lightsim.engine.ray_backend import RayBackend

            self.backend = RayBackend(scene, self.config, self.plan, self.assignment,
                                      self.probes_hv, address=address)
        else:
            from lightsim.engine.local import LocalBackend

            self.backend = LocalBackend(scene, self.config, self.plan, self.assignment,
                                        self.probes_hv)
        self.log: list[dict[str, Any]] = []
        self.frames = 0
        self.partial: dict[int, int] = {}  # frame index → photons of a partial frame
        self._t0: float | None = None
        self._elapsed_before = 0.0
        self.last: Estimate | None = None
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

    # -- frames --------------------------------------------------------------------------
    def frame(self, image: bool = True, shoot: bool = True, camera=None,
              mode: str = "interleaved", photons: int | None = None) -> Estimate:
        """One frame: every client shoots (unless ``shoot`` is False) and renders.

        ``mode`` ``interleaved`` is the paper's frame (each set its own pixels, then the box
        filter); ``pooled`` asks every set for every pixel (the final, full-resolution lux
        map; M² times the queries). The binning estimator always pools. ``camera`` (a
        :class:`~lightsim.render.camera.PinholeCamera`) adds an interleaved luminance
        image (cd/m²) in ``Estimate.camera``; the plan must include the camera pass.
        ``photons`` (over all sets) makes the frame partial, e.g. the last of a budget.
        """
        if mode not in ("interleaved", "pooled"):
            raise ValueError(f"mode must be 'interleaved' or 'pooled', got {mode!r}")
        if camera is not None and not self.plan.camera:
            raise InputError("this session was planned without a camera view "
                             "(create it with camera=True)")
        self.start_clock()
        t0 = time.perf_counter()
        timings: dict[str, float] = {}
        if shoot:
            if photons is not None:
                self.partial[self.frames] = int(photons)
            self.backend.shoot(photons)
            timings["shoot"] = time.perf_counter() - t0
            self.frames += 1
        t1 = time.perf_counter()
        full = self.config.estimator == "bin" or mode == "pooled"
        results = self.backend.render(image=image and not full, probes=True,
                                      full_image=image and full, camera=camera)
        timings["render"] = time.perf_counter() - t1
        est = self._combine(results, image, timings, camera)
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
            self.backend.shoot()
            self.frames += 1

    def walkthrough(self, camera=None) -> Estimate:
        """A frame without shooting: the camera/view may change, the photons stay."""
        return self.frame(image=True, shoot=False, camera=camera)

    def _combine(self, results: list[dict[str, Any]], image: bool,
                 timings: dict[str, float], camera=None) -> Estimate:
        probes: dict[int, np.ndarray] = {}
        subs: dict[int, np.ndarray] = {}
        fulls: dict[int, np.ndarray] = {}
        cams: dict[int, np.ndarray] = {}
        full_rungs: dict[int, np.ndarray] = {}
        probe_rungs: dict[int, np.ndarray] = {}
        moments: dict[int, np.ndarray] = {}
        for r in results:
            probes.update(r["probes"])
            subs.update(r["sub_images"])
            fulls.update(r["full_images"])
            cams.update(r.get("camera_sub_images", {}))
            full_rungs.update(r.get("full_rungs", {}))
            probe_rungs.update(r.get("probe_rungs", {}))
            moments.update(r.get("moments", {}))
        t2 = time.perf_counter()
        emitted = self.emitted_per_set()
        ici_err = None
        lux = raw = rung_map = None
        if image and full_rungs and not subs:  # the written map; its figure over every pixel
            lux, rung_map, ici_err = self._ici_image(full_rungs, moments, emitted)
            raw = lux
        elif probe_rungs and len(probe_rungs) == len(emitted):
            ici_err = self._ici_error(probe_rungs, moments, emitted)
        if image and subs:
            lux, raw = assemble_interleaved(self.pattern, subs, self.config.filter_n)
        elif image and fulls:
            lux = raw = pool_full_images(fulls, emitted)
        cam_img = None
        if camera is not None and cams:
            W, H = camera.resolution
            cam_img, _ = assemble_interleaved(
                InterleavePattern(self.config.interleave, W, H), cams, self.config.filter_n)
        timings["assemble"] = time.perf_counter() - t2
        windows: dict[int, np.ndarray] = {}
        for r in results:
            windows.update(r.get("windows", {}))
        stats = probe_stats(probes, windows) if probes else None
        if probe_rungs and len(probe_rungs) == len(emitted):
            err = ici_err
        else:
            err = estimate_error(stats, self.grid_count) if stats is not None else None
        return Estimate(lux, raw, stats, None if err is None else err.total,
                        sum(emitted.values()), self.elapsed, timings, camera=cam_img,
                        error=err, rungs=rung_map)

    def _ici_areas(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(J+1, Q) window areas (m²) of the ICI rungs at pixels (clipped to the wall)."""
        from lightsim.engine.client import effective_radii
        from lightsim.render import ici

        frame = self.scene.wall
        dh, dv = frame.pixel_size_m
        W, H = frame.resolution
        sides = ici.rung_sides((dh, dv), effective_radii(self.config, frame, "pooled")[1])
        return ici.window_cells(H, W, rows, cols, sides) * (0.25 * dh * dv)

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
        rows, cols = np.divmod(np.arange(H * W), W)
        wm = ici.written_map(flat, emitted, ici.power_moment(moments),
                             self._ici_areas(rows, cols), self.config.ici_gamma)
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
                               self._ici_areas(rows, cols), self.config.ici_gamma).error

    def probe(self, points_hv: np.ndarray) -> ProbeStats:
        """Estimates of every set at wall points (h, v in m): mean, standard error, values."""
        return probe_stats(self.backend.probe(np.asarray(points_hv, dtype=np.float64)))

    # -- interaction ---------------------------------------------------------------------
    def update(self, *, scene: Scene | None = None,
               material: tuple[str, dict[str, Any]] | None = None,
               part_transform: tuple[str, np.ndarray] | None = None,
               light_transform: np.ndarray | None = None) -> None:
        """Interaction mode: change the scene and discard the accumulated photons.

        ``material=(part, {"ior": 1.55})`` or ``{"reflectance": 0.8}``/``{"albedo": …}``/
        ``{"sigma": …}`` changes a material; ``light_transform`` (4×4) moves every emitter —
        both keep the embree scene; ``part_transform=(part, 4×4)`` moves a part and
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
        self.scene, _ = apply_changes(self.scene, changes)  # validates before sending
        self.backend.apply(changes)
        self.frames = 0
        self.partial = {}
        self.log.append({"event": "update", "seconds": self.elapsed})

    # -- accounting ----------------------------------------------------------------------
    @property
    def radii_m(self) -> tuple[float, float]:
        """(min, max) density-estimation radius in use (m)."""
        from lightsim.engine.client import effective_radii

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
        out = {"emitted": float(luminous(emitted[None, :])[0] / n)}
        for i, k in enumerate(LEDGER):
            out[k] = float(luminous(ledger[i][None, :])[0] / n)
        return out

    def caustic_yield(self) -> float:
        stats = self.backend.stats()
        n = sum(st["emitted"] for st in stats.values())
        return sum(st["caustic"] for st in stats.values()) / n if n else 0.0

    # -- the batch loop ------------------------------------------------------------------
    def run(self, photons: int | None = None, seconds: float | None = None,
            target_error: float | None = None, min_frames: int = 3,
            callback: Callable[[Estimate], None] | None = None,
            should_stop: Callable[[], bool] | None = None) -> Estimate:
        """Shoot frames until a budget is met, then render the final image.

        Stops at whichever comes first: exactly ``photons`` emitted (total over sets; the
        last frame is partial, except with Selective Photon Tracing, whose passes are whole),
        ``seconds`` elapsed, or the estimated relative error ≤ ``target_error`` — with the
        blur at its upper bound, so an unresolved blur cannot stop a run early (after at
        least ``min_frames`` frames). With no budget at all, one frame is shot.
        """
        if photons is None and seconds is None and target_error is None:
            photons = self.config.frame_photons
        if target_error is not None and not (0 < target_error < 1):
            raise InputError(f"target error must lie in (0, 1), got {target_error}")
        self.start_clock()
        while True:
            done = sum(self.emitted_per_set().values())
            if photons is not None and done >= photons:
                break
            if seconds is not None and self.elapsed >= seconds and self.frames > 0:
                break
            if should_stop is not None and should_stop():
                break
            rest = None if photons is None else photons - done
            full = self.config.photons_per_set * self.config.n_sets
            partial = rest if rest is not None and rest < full and not self.plan.spt else None
            est = self.frame(image=False, photons=partial)
            if callback is not None:
                callback(est)
            if (target_error is not None and est.error is not None
                    and self.frames >= min_frames and est.error.upper <= target_error):
                break
        final = self.frame(image=True, shoot=False, mode=self.config.final)
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


def finite_or_none(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)
