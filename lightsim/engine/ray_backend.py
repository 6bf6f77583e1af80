"""Ray backend: clients are Ray actors (``--workers N`` locally, ``--address`` on a cluster).

Only what the paper sends crosses the network (section 4.2): the scene goes to the
object store once per change, and per frame every actor returns its sets' filtered
quantities — sub-image pixels and probe values (lx) — never photons. The backend counts
those bytes (``bytes_last_frame``).

Faults: an actor that dies mid-frame is replaced by a new one that replays its sets to
where they were (photons are a function of seed, set and index, so the replay is exact)
and the frame is computed again; the run ends with the same result as without the fault.

=====================  =====  ==========  ===============================================
parameter              unit   default     meaning
=====================  =====  ==========  ===============================================
``address``            –      none        existing cluster (``HOST:PORT``, ``auto``);
                                          none starts a local Ray runtime
``threads per actor``  –      cores / N   ray-casting and numba threads of each actor
                                          (``RunConfig.threads`` when set)
``max_retries``        –      3           replacements of a dead actor within one call
=====================  =====  ==========  ===============================================
"""

from __future__ import annotations

import os
import pickle
import socket
from collections.abc import Callable
from typing import Any

import numba
import numpy as np

from lightsim.engine.client import Client
from lightsim.engine.config import RunConfig
from lightsim.engine.plan import Plan
from lightsim.engine.process import tune_process
from lightsim.engine.results import ClientFrame, RenderRequest, ShootResult
from lightsim.errors import ClusterError
from lightsim.scene import Scene


def import_ray():
    """The ``ray`` module, imported on first use (Ray's import is heavy, and only a run
    with workers or a cluster needs it)."""
    import ray

    return ray


def _probe_address(address: str, timeout: float = 5.0) -> None:
    """Fail fast with one line if a HOST:PORT cluster address does not answer.

    ``ray.init(address=…)`` on a dead address retries for minutes; a plain TCP connect to
    the GCS port tells within seconds.
    """
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or "://" in address:
        return  # "auto", "ray://…": let Ray resolve them
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ClusterError(f"cannot reach a Ray cluster at {address}: {reason}") from None


