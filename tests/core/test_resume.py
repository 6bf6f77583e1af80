"""SIGINT writes a checkpoint atomically; ``--resume`` reaches the uninterrupted result."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh

from lightsim.io.exr import read_exr
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb


@pytest.fixture(scope="module")
def lamp(tmp_path_factory):
    path = tmp_path_factory.mktemp("lamp") / "lamp.glb"
    ico = trimesh.creation.icosphere(1, radius=1e-3)
    box = trimesh.creation.box(bounds=[[-0.3, -0.3, 0.4], [0.3, 0.3, 0.45]])
    write_glb(path, [
        GltfPart("filament", np.asarray(ico.vertices), np.asarray(ico.faces), None,
                 GltfMaterial("f", emissive=(1, 1, 1)), extras={"lightsim": {"flux_lm": 800.0}}),
        GltfPart("cover", np.asarray(box.vertices), np.asarray(box.faces), None,
                 GltfMaterial("pc", transmission=1.0, ior=1.59)),
    ])
    return path


PHOTONS = 6_000_000  # several seconds: the signal lands mid-run
ARGS = ["--photons", str(PHOTONS), "--frame-photons", "30000", "--wall-distance", "3",
        "--wall-size", "6x6", "--resolution", "48x48", "-M", "3", "--explain"]


def _cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "lightsim.cli.main", "simulate", *args]


@pytest.fixture(scope="module")
def reference(lamp, tmp_path_factory):
    """The uninterrupted run both signals' resumed runs must reach (made once)."""
    ref = tmp_path_factory.mktemp("ref") / "ref"
    res = subprocess.run(_cmd(str(lamp), *ARGS, "--out", str(ref), "--quiet"),
                         capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert res.returncode == 0, res.stderr[-2000:]
    return ref


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_then_resume_matches_uninterrupted(lamp, reference, tmp_path, sig):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    out = tmp_path / "run"
    proc = subprocess.Popen(_cmd(str(lamp), *ARGS, "--out", str(out)), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    # wait until the plan is printed: the signal handlers are in place and frames start
    t0 = time.monotonic()
    for line in proc.stdout:
        if line.startswith("plan:") or time.monotonic() - t0 > 120:
            break
    time.sleep(0.5)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
    assert "checkpoint" in err and "--resume" in err
    ckpt = json.loads((out / "checkpoint.json").read_text())
    done = sum(ckpt["session"]["counters"].values())
    assert 0 <= done < PHOTONS // 30000 * 9  # stopped early
    assert not (out / "wall_lux.exr").exists()
    assert not [p for p in out.iterdir() if ".tmp" in p.name]

    res = subprocess.run(_cmd("--resume", str(out), "--quiet"), capture_output=True, text=True,
                         env=env, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert not (out / "checkpoint.json").exists()

    ref = reference
    a = read_exr(out / "wall_lux.exr")[0]["Y"]
    b = read_exr(ref / "wall_lux.exr")[0]["Y"]
    assert a.max() > 0 and np.array_equal(a, b)
    sa = json.loads((out / "summary.json").read_text())
    sb = json.loads((ref / "summary.json").read_text())
    assert sa["photons"] == sb["photons"] >= PHOTONS  # SPT passes vary in size
    assert sa["energy_lm"]["wall"] == pytest.approx(sb["energy_lm"]["wall"], rel=1e-12)


def test_resume_without_checkpoint_is_an_error(tmp_path):
    res = subprocess.run(_cmd("--resume", str(tmp_path)), capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 2
    assert "no checkpoint.json to resume" in res.stderr
