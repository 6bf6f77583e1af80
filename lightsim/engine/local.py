"""In-process backend (``--workers 0``): the clients are plain objects in this process.

No Ray is started. One client holds every set; it still uses every core, because embree
casts each ray batch on a pool of threads and the numba kernels run in parallel.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

from lightsim.engine.client import Client
from lightsim.engine.config import RunConfig
from lightsim.engine.plan import Plan
from lightsim.engine.results import ClientFrame, RenderRequest, ShootResult
from lightsim.scene import Scene


class LocalBackend:
    """Clients called one after the other in this process (a
    :class:`~lightsim.engine.backend.Backend`)."""

    def __init__(self, scene: Scene, config: RunConfig, plan: Plan,
                 assignment: list[list[int]], probes_hv: np.ndarray, caster=None) -> None:
        if config.threads:  # numba's pool is per process: honour an explicit thread count
            numba.set_num_threads(max(1, min(config.threads, numba.config.NUMBA_NUM_THREADS)))
        # ``caster``: the scene's RayCaster, shared (read-only) by the clients
        self.clients = [Client(scene, config, plan, sets, probes_hv, caster=caster)
                        for sets in assignment if sets]

    def shoot(self, total: int | None = None) -> list[ShootResult]:
        return [c.shoot(total) for c in self.clients]

    def render(self, request: RenderRequest) -> list[ClientFrame]:
        return [c.render(request) for c in self.clients]

    def probe(self, points_hv: np.ndarray) -> dict[int, np.ndarray]:
        out: dict[int, np.ndarray] = {}
        for c in self.clients:
            out.update(c.probe(points_hv))
        return dict(sorted(out.items()))

    def apply(self, changes: list[tuple]) -> None:
        for c in self.clients:
            c.apply(changes)

    def stats(self) -> dict[int, dict[str, Any]]:
        out: dict[int, dict[str, Any]] = {}
        for c in self.clients:
            out.update(c.stats())
        return dict(sorted(out.items()))

    def per_source(self) -> list[tuple[np.ndarray, np.ndarray, dict[int, np.ndarray]] | None]:
        return [c.per_source() for c in self.clients]

    def apertures(self) -> dict[int, Any]:
        out: dict[int, Any] = {}
        for c in self.clients:
            out.update(c.apertures())
        return dict(sorted(out.items()))

    def paths(self) -> dict[int, Any]:
        out: dict[int, Any] = {}
        for c in self.clients:
            out.update(c.paths())
        return dict(sorted(out.items()))

    def counters(self) -> dict[int, int]:
        out: dict[int, int] = {}
        for c in self.clients:
            out.update(c.counters())
        return out

    def replay(self, counters: dict[int, int], partial: dict[int, int] | None = None) -> None:
        counters = {int(k): int(v) for k, v in counters.items()}
        for c in self.clients:
            c.replay({s: counters.get(s, 0) for s in c.set_indices}, partial)

    def close(self) -> None:
        for c in self.clients:
            c.tracer.caster.close()