def init_ray(address: str | None, n_actors: int) -> bool:
    """Connect to the Ray cluster at ``address`` (``HOST:PORT``, ``auto``) or start a
    local Ray runtime with room for ``n_actors`` actors (at least one CPU each); returns
    True if this call started it (the caller then shuts it down). A cluster that does not
    answer raises :class:`~lightsim.errors.ClusterError` (one line)."""
    ray = import_ray()
    if ray.is_initialized():
        return False
    if address:
        _probe_address(address)
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                              "configure_logging": False}
    try:
        if address:
            ray.init(address=address, **kwargs)
        else:
            ray.init(num_cpus=max(n_actors, os.cpu_count() or 1), **kwargs)
    except (ConnectionError, TimeoutError, RuntimeError, ValueError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        where = f"at {address}" if address else "locally"
        raise ClusterError(f"cannot reach a Ray cluster {where}: {msg}") from None
    return True


def _actor_class():
    ray = import_ray()

    @ray.remote(max_restarts=0, max_task_retries=0)
    class ClientActor:
        """A :class:`~lightsim.engine.client.Client` living in a Ray worker process."""

        def __init__(self, scene: Scene, config: RunConfig, plan: Plan, sets: list[int],
                     probes_hv: np.ndarray, threads: int) -> None:
            tune_process()  # a worker process of its own: the command's process policy
            numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
            self.client = Client(scene, config.with_(threads=threads), plan, sets, probes_hv)

        def shoot(self, total: int | None) -> ShootResult:
            return self.client.shoot(total)

        def render(self, request: RenderRequest) -> ClientFrame:
            return self.client.render(request)

        def probe(self, points_hv: np.ndarray) -> dict[int, np.ndarray]:
            return self.client.probe(points_hv)

        def apply_refs(self, changes: list[tuple]) -> None:
            """Interaction changes; whole scenes arrive as object refs inside the list."""
            import ray

            self.client.apply([("scene", ray.get(c[1])) if c[0] == "scene" else c
                               for c in changes])

        def stats(self) -> dict[int, dict[str, Any]]:
            return self.client.stats()

        def apertures(self) -> dict[int, np.ndarray | None]:
            return self.client.apertures()

        def counters(self) -> dict[int, int]:
            return self.client.counters()

        def replay(self, frames: dict[int, int], partial: dict[int, int]) -> None:
            self.client.replay(frames, partial)

        def pid(self) -> int:
            return os.getpid()

    return ClientActor


class RayBackend:
    """Clients as Ray actors (a :class:`~lightsim.engine.backend.Backend`), with static
    set assignment and exact replay on faults."""

    def __init__(self, scene: Scene, config: RunConfig, plan: Plan,
                 assignment: list[list[int]], probes_hv: np.ndarray,
                 address: str | None = None, max_retries: int = 3) -> None:
        self.assignment = [sets for sets in assignment if sets]
        self.started = init_ray(address, len(self.assignment))
        ray = import_ray()
        self.config, self.plan, self.probes_hv = config, plan, probes_hv
        self.max_retries = max_retries
        cpus = int(ray.cluster_resources().get("CPU", os.cpu_count() or 1))
        self.threads = config.threads or max(1, cpus // max(1, len(self.assignment)))
        self._cls = _actor_class()
        self.scene_ref = self.base_ref = ray.put(scene)  # base: where newcomers start
        self.scene_bytes = len(pickle.dumps(scene))
        self.actors = [self._spawn(sets) for sets in self.assignment]
        self.frames_shot = [0] * len(self.actors)  # per actor, for replay after a fault
        self.partial: dict[int, int] = {}  # frame index → photons of a partial frame
        self.changes_log: list[list[tuple]] = []  # interaction changes, replayed to newcomers
        self.bytes_last_frame = 0
        self.restarts = 0

    def _spawn(self, sets: list[int]):
        return self._cls.options(num_cpus=0).remote(self.base_ref, self.config, self.plan,
                                                   sets, self.probes_hv, self.threads)

    # -- calls with fault recovery --------------------------------------------------------
    def _call_all(self, call: Callable[[Any], Any]) -> list[Any]:
        """``call(actor)`` (one remote method call) on every actor, answers in order."""
        refs = [call(a) for a in self.actors]
        return [self._get(i, ref, call) for i, ref in enumerate(refs)]

    def _get(self, i: int, ref, call: Callable[[Any], Any]) -> Any:
        ray = import_ray()
        for attempt in range(self.max_retries + 1):
            try:
                return ray.get(ref)
            except (ray.exceptions.RayActorError, ray.exceptions.WorkerCrashedError,
                    ray.exceptions.ObjectLostError) as exc:
                if attempt == self.max_retries:
                    raise ClusterError(f"client {i} (sets {self.assignment[i]}) died "
                                       f"{attempt + 1} times: {type(exc).__name__}") from None
                self._replace(i)
                ref = call(self.actors[i])
        raise AssertionError("unreachable")

    def _replace(self, i: int) -> None:
        """A new actor for client i, replayed to the frames it had completed."""
        ray = import_ray()
        self.restarts += 1
        actor = self._spawn(self.assignment[i])
        for sent in self.changes_log:  # bring the newcomer to the current scene
            ray.get(actor.apply_refs.remote(sent))
        frames = {s: self.frames_shot[i] for s in self.assignment[i]}
        ray.get(actor.replay.remote(frames, dict(self.partial)))
        self.actors[i] = actor

    # -- backend interface --------------------------------------------------------------
    def shoot(self, total: int | None = None) -> list[ShootResult]:
        if total is not None:  # a partial frame, replayed as such after a fault
            self.partial[max(self.frames_shot, default=0)] = int(total)
        out = self._call_all(lambda a: a.shoot.remote(total))
        self.frames_shot = [f + 1 for f in self.frames_shot]
        return out

    def render(self, request: RenderRequest) -> list[ClientFrame]:
        out = self._call_all(lambda a: a.render.remote(request))
        self.bytes_last_frame = sum(f.nbytes for c in out for f in c.sets)
        return out

    def probe(self, points_hv: np.ndarray) -> dict[int, np.ndarray]:
        out: dict[int, np.ndarray] = {}
        for r in self._call_all(lambda a: a.probe.remote(points_hv)):
            out.update(r)
        return dict(sorted(out.items()))

    def apply(self, changes: list[tuple]) -> None:
        """Send the changes to every actor; a new whole scene goes via the object store."""
        ray = import_ray()
        sent = []
        for change in changes:
            if change[0] == "scene":
                self.scene_ref = ray.put(change[1])
                self.scene_bytes = len(pickle.dumps(change[1]))
                sent.append(("scene", self.scene_ref))
            else:
                sent.append(change)
        self.changes_log.append(sent)
        self._call_all(lambda a: a.apply_refs.remote(sent))
        self.frames_shot = [0] * len(self.actors)
        self.partial = {}

    def stats(self) -> dict[int, dict[str, Any]]:
        out: dict[int, dict[str, Any]] = {}
        for r in self._call_all(lambda a: a.stats.remote()):
            out.update(r)
        return dict(sorted(out.items()))

    def apertures(self) -> dict[int, Any]:
        out: dict[int, Any] = {}
        for r in self._call_all(lambda a: a.apertures.remote()):
            out.update(r)
        return dict(sorted(out.items()))

    def counters(self) -> dict[int, int]:
        out: dict[int, int] = {}
        for r in self._call_all(lambda a: a.counters.remote()):
            out.update(r)
        return out

    def replay(self, counters: dict[int, int], partial: dict[int, int] | None = None) -> None:
        counters = {int(k): int(v) for k, v in counters.items()}
        ray = import_ray()
        refs = []
        self.partial = {int(k): int(v) for k, v in (partial or {}).items()}
        for i, (actor, sets) in enumerate(zip(self.actors, self.assignment, strict=True)):
            frames = {s: counters.get(s, 0) for s in sets}
            refs.append(actor.replay.remote(frames, dict(self.partial)))
            self.frames_shot[i] = max(frames.values(), default=0)
        ray.get(refs)

    def pids(self) -> list[int]:
        ray = import_ray()
        return ray.get([a.pid.remote() for a in self.actors])

    def close(self) -> None:
        ray = import_ray()
        for a in self.actors:
            try:
                ray.kill(a)
            except Exception:  # already gone
                pass
        self.actors = []
        if self.started and ray.is_initialized():
            ray.shutdown()
