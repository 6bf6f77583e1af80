"""Distributed rendering on real Ray (no mocks), isolated on loopback.

Ray start-up costs seconds, so the checks share runtimes: one local runtime for the
backend comparison and the fault test, and one two-node cluster for ``--address``.
"""

from __future__ import annotations

import json
import shutil
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh

from lightsim.io.exr import read_exr
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb

from netns import SCENE_SCRIPT, run_in_netns

pytestmark = pytest.mark.ray

def test_backends_identical_and_actor_fault_replayed(tmp_path):
    script = tmp_path / "ray_check.py"
    script.write_text(SCENE_SCRIPT + textwrap.dedent("""
        import json, os, signal, sys
        from lightsim.engine.config import RunConfig
        from lightsim.engine.server import Session

        cfg = RunConfig(frame_photons=40_000, interleave=3)
        out = {}
        images = {}
        for workers in (0, 1, 2):
            with Session(scene(), cfg, workers=workers) as s:
                est = s.run(photons=160_000)
                images[workers] = est.lux
                out[f"energy{workers}"] = s.energy()["wall"]
        # an interaction change, then a fault: kill one actor's process after the second
        # frame; the replacement must replay the change and the frames
        with Session(scene(), cfg, workers=0) as s:
            s.update(material=("reflector", {"reflectance": 0.6}))
            images["changed"] = s.run(photons=160_000).lux
        with Session(scene(), cfg, workers=2) as s:
            s.update(material=("reflector", {"reflectance": 0.6}))
            killed = []
            def cb(est):
                if s.frames == 2 and not killed:
                    pid = s.backend.pids()[1]
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
            est = s.run(photons=160_000, callback=cb)
            images["fault"] = est.lux
            out["restarts"] = s.backend.restarts
            out["killed"] = killed
            out["new_pids"] = s.backend.pids()
            out["bytes"] = s.backend.bytes_last_frame
        for k, img in images.items():
            out[f"same_{k}"] = bool(np.array_equal(img, images[0]))
        out["same_fault"] = bool(np.array_equal(images["fault"], images["changed"]))
        out["changed_differs"] = not np.array_equal(images["changed"], images[0])
        out["lit"] = float(images[0].max())
        print("RESULT " + json.dumps(out))
    """))
    res = run_in_netns(f"{sys.executable} {script}", timeout=400)
    assert res.returncode == 0, res.stderr[-3000:]
    line = next(ln for ln in res.stdout.splitlines() if ln.startswith("RESULT "))
    out = json.loads(line[len("RESULT "):])
    assert out["lit"] > 0
    assert out["same_1"] and out["same_2"], out
    assert out["energy0"] == out["energy1"] == out["energy2"]
    assert out["restarts"] >= 1 and out["killed"][0] not in out["new_pids"]
    assert out["same_fault"], "the run with a killed actor must end with the same image"
    assert out["changed_differs"]
    assert out["bytes"] > 0


def test_cluster_address_two_nodes(tmp_path):
    """`ray start --head` + a second node; `simulate --address`; `ray stop` always runs."""
    lamp = tmp_path / "lamp.py"
    lamp.write_text(SCENE_SCRIPT + textwrap.dedent(f"""
        import trimesh
        from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb
        s = scene()
        parts = []
        for p in s.parts:
            if p.role == "wall":
                continue
            if p.role == "emitter":
                mat = GltfMaterial("f", emissive=(1, 1, 1))
                extras = {{"lightsim": {{"flux_lm": p.flux_lm}}}}
            else:
                mat = GltfMaterial("m", base_color=(0.9, 0.9, 0.9), metallic=1.0)
                extras = None
            parts.append(GltfPart(p.name, p.vertices, p.faces, p.normals, mat, extras=extras))
        write_glb("{tmp_path / 'lamp.glb'}", parts)
    """))
    out_a, out_b = tmp_path / "a", tmp_path / "b"
    common = ("--photons 80000 --frame-photons 40000 -M 2 --wall-distance 2 "
              "--wall-size 4x4 --resolution 32x32 --quiet")
    port = 6391
    # the ray command of this interpreter's environment (a venv's bin need not be on PATH)
    ray = (shutil.which("ray", path=str(Path(sys.executable).parent))
           or f'{sys.executable} -c "from ray.scripts.scripts import main; main()"')
    sim = f"{sys.executable} -m lightsim.cli.main simulate {tmp_path / 'lamp.glb'} {common}"
    script = f"""
        set -e
        trap '{ray} stop --force >/dev/null 2>&1 || true' EXIT
        {sys.executable} {lamp}
        {ray} start --head --port={port} --num-cpus=1 --include-dashboard=false \
            --disable-usage-stats >/dev/null
        {ray} start --address=127.0.0.1:{port} --num-cpus=1 >/dev/null
        {sim} --out {out_a} \
            --address 127.0.0.1:{port} --workers 2
        {sim} --out {out_b}
        {sys.executable} -c "import ray; ray.init(address='127.0.0.1:{port}', \
            log_to_driver=False); print('NODES', len([n for n in ray.nodes() if n['Alive']]))"
    """
    res = run_in_netns(textwrap.dedent(script), timeout=400)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    assert "NODES 2" in res.stdout
    a = read_exr(out_a / "wall_lux.exr")[0]["Y"]
    b = read_exr(out_b / "wall_lux.exr")[0]["Y"]
    assert a.max() > 0 and np.array_equal(a, b)
    summary = json.loads((out_a / "summary.json").read_text())
    assert summary["workers"] == 2


def test_unreachable_cluster_is_one_line(tmp_path):
    ico = trimesh.creation.icosphere(1, radius=1e-3)
    glb = tmp_path / "p.glb"
    write_glb(glb, [GltfPart("filament", np.asarray(ico.vertices), np.asarray(ico.faces), None,
                             GltfMaterial("f", emissive=(1, 1, 1)),
                             extras={"lightsim": {"flux_lm": 10.0}})])
    res = run_in_netns(f"{sys.executable} -m lightsim.cli.main simulate {glb} "
                       f"--address 127.0.0.1:1 --out {tmp_path / 'o'} --quiet", timeout=120)
    assert res.returncode == 2, res.stderr[-2000:]
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "cannot reach a Ray cluster at 127.0.0.1:1" in lines[0], lines
    assert "Traceback" not in res.stderr
