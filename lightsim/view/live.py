"""The session thread of ``lightsim view``: the paper's interaction and accumulation modes.

One thread owns the engine :class:`~lightsim.engine.server.Session` (the engine is not
thread-safe and need not be). The web app only *submits* edits; edits that arrive while a
frame is computed are coalesced (the latest controls win), so a dragged slider never
builds a queue.

* **Interaction** (paper section 4.1): an edit → ``Session.update`` discards the photons;
  the next frame shoots a new batch (the first one after an edit at most
  ``quick_photons``), renders the interleaved image and box-filters it — and nothing
  else: no probes, no error figure, no regulation (``Session.frame(probes=False)``).
* **Accumulation** (the paper's walkthrough with a still scene): no edit → photon batches
  are added to the maps (``Session.accumulate``) for ``step_seconds``, then one estimate
  gives the error figure and, at most every ``image_interval`` seconds, the interleaved
  image; once the error figure is ≤ ``pooled_error`` the
  pooled full-resolution map (the written result) is drawn, again each time the photon
  count has doubled; from then on only pooled maps are drawn.
* The error figure and photon count are published every step; the regulation table once
  the scene is still, at most every ``regulation_interval`` seconds (its ~10³ probes per
  set cost about a frame's queries).
* Nothing is lost: every applied edit is appended to ``edits.jsonl`` (flushed and
  fsynced) and the current controls to ``state.json`` (atomic) in the session folder;
  ``lightsim view --state FILE`` restores them.

=========================  =====  =======  ==================================================
parameter                  unit   default  meaning
=========================  =====  =======  ==================================================
``step_seconds``           s      0.5      accumulation: photon batches shot between two
                                           estimates (error figure, image)
``image_interval``         s      0.5      accumulation: redraw the interleaved image at most
                                           this often (and ≤ 1/4 of the time)
``pooled_error``           –      0.05     error figure that triggers the first pooled map
``pooled_after``           s      ∞        … or still this long; then each 2× photons (a
                                           pooled map of few photons is noisier than the
                                           filtered frame, hence no time trigger by
                                           default)
``regulation_interval``    s      1.0      regulation table refresh once the scene is still
                                           (and ≤ 1/5 of the time)
``stop_error``             –      0.005    accumulation stops (idles) at this error figure
``max_photons``            –      2·10⁸    … or at this many photons
``camera``                 –      none     :class:`~lightsim.render.camera.PinholeCamera` of
                                           the second tab (rendered while a tab shows it)
``quick_photons``          –      20 000   photons of the first frame after an edit (at most
                                           the frame's photons): the low-quality frame
``estimate_share``         –      0.2      accumulation: the estimates (error figure,
                                           image) take at most this share of the time; the
                                           rest traces photons
``settle_seconds``         s      0.25     after an interaction frame, wait this long for the
                                           next edit before accumulating (an edit then
                                           need not wait for a batch in progress)
``warm_up``                –      True     run every code path once before ``ready`` is
                                           set (numba kernels compiled, no edit JITs)
``threads``                –      auto     numba threads of the session thread; auto = the
                                           warm-up times interaction frames and
                                           accumulation batches at 1 and at all threads
                                           and keeps the faster for each (on an
                                           oversubscribed machine the parallel kernels'
                                           barriers cost more than the second core gives)
=========================  =====  =======  ==================================================
"""

from __future__ import annotations

import json
import math
import os
import shutil
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.errors import LightsimError
from lightsim.render.frame import luminous
from lightsim.scene import Scene
from lightsim.view.controls import CONFIG_CONTROLS, POSE_CONTROLS, Controls
from lightsim.view.editor import SceneEditor
from lightsim.view.encode import encode_image


@dataclass
class RegulationTable:
    """What the page shows of a rule set: rows and the points to draw.

    ``rows``: name, kind, limit, value (cd), interval (cd), verdict; ``points``: name,
    h_deg, v_deg, verdict (test points drawn on the pattern).
    """

    title: str
    rows: list[dict[str, Any]]
    points: list[dict[str, Any]]
    unevaluated: int = 0


