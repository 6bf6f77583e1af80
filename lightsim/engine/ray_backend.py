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
                                          none starts a private local Ray instance
``actors``             –      CPUs        ``--workers N``, else one per CPU of the
                                          cluster; at most one per interleave set
``CPUs per actor``     –      1           reserved on the cluster (an equal share where
                                          N exceeds its CPUs; 0 for replacements)
``threads per actor``  –      CPUs / N    ray-casting and numba threads of each actor
                                          (``RunConfig.threads`` when set)
``max_retries``        –      3           replacements of a dead actor within one call
``PROBE_TIMEOUT_S``    s      5           an address, token check or head must answer
                                          within this
``HEAD_POLL_S``        s      2           the head node is checked this often while
                                          the actors work
=====================  =====  ==========  ===============================================

Connecting (:func:`connect`): ``--address`` first gets a TCP connect to the GCS port (a
wrong address fails in seconds), then the token, picked up as Ray's ``address="auto"``
does (:func:`pick_up_token`), is checked with one GCS request (a wrong or missing token
fails in a second, named as such). ``--workers N`` alone starts a private local Ray
instance, even where a Ray cluster already runs on the machine. ``--address`` without
``--workers`` runs one actor per CPU of the cluster, at most one per interleave set
(:func:`actor_count`), spread over the nodes.

A lost worker node: its actors' calls fail, the replacements start on the nodes left and
replay their sets (the map is the same, bit for bit). A lost head node: the next wait
notices within :data:`HEAD_POLL_S` and raises one line; the frames shot so far are known
here (:meth:`RayBackend.counters`), so the run can be checkpointed and resumed.
"""

from __future__ import annotations

import contextlib
import math
import os
import pickle
import socket
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
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

PROBE_TIMEOUT_S = 5.0
"""Seconds a cluster address, its token check or the head node may take to answer."""

HEAD_POLL_S = 2.0
"""Seconds between checks of the head node while waiting for the actors."""

AUTH_MODE_ENV = "RAY_AUTH_MODE"
"""Ray's authentication mode variable (``token`` or ``disabled``)."""


def import_ray():
    """The ``ray`` module, imported on first use (Ray's import is heavy, and only a run
    with workers or a cluster needs it)."""
    import ray

    return ray


def _probe_address(address: str, timeout: float = PROBE_TIMEOUT_S) -> None:
    """Fail fast with one line if a HOST:PORT cluster address does not answer.

    ``ray.init(address=…)`` on a dead address retries for minutes; a plain TCP connect to
    the GCS port tells within seconds.
    """
    hostport = _host_port(address)
    if hostport is None:
        return  # "auto", "ray://…": let Ray resolve them
    try:
        with socket.create_connection(hostport, timeout=timeout):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ClusterError(f"cannot reach a Ray cluster at {address}: {reason} (wrong "
                           "address? `ray start --head` prints the one to give)") from None


def _host_port(address: str) -> tuple[str, int] | None:
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or "://" in address:
        return None
    return host or "127.0.0.1", int(port)


def pick_up_token() -> bool:
    """Use token authentication if this machine holds a Ray token, as Ray's own
    ``address="auto"`` does: with ``RAY_AUTH_MODE`` unset and a token in
    ``RAY_AUTH_TOKEN``, the file ``RAY_AUTH_TOKEN_PATH`` names or ``~/.ray/auth_token``,
    the mode becomes ``token`` (for this process and the Ray processes it starts).
    Returns True if token authentication is on. A token sent to a cluster without
    authentication is ignored there, so picking one up never hurts."""
    from ray._raylet import AuthenticationTokenLoader, Config

    mode = os.environ.get(AUTH_MODE_ENV)
    if mode is not None:
        return mode.lower() == "token"
    if not AuthenticationTokenLoader.instance().has_token(ignore_auth_mode=True):
        return False
    os.environ[AUTH_MODE_ENV] = "token"
    Config.initialize("")  # Ray reads its settings once: again, now in token mode
    return True


