"""The re-aim study: random re-aims photographed on the marker board by random cameras;
the aim interval must cover the truth in at least 90 % of the trials it reads, and every
trial it does not read says why."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lightsim.validation.photo_aim_study import (
    AimStudySettings,
    aim_study,
    refusal_counts,
    summary_line,
    synthetic_simulation,
)
from lightsim.validation.photo_io import load_simulation

from support import run_cli

REPO = Path(__file__).resolve().parents[2]


def _check(result, n):
    assert len(result.trials) == n
    assert result.read + result.refused == n
    for t in result.trials:
        assert abs(t.dh_deg) <= 0.5 and abs(t.dv_deg) <= 0.5
        if t.read:
            assert t.covered == (abs(t.offset_deg - t.dv_deg) <= t.interval_deg)
            assert t.refused is None
        else:
            assert t.refused and t.covered is None  # a refusal always says why
    assert result.read >= n // 2, refusal_counts(result)
    assert result.coverage >= 0.9, [(t.dv_deg, t.offset_deg, t.interval_deg)
                                    for t in result.trials if t.read and not t.covered]


def test_aim_study_on_the_synthetic_beam(tmp_path):
    sim = synthetic_simulation(tmp_path)
    res = aim_study(sim, AimStudySettings(reaims=6, seed=3))
    _check(res, 6)
    assert res.passed and "pass" in summary_line(res)
    again = aim_study(sim, AimStudySettings(reaims=2, seed=3))  # seeded: same trials
    assert [(t.dh_deg, t.dv_deg) for t in again.trials] == [
        (t.dh_deg, t.dv_deg) for t in res.trials[:2]]


def test_cli_aim_study_reports_and_writes_json(tmp_path, capsys):
    out = tmp_path / "aim.json"
    code, stdout, _ = run_cli(["validate", "--aim-study", "--reaims", "3", "--quiet",
                               "--json", str(out)], capsys)
    assert code in (0, None)
    doc = json.loads(out.read_text())
    assert len(doc["aim_study"]) == 1 and len(doc["aim_study"][0]["trials"]) == 3
    assert "aim interval covers the true re-aim in" in stdout
    code, _, err = run_cli(["validate", "--aim-study", "--reaims", "0"], capsys)
    assert code == 2 and "Traceback" not in err


@pytest.mark.slow
@pytest.mark.parametrize("lamp, extra", [
    ("lowbeam.glb", ["--resolution", "320x128"]), ("headlight.glb", [])])
def test_aim_study_fifty_reaims_on_the_shipped_lamps(tmp_path, capsys, lamp, extra):
    code, _, err = run_cli(["simulate", str(REPO / "luminaires" / "examples" / lamp),
                            "--photons", "1000000", *extra, "--seed", "1", "--quiet",
                            "--outputs", "exr,json", "--out", str(tmp_path / "run")], capsys)
    assert code in (0, None), err
    res = aim_study(load_simulation(tmp_path / "run"), AimStudySettings(reaims=50))
    _check(res, 50)
