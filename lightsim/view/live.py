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

=========================  =====  =======  ==================================================
parameter                  unit   default  meaning
=========================  =====  =======  ==================================================
``batch_seconds``          s      0.05     accumulation: tracing time of the first batch
                                           after an edit (an edit waits at most one batch)
``batch_growth``           –      1.5      … times this per batch
``batch_max_seconds``      s      0.3      … up to this (from ~10⁵ photons a batch traces
                                           at the engine's full rate: larger batches gain
                                           nothing and make an edit wait longer)
``still_batch_photons``    –      5·10⁴    … but, once the scene is still, at least this
                                           many (per-call costs: a batch traces near
                                           the engine's full rate from ~5·10⁴ photons,
                                           which a loaded machine does not fit into
                                           0.3 s; more would make an edit wait ~1 s)
``still_seconds``          s      0.75     the scene is still this long after the last
                                           interaction frame;
                                           before, no estimate, pooled map or table either
                                           (nothing long for a paused drag's next edit to
                                           wait for)
``batch_photons``          –      2²⁰      photons of one batch at most (the session's
                                           frame; memory ≈ 100 B per photon of a batch)
``first_pooled_seconds``   s      1.0      tracing before the first pooled map (or the
                                           pooled map's own cost, if more) while no error
                                           law is known; with one, at the photons where
                                           e √N of the map nearest 5 % predicts 5 % ...
``first_cap_seconds``      s      30       ... but after at most this much tracing (or
                                           twice the pooled map's cost; meanwhile the
                                           interleaved image and grid figure go on)
``pooled_share``           –      0.1      pooled maps at doubled photons take at most this
                                           share of the time (a predicted crossing of
                                           5 %, 2 %, 1 %, 0.5 % is not delayed; none
                                           when the crossing is due before twice the
                                           photons now)
``probe_share``            –      0.1      the grid-probe error figure (only before the
                                           first pooled map) takes at most this share
``regulation_interval``    s      1.0      regulation table refresh once the scene is still
``regulation_share``       –      0.05     … and at most this share of the time (its kNN
                                           trees cost ~0.3–0.8 µs per new photon)
``stop_error``             –      0.005    accumulation stops (idles) at this error figure
``max_photons``            –      2·10⁸    … or at this many photons
``memory_share``           –      0.5      … or when the photon maps (at their insertion
                                           peak, ``engine.memory``) hold this share of the
                                           memory available at the last change (a still
                                           scene would otherwise fill the machine)
``camera``                 –      none     :class:`~lightsim.render.camera.PinholeCamera` of
                                           the second tab (rendered while a tab shows it;
                                           the session has the camera pass — every diffuse
                                           hit stored — only from the first such tab on)
``quick_photons``          –      5 000    photons of an interaction frame after an edit (at
                                           most the frame's photons): the low-quality frame
``frame_seconds``          s      0.18     … fewer if the tracer's measured rate does not
                                           fit them into this beside the frame's render,
                                           update and encode (a drag at ≥ 5 frames/s)
``min_photons``            –      3 000    … but at least this many
``interaction_step``       px     2        interaction frames render the interleaved image
                                           at every 2nd pixel (¼ of the kNN queries; the
                                           page scales it to the wall's size)
``settle_seconds``         s      0.45     after an interaction frame, wait this long for the
                                           next edit before accumulating (an edit then
                                           need not wait for a batch in progress)
``warm_up``                –      True     run every code path once before ``ready`` is
                                           set (numba kernels compiled, no edit JITs)
``threads``                –      auto     numba threads of the session thread; auto = the
                                           warm-up times interaction frames and
                                           accumulation batches at 1 and at all threads
                                           and keeps the faster for each (on an
                                           oversubscribed machine the parallel kernels'
                                           barriers cost more than the second core gives);
                                           still batches revise the accumulation's (a
                                           still scene's first batch and one in 8 at the
                                           other count; moving average of the rates)
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
from lightsim.view.controls import AIM_CONTROLS, CONFIG_CONTROLS, POSE_CONTROLS, Controls
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


# error figures at which the next pooled map is scheduled (where it is expected to cross)
ERROR_LEVELS = (0.05, 0.02, 0.01, 0.005)
LEVEL_AIM = 0.93  # a level's pooled map is aimed this far below it (the law's scatter) …
FIRST_AIM = 0.9  # … the first after an edit further: e √N moves ~10 % from edit to edit
LAW_MIN_PHOTONS = 200_000  # maps with fewer photons do not set the error law
THREAD_TRIAL = 8  # one still batch in this many runs at the other numba thread count
RATE_WEIGHT = 0.3  # weight of a batch's rate in the moving average per thread count

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
    make_session : callable (Scene, RunConfig, camera: bool) → Session
        Builds the engine session (in-process or Ray; injected by the CLI); ``camera``:
        with the camera pass (planned only while a tab shows the camera view: it stores
        every diffuse hit, not only the wall's, ~10 % more work per photon).
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

    def __init__(self, editor: SceneEditor, make_session: Callable[..., Any],
                 config: RunConfig, publish: Publish, *, controls: Controls | None = None,
                 regulation: RegulationHook | None = None, save_run: SaveHook | None = None,
                 folder: Path | None = None, camera: Any = None,
                 batch_seconds: float = 0.05, batch_growth: float = 1.5,
                 batch_max_seconds: float = 0.3, batch_photons: int = 1 << 20,
                 first_pooled_seconds: float = 1.0, first_cap_seconds: float = 30.0,
                 pooled_share: float = 0.1,
                 probe_share: float = 0.1, regulation_interval: float = 1.0,
                 regulation_share: float = 0.05, stop_error: float = 0.005,
                 max_photons: int = 200_000_000, quick_photons: int = 5_000,
                 frame_seconds: float = 0.18, min_photons: int = 3_000,
                 still_seconds: float = 0.75, memory_share: float = 0.5,
                 warm_up: bool = True, threads: int | str = "auto",
                 settle_seconds: float = 0.45, interaction_step: int = 2,
                 still_batch_photons: int = 50_000) -> None:
        self.editor = editor
        self.make_session = make_session
        self.base_config = config
        self.publish = publish
        self.regulation_hook = regulation
        self.save_hook = save_run
        self.folder = Path(folder) if folder is not None else None
        self.camera = camera
        self.camera_watchers = 0  # set by the app: tabs showing the camera view
        self._camera_pass = False  # whether the current session was planned with the camera
        self.batch_seconds = float(batch_seconds)
        self.batch_growth = max(1.0, float(batch_growth))
        self.batch_max_seconds = max(float(batch_max_seconds), self.batch_seconds)
        self.batch_photons = int(batch_photons)
        self.first_pooled_seconds = float(first_pooled_seconds)
        self.pooled_share = min(max(float(pooled_share), 0.01), 0.9)
        self.probe_share = min(max(float(probe_share), 0.01), 0.9)
        self.regulation_share = min(max(float(regulation_share), 0.01), 0.9)
        self._reg_cost = 0.0
        self._update_s = 0.0
        self._edit_wait = 0.0
        self.regulation_interval = regulation_interval
        self.stop_error = stop_error
        self.max_photons = max_photons
        self.quick_photons = int(quick_photons)
        self.warm_up = bool(warm_up)
        self.settle_seconds = float(settle_seconds)
        self.interaction_step = max(1, int(interaction_step))
        self.still_batch_photons = int(still_batch_photons)
        self._interaction_done = 0.0  # end of the last interaction frame
        if threads != "auto" and (not isinstance(threads, int) or threads < 1):
            raise LightsimError(f"threads must be 'auto' or ≥ 1, got {threads!r}")
        self.threads = threads
        self.thread_times: dict[int, float] = {}  # warm-up: threads → frame seconds
        self.accumulate_times: dict[int, float] = {}  # … → seconds of one batch
        self.frame_threads = self.accumulate_threads = None
        self.batch_rates: dict[int, float] = {}  # threads → photons/s of still batches
        self._still_batches = 0
        self.warm_batch = 50_000  # photons of the warm-up's timed accumulation batch
        self.first_cap_seconds = float(first_cap_seconds)
        self.frame_seconds = float(frame_seconds)
        self.still_seconds = float(still_seconds)
        self.memory_share = float(memory_share)
        self.min_photons = int(min_photons)
        self._overhead_s: float | None = None  # an interaction frame's seconds besides shooting
        # the written map's error law, noise ∝ 1/√N beside a blur that does not fall:
        # (photons, total, noise, blur) of the last written map with ≥ LAW_MIN_PHOTONS
        self._law: tuple[int, float, float, float] | None = None
        self._law_5: tuple[int, float] | None = None  # (N, e) of the map nearest 5 %
        self._rate: float | None = None  # photons/s of the last batch or frame
        self._pooled_cost = self._probe_cost = self._camera_cost = 0.0  # seconds
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
        self._reset_clock()
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
            self._open(self.editor.session_scene(self.controls), self.controls,
                       camera=self.warm_up or self._camera_wanted())
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
        """Every code path of the loop once (interaction frame, accumulation batch, grid
        figure, pooled map, camera, light transform, regulation) so that numba compiles
        its kernels now, not at the user's first edit; the photons are then discarded."""
        s = self.session
        t0 = time.perf_counter()
        s.frame(image=True, probes=False, camera=self.camera,
                photons=self._frame_photons(quick=True), image_step=self.interaction_step)
        self._accumulate_batch()
        s.frame(image=True)  # the kNN probes (the regulation table's path)
        self._probe_frame()
        # also its cost and, at one whole frame of photons, the scene's error law: the
        # first edit's first map is then drawn where 5 % is predicted
        self._pooled_frame(None)
        if self.regulation_hook is not None:
            self.regulation_hook(s)
        s.update(light_transform=np.eye(4))
        if self._camera_pass and not self._camera_wanted():  # no tab shows the camera
            self._open(self.editor.session_scene(self.controls), self.controls, camera=False)
        self._choose_threads()
        self._reset_clock()
        self.stats.log.clear()  # the log is of the user's session
        self.stats.timings = {"warm_up": time.perf_counter() - t0}

    def _choose_threads(self) -> None:
        """numba threads of this thread (``set_num_threads`` is per thread): ``threads``,
        or the faster of 1 and all, for an interaction frame and for an accumulation
        batch of ``warm_batch`` photons separately (best of two each)."""
        import numba

        top = int(numba.config.NUMBA_NUM_THREADS)
        if self.threads != "auto":
            self.frame_threads = self.accumulate_threads = min(int(self.threads), top)
            numba.set_num_threads(self.frame_threads)
            return
        s = self.session
        batch = self._partial(min(self.warm_batch, s.config.frame_photons))
        for n in sorted({1, top}):
            numba.set_num_threads(n)
            times, acc = [], []
            for _ in range(2):
                t0 = time.perf_counter()
                s.frame(image=True, probes=False, photons=self._frame_photons(quick=False),
                        image_step=self.interaction_step)
                t1 = time.perf_counter()
                s.shoot(batch)
                acc.append(time.perf_counter() - t1)
                times.append(t1 - t0)
                s.update(light_transform=np.eye(4))
            self.thread_times[n], self.accumulate_times[n] = min(times), min(acc)
        self.frame_threads = min(self.thread_times, key=self.thread_times.get)
        self.accumulate_threads = min(self.accumulate_times, key=self.accumulate_times.get)
        self.batch_rates = {n: batch / t for n, t in self.accumulate_times.items() if t > 0}
        numba.set_num_threads(self.frame_threads)

    def _batch_threads(self, still: bool) -> int | None:
        """numba threads of the next accumulation batch: the faster count by the rates
        measured so far (the warm-up's batch, then the still batches'). A still scene's
        first batch and one in ``THREAD_TRIAL`` after it run at the other count: the
        warm-up times one 50 000-photon batch at start-up, and the faster count moves
        with the batch size and the machine's load."""
        rates = self.batch_rates
        if self.threads != "auto" or len(rates) < 2:
            return self.accumulate_threads
        best = max(rates, key=rates.get)
        if not still:
            return best
        self._still_batches += 1
        if self._still_batches == 1 or self._still_batches % THREAD_TRIAL == 0:
            return next(n for n in rates if n != best)
        return best

    def _note_batch_rate(self, threads: int | None, rate: float) -> None:
        """A still batch's photons/s at ``threads`` (moving average, weight
        ``RATE_WEIGHT`` on the new batch; a still scene's first two set it)."""
        if threads is None or threads not in self.batch_rates:
            return
        old = self.batch_rates[threads]
        fresh = self._still_batches <= 2  # a still scene's first batches: now's rate
        self.batch_rates[threads] = rate if (old <= 0 or fresh) else \
            (1.0 - RATE_WEIGHT) * old + RATE_WEIGHT * rate

    def _threads_for(self, accumulating: bool, n: int | None = None) -> None:
        """Switch this thread's numba threads to ``n`` or the warm-up's choice for the
        work."""
        if n is None:
            n = self.accumulate_threads if accumulating else self.frame_threads
        if n is not None:
            import numba

            numba.set_num_threads(n)

    def _config(self, c: Controls, batch: bool = True) -> RunConfig:
        """The session's configuration: its frame is the accumulation's batch cap (an
        interaction frame is a partial frame of ``c.frame_photons``); ``batch=False``
        (Selective Photon Tracing, whose passes are always whole): the controls' frame."""
        photons = max(c.frame_photons, self.batch_photons) if batch else c.frame_photons
        return self.base_config.with_(k=c.k, interleave=c.interleave, frame_photons=photons)

    def _open(self, scene: Scene, c: Controls, camera: bool | None = None) -> None:
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
        self._reset_clock()

    def _camera_wanted(self) -> bool:
        """Whether a tab shows the camera view (the session then needs the camera pass)."""
        return self.camera is not None and self.camera_watchers > 0

    def _camera_shown(self) -> bool:
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
            n = min(n, self.quick_photons)
            if self._rate and self._overhead_s is not None:
                fit = self._rate * max(self.frame_seconds - self._overhead_s, 0.0)
                n = min(n, max(self.min_photons, int(fit)))
        return self._partial(n)

    def _reset_clock(self) -> None:
        self.mode = "interaction"
        self._changed_at = time.perf_counter()
        self._pooled_photons = 0
        self._last_reg = 0.0
        self._last_probe = 0.0
        self._last_camera = 0.0
        self._quick_due = True
        self._batch_s = self.batch_seconds
        self._traced_s = self._traced_at_pooled = 0.0
        self._honest = None
        self._blurs: list[tuple[float, float]] = []  # (blur², its se) of this scene's maps
        self._still_batches = 0  # batches since the scene became still
        self._figure = (None, None)
        self._memory_said = False
        from lightsim.engine.memory import available_bytes

        free = available_bytes()
        self._memory_budget = None if free is None else self.memory_share * free

    def _apply_pending(self) -> bool:
        with self._lock:
            pending, self._pending = self._pending, None
            upload, self._pending_scene = self._pending_scene, None
        if upload is not None:
            editor, c = upload
            self._open(editor.session_scene(c), c)
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
                self._reset_clock()
            elif changed & {*CONFIG_CONTROLS, "wall_distance_m"}:
                # the run configuration or the wall frame (probe grid, radii) changed
                self._open(ed.session_scene(new), new)
            else:
                self.session.update(scene=ed.session_scene(new))
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
        if self._camera_wanted() and not self._camera_pass:
            # a tab asks for the camera view: a session with the camera pass (the
            # photons start afresh, as after an edit)
            self._open(self.editor.session_scene(self.controls), self.controls, camera=True)
        s = self.session
        if not changed and self._converged():
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
        if self.mode == "interaction":
            self._interaction_frame(changed)
        else:
            self._accumulation_step()

    def _interaction_frame(self, changed: bool) -> None:
        """Only the picture: the probes, error figure and table wait for a still scene."""
        s = self.session
        camera = self.camera if self._camera_shown() else None
        t0 = time.perf_counter()
        est = s.frame(image=True, camera=camera, probes=False,
                      photons=self._frame_photons(quick=self._quick_due),
                      image_step=self.interaction_step)
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
        if time.perf_counter() - self._interaction_done < self.still_seconds:
            # a pause in a drag: only short batches, so the next edit waits ≤ one batch
            self.last_status = self._status()
            self.publish("status", self.last_status)
            return
        watched = self._camera_shown()
        now = time.perf_counter()
        camera_due = watched and now - self._last_camera >= max(1.0, 9.0 * self._camera_cost)
        pooled = self._pooled_due()
        # with the scene's error law the first pooled map is due within seconds: until
        # then nothing that builds the kNN trees (interleaved image, table), only the
        # cheap grid figure — every second goes to tracing
        run_up = self._honest is None and self._law_5 is not None
        if pooled:
            est = self._pooled_frame(self.camera if watched else None)
            self._publish_frame(est, "pooled", {})
        elif self._honest is None and self._probe_due() and not (run_up
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
        share = self.regulation_share
        reg_due = (self._last_reg == 0.0 and not run_up) or (
            pooled and time.perf_counter() - self._last_reg
            >= max(self.regulation_interval, self._reg_cost * (1 - share) / share))
        if self.regulation_hook is not None and not self._busy() and reg_due:
            t1 = time.perf_counter()
            table = self.regulation_hook(s)
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
        still = time.perf_counter() - self._interaction_done >= self.still_seconds
        if still:
            n = max(n, self.still_batch_photons)  # a loaded machine: not below full rate
        n = int(min(s.config.frame_photons, n))
        before = self._photons_now()
        threads = self._batch_threads(still)
        t0 = time.perf_counter()
        self._threads_for(accumulating=True, n=threads)
        try:
            s.shoot(self._partial(n))
        finally:
            self._threads_for(accumulating=False)
        dt = time.perf_counter() - t0
        done = self._photons_now() - before
        if dt > 0 and done > 0:
            self._rate = done / dt
            if still:
                self._note_batch_rate(threads, self._rate)
        self._traced_s += dt
        self._batch_s = min(self.batch_max_seconds, self._batch_s * self.batch_growth)
        self._log({"mode": "accumulation", "quality": "batch", "image": False,
                   "photons": self._photons_now(), "batch_photons": done, "batch_s": dt})

    def _log(self, entry: dict[str, Any]) -> None:
        """A log entry (the bench's breakdown), stamped ``t``: seconds since the last change."""
        entry.setdefault("t", time.perf_counter() - self._changed_at)
        self.stats.log.append(entry)

    def _photons_now(self) -> int:
        return int(sum(self.session.emitted_per_set().values()))

    def _probe_due(self) -> bool:
        """The grid-probe figure: at the first still step, then ≤ ``probe_share``."""
        share = self.probe_share
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
        self._pooled_cost = self.stats.last_frame_s = time.perf_counter() - t0
        self.stats.timings = dict(est.timings)
        self.stats.frames += 1
        self._traced_at_pooled = self._traced_s
        self._pooled_photons = int(est.photons)
        self._honest = (_finite(est.rel_error), int(est.photons))
        e = est.error
        if self._honest[0] is not None and est.photons >= LAW_MIN_PHOTONS:
            # the error law of this scene: where the next maps (and the next edit's first
            # map) are due; a warm-up-sized map is not yet in the 1/√N regime
            noise = _finite(e.noise) if e is not None else None
            blur = (_finite(e.bias) or 0.0) if e is not None else 0.0
            self._law = (int(est.photons), self._honest[0],
                         self._honest[0] if noise is None else noise, blur)
            measured = blur_estimate(e)
            if measured is not None:
                self._blurs.append(measured)
            near = self._law_5
            if near is None or abs(math.log(self._honest[0] / ERROR_LEVELS[0])) <= \
                    abs(math.log(near[1] / ERROR_LEVELS[0])):
                self._law_5 = (int(est.photons), self._honest[0])
        self._figure = (est, "written map")
        return est

    def _photons_for(self, level: float) -> float | None:
        """Photons at which the written map's figure is expected to reach ``level``
        (aimed ``LEVEL_AIM`` below it) from the last map's noise (∝ 1/√N) and the blur
        (kept: :meth:`_blur2`); None where the blur alone is above it."""
        if self._law is None:
            return None
        n, _, noise, _ = self._law
        room = (LEVEL_AIM * level) ** 2 - self._blur2()
        return None if room <= 0 else n * noise ** 2 / room

    def _blur2(self) -> float:
        """The written map's squared blur (relative²) for the prediction: the maps of
        this scene each measure the same blur (the rungs' windows do not shrink with the
        photons), so their estimates are pooled by their precision (1/se²): one map's
        blur² scatters by its se, at 1–4 M photons on the shipped headlight by as much as
        the blur² itself (blur 0.4–1.8 % from map to map, 1.4–1.5 % at 8–16 M)."""
        if self._law is None:
            return 0.0
        ok = [(b2, se) for b2, se in self._blurs if se > 0]
        if not ok:
            return self._law[3] ** 2
        w = [1.0 / (se * se) for _, se in ok]
        return sum(wi * b2 for wi, (b2, _) in zip(w, ok, strict=True)) / sum(w)

    def _pooled_due(self) -> bool:
        """The next pooled map (M² times an image's work). The first: where the scene's
        error law (the map nearest 5 % so far: e √N) predicts 5 % (aimed ``FIRST_AIM``
        below it), after at least the map's own cost of tracing — or, with no law yet,
        after ``first_pooled_seconds`` of tracing. Then where the figure is expected to
        cross the next level (noise ∝ 1/√N beside the blur), otherwise at twice the
        photons with its cost ≤ ``pooled_share`` of the time — unless the crossing is
        due before that."""
        if self._honest is None:
            first = max(self.first_pooled_seconds, self._pooled_cost)
            if self._law_5 is None:
                return self._traced_s >= first
            n, e = self._law_5
            n5 = n * (e / (FIRST_AIM * ERROR_LEVELS[0])) ** 2
            return (self._traced_s >= self._pooled_cost and self._photons_now() >= n5) or \
                self._traced_s >= max(self.first_cap_seconds, 2.0 * self._pooled_cost)
        err, n_last = self._honest
        photons = self._photons_now()
        if err is not None:
            below = [lv for lv in ERROR_LEVELS if lv < err]
            due = self._photons_for(below[0]) if below else None
            if due is not None and photons >= due:
                return True
            if due is not None and due <= 2 * photons:
                return False  # the next level's map comes before a doubled one would
        share = self.pooled_share
        return photons >= 2 * n_last and (self._traced_s - self._traced_at_pooled
                                          >= self._pooled_cost * (1 - share) / share)

    def _converged(self) -> bool:
        """Accumulation has reached ``stop_error`` (by the written map's figure),
        ``max_photons`` or ``memory_share`` of the memory: stop shooting."""
        if self.mode != "accumulation":
            return False
        if self._memory_full():
            return True
        if self._honest is None:
            return False
        err, photons = self._honest
        return photons >= self.max_photons or (err is not None and err <= self.stop_error)

    def _memory_full(self) -> bool:
        """The stored photons (at their insertion peak) have reached ``memory_share`` of
        the memory that was available when the scene last changed; said once."""
        from lightsim.engine.memory import bytes_per_photon

        if self._memory_budget is None:
            return False
        stats = self.session.backend.stats()
        records = sum(int(st.get("records", 0)) for st in stats.values())
        full = records * bytes_per_photon(self.session.plan.channels or 1, peak=True) \
            >= self._memory_budget
        if full and not self._memory_said:
            self._memory_said = True
            self._message("info", f"accumulation stopped at {self._photons_now():,} photons: "
                          f"the photon maps hold {100 * self.memory_share:.0f} % of the memory "
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
                "rel_error": _finite(est.rel_error), "wall": w.to_dict()}

    def _status(self, quality: str | None = None) -> dict[str, Any]:
        """Mode, photons and the latest error figure with where it comes from: the
        written map (a pooled map, at ``error_photons``) or the grid probes."""
        est, source = self._figure
        e = None if est is None else est.error
        return {"edit": self.edit, "mode": self.mode, "quality": quality or (
                    "pooled" if self._pooled_photons else "interleaved"),
                "photons": self._photons_now(),
                "rel_error": None if est is None else _finite(est.rel_error),
                "error_source": source,
                "error_photons": None if est is None else int(est.photons),
                "rel_noise": None if e is None else _finite(e.noise),
                "rel_bias": None if e is None else _finite(e.bias),
                "error_text": None if e is None else e.describe(),
                "still_s": time.perf_counter() - self._changed_at,
                "frame_s": self.stats.last_frame_s, "frames": self.stats.frames,
                "numba_threads": _numba_threads(),
                "batch_threads": self.accumulate_threads if self.threads != "auto" or len(
                    self.batch_rates) < 2 else max(self.batch_rates, key=self.batch_rates.get),
                "photons_per_s": self._rate,
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
            # the GLB is the edited scene as a user loads it: the lamp aimed, the wall fixed
            files = self.save_hook(tmp, s, est, self.controls, self.editor.build(self.controls))
            shutil.copy2(self.folder / "edits.jsonl", tmp / "edits.jsonl")
            os.replace(tmp, final)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return f"saved {final} ({', '.join(sorted(files))}, {est.photons:,} photons)"


def blur_estimate(e) -> tuple[float, float] | None:
    """(blur², its standard error), relative², of an error figure
    (:class:`~lightsim.render.frame.ErrorEstimate`): ``bias_upper``² = blur² + 2 se, and a
    negative blur² estimate reads as 0; None without the figure's parts."""
    bias = None if e is None else _finite(e.bias)
    upper = None if e is None else _finite(e.bias_upper)
    if bias is None or upper is None:
        return None
    return bias * bias, max(upper * upper - bias * bias, 0.0) / 2.0


def _finite(x: float | None) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _numba_threads() -> int:
    import numba

    return int(numba.get_num_threads())
