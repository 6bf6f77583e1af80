"""A rendering client: a group of interleave sets, their photons and their estimates.

The paper's client (sections 3.3, 4.3, 5) holds any number of the M×M interleave sets
(static assignment) and, per frame, shoots photons into them and returns their part of
the image and the probe estimates. Its two halves are their own modules:
:mod:`lightsim.engine.photonset` (sampler, photon stores, ledger; shoot, insert, replay)
and :mod:`lightsim.engine.estimator` (kNN / bin / ICI windows, the radius policy,
pooled vs interleaved). A set's state is a pure function of (scene, config, seed, set
index, frames shot), so a run is bit-identical however the sets are spread over clients.
"""

from __future__ import annotations

import os
import time
from dataclasses import replace as dc_replace
from typing import Any

import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.engine.estimator import SetEstimator, point_spec, scene_scale
from lightsim.engine.photonset import PhotonSets
from lightsim.engine.plan import Plan
from lightsim.engine.results import ClientFrame, RenderRequest, ShootResult
from lightsim.errors import InputError
from lightsim.raycast import WALL_MAX_TRIANGLES
from lightsim.scene import Scene
from lightsim.threads import second_thread


def apply_changes(scene: Scene, changes: list[tuple]) -> tuple[Scene, bool]:
    """Apply interaction changes to a scene: returns (new scene, geometry changed).

    Changes: ``("scene", Scene)``, ``("material", part, {"ior"|"reflectance"|"albedo"|
    "rgb"|"sigma": value})``, ``("transform", part, 4×4)``, ``("light", 4×4)`` (moves
    every emitter; emitters are not traced, so the embree scene stays), ``("wall", 4×4)``
    (moves the wall and its frame, :meth:`Scene.with_wall_transform`: the wall is
    intersected outside embree, so the embree scene stays — aiming the lamp by R is
    ``("wall", R⁻¹)``).
    """
    geometry = False
    for change in changes:
        kind = change[0]
        if kind == "scene":
            scene, geometry = change[1], True
        elif kind == "material":
            _, name, values = change
            part = next((p for p in scene.parts if p.name == name), None)
            if part is None:
                raise InputError(f"no part named '{name}'")
            kw: dict[str, Any] = {}
            if "ior" in values:
                kw["ior"] = float(values["ior"])
            for key in ("reflectance", "albedo", "rgb"):
                if key in values:
                    kw["rgb"] = np.broadcast_to(np.asarray(values[key], float), (3,)).copy()
            if "sigma" in values:
                kw["sigma"] = np.broadcast_to(np.asarray(values["sigma"], float), (3,)).copy()
            scene = scene.replace_part(name, material=dc_replace(part.material, **kw))
        elif kind == "transform":
            scene, geometry = scene.transform_part(change[1], change[2]), True
        elif kind == "light":
            for p in scene.emitters:
                scene = scene.transform_part(p.name, change[1])
        elif kind == "wall":
            scene = scene.with_wall_transform(change[1])
            # a wall too finely meshed to be tested exactly lives in embree: rebuild
            geometry = geometry or int(scene.tri_is_wall.sum()) > WALL_MAX_TRIANGLES
        else:
            raise ValueError(f"unknown change {kind!r}")
    return scene, geometry