RegulationHook = Callable[[Any], RegulationTable]
SaveHook = Callable[[Path, Any, Any, Controls, Scene], list[str]]
Publish = Callable[[str, Any], None]


@dataclass
class LiveStats:
    """Counters the page and the benchmark read (seconds, frames)."""

    frames: int = 0
    interaction_frames: int = 0
    images: int = 0
    edits_applied: int = 0
    edits_coalesced: int = 0
    last_frame_s: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    # the last frames: mode, seconds of shoot/render/assemble/encode, bytes sent
    log: deque = field(default_factory=lambda: deque(maxlen=500))


class LiveSession:
    """The session thread (see the module docstring).

    Parameters
    ----------
    editor : SceneEditor
    make_session : callable (Scene, RunConfig) → Session
        Builds the engine session (in-process or Ray; injected by the CLI).
    config : RunConfig
        Base run configuration; k, M and photons per frame come from the controls.
    publish : callable (kind, payload)
        ``("frame:wall" | "frame:camera", bytes)``, ``("status", dict)``, ``("regulation", dict)``,
        ``("message", dict)``; called from this thread.
    regulation : callable (session) → RegulationTable, optional
    save_run : callable (folder, session, estimate, controls, scene) → file names, optional
    folder : Path, optional
        Session folder (edit log, state, saved runs); None: nothing is written.
    """

    def __init__(self, editor: SceneEditor, make_session: Callable[[Scene, RunConfig], Any],
                 config: RunConfig, publish: Publish, *, controls: Controls | None = None,
                 regulation: RegulationHook | None = None, save_run: SaveHook | None = None,
                 folder: Path | None = None, camera: Any = None,
                 image_interval: float = 0.5, pooled_after: float = math.inf,
                 pooled_error: float = 0.05, step_seconds: float = 0.5,
                 regulation_interval: float = 1.0, stop_error: float = 0.005,
                 max_photons: int = 200_000_000, quick_photons: int = 20_000,
                 estimate_share: float = 0.2, warm_up: bool = True,
                 threads: int | str = "auto", settle_seconds: float = 0.25) -> None:
        self.editor = editor
        self.make_session = make_session
        self.base_config = config
        self.publish = publish
        self.regulation_hook = regulation
        self.save_hook = save_run
        self.folder = Path(folder) if folder is not None else None
        self.camera = camera
        self.camera_watchers = 0  # set by the app: tabs showing the camera view
        self.image_interval = image_interval
        self.pooled_after = pooled_after
        self.pooled_error = pooled_error
        self.step_seconds = step_seconds
        self._image_every = image_interval
        self._reg_cost = 0.0
        self._update_s = 0.0
        self.regulation_interval = regulation_interval
        self.stop_error = stop_error
        self.max_photons = max_photons
        self.quick_photons = int(quick_photons)
        self.estimate_share = float(estimate_share)
        self.warm_up = bool(warm_up)
        self.settle_seconds = float(settle_seconds)
        self._interaction_done = 0.0  # end of the last interaction frame
        if threads != "auto" and (not isinstance(threads, int) or threads < 1):
            raise LightsimError(f"threads must be 'auto' or ≥ 1, got {threads!r}")
        self.threads = threads
        self.thread_times: dict[int, float] = {}  # warm-up: threads → frame seconds
        self.accumulate_times: dict[int, float] = {}  # … → seconds of one batch
        self.frame_threads = self.accumulate_threads = None
        self._est_cost = 0.0  # seconds of the last accumulation estimate
        self._quick_due = False  # the next frame is the first after an edit
        self.ready = threading.Event()  # set once warmed up (or failed)
        self.controls = controls or editor.defaults()
        self.stats = LiveStats()
        self._lock = threading.Lock()
        self._pending: tuple[Controls, dict[str, Any]] | None = None
        self._pending_scene: tuple[SceneEditor, Controls] | None = None
        self._save_requests: list[dict[str, Any]] = []
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self.session = None
        self.edit = 0  # id of the latest applied edit (frames carry it)
        self.token: dict[str, Any] = {}
        self.mode = "interaction"
        self._changed_at = time.perf_counter()
        self._last_image = 0.0
        self._last_camera = 0.0
        self._last_reg = 0.0
        self._pooled_photons = 0
        self.last_status: dict[str, Any] = {}
        self.error: str | None = None
        if self.folder is not None:
            self.folder.mkdir(parents=True, exist_ok=True)

    # -- called from the web app (any thread) ------------------------------------------
    def submit(self, changes: dict[str, Any], token: dict[str, Any] | None = None) -> Controls:
        """Validate ``changes`` against the latest controls and queue them.

        Raises :class:`~lightsim.errors.InputError` (shown on the page) and leaves the
        session untouched when a value is bad.
        """
        with self._lock:
            current = self._pending[0] if self._pending else self.controls
            new = current.with_changes(changes, self.editor.bulb_names())
            if "bulb" in changes and "flux_lm" not in changes and new.bulb in self.editor.bulbs:
                new = new.with_changes({"flux_lm": self.editor.bulbs[new.bulb].flux_lm})
            if self._pending is not None:
                self.stats.edits_coalesced += 1
                merged = {**self._pending[1], **changes}
            else:
                merged = dict(changes)
            self._pending = (new, {"changes": merged, "token": token or {}})
        self._wake.set()
        return new

    def replace_scene(self, scene: Scene) -> None:
        """A new base scene (an upload): controls reset to the new scene's."""
        editor = SceneEditor(scene, self.editor.bulbs)
        with self._lock:
            self._pending_scene = (editor, editor.defaults())
            self._pending = None
        self._wake.set()

    def request_save(self, reply: Callable[[dict[str, Any]], None] | None = None) -> None:
        with self._lock:
            self._save_requests.append({"reply": reply})
        self._wake.set()

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="lightsim-view", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 30.0) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
        if self.session is not None:
            self.session.close()
            self.session = None

    # -- the thread --------------------------------------------------------------------
    def _run(self) -> None:
        try:
            self._open(self.editor.build(self.controls), self.controls)
        except LightsimError as exc:
            self.error = str(exc)
            self._message("error", f"cannot start the session: {exc}")
            self.ready.set()
            return
        try:
            if self.warm_up:
                self._warm()
            elif self.threads != "auto":
                self._choose_threads()
        finally:
            self.ready.set()
        self._autosave({"start": True})
        while not self._stop.is_set():
            try:
                self._step()
            except LightsimError as exc:  # bad edit that passed validation: keep running
                self._message("error", str(exc))
            except Exception as exc:  # an engine bug must not kill the page's session
                self._message("error", f"internal error: {type(exc).__name__}: {exc}")
                traceback.print_exc()
                time.sleep(0.2)

    def _warm(self) -> None:
        """Every code path of the loop once (interaction frame, estimate, pooled map,
        camera, light transform, regulation) so that numba compiles its kernels now, not
        at the user's first edit; the photons are then discarded."""
        s = self.session
        t0 = time.perf_counter()
        s.frame(image=True, probes=False, camera=self.camera,
                photons=min(self.quick_photons, s.config.frame_photons))
        s.accumulate(1)
        s.frame(image=True)
        s.frame(image=True, shoot=False, mode="pooled")
        if self.regulation_hook is not None:
            self.regulation_hook(s)
        s.update(light_transform=np.eye(4))
        self._choose_threads()
        self._reset_clock()
        self.stats.timings = {"warm_up": time.perf_counter() - t0}

    def _choose_threads(self) -> None:
        """numba threads of this thread (``set_num_threads`` is per thread): ``threads``,
        or the faster of 1 and all for an interaction frame (best of two each)."""
        import numba

        top = int(numba.config.NUMBA_NUM_THREADS)
        if self.threads != "auto":
            self.frame_threads = self.accumulate_threads = min(int(self.threads), top)
            numba.set_num_threads(self.frame_threads)
            return
        s = self.session
        for n in sorted({1, top}):
            numba.set_num_threads(n)
            times, acc = [], []
            for _ in range(2):
                t0 = time.perf_counter()
                s.frame(image=True, probes=False)
                t1 = time.perf_counter()
                s.accumulate(1)
                acc.append(time.perf_counter() - t1)
                times.append(t1 - t0)
                s.update(light_transform=np.eye(4))
            self.thread_times[n], self.accumulate_times[n] = min(times), min(acc)
        self.frame_threads = min(self.thread_times, key=self.thread_times.get)
        self.accumulate_threads = min(self.accumulate_times, key=self.accumulate_times.get)
        numba.set_num_threads(self.frame_threads)

    def _threads_for(self, accumulating: bool) -> None:
        """Switch this thread's numba threads to the warm-up's choice for the work."""
        n = self.accumulate_threads if accumulating else self.frame_threads
        if n is not None:
            import numba

            numba.set_num_threads(n)

    def _config(self, c: Controls) -> RunConfig:
        return self.base_config.with_(k=c.k, interleave=c.interleave,
                                      frame_photons=c.frame_photons)

    def _open(self, scene: Scene, c: Controls) -> None:
        config = self._config(c)  # validates (e.g. photons ≥ M²) before the old one closes
        session = self.make_session(scene, config)
        if self.session is not None:
            self.session.close()
        self.session = session
        self.controls = c
        self._reset_clock()

    def _reset_clock(self) -> None:
        self.mode = "interaction"
        self._changed_at = time.perf_counter()
        self._pooled_photons = 0
        self._last_reg = 0.0
        self._quick_due = True

    def _apply_pending(self) -> bool:
        with self._lock:
            pending, self._pending = self._pending, None
            upload, self._pending_scene = self._pending_scene, None
        if upload is not None:
            editor, c = upload
            self._open(editor.build(c), c)
            self.editor = editor
            self.edit += 1
            self._autosave({"upload": editor.base.source})
            self._message("info", f"new scene: {Path(editor.base.source).name}")
            self.publish("controls", self.describe())
            return True
        if pending is None:
            return False
        new, info = pending
        t0 = time.perf_counter()
        try:
            scene = self.editor.build(new)
            changed = new.changed(self.controls)
            if changed & {*CONFIG_CONTROLS, "wall_distance_m"}:
                # the run configuration or the wall frame (probe grid, radii) changed
                self._open(scene, new)
            elif changed <= POSE_CONTROLS:
                # only the filament moved: emitters are not traced, the embree scene stays
                delta = self.editor.emitter_matrix(new) @ np.linalg.inv(
                    self.editor.emitter_matrix(self.controls))
                self.session.update(light_transform=delta)
                self.controls = new
                self._reset_clock()
            else:
                self.session.update(scene=scene)
                self.controls = new
                self._reset_clock()
        except LightsimError as exc:
            self._message("error", str(exc))
            self.publish("controls", self.describe())  # the page snaps back
            return False
        self.edit += 1
        self._update_s = time.perf_counter() - t0
        self.token = dict(info.get("token") or {})
        self.stats.edits_applied += 1
        self._autosave(info["changes"])
        return True

    def _step(self) -> None:
        changed = self._apply_pending()
        self._handle_saves()
        s = self.session
        if not changed and self._converged(s):
            self._wake.wait(0.25)  # nothing left to gain: wait for an edit
            self._wake.clear()
            return
        if not changed and self.mode == "interaction" and s.frames >= 1:
            wait = self.settle_seconds - (time.perf_counter() - self._interaction_done)
            if wait > 0:  # a drag pauses briefly: keep the loop free for its next edit
                self._wake.clear()
                if not self._busy():
                    self._wake.wait(wait)
                return
            self.mode = "accumulation"
        if self.mode == "accumulation":
            # shoot batches between displayed frames, so the probe estimates, the image
            # and the error figure are paid once per step, not once per batch
            share = min(max(self.estimate_share, 0.01), 0.9)
            t_end = time.perf_counter() + max(self.step_seconds,
                                              self._est_cost * (1 - share) / share)
            self._threads_for(accumulating=True)
            try:
                while (time.perf_counter() < t_end and not self._busy()
                       and not self._stop.is_set()):
                    s.accumulate(1)
            finally:
                self._threads_for(accumulating=False)
            if self._busy():
                return  # an edit waits: do not render the old scene
        now = time.perf_counter()
        # once a pooled map is shown, a still scene shows only newer pooled maps
        image = self.mode == "interaction" or (
            self._pooled_photons == 0 and now - self._last_image >= self._image_every)
        camera = self.camera if (self.camera is not None and self.camera_watchers > 0 and (
            self.mode == "interaction" or now - self._last_camera >= self._image_every)) \
            else None
        t0 = time.perf_counter()
        if self.mode == "interaction":
            # only the picture: the probes, error figure and table wait for a still scene
            quick = self._quick_due and self.quick_photons < s.config.frame_photons
            est = s.frame(image=True, camera=camera, probes=False,
                          photons=self.quick_photons if quick else None)
            self._quick_due = False
            self._interaction_done = time.perf_counter()
        else:
            # the error figure of the consistent (ICI) map needs only its rung sums at
            # the grid probes: no kNN probe queries every step
            est = s.frame(image=image, camera=camera,
                          probes="ici" if s.config.uses_ici else True)
        self.stats.last_frame_s = time.perf_counter() - t0
        if self.mode == "accumulation":
            self._est_cost = self.stats.last_frame_s - est.timings.get("shoot", 0.0)
        self.stats.timings = dict(est.timings)
        self.stats.frames += 1
        if self.mode == "interaction":
            self.stats.interaction_frames += 1
        if image:  # keep the redraws of a still scene to ≤ 1/4 of the time
            self._image_every = max(self.image_interval, 3.0 * est.timings.get("render", 0))
        quality = "interleaved"
        if self.mode == "accumulation" and not self._busy() and self._pooled_due(est):
            est_p = s.frame(image=True, shoot=False, mode="pooled")
            self._pooled_photons = est_p.photons
            est, quality, image = est_p, "pooled", True
        entry = {"mode": self.mode, "quality": quality, "image": bool(image),
                 "update_s": self._update_s if changed else 0.0,
                 "photons": int(est.photons), "frame_s": self.stats.last_frame_s,
                 **{f"{k}_s": v for k, v in est.timings.items()}}
        if image and est.lux is not None:
            self._last_image = time.perf_counter()
            self.stats.images += 1
            t1 = time.perf_counter()
            msg = encode_image(luminous(est.lux), self._header("wall", est, quality))
            entry.update(encode_s=time.perf_counter() - t1, bytes=len(msg))
            self.publish("frame:wall", msg)
        self.stats.log.append(entry)
        if est.camera is not None:
            self._last_camera = time.perf_counter()
            self.publish("frame:camera", encode_image(luminous(est.camera),
                                                      self._header("camera", est,
                                                                   "interleaved")))
        self.last_status = self._status(est, quality)
        self.publish("status", self.last_status)
        # the table needs ~10³ probes per set: only once the scene is still, and at most
        # a fifth of the time
        if (self.regulation_hook is not None and self.mode == "accumulation"
                and not self._busy() and time.perf_counter() - self._last_reg
                >= max(self.regulation_interval, 4.0 * self._reg_cost)):
            t1 = time.perf_counter()
            table = self.regulation_hook(s)
            self._last_reg = time.perf_counter()
            self._reg_cost = self._last_reg - t1
            self.publish("regulation", {"edit": self.edit, "title": table.title,
                                        "rows": table.rows, "points": table.points,
                                        "unevaluated": table.unevaluated})

    def _pooled_due(self, est) -> bool:
        """The pooled map (M² times an image's queries) first when the error figure is
        ≤ ``pooled_error`` or the scene has been still ``pooled_after`` s, then each time
        the photons have doubled (so it costs a bounded share of the time)."""
        if self._pooled_photons:
            return est.photons >= 2 * self._pooled_photons
        still = time.perf_counter() - self._changed_at
        err = est.rel_error
        return still >= self.pooled_after or (err is not None and err <= self.pooled_error)

    def _converged(self, s) -> bool:
        """Accumulation has reached ``stop_error`` or ``max_photons``: stop shooting."""
        if self.mode != "accumulation" or s.last is None or self._pooled_photons == 0:
            return False
        err = s.last.rel_error
        photons = s.last.photons
        return photons >= self.max_photons or (err is not None and err <= self.stop_error)

    def _busy(self) -> bool:
        """An edit or a save is waiting: skip optional work so it is served first."""
        return self._pending is not None or self._pending_scene is not None \
            or bool(self._save_requests)

    # -- what the page receives ---------------------------------------------------------
    def _header(self, kind: str, est, quality: str) -> dict[str, Any]:
        w = self.session.scene.wall
        return {"kind": kind, "edit": self.edit, "token": self.token, "mode": self.mode,
                "quality": quality, "photons": int(est.photons),
                "rel_error": _finite(est.rel_error), "wall": w.to_dict()}

    def _status(self, est, quality: str) -> dict[str, Any]:
        e = est.error
        return {"edit": self.edit, "mode": self.mode, "quality": quality,
                "photons": int(est.photons), "rel_error": _finite(est.rel_error),
                "rel_noise": None if e is None else _finite(e.noise),
                "rel_bias": None if e is None else _finite(e.bias),
                "error_text": None if e is None else e.describe(),
                "still_s": time.perf_counter() - self._changed_at,
                "frame_s": self.stats.last_frame_s, "frames": self.stats.frames,
                "numba_threads": _numba_threads(),
                "timings": self.stats.timings}

    def describe(self) -> dict[str, Any]:
        """Controls, their specs and bulbs (the page's "hello")."""
        from lightsim.view.controls import SPECS

        return {"controls": self.controls.to_dict(), "specs": [s.to_dict() for s in SPECS],
                "bulbs": list(self.editor.bulb_names()),
                "scene": Path(self.editor.base.source).name,
                "regulation": self.regulation_hook is not None,
                "camera": self.camera is not None}

    def _message(self, level: str, text: str) -> None:
        self.publish("message", {"level": level, "text": text})

    # -- nothing lost -------------------------------------------------------------------
    def _autosave(self, changes: dict[str, Any]) -> None:
        if self.folder is None:
            return
        entry = {"time": time.time(), "edit": self.edit, "changes": changes,
                 "controls": self.controls.to_dict(), "scene": self.editor.base.source}
        with open(self.folder / "edits.jsonl", "a", encoding="utf-8") as fh:
            fh.write(json.dumps(entry) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        tmp = self.folder / f".state.json.{os.getpid()}.tmp"
        tmp.write_text(json.dumps({"scene": self.editor.base.source,
                                   "controls": self.controls.to_dict()}, indent=2))
        os.replace(tmp, self.folder / "state.json")

    def _handle_saves(self) -> None:
        with self._lock:
            requests, self._save_requests = self._save_requests, []
        for req in requests:
            try:
                result = {"level": "info", "text": self.save_now(), "saved": True}
            except LightsimError as exc:
                result = {"level": "error", "text": f"save failed: {exc}"}
            except OSError as exc:
                result = {"level": "error", "text": f"save failed: {exc.strerror or exc}"}
            self.publish("message", result)
            if req.get("reply"):
                req["reply"](result)

    def save_now(self) -> str:
        """Write a run folder of the current state (called in this thread); returns a line.

        The folder is written under a temporary name and renamed when complete, so an
        interrupted save leaves no half run folder.
        """
        if self.folder is None or self.save_hook is None:
            raise LightsimError("this session has no output folder")
        s = self.session
        if s.frames == 0:
            s.frame(image=False)
        est = s.frame(image=True, shoot=False, mode=s.config.final)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        n = 0
        while (self.folder / f"run-{stamp}-{n}").exists():
            n += 1
        final = self.folder / f"run-{stamp}-{n}"
        tmp = self.folder / f".{final.name}.partial"
        if tmp.exists():
            shutil.rmtree(tmp)
        tmp.mkdir(parents=True)
        try:
            files = self.save_hook(tmp, s, est, self.controls, s.scene)
            shutil.copy2(self.folder / "edits.jsonl", tmp / "edits.jsonl")
            os.replace(tmp, final)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return f"saved {final} ({', '.join(sorted(files))}, {est.photons:,} photons)"


def _finite(x: float | None) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _numba_threads() -> int:
    import numba

    return int(numba.get_num_threads())
