"""The session thread of ``lightsim view``: the paper's interaction and accumulation modes.

One thread owns the engine :class:`~lightsim.engine.server.Session` (the engine is not
thread-safe and need not be). The web app only *submits* edits; edits that arrive while a
frame is computed are coalesced (the latest controls win), so a dragged slider never
builds a queue.

* **Interaction** (paper section 4.1): an edit → ``Session.update`` discards the photons;
  the next frame shoots a new batch (the first one after an edit at most
  ``quick_photons``), renders the interleaved image and box-filters it — and nothing
  else: no probes, no error figure, no regulation (``Session.frame(probes=False)``).
  Filament moves are a light transform and aim / wall distance a wall placement (the
  embree scene stays, when the engine offers it); an interaction frame is a partial frame
  of ``photons per frame`` (the session's frame is the accumulation's batch cap).
* **Accumulation** (the paper's walkthrough with a still scene): no edit for
  ``settle_seconds`` → photon batches sized by time (``batch_seconds``, growing by
  ``batch_growth`` per batch up to ``batch_max_seconds``, at most ``batch_photons``) are
  added to every set's map, so accumulation runs at the tracer's rate and an edit waits
  at most one batch. The **pooled** full-resolution map — what ``simulate`` writes — is
  drawn with the written map's own error figure (over every pixel: the honest one),
  first where the scene's error law (from the warm-up's map at one whole frame of
  photons, then from every map) predicts 5 % — until then nothing that builds kNN
  trees, only the grid figure once — then where the figure is expected to cross the
  next of 5 %, 2 %, 1 %, 0.5 % (noise ∝ 1/√N beside a blur that does not fall),
  otherwise each time the photons have doubled with its cost kept to ``pooled_share``
  of the time.
* After every batch the photon count is published with the error figure of the last
  pooled map (``error_source`` "written map") or, before the first, the cheap figure of
  the ICI rungs at the grid probes (``error_source`` "grid probes", at most
  ``probe_share`` of the time); the regulation table at the first still step, then at
  most every ``regulation_interval`` seconds and ``regulation_share`` of the time.
* Nothing is lost: every applied edit is appended to ``edits.jsonl`` (flushed and
  fsynced) and the current controls to ``state.json`` (atomic) in the session folder;
  ``lightsim view --state FILE`` restores them.

Every setting (batch times, shares, the stop, photons of an interaction frame, threads)
is a field of :class:`~lightsim.view.settings.ViewSettings` (its module docstring is the
table); when the pooled map is due and the thread choice are
:mod:`lightsim.view.schedule`'s.
"""

from __future__ import annotations

import json
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

import numba
import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.engine.memory import available_bytes, bytes_per_photon
from lightsim.errors import LightsimError
from lightsim.render.frame import luminous
from lightsim.scene import Scene
from lightsim.view.controls import (
    AIM_CONTROLS,
    CONFIG_CONTROLS,
    POSE_CONTROLS,
    SPECS,
    Controls,
)
from lightsim.view.editor import BulbPreset, SceneEditor
from lightsim.view.encode import encode_image
from lightsim.view.schedule import PooledSchedule, ThreadChoice, finite_or_none
from lightsim.view.settings import ViewSettings

WARM_BATCH = 50_000  # photons of the warm-up's timed accumulation batch


@dataclass
class RegulationTable:
    """What the page shows of a rule set: rows and the points to draw.

    ``rows``: name, kind, limit, value (cd), interval (cd), verdict, decided (True: the
    verdict is pass or fail for good — the table decides verdicts as ``simulate --until
    decided`` does, its intervals holding over every look; False: still open);
    ``points``: name, h_deg, v_deg, verdict (test points drawn on the pattern).
    """

    title: str
    rows: list[dict[str, Any]]
    points: list[dict[str, Any]]
    unevaluated: int = 0


RegulationHook = Callable[[Any], RegulationTable]
SaveHook = Callable[[Path, Any, Any, Controls, Scene], list[str]]
Publish = Callable[[str, Any], None]


