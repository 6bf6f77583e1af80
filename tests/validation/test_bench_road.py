"""``lightsim bench road``: rows, ratios against the load time, no photons traced."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lightsim.io.exr import write_exr
from lightsim.io.summary import write_json
from lightsim.validation.bench.road import bench_road

from support import run_cli

FRAME = {"centre": [0.0, 0.0, 25.0], "h_axis": [-1.0, 0.0, 0.0], "v_axis": [0.0, 1.0, 0.0],
         "normal": [0.0, 0.0, -1.0], "h_range_m": [-15.0, 15.0], "v_range_m": [-6.0, 6.0],
         "distance_m": 25.0, "resolution": [160, 64]}


def _run(out: Path) -> Path:
    out.mkdir()
    write_exr(out / "wall_lux.exr", {"Y": np.full((64, 160), 8.0)})
    write_json(out / "summary.json", {"wall": FRAME})
    return out


def test_bench_road_rows(tmp_path: Path, capsys) -> None:
    run = _run(tmp_path / "run")
    rows = bench_road(run, repeats=1)
    assert rows[0]["step"] == "load run (baseline)"
    assert all(r["photons_traced"] == 0 and r["seconds"] > 0 for r in rows)
    assert rows[1]["ratio"] == rows[1]["seconds"] / rows[0]["seconds"]
    assert sorted(p.name for p in run.iterdir()) == ["summary.json", "wall_lux.exr"]
    code, out, err = run_cli(["bench", "road", str(run), "--repeats", "1", "--json",
                              str(tmp_path / "b.json")], capsys)
    assert code == 0, err
    assert "load run (baseline)" in out and (tmp_path / "b.json").is_file()
