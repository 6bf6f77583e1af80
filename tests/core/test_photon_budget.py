"""``--photons N`` shoots exactly N photons: the last frame is partial, and exact."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.io.summary import read_json, write_json
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb
from lightsim.validation.scenes.analytic import isotropic_case

from support import run_cli


@pytest.fixture(scope="module")
def scene():
    return isotropic_case(resolution=(32, 32)).scene


@pytest.mark.parametrize("photons", [20_001, 16_000, 7, 1])
def test_run_shoots_exactly_n(scene, photons):
    cfg = RunConfig(frame_photons=16_000, interleave=4, spt=False)
    with Session(scene, cfg) as s:
        est = s.run(photons=photons)
        per_set = s.emitted_per_set()
    assert est.photons == sum(per_set.values()) == photons
    assert np.all(np.isfinite(est.lux))  # sets left empty by a tiny budget stay harmless
    # split as evenly as possible: no set more than one photon ahead of another
    assert max(per_set.values()) - min(per_set.values()) <= 1


def test_partial_frame_replays_exactly(scene, tmp_path):
    cfg = RunConfig(frame_photons=16_000, interleave=2, spt=False)
    with Session(scene, cfg) as a:
        first = a.run(photons=37_003)
        write_json(tmp_path / "c.json", a.checkpoint())  # as in checkpoint.json
        ckpt = read_json(tmp_path / "c.json")
    assert a.partial == {2: 5003}
    with Session(scene, cfg, checkpoint=ckpt) as b:
        assert sum(b.emitted_per_set().values()) == 37_003
        again = b.frame(image=True, shoot=False, mode=cfg.final)
    np.testing.assert_array_equal(first.lux, again.lux)


def test_cli_photons_means_n(tmp_path, capsys):
    m = GltfMaterial("e", emissive=(1.0, 1.0, 1.0))
    v = 1e-3 * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    path = tmp_path / "lamp.glb"
    write_glb(path, [GltfPart("bulb", v, f, None, m, extras={"lightsim": {"flux_lm": 10}})])
    code, _, err = run_cli(["simulate", str(path), "--photons", "20000", "--resolution",
                            "32x16", "--out", str(tmp_path / "o"), "-q"], capsys)
    assert code in (0, None), err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["photons"] == 20_000
