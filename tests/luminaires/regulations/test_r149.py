"""UN R149 rule sets: shipped beside R112, loadable, provenance marked, and evaluated."""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.luminaires.regulations import evaluate, list_rulesets, load_ruleset, probe_points
from lightsim.luminaires.regulations.ruleset import iter_rule_names

R149 = ["r149-a-passing", "r149-b-passing", "r149-a-driving", "r149-b-driving",
        "r149-d-driving"]
R149_01 = ["r149-01-c-passing", "r149-01-a-driving", "r149-01-b-driving"]


def test_r149_listed_beside_r112():
    ids = [r["id"] for r in list_rulesets()]
    assert set(R149 + R149_01) <= set(ids) and "r112-b-passing" in ids
    for r in list_rulesets():
        assert r["version"] and r["source"], r    # --list-rulesets shows both


def test_list_rulesets_cli_shows_versions_and_sources(capsys):
    from support import run_cli

    code, out, _ = run_cli(["report", "--list-rulesets"], capsys)
    assert code in (0, None)
    block = out.split("r149-b-passing", 1)[1].split("\n")[:3]
    assert "version: 00 series" in block[1] and "ECE/TRANS/WP.29/2018/158" in block[2]
    assert "version: 01 series" in out.split("r149-01-c-passing", 1)[1]


@pytest.mark.parametrize("rid", R149_01)
def test_r149_01_sets_load_with_sources(rid):
    rs = load_ruleset(rid)
    assert rs.regulation == "UN R149" and rs.version.startswith("01 series")
    assert "ECE/TRANS/WP.29/2022/93" in rs.source
    probe_points(rs)


def test_r149_01_driving_points_two_sources():
    """01 series Table 5: H-12L…H-12R per class (sure), IM less-sure."""
    a, b = load_ruleset("r149-01-a-driving"), load_ruleset("r149-01-b-driving")
    for name, lim_a, lim_b in (("H-12L", 600, 1500), ("H-9R", 2000, 3400),
                               ("H-6L", 3400, 5000), ("H-3R", 12000, 17500)):
        assert a.geometry(name).min == lim_a and b.geometry(name).min == lim_b
        assert b.geometry(name).certainty == "sure"
    assert b.geometry("Imax").min == 40000 and b.geometry("Imax").certainty == "less-sure"


def test_r149_01_class_c_verdicts():
    """A synthetic class C beam: passes every tested rule; dimming it fails 75R."""
    rs = load_ruleset("r149-01-c-passing")
    pr = probe_points(rs)

    def beam(h, v, gain):
        below = np.where(np.abs(h) <= 9.0, 13000.0, 3000.0)
        val = np.where(v >= 0, 300.0, np.where(v < -3.5, 1000.0, below))
        return gain * val

    for gain, failing in ((1.0, set()), (0.9, {"75R"})):
        vals = np.tile(beam(pr.h_deg, pr.v_deg, gain), (4, 1))
        res = {r["name"]: r["verdict"] for r in evaluate(rs, pr, vals)}
        assert {n for n, v in res.items() if v == "fail"} == failing, res


@pytest.mark.parametrize("rid", R149)
def test_r149_sets_load_with_sources(rid):
    rs = load_ruleset(rid)
    assert rs.id == rid and rs.regulation == "UN R149"
    assert "2019" in rs.source and "ECE/TRANS/WP.29/2018/158" in rs.source
    assert rs.version.startswith("00 series")
    assert len(list(iter_rule_names(rs))) >= 3


def test_driving_beam_minimum_imax_per_class():
    """R149 Table 5: IM ≥ 27 000 (A), 40 500 (B), 43 800 cd (D) — the sure values."""
    for cls, imin in (("a", 27_000), ("b", 40_500), ("d", 43_800)):
        zone = load_ruleset(f"r149-{cls}-driving").geometry("Imax")
        assert zone.min == imin and zone.certainty == "sure"


def test_passing_beam_table8_values():
    """R149 00 Table 8 Part A: class A and B columns differ where the table says so."""
    a, b = load_ruleset("r149-a-passing"), load_ruleset("r149-b-passing")
    for name, lim_a, lim_b in (("50R", 5100, 10100), ("75R", 5100, 10100),
                               ("25L2", 1250, 1700), ("25R1", 1250, 1700)):
        assert a.geometry(name).min == lim_a and b.geometry(name).min == lim_b
    assert b.geometry("50V").min == 5100
    with pytest.raises(KeyError):
        a.geometry("50V")                      # class A has no 50V row
    for rs in (a, b):
        fifty_l = rs.geometry("50L")
        assert fifty_l.max == 13200 and fifty_l.min is None  # minima deleted by Supplement 1
        assert rs.geometry("IV").polygon[0] == (-5.15, -0.86)
    assert a.geometry("IV").min == 1700 and b.geometry("IV").min == 2500
    assert a.geometry("I").max == 17600 and b.geometry("I").max is None


def test_passing_beam_certainty_and_sources():
    """Sure rules name Table 8 and a second source; single-source rules say so."""
    rs = load_ruleset("r149-b-passing")
    r112 = load_ruleset("r112-b-passing")
    for name, old in (("B50L", "B50L"), ("75R", "75R"), ("50V", "50V"), ("50R", "50R"),
                      ("25L2", "25L"), ("25R1", "25R"), ("III", "III")):
        g, o = rs.geometry(name), r112.geometry(old)
        assert (g.min, g.max, g.h, g.v) == (o.min, o.max, o.h, o.v)
        assert g.certainty == "sure" and "Table 8" in g.source
    for name in ("IV", "I"):
        g = rs.geometry(name)
        assert g.certainty == "less-sure" and "one transcription" in g.note


def _low_beam(h, v, above=300.0):
    """A synthetic cut-off beam (cd): dim above H, bright below, brighter right of V."""
    return np.where(v >= 0, above, np.where(v <= -1.72, 5000.0, np.where(h < 0, 9000.0, 12000.0)))


@pytest.mark.parametrize("cls", ["a", "b"])
def test_passing_beam_verdicts(cls):
    """The synthetic beam passes every tested rule; 400 cd above H fails B50L only."""
    rs = load_ruleset(f"r149-{cls}-passing")
    pr = probe_points(rs)
    for above, failing in ((300.0, set()), (400.0, {"B50L"})):
        vals = np.tile(_low_beam(pr.h_deg, pr.v_deg, above), (4, 1))
        res = {r["name"]: r["verdict"] for r in evaluate(rs, pr, vals)}
        assert {n for n, v in res.items() if v == "fail"} == failing, res
        assert all(v == "pass" for n, v in res.items() if n not in failing), res


def test_r149_driving_verdicts():
    """Synthetic driving beam, 42 000 cd everywhere: passes class B (≥ 40 500), fails D."""
    for cls, verdict in (("b", "pass"), ("d", "fail")):
        rs = load_ruleset(f"r149-{cls}-driving")
        pr = probe_points(rs)
        res = {r["name"]: r for r in evaluate(rs, pr, np.full((4, len(pr)), 42_000.0))}
        assert res["Imax"]["verdict"] == verdict
        assert res["HV >= 0.8*Imax"]["verdict"] == "pass"
