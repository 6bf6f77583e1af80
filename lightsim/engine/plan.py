"""Scene plan: decide which stages a scene needs before shooting, and say why.

The user asked to leave out what a scene does not need. Before the first frame the
server looks at the scene (and a small pilot of photons that never enter an estimate) and
decides:

==================  ==========================================================================
stage               runs when
==================  ==========================================================================
SPT                 specular paths reach a diffuse surface but the plain caustic yield of the
                    pilot is below ``spt_threshold`` (0.5): a small caustic generator. In a
                    headlight nearly every photon crosses the bulb glass, so SPT is left out.
RGB                 a material is coloured (albedo/reflectance or attenuation not grey);
                    otherwise one luminous channel (a third of the memory and work)
absorption          a dielectric has KHR_materials_volume attenuation
interreflection     photons are recorded on every diffuse surface only for a camera view;
recording           the wall map needs wall photons only
camera pass         a camera view is asked for
far field           an intensity file (IES/LDT) is asked for: photons leaving the lamp kept
regulation probes   a regulation is asked for
==================  ==========================================================================

``--explain`` prints the plan; ``summary.json`` stores it under ``"plan"``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.materials import DIFFUSE
from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.scene import Scene
from lightsim.tracer import PhotonTracer

PILOT_SET = 1 << 20  # key space of planning pilots: never used by an interleave set


@dataclass
class Plan:
    """Stages that run (and the ones left out), with reasons."""

    spt: bool
    channels: int
    record: str
    camera: bool = False
    farfield: bool = False
    regulation: str | None = None
    absorption: bool = False
    pilot_yield: float | None = None
    pilot_photons: int = 0
    stages: list[dict[str, Any]] = field(default_factory=list)
    per_source: bool = False  # keep every emitter group's wall map (lightsim.persource)

    def to_dict(self) -> dict[str, Any]:
        return {"stages": self.stages, "pilot_yield": self.pilot_yield,
                "pilot_photons": self.pilot_photons}

    def explain(self) -> list[str]:
        return [f"{'run ' if s['run'] else 'skip'}  {s['stage']}: {s['reason']}"
                for s in self.stages]


def pilot_yield(scene: Scene, config: RunConfig, photons: int = 4096, caster=None) -> float:
    """Fraction of plain-sampled photons whose path is caustic (specular, then diffuse).

    ``caster`` (a :class:`~lightsim.raycast.RayCaster` of ``scene``, kept open) saves
    building the embree scene twice when the run traces with the same one."""
    tracer = PhotonTracer(scene, max_depth=config.max_depth, record="all",
                          threads=config.threads, caster=caster)
    idx = np.arange(photons, dtype=np.int64)
    pts = halton_points(idx, digit_permutations(config.seed, PILOT_SET, None))
    res = tracer.trace_points(pts, photon_keys(config.seed, PILOT_SET, 0, idx))
    if caster is None:
        tracer.caster.close()
    return float(res.caustic_source.mean()) if photons else 0.0


def make_plan(scene: Scene, config: RunConfig, *, camera: bool = False, farfield: bool = False,
              regulation: str | None = None, spt_threshold: float = 0.5,
              pilot_photons: int = 4096, caster=None) -> Plan:
    """Decide the stages for ``scene`` (see the module docstring); ``caster``: the run's
    ray caster, for the pilot (see :func:`pilot_yield`)."""
    stages: list[dict[str, Any]] = []

    def stage(name: str, run: bool, reason: str) -> None:
        stages.append({"stage": name, "run": bool(run), "reason": reason})

    mats = [p.material for p in scene.surfaces]
    specular = [m for m in mats if m.kind != DIFFUSE]

    # -- Selective Photon Tracing ------------------------------------------------------
    yld = None
    if config.spt is not None:
        spt = config.spt
        stage("selective photon tracing", spt, "forced by --spt" if spt else "forced off")
    elif not specular:
        spt = False
        stage("selective photon tracing", False, "no mirror or glass: no caustic paths")
    else:
        yld = pilot_yield(scene, config, pilot_photons, caster)
        if yld == 0.0:
            spt = False
            stage("selective photon tracing", False,
                  f"no caustic path among {pilot_photons} pilot photons")
        elif yld >= spt_threshold:
            spt = False
            stage("selective photon tracing", False,
                  f"plain sampling already yields {yld:.0%} caustic photons "
                  f"(≥ {spt_threshold:.0%}): nothing to gain")
        else:
            spt = True
            stage("selective photon tracing", True,
                  f"plain caustic yield {yld:.1%} < {spt_threshold:.0%}: refine pilots")

    # -- colour --------------------------------------------------------------------------
    coloured = [m.name for m in mats if m.coloured]
    if config.channels is not None:
        channels = config.channels
        stage("RGB channels", channels == 3, f"forced to {channels} channel(s)")
    elif coloured:
        channels = 3
        stage("RGB channels", True, f"coloured material(s): {', '.join(coloured[:4])}")
    else:
        channels = 1
        stage("RGB channels", False, "all materials grey: one luminous channel (lm, lx)")

    absorbing = [m.name for m in mats if np.any(m.sigma > 0)]
    stage("volume absorption", bool(absorbing),
          f"absorbing: {', '.join(absorbing[:4])}" if absorbing
          else "no KHR_materials_volume attenuation: Beer–Lambert skipped")

    record = config.record or ("all" if camera else "wall")
    stage("photons on non-wall surfaces", record == "all",
          "needed by the camera view" if record == "all" else
          "only the wall is estimated: other diffuse hits are booked, not stored")
    stage("camera pass", camera, "camera view requested" if camera else "no camera requested")
    stage("far-field intensity", farfield,
          "IES/LDT output requested" if farfield else "no intensity file requested")
    stage("regulation probes", regulation is not None,
          f"rule set {regulation}" if regulation else "no --regulation")
    W, H = scene.wall.resolution if scene.wall is not None else (0, 0)
    stage(f"wall map {W}×{H}", scene.wall is not None,
          "estimated at the requested resolution only" if scene.wall is not None
          else "no wall")
    return Plan(spt=spt, channels=channels, record=record, camera=camera, farfield=farfield,
                regulation=regulation, absorption=bool(absorbing), pilot_yield=yld,
                pilot_photons=pilot_photons if yld is not None else 0, stages=stages)