@dataclass(frozen=True)
class ViewHooks:
    """What the product adds to the engine's live session (the engine must not import
    ``luminaires``: :func:`lightsim.luminaires.live.view_hooks` builds these).

    Attributes
    ----------
    bulbs : dict of str → BulbPreset
        The bulb control's presets (filament meshes); empty: only the file's own bulb.
    regulation : callable (session) → RegulationTable, optional
        The regulation table of the current photons; None: no table.
    save_run : callable (folder, session, estimate, controls, scene) → file names, optional
        Writes a run folder ("save run"); None: saving is refused.
    """

    bulbs: dict[str, BulbPreset] = field(default_factory=dict)
    regulation: RegulationHook | None = None
    save_run: SaveHook | None = None


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
    make_session : callable (Scene, RunConfig, camera: bool) → Session
        Builds the engine session (in-process or Ray); ``camera``: with the camera pass
        (planned only while a tab shows the camera view: it stores every diffuse hit, not
        only the wall's, ~10 % more work per photon).
    config : RunConfig
        Base run configuration; k, M and photons per frame come from the controls.
    publish : callable (kind, payload)
        ``("frame:wall" | "frame:camera", bytes)``, ``("status", dict)``, ``("regulation", dict)``,
        ``("message", dict)``; called from this thread.
    settings : ViewSettings, optional
        The session thread's tuning (the command-line fields are not read here).
    hooks : ViewHooks, optional
        The regulation table and the run writer (the bulbs are the editor's).
    controls : Controls, optional
        The first controls (default: the editor's, which reproduce the scene).
    folder : Path, optional
        Session folder (edit log, state, saved runs); None: nothing is written.
    camera : PinholeCamera, optional
        The camera of the second tab (rendered while a tab shows it; the session has the
        camera pass — every diffuse hit stored — only from the first such tab on).
    """

    def __init__(self, editor: SceneEditor, make_session: Callable[..., Any],
                 config: RunConfig, publish: Publish, settings: ViewSettings | None = None,
                 hooks: ViewHooks | None = None, *, controls: Controls | None = None,
                 folder: Path | None = None, camera: Any = None) -> None:
        self.editor = editor
        self.make_session = make_session
        self.base_config = config
        self.publish = publish
        self.settings = settings if settings is not None else ViewSettings()
        self.hooks = hooks if hooks is not None else ViewHooks()
        self.folder = Path(folder) if folder is not None else None
        self.camera = camera
        self.camera_watchers = 0  # set by the app: tabs showing the camera view
        self._camera_pass = False  # whether the current session was planned with the camera
        st = self.settings
        self.schedule = PooledSchedule(st.first_pooled_seconds, st.first_cap_seconds,
                                       st.pooled_share)
        self.threads = ThreadChoice(fixed=None if st.threads == "auto" else int(st.threads))
        self._reg_cost = 0.0
        self._update_s = 0.0
        self._edit_wait = 0.0
        self._interaction_done = 0.0  # end of the last interaction frame
        self._overhead_s: float | None = None  # an interaction frame's seconds besides shooting
        self._rate: float | None = None  # photons/s of the last batch or frame
        self._probe_cost = self._camera_cost = 0.0  # seconds
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
        self.reset_clock()
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
            self._pending = (new, {"changes": merged, "token": token or {},
                                   "received": time.perf_counter()})
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
            # the warm-up runs the camera path too (its kernels compile before any edit)
            self.open_session(self.editor.session_scene(self.controls), self.controls,
                              camera=self.settings.warm_up or self._camera_wanted())
        except LightsimError as exc:
            self.error = str(exc)
            self._message("error", f"cannot start the session: {exc}")
            self.ready.set()
            return
        try:
            if self.settings.warm_up:
                self._warm()
            elif self.threads.fixed is not None:
                self._choose_threads()
        finally:
            self.ready.set()
        self._autosave({"start": True})
        while not self._stop.is_set():
            try:
                self.step()
            except LightsimError as exc:  # bad edit that passed validation: keep running
                self._message("error", str(exc))
            except Exception as exc:  # an engine bug must not kill the page's session
                self._message("error", f"internal error: {type(exc).__name__}: {exc}")
                traceback.print_exc()
                time.sleep(0.2)

    def _warm(self) -> None:
        """Every code path of the loop once (interaction frame, accumulation batch, grid
        figure, pooled map, camera, light transform, regulation) so that numba compiles
        its kernels now, not at the user's first edit; the photons are then discarded."""
        s = self.session
        t0 = time.perf_counter()
        s.frame(image=True, probes=False, camera=self.camera,
                photons=self._frame_photons(quick=True),
                image_step=self.settings.interaction_step)
        self._accumulate_batch()
        s.frame(image=True)  # the kNN probes (the regulation table's path)
        self._probe_frame()
        # also its cost and, at one whole frame of photons, the scene's error law: the
        # first edit's first map is then drawn where 5 % is predicted
        self._pooled_frame(None)
        if self.hooks.regulation is not None:
            self.hooks.regulation(s)
        s.update(light_transform=np.eye(4))
        if self._camera_pass and not self._camera_wanted():  # no tab shows the camera
            self.open_session(self.editor.session_scene(self.controls), self.controls,
                              camera=False)
        self._choose_threads()
        self.reset_clock()
        self.stats.log.clear()  # the log is of the user's session
        self.stats.timings = {"warm_up": time.perf_counter() - t0}

    def _choose_threads(self) -> None:
        """numba threads of this thread (``set_num_threads`` is per thread): ``threads``,
        or the faster of 1 and all, for an interaction frame and for an accumulation
        batch of ``WARM_BATCH`` photons separately (best of two each)."""
        top = int(numba.config.NUMBA_NUM_THREADS)
        choice = self.threads
        if choice.fixed is not None:
            choice.frame = choice.accumulate = min(choice.fixed, top)
            numba.set_num_threads(choice.frame)
            return
        s = self.session
        batch = self._partial(min(WARM_BATCH, s.config.frame_photons))
        frame_times, batch_times = {}, {}
        for n in sorted({1, top}):
            numba.set_num_threads(n)
            times, acc = [], []
            for _ in range(2):
                t0 = time.perf_counter()
                s.frame(image=True, probes=False, photons=self._frame_photons(quick=False),
                        image_step=self.settings.interaction_step)
                t1 = time.perf_counter()
                s.shoot(batch)
                acc.append(time.perf_counter() - t1)
                times.append(t1 - t0)
                s.update(light_transform=np.eye(4))
            frame_times[n], batch_times[n] = min(times), min(acc)
        choice.timed(frame_times, batch_times, batch)
        numba.set_num_threads(choice.frame)

    def _threads_for(self, accumulating: bool, n: int | None = None) -> None:
        """Switch this thread's numba threads to ``n`` or the warm-up's choice for the
        work."""
        if n is None:
            n = self.threads.accumulate if accumulating else self.threads.frame
        if n is not None:
            numba.set_num_threads(n)

    def _config(self, c: Controls, batch: bool = True) -> RunConfig:
        """The session's configuration: its frame is the accumulation's batch cap (an
        interaction frame is a partial frame of ``c.frame_photons``); ``batch=False``
        (Selective Photon Tracing, whose passes are always whole): the controls' frame."""
        photons = max(c.frame_photons, self.settings.batch_photons) if batch \
            else c.frame_photons
        return self.base_config.with_(k=c.k, interleave=c.interleave, frame_photons=photons)

    def open_session(self, scene: Scene, c: Controls, camera: bool | None = None) -> None:
        """A new engine session for ``scene`` and controls ``c``; ``camera``: with the
        camera pass (default: while a tab shows the camera view)."""
        config = self._config(c)  # validates (e.g. photons ≥ M²) before the old one closes
        camera = self._camera_wanted() if camera is None else bool(camera and self.camera)
        session = self.make_session(scene, config, camera=camera)
        if session.plan.spt and config.frame_photons != c.frame_photons:
            session.close()  # SPT passes are whole: no partial interaction frames
            session = self.make_session(scene, self._config(c, batch=False), camera=camera)
        if self.session is not None:
            self.session.close()
        self.session = session
        self._camera_pass = camera
        self.controls = c
        self.reset_clock()

    def _camera_wanted(self) -> bool:
        """Whether a tab shows the camera view (the session then needs the camera pass)."""
        return self.camera is not None and self.camera_watchers > 0

    def camera_shown(self) -> bool:
        """Whether to render the camera view now: a tab shows it and the session has the
        camera pass (a tab that has just asked gets it from the next session)."""
        return self._camera_pass and self._camera_wanted()

    def _partial(self, photons: int) -> int | None:
        """``photons`` as the argument of ``Session.shoot``/``frame``: None for a whole
        frame (and always with SPT: its passes are whole)."""
        s = self.session
        if s.plan.spt or photons >= s.config.frame_photons:
            return None
        return max(int(photons), s.config.n_sets)

    def _frame_photons(self, quick: bool) -> int | None:
        """Photons of an interaction frame: after an edit at most ``quick_photons``, and
        as many as the tracer's rate fits into ``frame_seconds`` beside the frame's other
        work (render, update, encode: measured on the last interaction frame), at least
        ``min_photons`` — the paper's interaction mode, fewer photons while dragging."""
        n = self.controls.frame_photons
        if quick:
            n = min(n, self.settings.quick_photons)
            if self._rate and self._overhead_s is not None:
                fit = self._rate * max(self.settings.frame_seconds - self._overhead_s, 0.0)
                n = min(n, max(self.settings.min_photons, int(fit)))
        return self._partial(n)

    def reset_clock(self) -> None:
        """A change: interaction mode, the photons and their figures start afresh, and the
        memory budget is that of the memory available now."""
        self.mode = "interaction"
        self._changed_at = time.perf_counter()
        self._pooled_photons = 0
        self._last_reg = 0.0
        self._last_probe = 0.0
        self._last_camera = 0.0
        self._quick_due = True
        self._batch_s = self.settings.batch_seconds
        self.schedule.reset()
        self.threads.reset()
        self._figure = (None, None)
        self._memory_said = False
        free = available_bytes()
        self._memory_budget = None if free is None else self.settings.memory_share * free

    def _apply_pending(self) -> bool:
        with self._lock:
            pending, self._pending = self._pending, None
            upload, self._pending_scene = self._pending_scene, None
        if upload is not None:
            editor, c = upload
            self.open_session(editor.session_scene(c), c)
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
        self._edit_wait = t0 - info.get("received", t0)  # waited for a batch or a frame
        try:
            changed = new.changed(self.controls)
            ed, old = self.editor, self.controls
            lamp_frame = ed.wall_aimable()  # the session's lamp is unaimed, its wall turned
            if changed and changed <= POSE_CONTROLS | (AIM_CONTROLS if lamp_frame else set()):
                # the filament moved (emitters are not traced) and/or the aim changed (the
                # wall is moved the other way, outside embree): the embree scene stays and
                # the edited scene need not be built
                kw: dict[str, Any] = {}
                if changed & POSE_CONTROLS:
                    if lamp_frame:
                        kw["light_transform"] = ed.pose_matrix(new) @ np.linalg.inv(
                            ed.pose_matrix(old))
                    else:
                        kw["light_transform"] = ed.emitter_matrix(new) @ np.linalg.inv(
                            ed.emitter_matrix(old))
                if changed & AIM_CONTROLS:
                    kw["wall_transform"] = ed.wall_matrix(new) @ np.linalg.inv(
                        ed.wall_matrix(old))
                self.session.update(**kw)
                self.controls = new
                self.reset_clock()
            elif changed & {*CONFIG_CONTROLS, "wall_distance_m"}:
                # the run configuration or the wall frame (probe grid, radii) changed
                self.open_session(ed.session_scene(new), new)
            else:
                self.session.update(scene=ed.session_scene(new))
                self.controls = new
                self.reset_clock()
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

    def step(self) -> None:
        """One step of the session thread: apply a pending edit or upload, serve saves,
        then an interaction frame or an accumulation step (or wait while converged)."""
        changed = self._apply_pending()
        self._handle_saves()
        if self._camera_wanted() and not self._camera_pass:
            # a tab asks for the camera view: a session with the camera pass (the
            # photons start afresh, as after an edit)
            self.open_session(self.editor.session_scene(self.controls), self.controls, camera=True)
        s = self.session
        if not changed and self._converged():
            self._wake.wait(0.25)  # nothing left to gain: wait for an edit
            self._wake.clear()
            return
        if not changed and self.mode == "interaction" and s.frames >= 1:
            wait = self.settings.settle_seconds - (time.perf_counter()
                                                   - self._interaction_done)
            if wait > 0:  # a drag pauses briefly: keep the loop free for its next edit
                self._wake.clear()
                if not self._busy():
                    self._wake.wait(wait)
                return
            self.mode = "accumulation"
        if self.mode == "interaction":
            self._interaction_frame(changed)
        else:
            self._accumulation_step()

    def _interaction_frame(self, changed: bool) -> None:
        """Only the picture: the probes, error figure and table wait for a still scene."""
        s = self.session
        camera = self.camera if self.camera_shown() else None
        t0 = time.perf_counter()
        est = s.frame(image=True, camera=camera, probes=False,
                      photons=self._frame_photons(quick=self._quick_due),
                      image_step=self.settings.interaction_step)
        self._quick_due = False
        self._interaction_done = time.perf_counter()
        self.stats.last_frame_s = self._interaction_done - t0
        if est.timings.get("shoot", 0.0) > 0 and est.photons > 0:
            self._rate = est.photons / est.timings["shoot"]
        self.stats.frames += 1
        self.stats.interaction_frames += 1
        update = self._update_s if changed else 0.0
        self._publish_frame(est, "interleaved", {"update_s": update, "token_n": self.token.get(
            "n"), "wait_s": self._edit_wait if changed else 0.0})
        entry = self.stats.log[-1]
        overhead = (self.stats.last_frame_s - est.timings.get("shoot", 0.0) + update
                    + entry.get("encode_s", 0.0))
        self._overhead_s = overhead if self._overhead_s is None else \
            0.5 * (self._overhead_s + overhead)

    def _accumulation_step(self) -> None:
        """One batch, then what is due: the pooled map with the written map's figure,
        the grid-probe figure (before the first pooled map), the camera, the table."""
        s = self.session
        self._accumulate_batch()
        if self._busy():
            return  # an edit waits: do not estimate the old scene
        if time.perf_counter() - self._interaction_done < self.settings.still_seconds:
            # a pause in a drag: only short batches, so the next edit waits ≤ one batch
            self.last_status = self._status()
            self.publish("status", self.last_status)
            return
        watched = self.camera_shown()
        now = time.perf_counter()
        camera_due = watched and now - self._last_camera >= max(1.0, 9.0 * self._camera_cost)
        pooled = self.schedule.due(self.photons_now)
        # with the scene's error law the first pooled map is due within seconds: until
        # then nothing that builds the kNN trees (interleaved image, table), only the
        # cheap grid figure — every second goes to tracing
        run_up = self.schedule.written is None and self.schedule.law_5 is not None
        if pooled:
            est = self._pooled_frame(self.camera if watched else None)
            self._publish_frame(est, "pooled", {})
        elif self.schedule.written is None and self._probe_due() and not (run_up
                                                                  and self._last_probe):
            # before the first pooled map: the grid figure (and the interleaved image)
            est = self._probe_frame(image=not run_up)
            if not run_up:
                self._publish_frame(est, "interleaved", {})
        if camera_due and time.perf_counter() - self._last_camera >= 1.0:
            t0 = time.perf_counter()
            est = s.frame(image=False, shoot=False, camera=self.camera, probes=False)
            self._camera_cost = time.perf_counter() - t0
            self._log({"mode": self.mode, "quality": "camera", "image": False,
                                   "frame_s": self._camera_cost})
            self._publish_camera(est)
        self.last_status = self._status()
        self.publish("status", self.last_status)
        # the table needs ~10³ probes per set: once the scene is still, then with each
        # pooled map (the drawn result), at most ``regulation_share`` of the time
        share = self.settings.regulation_share
        reg_due = (self._last_reg == 0.0 and not run_up) or (
            pooled and time.perf_counter() - self._last_reg
            >= max(self.settings.regulation_interval, self._reg_cost * (1 - share) / share))
        if self.hooks.regulation is not None and not self._busy() and reg_due:
            t1 = time.perf_counter()
            table = self.hooks.regulation(s)
            self._last_reg = time.perf_counter()
            self._reg_cost = self._last_reg - t1
            self._log({"mode": self.mode, "quality": "regulation",
                                   "image": False, "frame_s": self._reg_cost})
            self.publish("regulation", {"edit": self.edit, "title": table.title,
                                        "rows": table.rows, "points": table.points,
                                        "unevaluated": table.unevaluated})

    def _accumulate_batch(self) -> None:
        """Trace one batch of about ``_batch_s`` seconds at the measured rate into every
        set's map (the batch grows while the scene stays still)."""
        s = self.session
        rate = self._rate if self._rate else 1e5
        n = max(s.config.n_sets, rate * self._batch_s)
        still = time.perf_counter() - self._interaction_done >= self.settings.still_seconds
        if still:
            n = max(n, self.settings.still_batch_photons)  # a loaded machine: not below full rate
        n = int(min(s.config.frame_photons, n))
        before = self.photons_now()
        threads = self.threads.for_batch(still)
        t0 = time.perf_counter()
        self._threads_for(accumulating=True, n=threads)
        try:
            s.shoot(self._partial(n))
        finally:
            self._threads_for(accumulating=False)
        dt = time.perf_counter() - t0
        done = self.photons_now() - before
        if dt > 0 and done > 0:
            self._rate = done / dt
            if still:
                self.threads.note_rate(threads, self._rate)
        self.schedule.traced_s += dt
        self._batch_s = min(self.settings.batch_max_seconds,
                            self._batch_s * self.settings.batch_growth)
        self._log({"mode": "accumulation", "quality": "batch", "image": False,
                   "photons": self.photons_now(), "batch_photons": done, "batch_s": dt})

    def _log(self, entry: dict[str, Any]) -> None:
        """A log entry (the bench's breakdown), stamped ``t``: seconds since the last change."""
        entry.setdefault("t", time.perf_counter() - self._changed_at)
        self.stats.log.append(entry)

    def photons_now(self) -> int:
        """Photons emitted into the current session's maps (all sets)."""
        return int(sum(self.session.emitted_per_set().values()))

    def _probe_due(self) -> bool:
        """The grid-probe figure: at the first still step, then ≤ ``probe_share``."""
        share = self.settings.probe_share
        return self._last_probe == 0.0 or time.perf_counter() - self._last_probe >= \
            self._probe_cost * (1 - share) / share

    def _probe_frame(self, image: bool = False):
        """The cheap error figure: the ICI rungs at the grid probes only (or the kNN
        probes without ICI), with the interleaved image if ``image``."""
        s = self.session
        t0 = time.perf_counter()
        est = s.frame(image=image, shoot=False, probes="ici" if s.config.uses_ici else True)
        self._last_probe = time.perf_counter()
        self._probe_cost = self.stats.last_frame_s = self._last_probe - t0
        self._log({"mode": self.mode, "quality": "grid probes", "image": False,
                               "photons": int(est.photons), "frame_s": self._probe_cost})
        self.stats.timings = dict(est.timings)
        self._figure = (est, "grid probes")
        return est

    def _pooled_frame(self, camera):
        """The pooled full-resolution map (the written result) and its own error figure
        over every pixel (ICI rung sums; no kNN probe queries)."""
        s = self.session
        t0 = time.perf_counter()
        # with ICI the written map's figure comes from its own rung sums over every pixel:
        # asking for the grid probes' rungs too would build every set's summed-area
        # table a second time for a figure that is then not used
        est = s.frame(image=True, shoot=False, mode="pooled", camera=camera,
                      probes=False if s.config.uses_ici else True)
        # the first map after an edit (Session.update resets the choice) makes both the
        # centred and the directional map and keeps the one with the lower figure; later
        # maps of the same scene make only that one (half the cost)
        s.directional_map = s.last_map_fused
        cost = self.stats.last_frame_s = time.perf_counter() - t0
        self.stats.timings = dict(est.timings)
        self.stats.frames += 1
        self._pooled_photons = int(est.photons)
        self.schedule.note_map(est, cost)
        self._figure = (est, "written map")
        return est

    def _converged(self) -> bool:
        """Accumulation has reached ``stop_error`` (by the written map's figure),
        ``max_photons`` or ``memory_share`` of the memory: stop shooting."""
        if self.mode != "accumulation":
            return False
        if self._memory_full():
            return True
        if self.schedule.written is None:
            return False
        err, photons = self.schedule.written
        return photons >= self.settings.max_photons or (err is not None
                                                        and err <= self.settings.stop_error)

    def _memory_full(self) -> bool:
        """The stored photons (at their insertion peak) have reached ``memory_share`` of
        the memory that was available when the scene last changed; said once."""
        if self._memory_budget is None:
            return False
        stats = self.session.backend.stats()
        records = sum(int(st.get("kept", 0)) for st in stats.values())
        full = records * bytes_per_photon(self.session.plan.channels or 1, peak=True) \
            >= self._memory_budget
        if full and not self._memory_said:
            self._memory_said = True
            self._message("info", f"accumulation stopped at {self.photons_now():,} photons: "
                          f"the photon maps hold {100 * self.settings.memory_share:.0f} % of "
                          "the memory "
                          "available (a change starts afresh)")
        return full

    def _busy(self) -> bool:
        """An edit or a save is waiting: skip optional work so it is served first."""
        return self._pending is not None or self._pending_scene is not None \
            or bool(self._save_requests)

    # -- what the page receives ---------------------------------------------------------
    def _publish_frame(self, est, quality: str, entry: dict[str, Any]) -> None:
        """The wall image (and camera), the status and a log entry of a drawn frame."""
        entry = {"mode": self.mode, "quality": quality, "image": est.lux is not None,
                 "photons": int(est.photons), "frame_s": self.stats.last_frame_s,
                 **entry, **{f"{k}_s": v for k, v in est.timings.items()}}
        self.stats.timings = dict(est.timings)
        if est.lux is not None:
            self.stats.images += 1
            t1 = time.perf_counter()
            msg = encode_image(luminous(est.lux), self._header("wall", est, quality))
            entry.update(encode_s=time.perf_counter() - t1, bytes=len(msg))
            self.publish("frame:wall", msg)
        self._log(entry)
        self._publish_camera(est)
        if self.mode == "interaction":
            self.last_status = self._status(quality)
            self.publish("status", self.last_status)

    def _publish_camera(self, est) -> None:
        if est.camera is not None:
            self._last_camera = time.perf_counter()
            self.publish("frame:camera", encode_image(luminous(est.camera),
                                                      self._header("camera", est,
                                                                   "interleaved")))

    def _header(self, kind: str, est, quality: str) -> dict[str, Any]:
        w = self.session.scene.wall
        return {"kind": kind, "edit": self.edit, "token": self.token, "mode": self.mode,
                "quality": quality, "photons": int(est.photons),
                "rel_error": finite_or_none(est.rel_error), "wall": w.to_dict()}

    def _status(self, quality: str | None = None) -> dict[str, Any]:
        """Mode, photons and the latest error figure with where it comes from: the
        written map (a pooled map, at ``error_photons``) or the grid probes."""
        est, source = self._figure
        e = None if est is None else est.error
        return {"edit": self.edit, "mode": self.mode, "quality": quality or (
                    "pooled" if self._pooled_photons else "interleaved"),
                "photons": self.photons_now(),
                "rel_error": None if est is None else finite_or_none(est.rel_error),
                "error_source": source,
                "error_photons": None if est is None else int(est.photons),
                "rel_noise": None if e is None else finite_or_none(e.noise),
                "rel_bias": None if e is None else finite_or_none(e.bias),
                "error_text": None if e is None else e.describe(),
                "still_s": time.perf_counter() - self._changed_at,
                "frame_s": self.stats.last_frame_s, "frames": self.stats.frames,
                "numba_threads": int(numba.get_num_threads()),
                "batch_threads": self.threads.batch_threads(),
                "photons_per_s": self._rate,
                "timings": self.stats.timings}

    def describe(self) -> dict[str, Any]:
        """Controls, their specs and bulbs (the page's "hello")."""
        return {"controls": self.controls.to_dict(), "specs": [s.to_dict() for s in SPECS],
                "bulbs": list(self.editor.bulb_names()),
                "scene": Path(self.editor.base.source).name,
                "regulation": self.hooks.regulation is not None,
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
        if self.folder is None or self.hooks.save_run is None:
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
            # the GLB is the edited scene as a user loads it: the lamp aimed, the wall fixed
            files = self.hooks.save_run(tmp, s, est, self.controls,
                                        self.editor.build(self.controls))
            shutil.copy2(self.folder / "edits.jsonl", tmp / "edits.jsonl")
            os.replace(tmp, final)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return f"saved {final} ({', '.join(sorted(files))}, {est.photons:,} photons)"
