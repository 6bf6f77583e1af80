"""``--until decided``: the look schedule, the running intervals and wrong-verdict counts."""

from __future__ import annotations

import json
import math

import pytest

from lightsim.errors import InputError
from lightsim.luminaires.analyses import for_options
from lightsim.luminaires.regulations.sequential import LookSchedule, merge_row
from lightsim.simulate import SimulateOptions, photon_keeper
from lightsim.validation.sequential_study import simulated_looks, until_study
from tests.support import run_cli, write_point_lamp


def test_schedule_splits_the_budget_over_doubling_looks():
    s = LookSchedule(200_000, 400_000_000)
    assert s.planned()[:3] == (200_000, 400_000, 800_000)
    assert s.looks == 12  # 11 doublings below the cap and the last look
    assert s.level(0.95) == pytest.approx(1 - 0.05 / 12)
    assert s.due(400_000, 200_000) and not s.due(399_999, 200_000)
    with pytest.raises(InputError):
        LookSchedule(0, 10)


def _row(lo: float, hi: float) -> dict:
    return {"name": "p", "kind": "point", "interval_cd": [lo, hi], "limit": {"min": 100.0}}


def test_running_interval_is_the_intersection_and_a_decision_stays():
    r1 = merge_row(None, _row(50.0, 300.0), 10)
    assert r1["verdict"] == "uncertain" and not r1["decided"]
    r2 = merge_row(r1, _row(120.0, 400.0), 20)
    assert r2["interval_cd"] == [120.0, 300.0] and r2["decided"]
    assert r2["decided_at_photons"] == 20
    r3 = merge_row(r2, _row(90.0, 250.0), 40)  # a wider look cannot undo the decision
    assert r3["interval_cd"] == [120.0, 250.0] and r3["verdict"] == "pass"
    assert r3["decided_at_photons"] == 20
    r4 = merge_row(r3, _row(10.0, 60.0), 80)  # disjoint: some bound was wrong, restart
    assert r4["resets"] == 1 and r4["verdict"] == "fail" and r4["decided_at_photons"] == 80


def test_wrong_decisions_stay_within_the_nominal_rate():
    """Rules at, inside and outside their limits, looked at on the schedule: every rule's
    wrong verdicts within what Binomial(runs, α/2) explains at 99.9 %."""
    study = simulated_looks(40, looks=6, seed=5)
    allowed = study.allowed()
    assert sum(study.decided.values()) > 0
    for name, wrong in study.wrong.items():
        assert wrong <= allowed, (name, wrong, allowed)


@pytest.mark.slow
def test_wrong_decisions_over_many_runs():
    study = simulated_looks(400, seed=11)
    for name, wrong in study.wrong.items():
        assert wrong <= study.allowed(), (name, wrong)