def _check_token(address: str) -> None:
    """One request to the cluster's GCS: a refused token fails here within a second,
    where ``ray.init`` would wait 20 s and then name a connection failure."""
    from ray._raylet import AuthenticationTokenLoader, GcsClient
    from ray.exceptions import AuthenticationError

    if _host_port(address) is None:
        return
    try:
        with _quiet_stderr():  # Ray's C++ client logs the refusal too: one line is ours
            GcsClient(address=address).internal_kv_get(b"lightsim-probe", None,
                                                        timeout=PROBE_TIMEOUT_S)
    except AuthenticationError:
        mode = os.environ.get(AUTH_MODE_ENV, "")
        has = AuthenticationTokenLoader.instance().has_token(ignore_auth_mode=True)
        fix = ("give this machine the head node's token (`ray get-auth-token` there) in "
               "RAY_AUTH_TOKEN, or in a file named by RAY_AUTH_TOKEN_PATH")
        if mode.lower() != "token" and mode:
            why = (f"the Ray cluster at {address} requires token authentication but "
                   f"{AUTH_MODE_ENV}={mode} here: unset it or set {AUTH_MODE_ENV}=token")
        elif has:
            why = f"the Ray cluster at {address} refused this machine's token (wrong token): {fix}"
        else:
            why = (f"the Ray cluster at {address} requires an authentication token and this "
                   f"machine has none: {fix}")
        raise ClusterError(why) from None
    except Exception:  # anything else: ray.init names it
        return


@contextlib.contextmanager
def _quiet_stderr() -> Iterator[None]:
    """File descriptor 2 to /dev/null for the block (C++ logging bypasses Python's)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


@dataclass
class RayCluster:
    """The Ray runtime a run uses, as found when connecting.

    ``address`` None: a private local instance this process started (``started``)."""

    address: str | None
    cpus: int
    nodes: int
    started: bool
    gcs_address: str = ""

    def head_alive(self) -> bool:
        """Whether the cluster's GCS (on the head node) still accepts connections."""
        hostport = _host_port(self.gcs_address)
        if hostport is None:
            return True
        try:
            with socket.create_connection(hostport, timeout=PROBE_TIMEOUT_S):
                return True
        except OSError:
            return False


def connect(address: str | None, n_actors: int) -> RayCluster:
    """Connect to the Ray cluster at ``address`` (``HOST:PORT``, ``auto``) or start a
    private local Ray instance with room for ``n_actors`` actors (one CPU each).

    A private instance is started even where a Ray cluster already runs on this machine
    (``ray.init()`` would join that one, and refuse the CPU count). A cluster that does
    not answer, or refuses the token, raises :class:`~lightsim.errors.ClusterError`
    (one line, within seconds)."""
    ray = import_ray()
    started = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                  "configure_logging": False}
        if address:
            _probe_address(address)
            pick_up_token()
            _check_token(address)
        try:  # Ray's C++ side logs start-up warnings here; failures are raised too
            with _quiet_stderr():
                if address:
                    ray.init(address=address, **kwargs)
                else:
                    ray.init(address="local", num_cpus=max(n_actors, os.cpu_count() or 1),
                             **kwargs)
        except (ConnectionError, TimeoutError, RuntimeError, ValueError) as exc:
            text = str(exc).strip()
            msg = text.splitlines()[0] if text else type(exc).__name__
            where = f"at {address}" if address else "locally"
            raise ClusterError(f"cannot reach a Ray cluster {where}: {msg}") from None
        started = True
    alive = [n for n in ray.nodes() if n.get("Alive")]
    cpus = int(ray.cluster_resources().get("CPU", 0))
    gcs = ray.get_runtime_context().gcs_address
    return RayCluster(address if address else None, cpus, len(alive), started, gcs)


def init_ray(address: str | None, n_actors: int) -> bool:
    """:func:`connect`; True if this call started the runtime (the caller then shuts it
    down)."""
    return connect(address, n_actors).started


def actor_count(cluster: RayCluster, workers: int, n_sets: int) -> tuple[int, list[str]]:
    """Actors for a run and the notes that say why.

    ``workers`` N ≥ 1: N actors; 0 (``--address`` alone): one per CPU of the cluster.
    Never more than the ``n_sets`` interleave sets (an actor holds whole sets); where the
    cluster has more CPUs than sets, a note says how large ``-M`` would use them all —
    the sets are never changed here, as a different ``-M`` is a different run."""
    notes: list[str] = []
    n = workers if workers else max(1, cluster.cpus)
    if n > n_sets:
        m = math.isqrt(n_sets)
        wanted = f"--workers {workers}" if workers else f"its {cluster.cpus} CPUs"
        where = f"the Ray cluster at {cluster.address}" if cluster.address else "this run"
        k = math.isqrt(n - 1) + 1
        sets = f"{n_sets} interleave set{'s' if n_sets > 1 else ''}"
        notes.append(f"{where} could run {n} actors ({wanted}) but -M {m} gives {sets}, "
                     f"one actor each at most: {n_sets} run; -M {k} ({k * k} sets) would use "
                     "them all (a different -M is a different, equally valid run)")
        n = n_sets
    return n, notes


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

        def per_source(self) -> tuple[np.ndarray, np.ndarray, dict[int, np.ndarray]] | None:
            return self.client.per_source()

        def paths(self) -> dict[int, Any]:
            return self.client.paths()

        def counters(self) -> dict[int, int]:
            return self.client.counters()

        def replay(self, frames: dict[int, int], partial: dict[int, int]) -> None:
            self.client.replay(frames, partial)

        def pid(self) -> int:
            return os.getpid()

        def node(self) -> str:
            """The id of the Ray node this actor runs on."""
            import ray

            return ray.get_runtime_context().get_node_id()

    return ClientActor


