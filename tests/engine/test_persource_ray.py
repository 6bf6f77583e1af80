"""Per-source maps on Ray actors (simulate --per-source --workers 2): every emitter
group's map, its variance and the all-on channel equal the in-process run's, bit for bit."""

from __future__ import annotations

import json
import sys
import textwrap
from pathlib import Path

import pytest

from netns import run_in_netns

pytestmark = pytest.mark.ray

MATRIX = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "matrix.glb"


def test_per_source_maps_on_two_workers_equal_in_process(tmp_path):
    script = tmp_path / "per_source_ray.py"
    script.write_text(textwrap.dedent(f"""
        import json
        from pathlib import Path
        import numpy as np
        from lightsim.io.exr import read_exr
        from lightsim.simulate import SimulateOptions, run_simulation

        base = Path({str(tmp_path)!r})
        maps, summaries = {{}}, {{}}
        for workers in (0, 2):
            out = base / f"w{{workers}}"
            opts = SimulateOptions(scene_path={str(MATRIX)!r}, photons=80_000,
                                   out_dir=str(out), resolution=(48, 24), per_source=True,
                                   workers=workers, outputs=("exr", "json"),
                                   config={{"frame_photons": 20_000}})
            res = run_simulation(opts)
            summaries[workers] = res.summary["per_source"]
            maps[workers] = (read_exr(out / "per_source.exr"),
                             read_exr(out / "per_source_var.exr"))
        (a, ameta), (av, _) = maps[0]
        (b, bmeta), (bv, _) = maps[2]
        out = {{"groups": ameta["groups"], "groups2": bmeta["groups"],
               "channels": sorted(a), "channels2": sorted(b),
               "same_lux": all(np.array_equal(a[k], b[k]) for k in a),
               "same_var": all(np.array_equal(av[k], bv[k]) for k in av),
               "lit": float(a["Y"].max()),
               "lit_groups": sum(int(a[g].max() > 0) for g in ameta["groups"]),
               "errors": [g["rel_error"] for g in summaries[0]["groups"]],
               "errors2": [g["rel_error"] for g in summaries[2]["groups"]],
               "photons": [ameta["photons"], bmeta["photons"]]}}
        print("RESULT " + json.dumps(out))
    """))
    res = run_in_netns(f"{sys.executable} {script}", timeout=500)
    assert res.returncode == 0, res.stderr[-3000:]
    line = next(ln for ln in res.stdout.splitlines() if ln.startswith("RESULT "))
    out = json.loads(line[len("RESULT "):])
    assert len(out["groups"]) == 16 and out["groups"] == out["groups2"]
    assert out["channels"] == out["channels2"] and "Y" in out["channels"]
    assert out["lit"] > 0 and out["lit_groups"] == 16
    assert out["photons"][0] == out["photons"][1] >= 80_000
    assert out["same_lux"], "per-source maps on 2 Ray workers differ from in-process"
    assert out["same_var"]
    assert out["errors"] == out["errors2"]
