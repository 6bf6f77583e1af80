"""The written map's radius rule (ICI over nested windows) and the exact shield cut-off."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lightsim.render import ici
from lightsim.scene import make_wall
from lightsim.validation.scenes import analytic as an


def test_window_sums_match_brute_force_and_clip_at_the_wall():
    rng = np.random.default_rng(3)
    H, W, C = 7, 9, 2
    sub = rng.random((2 * H, 2 * W, C))
    rows, cols = np.divmod(np.arange(H * W), W)
    sides = np.array([1, 2, 3, 4])
    sums, cells = ici.window_sums(sub, rows, cols, sides)
    for q in (0, 13, 31, H * W - 1):
        r, c = rows[q], cols[q]
        for j, m in enumerate(sides):
            r0, r1 = max(0, 2 * r + 1 - m), min(2 * H, 2 * r + 1 + m)
            c0, c1 = max(0, 2 * c + 1 - m), min(2 * W, 2 * c + 1 + m)
            assert np.allclose(sums[j, q], sub[r0:r1, c0:c1].sum(axis=(0, 1)))
            assert cells[j, q] == (r1 - r0) * (c1 - c0)
    # rung 0 is the pixel itself: its four half-pixel cells
    assert np.allclose(sums[0], sub.reshape(H, 2, W, 2, C).sum(axis=(1, 3)).reshape(-1, C))


def test_lattice_index_puts_pixel_centres_on_cell_corners():
    _, frame = make_wall(25.0, (2.0, 1.0), resolution=(4, 2))
    # pixel (row 0, col 0) spans h ∈ [−1, −0.5), v ∈ (0, 0.5]; its centre (−0.75, 0.25)
    flat, ok = ici.lattice_index(np.array([-0.76, -0.74, -0.76]),
                                 np.array([0.26, 0.24, -0.6]), frame)
    assert ok.tolist() == [True, True, False]
    assert flat[0] == 0 and flat[1] == 1 * 8 + 1  # cells (0, 0) and (1, 1)


def test_rung_sides_and_the_shrinking_ladder():
    px = (0.01, 0.01)
    r_pix = math.sqrt(px[0] * px[1] / math.pi)
    assert ici.rung_sides(px, 4 * r_pix).tolist() == [1, 2, 3, 4]
    assert ici.rung_sides(px, r_pix).tolist() == [1]
    assert ici.rung_sides(px, math.inf).tolist() == [1, 2, 3, 4]
    sides = np.array([1, 2, 3, 4])
    assert ici.shrink_sides(sides, ici.SHRINK_START).tolist() == [1, 2, 3, 4]
    # m = ⌊4 (Λ₀/Λ)^(1/6)⌋: 3 from Λ₀ on, 2 from (4/3)^6 Λ₀ ≈ 5.6 Λ₀, 1 from 4^6 Λ₀
    assert ici.shrink_sides(sides, 2 * ici.SHRINK_START).tolist() == [1, 2, 3]
    assert ici.shrink_sides(sides, 12 * ici.SHRINK_START).tolist() == [1, 2]
    assert ici.shrink_sides(sides, 5000 * ici.SHRINK_START).tolist() == [1]


def _step_rungs(level_left: float, level_right: float, counts: float, S: int, seed: int):
    """Synthetic sets on a 1-row strip: a step between columns 19 and 20."""
    rng = np.random.default_rng(seed)
    W = 40
    truth = np.where(np.arange(W) < 20, level_left, level_right)
    sides = np.array([1, 2, 3, 4])
    rungs = {}
    for s in range(S):
        est = []
        for m in sides:  # window of m pixels: mean over the columns it covers
            k = np.ones(m) / m
            mean = np.convolve(np.pad(truth, m, mode="edge"), k, mode="same")[m:-m]
            if m % 2 == 0:  # even windows centred on the pixel centre: half pixels at ends
                k = np.r_[0.5, np.ones(m - 1), 0.5] / m
                mean = np.convolve(np.pad(truth, m, mode="edge"), k, mode="same")[m:-m]
            lam = mean * counts * m  # photons per set in the window
            est.append(rng.poisson(lam) / (counts * m))
        rungs[s] = np.stack(est)[..., None]  # (J+1, Q, 1), unit photon power, area m
    return truth, rungs, sides


def test_ici_keeps_the_edge_and_averages_the_flat_parts():
    S, counts = 16, 400.0  # photons per set and pixel at level 1
    _, rungs, sides = _step_rungs(1.0, 0.0, counts, S, 5)
    emitted = dict.fromkeys(range(S), 1)
    # σ model: E q / (N A) with q = 1 photon power, N = S, A = counts · m per rung
    areas = np.array([counts * m for m in sides], dtype=float)
    choice = ici.choose(rungs, emitted, 1.0, areas, 2.0)
    # the two pixels at the step keep a small window, the flat parts the largest
    assert choice.rung[19] <= 1 and choice.rung[20] <= 1
    assert np.all(choice.rung[:15] == 3) and np.all(choice.rung[25:] == 3)
    assert abs(choice.lux[19, 0] - 1.0) < 0.15 and abs(choice.lux[20, 0]) < 0.1
    # the error figure sees noise only where the rungs agree, and no blur at the step
    err = ici.estimate_error(rungs, choice, lit_fraction=0.1)
    assert err is not None and err.noise < 0.05


def test_choose_without_photons_is_zero_and_rung_zero():
    rungs = {s: np.zeros((4, 5, 1)) for s in range(4)}
    choice = ici.choose(rungs, dict.fromkeys(range(4), 0), 0.0, np.ones(4), 2.0)
    assert np.all(choice.lux == 0) and choice.lux.shape == (5, 1)
    assert ici.estimate_error(rungs, choice) is None


def test_shield_step_pixel_means_are_exact():
    case = an.shield_case(resolution=(16, 8))
    frame = case.frame
    exact = case.pixel_means(frame)
    h, v = frame.pixel_centres()
    dh, dv = frame.pixel_size_m
    t, c = case.extra["slope"], case.extra["offset_m"]
    u = (np.arange(600) + 0.5) / 600 - 0.5  # midpoint rule: error ~ 1/600 at the step
    straddling = 0
    for i in range(len(v)):
        for j in range(len(h)):
            hh, vv = np.meshgrid(h[j] + u * dh, v[i] + u * dv)
            brute = case.exact(hh, vv).mean()
            assert brute == pytest.approx(exact[i, j], abs=2e-5 * exact.max())
            line = t * hh + c
            straddling += bool((vv < line).any() and (vv >= line).any())
    assert straddling >= 10  # the tilted edge crosses pixels at many offsets
    # lit below the line, dark above
    assert exact[-1, 0] > 0 and exact[0, -1] == 0
