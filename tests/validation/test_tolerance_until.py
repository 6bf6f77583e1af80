"""``lightsim tolerance --until decided``: each sample stops when its verdicts are decided,
and a sample that reaches its cap says what is still open."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lightsim.simulate import SimulateOptions
from lightsim.validation.tolerance import TOLERANCE_BOXES, run_sample, run_tolerance

from support import write_point_lamp

RULES = "r112-b-passing"
FRAME = 100_000


@pytest.fixture(scope="module")
def lamp(tmp_path_factory) -> Path:
    """A 1000 lm isotropic filament: 79.6 cd in every direction, far from most limits."""
    return write_point_lamp(tmp_path_factory.mktemp("lamp") / "lamp.glb")


def _opts(lamp: Path, out: Path, photons: int, until: str = "decided") -> SimulateOptions:
    # 1.5° apertures: the isotropic source's few photons per aperture decide within ~2 M
    return SimulateOptions(str(lamp), out_dir=str(out), photons=photons, resolution=(80, 32),
                           regulation=RULES, aperture=1.5,
                           config={"seed": 3, "frame_photons": FRAME}, until=until)


def test_a_sample_stops_when_decided_or_reports_its_cap(lamp, tmp_path):
    capped = run_sample(_opts(lamp, tmp_path, 2 * FRAME), np.zeros(5))
    assert capped.photons == 2 * FRAME and capped.decided is False
    assert "uncertain" in capped.verdicts  # the cap came first: something is open
    cap = 64 * FRAME
    big = run_sample(_opts(lamp, tmp_path, cap), np.zeros(5))
    assert big.decided and "uncertain" not in big.verdicts
    # it stopped at a look of the doubling schedule, well before its cap
    assert big.photons < cap and big.photons in {FRAME * 2 ** k for k in range(6)}
    truth = 1000.0 / (4 * np.pi)
    for name, verdict, lim in zip(big.names, big.verdicts, big.limits, strict=True):
        ok = (lim.get("min") is None or truth >= lim["min"]) and (
            lim.get("max") is None or truth <= lim["max"])
        if name.isdigit() or name in ("B50L", "BR", "75R", "75L", "50L", "50R", "50V"):
            assert verdict == ("pass" if ok else "fail"), name


def test_study_records_the_photons_each_sample_took(lamp, tmp_path):
    study = run_tolerance(_opts(lamp, tmp_path, 2 * FRAME), samples=1, seed=1,
                          box=TOLERANCE_BOXES["H4"])
    doc = study.to_dict()
    assert doc["until"] == "decided"
    used = doc["photons_used"]
    assert used["max"] <= 2 * FRAME
    assert used["total"] == sum(s["photons"] for s in doc["samples"])
    assert all(s["decided"] is False for s in doc["samples"])


def test_until_verdict_stops_a_failing_sample_at_its_first_sure_fail(lamp, tmp_path):
    """``--until verdict``: the isotropic lamp fails 75R (79.6 cd ≪ 10 100) at the first
    look, so the sample stops there; its fails are true ones."""
    s = run_sample(_opts(lamp, tmp_path, 64 * FRAME, until="verdict"), np.zeros(5))
    assert s.photons == FRAME and s.decided
    truth = 1000.0 / (4 * np.pi)
    verdicts = dict(zip(s.names, s.verdicts, strict=True))
    assert verdicts["75R"] == "fail"
    for name, verdict, lim in zip(s.names, s.verdicts, s.limits, strict=True):
        if verdict == "fail" and (name.isdigit() or len(name) <= 4):
            assert (lim.get("min") is not None and truth < lim["min"]) or (
                lim.get("max") is not None and truth > lim["max"]), name
