"""``lightsim simulate --outputs``: a run writes only the files asked for (summary.json
always), with the same map and summary figures as a run that writes everything."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lightsim.io.exr import read_exr
from lightsim.options import lookup, parse_names
from lightsim.simulate import SimulateOptions

from support import run_cli as _run
from support import write_point_lamp

ARGS = ["--photons", "100000", "--wall-distance", "2", "--wall-size", "4x4",
        "--resolution", "24x24", "--frame-photons", "50000", "--quiet"]


@pytest.fixture(scope="module")
def point_lamp(tmp_path_factory):
    """An isotropic 1000 lm source 2 m from the wall, nothing else."""
    return write_point_lamp(tmp_path_factory.mktemp("lamp") / "point.glb")


def test_parse_names_orders_and_expands_all():
    names = ("exr", "png", "json")
    assert parse_names("json,exr", names) == ("exr", "json")
    assert parse_names("all", names) == names
    assert parse_names("exr,exr, json", names) == ("exr", "json")
    assert parse_names("exr,bogus", names) == ("exr", "bogus")  # the check names it
    opt = lookup(SimulateOptions, "outputs")
    assert opt.default == opt.choices  # default: every file


def test_only_the_asked_files_are_written_with_the_same_content(point_lamp, tmp_path, capsys):
    full, lean = tmp_path / "full", tmp_path / "lean"
    code, _, err = _run(["simulate", str(point_lamp), *ARGS, "--out", str(full)], capsys)
    assert code == 0, err
    code, _, err = _run(["simulate", str(point_lamp), *ARGS, "--out", str(lean),
                         "--outputs", "exr,json"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in lean.iterdir()) == ["summary.json", "wall_lux.exr"]
    assert {"wall_lux.png", "isolux.png", "road.png", "error_vs_time.png"} <= {
        p.name for p in full.iterdir()}
    a, b = (json.loads((d / "summary.json").read_text()) for d in (full, lean))
    assert b["outputs"] == ["summary.json", "wall_lux.exr"]
    # the same photons give the same map and the same figures, plots or not
    assert np.array_equal(read_exr(full / "wall_lux.exr")[0]["Y"],
                          read_exr(lean / "wall_lux.exr")[0]["Y"])
    for key in ("photons", "rel_error", "lux", "road", "isolux", "cutoff"):
        assert a[key] == b[key], key


def test_summary_only_run(point_lamp, tmp_path, capsys):
    out = tmp_path / "json"
    code, _, err = _run(["simulate", str(point_lamp), *ARGS, "--out", str(out),
                         "--outputs", "json"], capsys)
    assert code == 0, err
    assert [p.name for p in out.iterdir()] == ["summary.json"]
    t = json.loads((out / "summary.json").read_text())["timings_s"]
    assert set(t) == {"load", "session", "sample", "trace", "insert", "estimate",
                      "final_map", "outputs"}
    assert all(v >= 0 for v in t.values()) and t["trace"] > 0


@pytest.mark.parametrize("value,match", [("exr,pdf", "unknown name(s) pdf"),
                                         (",", "give at least one")])
def test_bad_outputs_exit_2_with_one_line(point_lamp, tmp_path, capsys, value, match):
    out = tmp_path / "bad"
    code, _, err = _run(["simulate", str(point_lamp), *ARGS, "--out", str(out),
                         "--outputs", value], capsys)
    assert code == 2
    lines = [ln for ln in err.strip().splitlines() if ln]
    assert len(lines) == 1 and match in lines[0], err
    assert not out.exists()
