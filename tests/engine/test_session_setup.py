"""The session's set-up work is done once: the plan's pilot and the run's photon sets
share the embree scene and the packed triangle rows (lightsim.engine.server)."""

from __future__ import annotations

import numpy as np
import pytest

from lightsim import tracer
from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.validation.scenes.analytic import paraboloid_case


@pytest.fixture(scope="module")
def mirror():
    return paraboloid_case(resolution=(16, 16), radial=8, azimuthal=32).scene


def test_pilot_and_run_pack_the_triangles_once_and_trace_the_same(mirror, monkeypatch):
    built: list[int] = []
    real = tracer.Geometry.from_scene.__func__

    def counting(cls, scene):
        built.append(scene.n_triangles)
        return real(cls, scene)

    # SPT forced on: no pilot, the run's tracer packs its own rows
    alone = RunConfig(frame_photons=4_000, interleave=2, seed=2, spt=True)
    with Session(mirror, alone) as s:
        own = s.run(photons=8_000).lux
    monkeypatch.setattr(tracer.Geometry, "from_scene", classmethod(counting))
    with Session(mirror, RunConfig(frame_photons=4_000, interleave=2, seed=2)) as s:
        assert s.plan.pilot_yield is not None and s.plan.spt  # the pilot chose SPT
        assert built == [mirror.n_triangles]  # the pilot's rows serve the run too
        shared = s.run(photons=8_000).lux
        s.update(wall_transform=np.eye(4))  # a moved wall: a new scene, the rows copied
        assert s.scene is not mirror
        s.run(photons=4_000)
    assert built == [mirror.n_triangles]
    np.testing.assert_array_equal(shared, own)  # the same photons, the same map
