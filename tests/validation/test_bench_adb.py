"""lightsim bench adb: its rows (a short sequence on a small per-source run; the figures
themselves belong to the benchmarks page, not to a test)."""

from __future__ import annotations

from pathlib import Path

from lightsim.simulate import SimulateOptions, run_simulation
from lightsim.validation.bench.adb import bench_adb

MATRIX = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "matrix.glb"


def test_bench_rows(tmp_path):
    run = tmp_path / "run"
    run_simulation(SimulateOptions(scene_path=str(MATRIX), photons=40_000, out_dir=str(run),
                                   resolution=(64, 32), per_source=True, outputs=("json",)))
    rows = bench_adb(run, frames=12)
    steps = [r["step"] for r in rows]
    assert steps[0] == "re-trace one frame (baseline)" and rows[0]["ratio"] == 1.0
    seq = next(r for r in rows if r["frames"] == 12 and "within_target" in r)
    assert seq["seconds"] > 0 and seq["ratio"] == seq["seconds"] / rows[0]["seconds"]
    assert sorted(p.name for p in run.iterdir() if p.name.startswith("adb")) == []