@pytest.mark.parametrize("extra, text", [
    ([], "--regulation"),
    (["--regulation", "r112-b-passing", "--photons", "0"], "photons"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, extra, text):
    glb = write_point_lamp(tmp_path / "lamp.glb")
    code, _out, err = run_cli(["simulate", str(glb), "--until", "decided",
                              "--out", str(tmp_path / "o"), *extra], capsys)
    assert code == 2
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and text in lines[0], err
    assert "Traceback" not in err


def _verdicts(summary: dict) -> dict[str, tuple[str, bool]]:
    return {r["name"]: (r["verdict"], r.get("decided", False))
            for r in summary["regulation"]["results"] if r.get("kind") != "measure"}


def test_guided_until_steers_to_the_open_rules_and_decides_truly(tmp_path, capsys):
    """A 1000 lm isotropic source (79.6 cd in every direction): with --guide points the
    rule aims the photons at every test point and zone before the first look, then only
    at the open rules' ones; each decided verdict is the true one, in both runs."""
    glb = write_point_lamp(tmp_path / "lamp.glb")
    truth = 1000.0 / (4 * math.pi)
    got = {}
    for guide in ("off", "points"):
        out = tmp_path / guide
        code, _o, err = run_cli(["simulate", str(glb), "--until", "decided", "--regulation",
                                 "r112-b-passing", "--photons", "800000", "--resolution",
                                 "80x32", "--guide", guide, "--seed", "3", "--out", str(out),
                                 "--quiet"], capsys)
        assert code == 0, err
        summary = json.loads((out / "summary.json").read_text())
        got[guide] = summary
        for r in summary["regulation"]["results"]:
            if r.get("kind") != "point" or not r.get("decided"):
                continue
            lim = r["limit"]
            ok = (lim.get("min") is None or truth >= lim["min"]) and (
                lim.get("max") is None or truth <= lim["max"])
            assert r["verdict"] == ("pass" if ok else "fail"), r
            lo, hi = r["interval_cd"]
            assert lo <= truth <= hi, r
    steered = got["points"]["until"]["guided"]
    assert got["off"]["until"]["guided"] == [] and "guide" not in got["off"]
    rows = got["points"]["config"]["guide_targets"]
    first = [r for r in rows if r[0] == 0]  # every point and zone, from frame 0
    assert len(first) == got["points"]["guide"]["targets"] == len(
        got["points"]["guide"]["regions_deg"])
    assert steered and len({r[0] for r in rows}) == 1 + len(steered)
    opened = len(got["points"]["until"]["undecided"])
    assert steered[-1]["targets"] <= len(first)
    # decided rules drop out: the last targets cover only the rules open before it
    assert opened <= steered[-1]["targets"] or opened == 0
    # the same decisions where both decided (the truth is far from most limits)
    a, b = _verdicts(got["off"]), _verdicts(got["points"])
    for name in a:
        if a[name][1] and b[name][1]:
            assert a[name][0] == b[name][0], name


def test_until_verdict_stops_at_the_first_sure_fail(tmp_path, capsys):
    """``--until verdict`` on a 1000 lm isotropic source (79.6 cd everywhere, far below
    75R's 10 100 cd): the lamp's verdict is decided — fail — at the first look, with the
    rule that decided it true and the rules still open reading uncertain; ``--until
    decided`` on the same lamp runs on."""
    glb = write_point_lamp(tmp_path / "lamp.glb")
    truth = 1000.0 / (4 * math.pi)
    got = {}
    for mode in ("verdict", "decided"):
        out = tmp_path / mode
        code, text, err = run_cli(["simulate", str(glb), "--until", mode, "--regulation",
                                   "r112-b-passing", "--photons", "400000",
                                   "--frame-photons", "100000", "--resolution", "80x32",
                                   "--seed", "3", "--out", str(out)], capsys)
        assert code == 0, err
        got[mode] = (json.loads((out / "summary.json").read_text()), text)
    summary, text = got["verdict"]
    until = summary["until"]
    assert until["rule"] == "verdict" and until["stopped_by"] == "verdict"
    assert until["lamp_verdict"] == "fail" and until["photons"] == 100_000
    assert "the lamp fails, decided at 100,000 photons" in text
    rows = {r["name"]: r for r in summary["regulation"]["results"]}
    assert rows["75R"]["verdict"] == "fail" and rows["75R"]["interval_cd"][1] < 10_100
    for r in rows.values():
        if r.get("kind") == "point" and r["verdict"] in ("pass", "fail"):
            lim = r["limit"]
            ok = (lim.get("min") is None or truth >= lim["min"]) and (
                lim.get("max") is None or truth <= lim["max"])
            assert r["verdict"] == ("pass" if ok else "fail"), r
    assert until["undecided"] and all(rows[o["name"]]["verdict"] == "uncertain"
                                      for o in until["undecided"])
    assert got["decided"][0]["until"]["photons"] > until["photons"]


@pytest.mark.parametrize("guide", [False, True])
def test_traced_lamps_decide_wrongly_no_more_than_nominal(guide):
    """Synthetic Type A lamps of known intensities, traced with --until decided (and with
    --guide points): every decided verdict against the exact one, the wrong ones within
    what Binomial(decided, α/2) explains at 99.9 %."""
    study = until_study(2, 1, cap_photons=400_000, resolution=(80, 32), guide=guide)
    assert study.decisive > 10
    assert study.wrong <= study.allowed(), study.to_dict()
    assert all(r.photons <= 400_000 for r in study.runs)


@pytest.mark.slow
@pytest.mark.parametrize("guide", [False, True])
def test_traced_lamps_many_seeds(guide):
    study = until_study(6, 3, cap_photons=4_000_000, guide=guide, seed=4)
    assert study.wrong <= study.allowed(), study.to_dict()


def test_guided_verdict_runs_keep_no_photon():
    """--guide points with --until decided reads detector apertures only: its photons
    need not be kept, so a large cap fits in memory."""
    opts = SimulateOptions(scene_path="x.glb", regulation="r112-b-passing,r149-b-passing",
                           until="decided", config={"guide": "points"})
    analyses = for_options(opts)
    assert "guide" in [a.name for a in analyses]
    assert photon_keeper(opts, opts.run_config(), analyses) is None
