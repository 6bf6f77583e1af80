"""``lightsim validate --coverage --guide``: with importance-driven emission the intervals
still cover the exact aperture means at the nominal rate and no verdict is wrong beyond
it (synthetic Type A lamps of known intensities)."""

from __future__ import annotations

import pytest

from lightsim.validation.coverage import coverage_study


def _check(result) -> None:
    lo, hi = result.band()
    assert result.guide and result.evaluations > 0
    assert lo <= result.rate <= hi, (result.rate, lo, hi)
    for kind, count in result.rules.items():
        assert count.wrong <= count.allowed(), (kind, count.to_dict())


def test_guided_coverage_quick():
    _check(coverage_study(lamps=2, photons=500_000, guide=True, seed=3, quad=16,
                          zone_quad=8))


@pytest.mark.slow
def test_guided_coverage_at_1m():
    _check(coverage_study(lamps=20, photons=1_000_000, guide=True, seed=5))
