"""UN R149 rule sets: shipped beside R112, loadable, provenance marked, and evaluated."""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.luminaires.regulations import evaluate, list_rulesets, load_ruleset, probe_points
from lightsim.luminaires.regulations.ruleset import iter_rule_names

R149 = ["r149-a-passing", "r149-b-passing", "r149-a-driving", "r149-b-driving",
        "r149-d-driving"]


def test_r149_listed_beside_r112():
    ids = [r["id"] for r in list_rulesets()]
    assert set(R149) <= set(ids) and "r112-b-passing" in ids


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


def test_passing_beam_values_are_marked_less_sure():
    """The R149 passing-beam points carried over from R112 01 say so, rule by rule."""
    r149, r112 = load_ruleset("r149-b-passing"), load_ruleset("r112-b-passing")
    for name in ("B50L", "75R", "50V", "50R", "25L", "25R", "III"):
        a, b = r149.geometry(name), r112.geometry(name)
        assert (a.min, a.max, a.h, a.v) == (b.min, b.max, b.h, b.v)
        assert a.certainty == "less-sure" and "R112" in a.note


def test_r149_driving_verdicts():
    """Synthetic driving beam, 42 000 cd everywhere: passes class B (≥ 40 500), fails D."""
    for cls, verdict in (("b", "pass"), ("d", "fail")):
        rs = load_ruleset(f"r149-{cls}-driving")
        pr = probe_points(rs)
        res = {r["name"]: r for r in evaluate(rs, pr, np.full((4, len(pr)), 42_000.0))}
        assert res["Imax"]["verdict"] == verdict
        assert res["HV >= 0.8*Imax"]["verdict"] == "pass"
