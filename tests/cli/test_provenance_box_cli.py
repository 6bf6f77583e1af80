"""lightsim report --provenance-box on a --provenance run of a shipped lamp."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lightsim.cli.main import main
from lightsim.io.caption import read_caption
from lightsim.luminaires.provenance_report import REGIONS_FILE, region_breakdown

from support import run_cli

EXAMPLES = Path(__file__).parents[2] / "luminaires" / "examples"


@pytest.fixture(scope="module")
def lowbeam_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("prov") / "run"
    with pytest.raises(SystemExit) as exc:
        main(["simulate", str(EXAMPLES / "lowbeam.glb"), "--photons", "100000",
              "--regulation", "r112-b-passing", "--provenance", "--resolution", "160x64",
              "--outputs", "json", "--out", str(out), "--quiet"])
    assert exc.value.code == 0
    return out


def test_box_prints_classes_adding_up_and_draws_the_lamp(lowbeam_run, capsys):
    code, out, err = run_cli(["report", "--provenance-box", "-8,-1,0.5,2", str(lowbeam_run)],
                             capsys)
    assert code == 0, err
    assert "region H" in out and "lx" in out and "filament" in out
    b = region_breakdown(lowbeam_run, (-8, -1, 0.5, 2))
    assert b["sum_lx"] == pytest.approx(b["value_lx"], rel=1e-9)
    lo, hi = b["interval_lx"]
    assert lo <= b["sum_lx"] <= hi
    png = list(lowbeam_run.glob("provenance-box-*.png"))
    assert len(png) == 1 and png[0].stat().st_size > 1000
    assert "photons" in (read_caption(png[0]) or ""), read_caption(png[0])
    # the whole raster holds the wall's flux the run reports
    s = json.loads((lowbeam_run / "summary.json").read_text())
    with np.load(lowbeam_run / REGIONS_FILE) as d:
        n_sets = len(d["emitted"])
        wall_lm = float(d["flux"].sum()) / n_sets
    assert wall_lm == pytest.approx(s["energy_lm"]["wall"], rel=0.02)


def test_bad_boxes_and_runs_without_provenance(lowbeam_run, tmp_path, capsys):
    for box in ("1,0,0,1", "a,b,c,d", "0,1,2", "70,80,0,1"):
        code, _, err = run_cli(["report", "--provenance-box", box, str(lowbeam_run)], capsys)
        assert code == 2 and "region box" in err and len(err.strip().splitlines()) == 1, err
    plain = tmp_path / "plain"
    code, _, err = run_cli(["simulate", str(EXAMPLES / "lowbeam.glb"), "--photons", "20000",
                            "--resolution", "80x32", "--outputs", "json", "--out", str(plain),
                            "--quiet"], capsys)
    assert code == 0, err
    code, _, err = run_cli(["report", "--provenance-box", "-8,-1,0.5,2", str(plain)], capsys)
    assert code == 2 and "without --provenance" in err and len(err.strip().splitlines()) == 1
    assert not list(plain.glob("provenance-box-*.png"))


def test_view_and_report_refuse_a_corrupt_region_file(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / REGIONS_FILE).write_bytes(b"not an npz file")
    (run / "summary.json").write_text(json.dumps({"provenance": {"rulesets": {}}}))
    for argv in (["view", str(run)], ["report", "--provenance-box=-1,1,-1,1", str(run)]):
        code, _, err = run_cli(argv, capsys)
        assert code == 2 and "corrupt provenance file" in err, err
        assert len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in run.iterdir()) == [REGIONS_FILE, "summary.json"]