class Client:
    """Holds a group of interleave sets and computes their part of every frame.

    Parameters
    ----------
    scene : Scene
    config : RunConfig
    plan : Plan
        Which stages run (SPT, channels, recording, camera).
    set_indices : list of int
        The interleave sets this client owns (static assignment).
    probes_hv : (P, 2) array
        Wall coordinates (h, v in m) of the probe points every set estimates.
    caster : RayCaster, optional
        The scene's embree scene when the caller already built it (else built here).
    """

    def __init__(self, scene: Scene, config: RunConfig, plan: Plan, set_indices: list[int],
                 probes_hv: np.ndarray, caster=None) -> None:
        self.config = config
        self.probes_hv = np.asarray(probes_hv, dtype=np.float64).reshape(-1, 2)
        spec = point_spec(config, scene.wall, self.probes_hv, scene_scale(scene))
        self.photons = PhotonSets(scene, config, plan, set_indices, caster=caster,
                                  points=spec)
        self._new_estimator()

    def _new_estimator(self) -> None:
        p = self.photons
        self.estimator = SetEstimator(p.scene, p.tracer.caster, self.config, p.channels,
                                      self.probes_hv)

    @property
    def set_indices(self) -> list[int]:
        return self.photons.set_indices

    @property
    def tracer(self):
        return self.photons.tracer

    # -- interaction ---------------------------------------------------------------------
    def update(self, scene: Scene, geometry_changed: bool = True) -> None:
        """Interaction: a changed scene discards the accumulated photons.

        The embree scene is rebuilt only when geometry changed (materials alone reuse it).
        """
        caster = None if geometry_changed else self.photons.tracer.caster
        self.photons.set_scene(scene, caster)
        self.photons.reset()
        self._new_estimator()

    def apply(self, changes: list[tuple]) -> None:
        """Apply interaction changes (see :func:`apply_changes`) and discard the photons.

        ``("guide", rows)`` is no interaction: it replaces the run's guide targets
        (:attr:`RunConfig.guide_targets <lightsim.engine.config.RunConfig.guide_targets>`,
        rows that say from which frame on each holds) and keeps the photons."""
        guides = [c for c in changes if c[0] == "guide"]
        changes = [c for c in changes if c[0] != "guide"]
        for _, rows in guides:
            self.guide(rows)
        if changes:
            scene, geometry = apply_changes(self.photons.scene, changes)
            self.update(scene, geometry)

    def guide(self, rows: tuple) -> None:
        """Use the guide target rows ``rows`` (the whole history, from frame 0)."""
        self.config = self.config.with_(guide_targets=tuple(tuple(r) for r in rows))
        self.photons.set_config(self.config)

    # -- a frame -------------------------------------------------------------------------
    def shoot(self, total: int | None = None) -> ShootResult:
        """Shoot one frame of photons into every owned set (see :meth:`PhotonSets.shoot`)."""
        return self.photons.shoot(total)

    def render(self, request: RenderRequest) -> ClientFrame:
        """Every owned set's answer to ``request``, in set order."""
        t0 = time.perf_counter()
        sets = self.photons.sets
        n = len(self.set_indices)
        rungs: list[tuple[np.ndarray | None, np.ndarray | None]] = [(None, None)] * n
        threads = self.config.threads or os.cpu_count() or 1
        probe_rungs = bool(request.error) and self.config.uses_ici
        if (request.full_image or probe_rungs) and self.config.uses_ici and threads > 1 \
                and n > 1:
            # the written map's rungs and the error figure's rungs at the grid probes, set
            # by set on the cores (each set's sums are its own: the same numbers in any
            # order); the rest of each set's answer follows here, in set order
            est = self.estimator

            def sums(s: int) -> tuple[np.ndarray | None, np.ndarray | None]:
                st = sets[s]
                return (est.full_rungs(st) if request.full_image else None,
                        est.probe_rungs(st) if probe_rungs and st.wall_moments is not None
                        else None)

            # the second half of the sets on a second thread (no pool to start per
            # frame: on a small wall a set's probe sums take ~0.1 ms)
            half = n // 2
            pending = second_thread().submit(lambda: [sums(s) for s in self.set_indices[half:]])
            try:
                first = [sums(s) for s in self.set_indices[:half]]
            finally:
                second = pending.result()
            rungs = first + second
        frames = [self.estimator.render(sets[s], request, len(sets), full, probe)
                  for s, (full, probe) in zip(self.set_indices, rungs, strict=True)]
        return ClientFrame(frames, time.perf_counter() - t0)

    def probe(self, points_hv: np.ndarray) -> dict[int, np.ndarray]:
        """Every owned set's illuminance (lx) at wall points (h, v in m): {set: (P, C)}."""
        sets = self.photons.sets
        return {s: self.estimator.probe(sets[s], points_hv) for s in self.set_indices}

    # -- statistics, checkpoints ---------------------------------------------------------
    def stats(self) -> dict[int, dict[str, Any]]:
        return self.photons.stats()

    def per_source(self) -> tuple[np.ndarray, np.ndarray, dict[int, np.ndarray]] | None:
        """ΣΦ, ΣΦ² per emitter group and pixel over the owned sets, and every owned set's
        all-group pixel sums as the binning estimator keeps them (``--per-source``)."""
        ps = self.photons.per_source
        return None if ps is None else (ps.power, ps.square, dict(ps.sets))

    def apertures(self) -> dict[int, np.ndarray | None]:
        return self.photons.apertures()

    def paths(self) -> dict[int, Any]:
        return self.photons.paths()

    def counters(self) -> dict[int, int]:
        return self.photons.counters()

    def replay(self, frames: dict[int, int], partial: dict[int, int] | None = None) -> None:
        self.photons.replay(frames, partial)
