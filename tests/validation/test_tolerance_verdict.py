"""The tolerance study's verdict at the box centre is ``lightsim simulate``'s verdict.

Every sample is evaluated with simulate's estimator (detector apertures at the test points,
its default 0.15°) and rule evaluation, so the centre sample of a study reproduces a plain
``simulate`` run of the same photons and seed: values, 95 % intervals and verdicts.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from lightsim.luminaires.analyses import for_options
from lightsim.simulate import SimulateOptions, run_simulation
from lightsim.validation.tolerance import run_tolerance

REPO = Path(__file__).resolve().parents[2]
LOWBEAM = REPO / "luminaires" / "examples" / "lowbeam.glb"
RULES = "r149-b-passing"


def _opts(out: Path) -> SimulateOptions:
    # simulate's own defaults for the estimator (no aperture given: 0.15° apertures)
    return SimulateOptions(str(LOWBEAM), out_dir=str(out), photons=100_000,
                           resolution=(80, 32), regulation=RULES, config={"seed": 7})


def test_centre_sample_verdicts_are_simulates(tmp_path):
    opts = _opts(tmp_path / "plain")
    assert opts.aperture > 0  # the study's default estimator is simulate's default
    res = run_simulation(opts, analyses=for_options(opts))
    reg = res.summary["regulation"]
    assert reg["method"]["name"] == "aperture"
    plain = {r["name"]: r for r in reg["results"] if r.get("limit") and r["verdict"] != "info"}
    study = run_tolerance(_opts(tmp_path / "study"), samples=1, seed=1)
    nom = study.nominal
    assert nom.offset == [0.0] * 5 and study.aperture_deg == opts.aperture
    assert set(nom.names) == set(plain)
    for i, name in enumerate(nom.names):
        r = plain[name]
        assert nom.verdicts[i] == r["verdict"], name
        assert nom.value_cd[i] == pytest.approx(r["value_cd"], rel=1e-12, abs=1e-9), name
        assert [nom.lo_cd[i], nom.hi_cd[i]] == pytest.approx(r["interval_cd"], rel=1e-12,
                                                             abs=1e-9), name
    # the study's per-point summary quotes the same centre verdicts
    assert {p.name: p.nominal_verdict for p in study.points} == {
        n: r["verdict"] for n, r in plain.items()}
    # the displaced sample is a different geometry with the same photons: it differs
    assert study.samples[1].value_cd != nom.value_cd


def test_two_rule_sets_are_simulates_two_tables(tmp_path):
    # `--regulation a,b` as in the README demo: each set counts its own apertures (appended
    # after the other's), and every point's centre value is the one in simulate's table
    two = "r112-b-passing,r149-b-passing"
    opts = SimulateOptions(str(LOWBEAM), out_dir=str(tmp_path / "plain"), photons=50_000,
                           resolution=(80, 32), regulation=two, config={"seed": 3})
    res = run_simulation(opts, analyses=for_options(opts))
    plain = {}
    for key, rs in (("regulation", "r112-b-passing"), ("regulation:r149-b-passing",
                                                        "r149-b-passing")):
        for r in res.summary[key]["results"]:
            if r.get("limit") and r["verdict"] != "info":
                plain[f"{rs}:{r['name']}"] = r
    study = run_tolerance(SimulateOptions(str(LOWBEAM), out_dir=str(tmp_path / "study"),
                                          photons=50_000, resolution=(80, 32),
                                          regulation=two, config={"seed": 3}),
                          samples=1, seed=1)
    nom = study.nominal
    assert set(nom.names) == set(plain)
    assert any(n.startswith("r112") for n in nom.names)
    assert any(n.startswith("r149") for n in nom.names)
    for i, name in enumerate(nom.names):
        assert nom.value_cd[i] == pytest.approx(plain[name]["value_cd"], rel=1e-12,
                                                abs=1e-9), name
        assert nom.verdicts[i] == plain[name]["verdict"], name
