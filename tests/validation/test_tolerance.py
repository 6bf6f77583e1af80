"""Bulb-tolerance study (lightsim.validation.tolerance, ``lightsim tolerance``)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.stats import binomtest

import lightsim.validation.tolerance as tolerance_mod
from lightsim.errors import InputError
from lightsim.luminaires.analyses import for_options
from lightsim.simulate import SimulateOptions, load, run_simulation
from lightsim.validation.tolerance import (
    MM,
    TOLERANCE_BOXES,
    clopper_pearson,
    displace_emitters,
    fit_sensitivity,
    run_sample,
    run_tolerance,
    sample_design,
    study_from_dict,
    write_study,
)

REPO = Path(__file__).resolve().parents[2]
LAMP = REPO / "luminaires" / "examples" / "headlight.glb"
RULES = "r112-b-passing"
PHOTONS = 100_000  # kNN at the points: smooth enough at 1e5 photons on 160×64


def _opts(out: Path, **kw) -> SimulateOptions:
    return SimulateOptions(str(LAMP), out_dir=str(out), photons=PHOTONS, resolution=(160, 64),
                           regulation=RULES, aperture=0.0, config={"seed": 3}, **kw)


# -- design, geometry and statistics (fast) ---------------------------------------------


def test_design_is_a_seeded_latin_hypercube_inside_the_box():
    box = TOLERANCE_BOXES["H4"]
    x = sample_design(box, 20, seed=5, tilt=True)
    assert x.shape == (21, 5) and np.all(x[0] == 0)
    half = np.array([*box.half_m, box.tilt_deg, box.tilt_deg])
    assert np.all(np.abs(x[1:]) <= half)
    # Latin hypercube: every one of the 20 strata of every axis holds exactly one sample
    strata = np.floor((x[1:] / half + 1) / 2 * 20).astype(int)
    for j in range(5):
        assert sorted(strata[:, j]) == list(range(20))
    assert np.array_equal(x, sample_design(box, 20, seed=5, tilt=True))
    assert not np.array_equal(x, sample_design(box, 20, seed=6, tilt=True))
    y = sample_design(box, 4, seed=5, centre_m=(0, -1 * MM, 0))
    assert np.all(y[:, 3:] == 0) and y[0, 1] == -1 * MM
    with pytest.raises(InputError):
        sample_design(box, 0)
    with pytest.raises(InputError):
        sample_design(box, 3, centre_m=(0, float("nan"), 0))


def test_clopper_pearson_matches_scipy_binomtest():
    for k, n in ((0, 10), (3, 10), (10, 10), (17, 50), (1, 1)):
        ci = binomtest(k, n).proportion_ci(0.95, method="exact")
        assert clopper_pearson(k, n) == pytest.approx((ci.low, ci.high), abs=1e-12)
    assert clopper_pearson(0, 0) == (0.0, 1.0)


def test_displacing_moves_and_tilts_only_the_filament():
    scene = load(_opts(Path(".")))
    off = np.array([0.1 * MM, -0.2 * MM, 0.3 * MM, 0.0, 0.0])
    moved = displace_emitters(scene, off)
    for a, b in zip(scene.parts, moved.parts):
        if a.role == "emitter":
            assert np.allclose(b.vertices - a.vertices, off[:3], atol=1e-15)
        else:
            assert b.vertices is a.vertices
    tilted = displace_emitters(scene, np.array([0, 0, 0, 0.0, 90.0]))
    e0 = next(p for p in scene.parts if p.role == "emitter")
    e1 = next(p for p in tilted.parts if p.role == "emitter")
    ext0, ext1 = np.ptp(e0.vertices, axis=0), np.ptp(e1.vertices, axis=0)
    assert ext1[0] == pytest.approx(ext0[2], rel=1e-9)  # the axial coil now lies along X
    c0 = 0.5 * (e0.vertices.min(0) + e0.vertices.max(0))
    c1 = 0.5 * (e1.vertices.min(0) + e1.vertices.max(0))
    assert np.allclose(c0, c1, atol=1e-9)
    with pytest.raises(InputError):
        displace_emitters(scene, np.array([0, 0, np.inf, 0, 0]))


# -- studies (a few seconds per sample) -------------------------------------------------


@pytest.fixture(scope="module")
def nominal_study(tmp_path_factory):
    return run_tolerance(_opts(tmp_path_factory.mktemp("nom")), samples=2, seed=1)


@pytest.fixture(scope="module")
def misplaced_study(tmp_path_factory):
    # a holder that puts every filament 1 mm low: 5× outside the ±0.2 mm box
    return run_tolerance(_opts(tmp_path_factory.mktemp("mis")), samples=2, seed=1,
                         centre_m=(0.0, -1.0 * MM, 0.0))


def test_common_random_numbers_nominal_sample_equals_a_plain_run(nominal_study, tmp_path):
    opts = _opts(tmp_path / "plain")
    res = run_simulation(opts, analyses=for_options(opts))
    plain = {r["name"]: r["value_cd"] for r in res.summary["regulation"]["results"]}
    nom = nominal_study.nominal
    assert nom.offset == [0.0] * 5
    for name, value in zip(nom.names, nom.value_cd):
        assert value == pytest.approx(plain[name], rel=1e-12, abs=1e-9), name


def test_misplaced_filament_is_flagged_as_failing(nominal_study, misplaced_study):
    nom = {p.name: p for p in nominal_study.points}
    mis = {p.name: p for p in misplaced_study.points}
    # the example's 75R passes at the nominal filament (with its interval) but is marginal:
    # a sample inside the box (0.2 mm low, 0.3 mm forward) already misses it. 1 mm low, the
    # beam loses 75R in every sample, and the study says so.
    assert nom["75R"].nominal_verdict == "pass" and nom["75R"].pass_rate > 0
    assert mis["75R"].pass_rate == 0.0 and mis["75R"].nominal_verdict == "fail"
    assert mis["75R"].worst_margin < 0 and mis["75R"].worst_cd < nom["75R"].worst_cd
    assert misplaced_study.all_pass_rate()[0] == 0.0
    # the interval of a 0-of-2 rate still admits a pass: it is an honest small-sample bound
    assert mis["75R"].pass_interval[0] == 0.0 and mis["75R"].pass_interval[1] < 1.0


def test_study_files_read_back(nominal_study, tmp_path):
    files = write_study(nominal_study, tmp_path)
    doc = json.loads((tmp_path / "tolerance.json").read_text())
    assert len(doc["samples"]) == 3 and doc["box"]["category"] == "H4"
    assert {p["name"] for p in doc["points"]} >= {"75R", "B50L", "III"}
    with open(tmp_path / "tolerance.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3 * len(nominal_study.points)
    r75 = [r for r in rows if r["point"] == "75R"]
    assert float(r75[0]["value_cd"]) == pytest.approx(nominal_study.nominal.value_cd[
        nominal_study.nominal.names.index("75R")], rel=1e-5)
    with Image.open(files[2]) as im:
        assert im.format == "PNG" and im.size[0] > 200


# -- command line -------------------------------------------------------------------------


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lightsim.cli.main", "tolerance", *args],
                          capture_output=True, text=True, timeout=300, cwd=REPO)


@pytest.mark.parametrize("args, needle", [
    (["missing.glb", "--regulation", RULES], "no such file"),
    ([str(LAMP), "--regulation", "r999"], "r999"),
    ([str(LAMP), "--regulation", RULES, "--samples", "0"], "--samples"),
    ([str(LAMP), "--regulation", RULES, "--box", "0.2,nan,0.3"], "--box"),
    ([str(LAMP), "--regulation", RULES, "--centre", "1,2"], "--centre"),
    ([str(LAMP), "--regulation", RULES, "--bulb", "H99", "--samples", "1"], "H99"),
])
def test_bad_input_is_one_line_and_exit_2(args, needle, tmp_path):
    r = _cli(*args, "--out", str(tmp_path / "o"))
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], r.stderr
    assert not (tmp_path / "o" / "tolerance.json").exists()


@pytest.mark.slow
@pytest.mark.ray
def test_ray_workers_give_the_same_samples(nominal_study, tmp_path):
    pytest.importorskip("ray")
    study = run_tolerance(_opts(tmp_path), samples=2, seed=1, workers=2)
    for a, b in zip(study.samples, nominal_study.samples):
        assert a.offset == b.offset
        assert np.allclose(a.value_cd, b.value_cd, rtol=1e-12)


def test_a_sample_that_cannot_be_aimed_fails_every_point(monkeypatch, tmp_path):
    real = tolerance_mod.regulation_check

    def no_cutoff(session, lux, ruleset, traffic="right", aim=False, **kw):
        if aim:
            raise InputError("--aim: no cut-off found")
        return real(session, lux, ruleset, traffic, aim, **kw)

    monkeypatch.setattr(tolerance_mod, "regulation_check", no_cutoff)
    opts = SimulateOptions(str(LAMP), out_dir=str(tmp_path), photons=20_000,
                           resolution=(80, 32), regulation=RULES, aperture=0.0, aim=True)
    s = run_sample(opts, np.zeros(5))
    assert s.names and not any(s.value_pass) and not any(s.sure_pass)
    assert all(v.startswith("not aimable") for v in s.verdicts)
    with pytest.raises(InputError):  # without --aim the same error is the user's problem
        monkeypatch.setattr(tolerance_mod, "regulation_check",
                            lambda *a, **k: (_ for _ in ()).throw(InputError("bad")))
        run_sample(SimulateOptions(str(LAMP), out_dir=str(tmp_path), photons=20_000,
                                   resolution=(80, 32), regulation=RULES, aperture=0.0),
                   np.zeros(5))


def test_cli_study_writes_its_files_and_table(tmp_path):
    out = tmp_path / "study"
    r = _cli(str(LAMP), "--regulation", RULES, "--samples", "1", "--photons", "20000",
             "--resolution", "80x32", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    assert "pass rate" in r.stdout and "75R" in r.stdout and "ASSUMPTION" in r.stdout
    doc = json.loads((out / "tolerance.json").read_text())
    assert len(doc["samples"]) == 2 and doc["photons"] == 20000
    assert (out / "tolerance.csv").stat().st_size > 0 and (out / "tolerance.png").exists()


# -- sensitivity (least-squares plane) and reading a study back ------------------------


def test_sensitivity_fit_recovers_a_known_plane():
    box = TOLERANCE_BOXES["H4"]
    off = sample_design(box, 40, seed=2)
    # 10 000 cd at the centre, +500 cd per 0.1 mm of dx, −2 000 per 0.1 mm of dy, none in dz
    truth = 10_000 + 500 * off[:, 0] / (0.1 * MM) - 2_000 * off[:, 1] / (0.1 * MM)
    rng = np.random.default_rng(0)
    noisy = truth + rng.normal(0, 100.0, len(truth))
    s = fit_sensitivity(off, noisy, {"min": 8_000.0})
    assert s.axes == ["dx", "dy", "dz"] and s.samples == 41
    for b, se, want in zip(s.per_step_cd, s.se_cd, (500.0, -2_000.0, 0.0)):
        assert 0 < se < 60 and abs(b - want) < 4 * se
    assert s.centre_cd == pytest.approx(10_000, abs=60) and s.rms_cd == pytest.approx(100, rel=0.3)
    assert 0.99 < s.r2 < 1.0
    # along dy alone the plane meets 8 000 cd at +0.1 mm; dz's slope is not resolved
    assert s.reach_mm[1] == pytest.approx(0.1, rel=0.05) and s.reach_mm[2] is None
    assert s.reach_mm[0] == pytest.approx(-0.4, rel=0.1)
    # a centre already below the limit has no reach left; a fixed axis is not fitted
    assert fit_sensitivity(off, noisy, {"min": 12_000.0}).reach_mm[:2] == [0.0, 0.0]
    flat = off.copy()
    flat[:, 2] = 0.0
    assert fit_sensitivity(flat, noisy, {"max": 1e6}).axes == ["dx", "dy"]
    exact = fit_sensitivity(off[:4], truth[:4], {})  # 4 samples, 4 parameters: no error
    assert exact.per_step_cd == pytest.approx([500.0, -2_000.0, 0.0], abs=1e-6)
    assert all(np.isnan(exact.se_cd)) and exact.reach_mm == [None] * 3
    few = fit_sensitivity(off[:3], truth[:3], {})  # 3 samples: the plane is not determined
    assert all(np.isnan(few.per_step_cd)) and np.isnan(few.centre_cd) and few.samples == 3


def test_study_reads_back_from_its_json(nominal_study, tmp_path):
    write_study(nominal_study, tmp_path)
    back = study_from_dict(json.loads((tmp_path / "tolerance.json").read_text()))
    assert back.box == nominal_study.box and back.aperture_deg is None
    for a, b in zip(back.points, nominal_study.points):
        assert a.name == b.name and a.pass_rate == b.pass_rate
        assert a.worst_cd == b.worst_cd and a.sure_fail_rate == b.sure_fail_rate
        assert a.sensitivity.per_step_cd == pytest.approx(b.sensitivity.per_step_cd, nan_ok=True)
    with pytest.raises(InputError):
        study_from_dict({"samples": []})
