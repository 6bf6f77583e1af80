"""The target-error stop study: runs stop, are scored against the exact answer, and the
outputs are written and read back."""

import csv
import json

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.validation import stop_study as ss


def test_region_mask_interior_within_lit():
    y, x = np.mgrid[-20:21, -20:21]
    exact = np.where(np.hypot(x, y) < 15, 100.0, 0.0)
    lit = ss.region_mask(exact, "lit", (1e-3, 1e-3))
    inner = ss.region_mask(exact, "interior", (1e-3, 1e-3))
    assert inner.sum() < lit.sum() and not np.any(inner & ~lit)
    with pytest.raises(InputError):
        ss.region_mask(exact, "edge", (1e-3, 1e-3))


def test_bad_input():
    with pytest.raises(InputError):
        ss.run_study(["no-such-case"], (0.02,), 1)
    with pytest.raises(InputError):
        ss.run_study(["lambertian"], (1.5,), 1)
    with pytest.raises(InputError):
        ss.run_study(["lambertian"], (0.02,), 0)


def test_one_case_stops_near_target(tmp_path):
    study = ss.run_study(["lambertian"], (0.05,), seeds=2)
    assert len(study.runs) == 2
    for r in study.runs:
        assert r.figure is not None and r.figure <= 0.05 * 1.01
        assert 0.3 < r.ratio < 1.5  # the true error is of the order of the target
    s = study.summary[0]
    assert s.runs == 2 and s.min_ratio <= s.median_ratio <= s.max_ratio
    paths = ss.write_outputs(study, tmp_path)
    rows = list(csv.DictReader(paths["csv"].open()))
    assert [int(r["seed"]) for r in rows] == [1, 2]
    doc = json.loads(paths["json"].read_text())
    assert doc["summary"][0]["runs"] == 2
    assert paths["png"].stat().st_size > 0


@pytest.mark.slow
def test_twenty_seeds_paraboloid_fine():
    study = ss.run_study(["paraboloid-fine"], (0.02,), seeds=20)
    s = study.summary[0]
    assert s.runs == 20
    # honesty: stops above the target stay near the nominal rate
    assert s.above <= max(2, round(3 * ss.STOP_ALPHA * s.runs))
