"""Per-level smoothing of iso-lux lines near the noise floor (lightsim.io.contour_noise)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from lightsim.io.contour_noise import level_sigma_px, smoothed_for_levels
from lightsim.io.plots import isolux_plot


def test_sigma_law():
    # at the floor (16 photons) reaching 256 photons needs 16x the area: 4πσ² = 15·A
    assert level_sigma_px(1.0, 1.0, 10.0) == pytest.approx(math.sqrt(15 * 10 / (4 * math.pi)))
    assert level_sigma_px(16.0, 1.0, 10.0) == 0.0           # 256 photons already
    assert level_sigma_px(32.0, 1.0, 10.0) == 0.0
    for bad in (0.0, -1.0, math.nan, math.inf):
        assert level_sigma_px(1.0, bad, 10.0) == 0.0
        assert level_sigma_px(1.0, 1.0, bad) == 0.0


def _noisy_beam(photons_per_px_at_peak: float, seed: int = 3):
    """A smooth beam (lx) and a density estimate of it: Poisson photon counts per pixel
    averaged over a 4 x 4 pixel box (16 px, like a kNN disk), so the noise is correlated
    over the estimate's area as in a photon map."""
    y, x = np.mgrid[0:96, 0:192]
    truth = 20.0 * np.exp(-(((x - 96) / 40.0) ** 2 + ((y - 48) / 18.0) ** 2))
    rng = np.random.default_rng(seed)
    counts = rng.poisson(truth / 20.0 * photons_per_px_at_peak)
    est = ndimage.uniform_filter(counts.astype(float), 4, mode="nearest")
    return truth, est / photons_per_px_at_peak * 20.0


def test_smoothing_removes_islands_near_the_floor():
    truth, est = _noisy_beam(25.0)
    floor = 16 / (16 * 25.0) * 20.0     # an estimate (16 px) holds 16 photons at 0.8 lx
    levels = [1.0, 2.0, 5.0, 15.0]
    imgs, band, sigmas = smoothed_for_levels(est, levels, floor, 16.0)
    assert sigmas[0] > sigmas[1] > sigmas[2] > 0.0 and sigmas[-1] == 0.0
    raw_regions = 0
    for lv, im in zip(levels[:3], imgs, strict=False):
        raw_regions += ndimage.label(est >= lv)[1]
        assert ndimage.label(im >= lv)[1] == 1, lv           # one clean region per level
        # and the smoothed line stays where the true one is (area within 5 %)
        assert abs((im >= lv).sum() / (truth >= lv).sum() - 1) < 0.05
    assert raw_regions >= 10                                 # while the raw lines speckle
    assert imgs[-1] is est or np.array_equal(imgs[-1], est)  # no blur where not needed
    assert band.min() == -1 and band.max() == len(levels) - 1


def test_isolux_plot_with_estimate_area(tmp_path):
    _, est = _noisy_beam(400.0)
    frame = {"centre": [0, 0, 25], "h_axis": [-1, 0, 0], "v_axis": [0, 1, 0],
             "normal": [0, 0, -1], "h_range_m": [-15, 15], "v_range_m": [-7.5, 7.5],
             "distance_m": 25.0, "resolution": [192, 96]}
    p = isolux_plot(tmp_path / "iso.png", est, frame, noise_floor_lx=0.8,
                    estimate_area_px=1.0)
    assert p.stat().st_size > 10_000
