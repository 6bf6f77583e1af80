"""Cut-off detection (R112 annex 9 scans), sharpness, linearity, aim and re-aiming."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import ndimage

from lightsim.errors import InputError
from lightsim.render.cutoff import (
    TARGET_V_DEG,
    aim_shift,
    apply_shift,
    cutoff_interval,
    find_cutoff,
    scan_sample_points,
)
from lightsim.render.filters import gaussian_filter1d, map_coordinates
from lightsim.wall import WallFrame, lux_from_candela, wall_m_from_deg

D = 25.0
FRAME = {"distance_m": D, "h_range_m": [-wall_m_from_deg(20.0), wall_m_from_deg(20.0)],
         "v_range_m": [-wall_m_from_deg(5.0), wall_m_from_deg(5.0)], "resolution": [640, 320]}
WF = WallFrame.from_any(FRAME)
HD = WF.h_deg()[None, :]
VD = WF.v_deg()[:, None]


def step_pattern(v0: float | np.ndarray, width: float = 0.08, decades: float = 2.0,
                 noise: float = 0.05, seed: int = 0) -> np.ndarray:
    """log10 E = smoothed step falling by ``decades`` at V = v0 (going up), with noise."""
    log_e = 1.5 - 0.5 * decades * (1 + np.tanh((VD - v0) / width)) - 0.002 * HD**2
    e = 10.0**log_e * np.ones_like(HD)
    rng = np.random.default_rng(seed)
    return e * (1 + noise * rng.standard_normal(e.shape))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_known_cutoff_found_within_0_05_deg(seed):
    res = find_cutoff(step_pattern(-0.57, seed=seed), FRAME)
    assert res.found and res.message == "ok"
    assert res.v_cutoff_deg == pytest.approx(-0.57, abs=0.05)
    for scan in res.scans:
        assert scan.found and scan.v_inflection_deg == pytest.approx(-0.57, abs=0.05)
    assert [s.h_deg for s in res.scans] == [-1.5, -2.5, -3.5]    # left of V-V
    assert res.linear is True and res.spread_deg < 0.05
    assert res.aim_dv_deg == pytest.approx(0.0, abs=0.05)
    json.dumps(res.to_dict())


def test_sharpness_matches_the_analytic_step():
    # G = log E(v0 − 0.05) − log E(v0 + 0.05) = decades·tanh(0.05/width) for the tanh step
    width, decades = 0.3, 1.5
    res = find_cutoff(step_pattern(-0.3, width=width, decades=decades, noise=0.0), FRAME)
    assert res.sharpness_g == pytest.approx(decades * np.tanh(0.05 / width), rel=0.05)
    assert res.sharpness_ok is True                                # 0.248 in 0.13–0.40
    sharp = find_cutoff(step_pattern(-0.3, width=0.05, noise=0.0), FRAME)
    assert sharp.sharpness_g > 0.4 and sharp.sharpness_ok is False


def test_aim_shift_and_apply_shift_put_the_cutoff_at_0_57_down():
    lux = step_pattern(0.2, noise=0.03)
    dh, dv = aim_shift(lux, FRAME)
    assert dh == 0.0 and dv == pytest.approx(TARGET_V_DEG - 0.2, abs=0.05)
    aimed = apply_shift(lux, FRAME, dh, dv)
    assert find_cutoff(aimed, FRAME).v_cutoff_deg == pytest.approx(TARGET_V_DEG, abs=0.05)


def test_linearity_fails_for_a_tilted_cutoff():
    tilted = step_pattern(-0.57 + 0.15 * (HD + 2.5), noise=0.0)    # 0.3° over 1.5…3.5°
    res = find_cutoff(tilted, FRAME)
    assert res.found and res.linear is False and res.spread_deg == pytest.approx(0.3, abs=0.05)


def test_left_hand_traffic_scans_right_of_v():
    lux = np.where(HD > 0, step_pattern(-0.57, noise=0.0), step_pattern(0.8, noise=0.0))
    right = find_cutoff(lux, FRAME, traffic="right")
    left = find_cutoff(lux, FRAME, traffic="left")
    assert [s.h_deg for s in left.scans] == [1.5, 2.5, 3.5]
    assert left.v_cutoff_deg == pytest.approx(-0.57, abs=0.05)
    assert right.v_cutoff_deg == pytest.approx(0.8, abs=0.05)


@pytest.mark.parametrize("lux, fragment", [
    (np.zeros((320, 640)), "no light"),
    (np.full((320, 640), 5.0), "does not fall off"),
    (np.random.default_rng(3).random((320, 640)), "contrast"),
    (np.full((320, 640), np.nan), "no light"),
])
def test_no_cutoff_is_reported_not_raised(lux, fragment):
    res = find_cutoff(lux, FRAME)
    assert res.found is False and res.message.startswith("no cut-off found")
    assert fragment in res.message
    assert res.aim_dv_deg is None
    with pytest.raises(InputError, match="cannot aim"):
        aim_shift(lux, FRAME)


def test_saturated_and_black_regions():
    lux = step_pattern(-0.57, noise=0.05)
    clipped = np.minimum(lux, np.quantile(lux, 0.9))          # clipped hot region
    res = find_cutoff(clipped, FRAME)
    assert res.found and res.v_cutoff_deg == pytest.approx(-0.57, abs=0.1)
    black = np.where(VD > -0.57, 0.0, lux)                      # hard edge into pure black
    res = find_cutoff(black, FRAME)
    assert res.found and res.v_cutoff_deg == pytest.approx(-0.57, abs=0.05)
    assert np.isfinite(res.sharpness_g)


def test_apply_shift_moves_a_spot_and_round_trips():
    hm, vm = np.meshgrid(WF.h_m(), WF.v_m())
    spot = 10000.0 * np.exp(-((HD - 0.0) ** 2 + (VD - 0.0) ** 2) / (2 * 0.6**2))
    lux = lux_from_candela(spot, hm, vm, D)
    moved = apply_shift(lux, FRAME, 3.0, -1.0)
    i, j = np.unravel_index(np.argmax(moved), moved.shape)
    assert WF.h_deg()[j] == pytest.approx(3.0, abs=0.07)       # pixel pitch 0.0625°
    assert WF.v_deg()[i] == pytest.approx(-1.0, abs=0.04)
    back = apply_shift(moved, FRAME, -3.0, 1.0)
    core = np.abs(HD) + np.abs(VD) < 3
    assert np.allclose(back[core], lux[core], rtol=0.02, atol=0.1)
    far = apply_shift(lux, FRAME, 30.0, 0.0)   # pixels left of 10° R look beyond 20° L
    assert np.all(far[:, WF.h_deg() < 9.9] == 0.0)
    assert np.all(apply_shift(lux, FRAME, 30.0, 0.0, fill=-1.0)[:, :10] == -1.0)


def test_bad_inputs():
    with pytest.raises(InputError, match="shape"):
        find_cutoff(np.ones((10, 10)), FRAME)
    with pytest.raises(InputError, match="traffic"):
        find_cutoff(step_pattern(-0.57), FRAME, traffic="middle")


# ---- the cut-off position's interval from the sets (jackknife) --------------------------
def _set_values(v0: float, noise: float, seed: int, sets: int = 16) -> np.ndarray:
    hv, _, _ = scan_sample_points(FRAME)
    hd = np.degrees(np.arctan2(hv[:, 0], D))
    vd = np.degrees(np.arctan2(hv[:, 1], D))
    e = 10.0 ** (1.5 - (1 + np.tanh((vd - v0) / 0.08)) - 0.002 * hd**2)
    rng = np.random.default_rng(seed)
    return e[None, :] * (1 + noise * rng.standard_normal((sets, len(e))))


def test_cutoff_interval_covers_the_true_position():
    covered, widths = [], []
    for seed in range(24):
        ci = cutoff_interval(_set_values(-0.57, 0.3, seed), FRAME, None)
        assert ci.found_sets == 16 and ci.interval_deg is not None
        lo, hi = ci.interval_deg
        covered.append(lo <= -0.57 <= hi)
        widths.append(hi - lo)
    # 95 % intervals: at least 19 of 24 (P(fewer) < 2 % for exact coverage)
    assert sum(covered) >= 19
    narrow = cutoff_interval(_set_values(-0.57, 0.075, 99), FRAME, None)
    # a quarter of the noise: a much narrower interval (≈ ¼)
    assert (narrow.interval_deg[1] - narrow.interval_deg[0]) < 0.5 * np.median(widths)
    json.dumps(narrow.to_dict())


def test_cutoff_interval_degenerate_inputs():
    flat = np.ones((16, _set_values(-0.57, 0.0, 0).shape[1]))
    ci = cutoff_interval(flat, FRAME, None)   # no cut-off anywhere: reported, not raised
    assert ci.found_sets == 0 and ci.interval_deg is None
    one = cutoff_interval(_set_values(-0.57, 0.1, 1, sets=1), FRAME, -0.57)
    assert one.interval_deg is None
    assert cutoff_interval(np.zeros((4, 7)), FRAME, None).interval_deg is None  # bad shape


def test_numpy_filters_match_scipy_ndimage():
    """The numpy bilinear sampler and Gaussian (scipy.ndimage is not imported by a run)
    agree with scipy.ndimage to rounding, edges and out-of-range coordinates included."""
    rng = np.random.default_rng(0)
    for H, W in [(1, 1), (1, 5), (7, 1), (40, 64)]:
        img = rng.random((H, W))
        r, c = rng.uniform(-3, H + 2, 300), rng.uniform(-3, W + 2, 300)
        np.testing.assert_allclose(map_coordinates(img, [r, c]),
                                   ndimage.map_coordinates(img, [r, c], order=1,
                                                           mode="nearest"), atol=1e-14)
    for n in (1, 3, 200):
        x = rng.random(n)
        for s in (0.1, 1.0, 2.5, 12.0):
            np.testing.assert_allclose(gaussian_filter1d(x, s),
                                       ndimage.gaussian_filter1d(x, s, mode="nearest"),
                                       atol=1e-14)