def _per_node(nodes: list[str]) -> list[int]:
    """Actors per node, most first."""
    counts: dict[str, int] = {}
    for node in nodes:
        counts[node] = counts.get(node, 0) + 1
    return sorted(counts.values(), reverse=True)


class RayBackend:
    """Clients as Ray actors (a :class:`~lightsim.engine.backend.Backend`), with static
    set assignment and exact replay on faults.

    Each actor reserves CPUs of the cluster (one, or an equal share where more actors
    are asked for than there are CPUs) and they are spread over the nodes; a replacement
    for an actor whose node was lost reserves none, so it starts on what is left."""

    def __init__(self, scene: Scene, config: RunConfig, plan: Plan,
                 assignment: list[list[int]], probes_hv: np.ndarray,
                 address: str | None = None, max_retries: int = 3,
                 cluster: RayCluster | None = None) -> None:
        self.assignment = [sets for sets in assignment if sets]
        n = len(self.assignment)
        self.cluster = cluster or connect(address, n)
        self.started = self.cluster.started
        ray = import_ray()
        self.config, self.plan, self.probes_hv = config, plan, probes_hv
        self.max_retries = max_retries
        cpus = max(1, self.cluster.cpus)
        self.threads = config.threads or max(1, cpus // max(1, n))
        # CPUs reserved per actor: whole ones where they fit, else an equal share
        self.actor_cpus = 1.0 if n <= cpus else math.floor(cpus / n * 1e4) / 1e4
        self._cls = _actor_class()
        self.scene_ref = self.base_ref = ray.put(scene)  # base: where newcomers start
        self.scene_bytes = len(pickle.dumps(scene))
        self.actors = [self._spawn(sets, self.actor_cpus) for sets in self.assignment]
        self.frames_shot = [0] * len(self.actors)  # per actor, for replay after a fault
        self.partial: dict[int, int] = {}  # frame index → photons of a partial frame
        self.changes_log: list[list[tuple]] = []  # interaction changes, replayed to newcomers
        self.bytes_last_frame = 0
        self.restarts = 0
        self.head_lost = False
        self.nodes: list[str] = []
        self.nodes = self._call_all(lambda a: a.node.remote())  # where each actor runs
        self.start_per_node = _per_node(self.nodes)

    def _spawn(self, sets: list[int], cpus: float):
        return self._cls.options(num_cpus=cpus, scheduling_strategy="SPREAD").remote(
            self.base_ref, self.config, self.plan, sets, self.probes_hv, self.threads)

    def placement(self) -> dict[str, Any]:
        """Where the run's actors are: nodes and CPUs of the cluster, actors per node."""
        return {"address": self.cluster.address or "local", "nodes": self.cluster.nodes,
                "cpus": self.cluster.cpus, "actors": len(self.actors),
                "actors_per_node": _per_node(self.nodes),
                "actors_per_node_at_start": self.start_per_node,
                "restarts": self.restarts}

    # -- calls with fault recovery --------------------------------------------------------
    def _call_all(self, call: Callable[[Any], Any]) -> list[Any]:
        """``call(actor)`` (one remote method call) on every actor, answers in order."""
        refs = [call(a) for a in self.actors]
        return [self._get(i, ref, call) for i, ref in enumerate(refs)]

    def _wait(self, ref) -> Any:
        """``ray.get(ref)``, watching the head node while waiting: a lost head raises
        :class:`~lightsim.errors.ClusterError` within seconds (Ray itself would wait a
        minute, then end this process)."""
        ray = import_ray()
        while True:
            ready, _ = ray.wait([ref], timeout=HEAD_POLL_S)
            if ready:
                return ray.get(ready[0])
            self._check_head()

    def _check_head(self) -> None:
        """Raise :class:`~lightsim.errors.ClusterError` (one line) if the head node is
        gone: every call into Ray would then hang until Ray ends this process."""
        if not self.cluster.head_alive():
            self.head_lost = True
            where = self.cluster.address or "on this machine"
            if self.cluster.gcs_address != where:
                where += f", GCS at {self.cluster.gcs_address}"
            raise ClusterError(f"lost the Ray cluster's head node ({where})")

    def _get(self, i: int, ref, call: Callable[[Any], Any]) -> Any:
        """The answer of client i's call ``ref``; a client lost meanwhile (its process or
        its node) is replaced, replayed and asked again, up to ``max_retries`` times."""
        ray = import_ray()
        lost = (ray.exceptions.RayActorError, ray.exceptions.WorkerCrashedError,
                ray.exceptions.ObjectLostError, ray.exceptions.NodeDiedError)
        last = ""
        for _attempt in range(self.max_retries + 1):
            try:
                if ref is None:
                    self._replace(i)
                    ref = call(self.actors[i])
                return self._wait(ref)
            except lost as exc:
                self._check_head()  # a lost head takes its actors with it: no replacing
                last, ref = type(exc).__name__, None
        raise ClusterError(f"client {i} (sets {self.assignment[i]}) was lost "
                           f"{self.max_retries + 1} times (last: {last})")

    def _replace(self, i: int) -> None:
        """A new actor for client i, replayed to the frames it had completed.

        It is placed away from the node the lost one ran on (that node may be dying
        without Ray knowing yet): on this process's node if it can, and it reserves no
        CPU (a lost node took its CPUs with it)."""
        ray = import_ray()
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        self.restarts += 1
        with contextlib.suppress(Exception):  # it may be alive but unreachable
            ray.kill(self.actors[i], no_restart=True)
        avoid = self.nodes[i] if i < len(self.nodes) else None
        here = ray.get_runtime_context().get_node_id()
        alive = [n["NodeID"] for n in ray.nodes() if n.get("Alive") and n["NodeID"] != avoid]
        target = here if here in alive else (alive[0] if alive else None)
        strategy = (NodeAffinitySchedulingStrategy(target, soft=True) if target
                    else "DEFAULT")
        actor = self._cls.options(num_cpus=0, scheduling_strategy=strategy).remote(
            self.base_ref, self.config, self.plan, self.assignment[i], self.probes_hv,
            self.threads)
        self.actors[i] = actor
        for sent in self.changes_log:  # bring the newcomer to the current scene
            self._wait(actor.apply_refs.remote(sent))
        frames = {s: self.frames_shot[i] for s in self.assignment[i]}
        self._wait(actor.replay.remote(frames, dict(self.partial)))
        if i < len(self.nodes):
            self.nodes[i] = self._wait(actor.node.remote())

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

    def per_source(self) -> list[tuple[np.ndarray, np.ndarray, dict[int, np.ndarray]] | None]:
        return list(self._call_all(lambda a: a.per_source.remote()))

    def apertures(self) -> dict[int, Any]:
        out: dict[int, Any] = {}
        for r in self._call_all(lambda a: a.apertures.remote()):
            out.update(r)
        return dict(sorted(out.items()))

    def paths(self) -> dict[int, Any]:
        out: dict[int, Any] = {}
        for r in self._call_all(lambda a: a.paths.remote()):
            out.update(r)
        return dict(sorted(out.items()))

    def counters(self) -> dict[int, int]:
        """Frames shot per set, as this process counted them (every frame reaches every
        set): known without the actors, so a run whose head node is lost can still be
        checkpointed."""
        return {s: self.frames_shot[i] for i, sets in enumerate(self.assignment)
                for s in sets}

    def replay(self, counters: dict[int, int], partial: dict[int, int] | None = None) -> None:
        counters = {int(k): int(v) for k, v in counters.items()}
        refs = []
        self.partial = {int(k): int(v) for k, v in (partial or {}).items()}
        for i, (actor, sets) in enumerate(zip(self.actors, self.assignment, strict=True)):
            frames = {s: counters.get(s, 0) for s in sets}
            refs.append(actor.replay.remote(frames, dict(self.partial)))
            self.frames_shot[i] = max(frames.values(), default=0)
        for ref in refs:
            self._wait(ref)

    def pids(self) -> list[int]:
        ray = import_ray()
        return ray.get([a.pid.remote() for a in self.actors])

    def close(self) -> None:
        ray = import_ray()
        if self.head_lost:  # nothing to release there; calls into Ray would hang
            self.actors = []
            return
        for a in self.actors:
            try:
                ray.kill(a)
            except Exception:  # already gone
                pass
        self.actors = []
        if self.started and ray.is_initialized():
            ray.shutdown()
