"""``lightsim design --restarts N``: N designs, each checked as the README demo checks the
shipped lamp, the best kept (``luminaires/design_check.py``)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from lightsim.engine.config import RunConfig
from lightsim.luminaires.design_check import LampCheck, check_lamp, choose, rule_margin
from lightsim.luminaires.design_lamp import read_design

from support import write_point_lamp

LOWBEAM = Path(__file__).parents[2] / "luminaires" / "examples" / "lowbeam.glb"
TINY = ["--regulation", "r112-b-passing", "--rings", "1", "--sectors", "4",
        "--optimiser", "simulator", "--evaluations", "2", "--rounds", "1",
        "--photons", "20000", "--resolution", "80x32", "--validate-factor", "0",
        "--aim-photons", "20000", "--ring-offsets", "0", "--foreground", "0", "--quiet"]


def _design(tmp_path: Path, name: str, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lightsim.cli.main", "design", name,
                           *TINY, *extra], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path)


def test_rule_margin_reads_the_interval_against_each_limit():
    assert rule_margin({"limit": {"min": 100.0}, "interval_cd": [200.0, 300.0]}) == \
        pytest.approx(math.log(2.0))
    assert rule_margin({"limit": {"max": 600.0}, "interval_cd": [100.0, 300.0]}) == \
        pytest.approx(math.log(2.0))
    # both limits: the nearer one; a zone's maximum is judged at its brightest probe
    assert rule_margin({"limit": {"min": 65.0, "max": 625.0},
                        "interval_cd": [130.0, 500.0]}) == pytest.approx(math.log(1.25))
    zone = {"kind": "zone", "limit": {"max": 625.0}, "interval_cd": [10.0, 20.0],
            "max_interval_cd": [400.0, 1250.0]}
    assert rule_margin(zone) == pytest.approx(math.log(0.5))
    assert rule_margin({"limit": {"min": 100.0}, "interval_cd": [0.0, 5.0]}) == -math.inf
    assert rule_margin({"limit": {"max": 100.0}, "interval_cd": [0.0, 0.0]}) == math.inf
    assert rule_margin({"limit": {"min": 1.0}, "interval_cd": [math.nan, 1.0]}) == -math.inf
    assert rule_margin({"limit": {}, "interval_cd": [1.0, 2.0]}) == math.inf


def test_choose_prefers_fewer_rows_not_passing_then_margin_then_j():
    bad = LampCheck(not_passing=[(2, "r", "III", "uncertain")], min_margin=-0.05)
    good = LampCheck(min_margin=0.02)
    better = LampCheck(min_margin=0.10)
    assert choose([bad, good], [0.1, 5.0]) == 1
    assert choose([good, better], [0.1, 5.0]) == 1
    assert choose([good, LampCheck(min_margin=0.02)], [3.0, 1.0]) == 1
    assert choose([good, LampCheck(min_margin=0.02)], [math.nan, 1.0]) == 1
    with pytest.raises(ValueError):
        choose([], [])


def test_check_lamp_reads_what_simulate_reports(tmp_path):
    """The check is ``lightsim simulate`` with the demo's settings: the same rows fail to
    pass, the same smallest margin."""
    chk = check_lamp(LOWBEAM, "r112-b-passing,r149-b-passing", photons=1_000_000,
                     seeds=[4])
    r = subprocess.run([sys.executable, "-m", "lightsim.cli.main", "simulate", str(LOWBEAM),
                        "--photons", "1000000", "--resolution", "320x128", "--seed", "4",
                        "--regulation", "r112-b-passing,r149-b-passing", "--quiet",
                        "--outputs", "json", "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    rows = [(t["ruleset"], q) for k, t in s.items() if k.startswith("regulation")
            for q in t["results"] if q["verdict"] != "info" and q.get("limit")]
    assert chk.rows == len(rows) == 36
    want = [(4, rs, q["name"], q["verdict"]) for rs, q in rows if q["verdict"] != "pass"]
    cut = s["cutoff"]  # annex 9's linearity counts as a row the lamp does not pass
    assert cut["linear"] == (cut["spread_deg"] <= 0.2)
    if not cut["linear"]:
        want.append((4, "annex 9", "linearity", f"fail ({cut['spread_deg']:.3f}°)"))
    assert sorted(chk.not_passing) == sorted(want) and want  # 1 M photons: some uncertain
    assert chk.min_margin == pytest.approx(min(rule_margin(q) for _, q in rows))
    assert len(chk.seconds) == 1 and chk.seconds[0] > 0


def test_restarts_keep_the_best_checked_design_and_leave_nothing_behind(tmp_path):
    r = _design(tmp_path, "best.glb", "--restarts", "2", "--restart-photons", "50000",
                "--restart-resolution", "80x32", "--restart-seeds", "1,2")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["best.glb"]  # no temporary files
    x, layout, rec = read_design(tmp_path / "best.glb")  # (the record drops empty lists)
    assert [t["seed"] for t in rec["restarts"]] == [1, 2]
    checks = [LampCheck(not_passing=[tuple(v) for v in t["check"].get("not_passing", [])],
                        min_margin=float(t["check"]["min_margin"]))
              for t in rec["restarts"]]
    for t in rec["restarts"]:
        assert t["check"]["rows"] == 2 * 20  # R112: 20 rows with limits per check run
        assert len(t["check"]["seconds"]) == 2
    objectives = [math.nan if t["objective"] is None else t["objective"]
                  for t in rec["restarts"]]
    best = choose(checks, objectives)
    assert rec["chosen"] == best and rec["seed"] == best + 1
    # the kept lamp is the one a plain design at that seed makes
    plain = _design(tmp_path, "plain.glb", "--seed", str(best + 1))
    assert plain.returncode == 0, plain.stderr
    x1, layout1, rec1 = read_design(tmp_path / "plain.glb")
    assert list(x) == list(x1) and layout == layout1 and "restarts" not in rec1
    assert rec["objective"] == rec1["objective"]


@pytest.mark.parametrize("extra, needle", [(["--restarts", "0"], "--restarts"),
                                           (["--restart-seeds", "1,a"], "--restart-seeds"),
                                           (["--restart-seeds", "-1"], "--restart-seeds"),
                                           (["--restart-photons", "0"], "--restart-photons"),
                                           (["--restart-resolution", "big"],
                                            "--restart-resolution")])
def test_bad_restart_options_are_one_line_and_exit_2(extra, needle, tmp_path):
    r = _design(tmp_path, "o.glb", *extra)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], r.stderr
    assert not (tmp_path / "o.glb").exists()


def test_check_lamp_until_decided_stops_each_run_at_its_decision(tmp_path):
    """``until="decided"`` (``design --until decided``): each check run stops at the look
    that decides every verdict — fewer photons than the cap, no "uncertain" row left."""
    lamp = write_point_lamp(tmp_path / "lamp.glb")  # 79.6 cd everywhere
    cap = 12_800_000
    chk = check_lamp(lamp, "r112-b-passing", photons=cap, resolution=(80, 32), seeds=[1],
                     aperture=1.5, until="decided")
    assert len(chk.photons) == 1 and chk.photons[0] < cap
    first = RunConfig().frame_photons
    assert chk.photons[0] in {first * 2 ** k for k in range(6)}
    assert chk.rows > 0 and not [r for r in chk.not_passing if r[3] == "uncertain"]
