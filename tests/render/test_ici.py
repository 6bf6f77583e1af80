"""The written map's radius rule (ICI over nested windows) and the exact shield cut-off."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lightsim.render import ici
from lightsim.render.ici import held_out_blur
from lightsim.render.written_map import FUSED_MARGIN, error_figure, written_map
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


def _numpy_window_sums(sub: np.ndarray, geometry) -> np.ndarray:
    """The definition the compiled paths reproduce: NumPy's summed-area table (``cumsum``
    down the columns, then along the rows) and each window's four corners by fancy
    indexing."""
    H2, W2, C = sub.shape
    sat = np.zeros((H2 + 1, W2 + 1, C))
    np.cumsum(sub, axis=0, out=sat[1:, 1:])
    np.cumsum(sat[1:, 1:], axis=1, out=sat[1:, 1:])
    return np.stack([sat[r1, c1] - sat[r0, c1] - sat[r1, c0] + sat[r0, c0]
                     for r0, r1, c0, c1 in geometry.bounds])


@pytest.mark.parametrize("H,W,C", [(7, 9, 2), (1, 1, 1), (16, 40, 3), (3, 1, 1)])
def test_raster_window_sums_are_numpys_bit_for_bit(H, W, C):
    """The compiled pass over every pixel, and the compiled table for any query list
    (the same geometry with the raster flag off, with and without its stacked bounds),
    against the summed-area table NumPy builds, bit for bit across 60 decades."""
    rng = np.random.default_rng(H * W)
    sub = rng.random((2 * H, 2 * W, C)) * 10.0 ** rng.integers(-30, 30, (2 * H, 2 * W, C))
    rows, cols = np.divmod(np.arange(H * W), W)
    sides = np.array([1, 2, 3, 5])
    geometry = ici.WindowGeometry.of(H, W, rows, cols, sides)
    assert geometry.raster
    want = _numpy_window_sums(sub, geometry)
    fast, cells = ici.window_sums(sub, rows, cols, sides, geometry)
    np.testing.assert_array_equal(fast, want)
    for general in (ici.WindowGeometry(geometry.bounds, geometry.cells),
                    ici.WindowGeometry(geometry.bounds, geometry.cells,
                                       stacked=geometry.stacked)):
        slow, cells_slow = ici.window_sums(sub, rows, cols, sides, general)
        np.testing.assert_array_equal(slow, want)
        np.testing.assert_array_equal(cells, cells_slow)
    assert not ici.WindowGeometry.of(H, W, rows[::-1], cols[::-1], sides).raster or H * W == 1


def test_window_sums_of_a_query_list_are_numpys_bit_for_bit():
    """Queries too many for the direct sums and not the raster (the grid probes of a
    small wall): the compiled summed-area table, in any order, with repeats and the
    wall's corners."""
    H, W, C = 24, 20, 2
    rng = np.random.default_rng(5)
    sub = rng.random((2 * H, 2 * W, C)) * 10.0 ** rng.integers(-30, 30, (2 * H, 2 * W, C))
    rows = np.r_[rng.integers(0, H, 300), 0, H - 1, 0, H - 1, 7, 7]
    cols = np.r_[rng.integers(0, W, 300), 0, W - 1, W - 1, 0, 3, 3]
    sides = np.array([1, 2, 3, 4])
    geometry = ici.WindowGeometry.of(H, W, rows, cols, sides)
    assert not geometry.raster and not geometry.direct
    sums, _ = ici.window_sums(sub, rows, cols, sides, geometry)
    np.testing.assert_array_equal(sums, _numpy_window_sums(sub, geometry))
    empty = ici.WindowGeometry.of(H, W, rows[:0], cols[:0], sides)
    assert ici.window_sums(sub, rows[:0], cols[:0], sides, empty)[0].shape == (4, 0, C)


@pytest.mark.parametrize("H,W,C", [(64, 160, 3), (256, 640, 1), (40, 30, 2)])
def test_direct_window_sums_at_few_pixels_are_exact_where_the_table_cancels(H, W, C):
    """A frame's grid probes are summed cell by cell (no pass over the whole lattice):
    to rounding of the exact sums even across 60 decades, where the summed-area table's
    corner differences lose every digit of a dark window beside a bright one."""
    rng = np.random.default_rng(H + W)
    sub = rng.random((2 * H, 2 * W, C)) * 10.0 ** rng.integers(-30, 30, (2 * H, 2 * W, C))
    rows = np.r_[rng.integers(0, H, 40), 0, H - 1]  # the wall's edges clip windows
    cols = np.r_[rng.integers(0, W, 40), W - 1, 0]
    for sides in (np.array([1, 2, 3, 4]), np.array([1, 2, 3, 5]), np.array([2, 7])):
        geometry = ici.WindowGeometry.of(H, W, rows, cols, sides)
        assert geometry.direct and not geometry.raster
        sums, cells = ici.window_sums(sub, rows, cols, sides, geometry)
        for q in range(len(rows)):
            r, c = rows[q], cols[q]
            for j, m in enumerate(sides):
                r0, r1 = max(0, 2 * r + 1 - m), min(2 * H, 2 * r + 1 + m)
                c0, c1 = max(0, 2 * c + 1 - m), min(2 * W, 2 * c + 1 + m)
                exact = sub[r0:r1, c0:c1].astype(np.longdouble).sum(axis=(0, 1))
                np.testing.assert_allclose(sums[j, q], exact.astype(float), rtol=1e-13)
                assert cells[j, q] == (r1 - r0) * (c1 - c0)
    none = ici.window_sums(sub, rows[:0], cols[:0], sides)
    assert none[0].shape == (len(sides), 0, C) and none[1].shape == (len(sides), 0)
    # every pixel is the raster's pass; a query list as long as the wall: the table
    rows_all, cols_all = np.divmod(np.arange(H * W), W)
    assert not ici.WindowGeometry.of(H, W, rows_all[::-1], cols_all[::-1], sides).direct


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
    fig = error_figure(rungs, choice, lit_fraction=0.1)
    assert fig is not None and fig.error.noise < 0.05


def test_choose_without_photons_is_zero_and_rung_zero():
    rungs = {s: np.zeros((4, 5, 1)) for s in range(4)}
    choice = ici.choose(rungs, dict.fromkeys(range(4), 0), 0.0, np.ones(4), 2.0)
    assert np.all(choice.lux == 0) and choice.lux.shape == (5, 1)
    assert error_figure(rungs, choice) is None


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


# -- the error figure against a planted blur ------------------------------------------

def _lattice_field(H: int, W: int, level: float) -> np.ndarray:
    """Expected photons per set in each half-pixel cell: a gradient with an oblique 4:1
    step (every pixel stays lit at 10 % of the maximum)."""
    y, x = np.mgrid[0:2 * H, 0:2 * W] + 0.5
    lam = level * (1.0 + x / (2 * W))
    return np.where(y > 0.3 * x + 6, lam, 0.25 * lam)


def _poisson_sets(lam: np.ndarray, S: int, sides: np.ndarray, rng) -> dict[int, np.ndarray]:
    """Every set's rungs from its own Poisson photons (unit power) on the lattice, so the
    rungs are nested exactly as the real windows are."""
    H, W = lam.shape[0] // 2, lam.shape[1] // 2
    rows, cols = np.divmod(np.arange(H * W), W)
    out = {}
    for s in range(S):
        sums, cells = ici.window_sums(rng.poisson(lam)[..., None].astype(float), rows, cols,
                                      sides)
        out[s] = sums / cells[..., None]
    return out


def _exact_rungs(lam: np.ndarray, sides: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    H, W = lam.shape[0] // 2, lam.shape[1] // 2
    rows, cols = np.divmod(np.arange(H * W), W)
    sums, cells = ici.window_sums(lam[..., None], rows, cols, sides)
    return sums[..., 0] / cells, cells


@pytest.mark.parametrize("level", [0.3, 3.0])  # ≈ 20 and 200 photons per pixel (all sets)
def test_error_figure_is_unbiased_for_a_planted_blur(level):
    """At a fixed rung (the 4 × 4 window everywhere) the blur and noise the figure reports
    average to the exact ones, and its standard error matches its scatter."""
    H, W, S, R = 12, 24, 16, 40
    sides = np.arange(1, 5)
    lam = _lattice_field(H, W, level)
    exact, cells = _exact_rungs(lam, sides)
    mu = exact[0]
    true_b2 = np.mean((exact[3] - mu) ** 2) / mu.mean() ** 2
    true_n2 = np.mean(exact[3] / (cells[3] * S)) / mu.mean() ** 2  # Poisson, pooled sets
    rng = np.random.default_rng(11)
    choice = ici.IciChoice(np.full(H * W, 3), None)
    figs = [error_figure(_poisson_sets(lam, S, sides, rng), choice, 0.0) for _ in range(R)]
    b2 = np.array([f.bias2 for f in figs])
    n2 = np.array([f.error.noise**2 for f in figs])
    se = float(np.mean([f.bias2_se for f in figs]))
    assert abs(b2.mean() - true_b2) < 4.0 * b2.std(ddof=1) / math.sqrt(R)
    assert n2.mean() == pytest.approx(true_n2, rel=0.05)
    assert se == pytest.approx(b2.std(ddof=1), rel=0.35)
    # the noise subtraction matters: without it the blur would read high by Var(D̄) =
    # σ₀² − σ₃² (nested windows), several times the tolerance above
    var_d = np.mean(mu / (cells[0] * S) - exact[3] / (cells[3] * S)) / mu.mean() ** 2
    assert var_d > 2.5 * 4.0 * b2.std(ddof=1) / math.sqrt(R)


def test_written_map_figure_is_honest_although_the_rungs_come_from_the_same_photons():
    """ICI keeps the large window where D = E_j − E_0 came out small, so D̄² − se_D² at
    the chosen rungs reads low; the held-out pairs do not (ratio of the figure to the
    actual error of the written map over repeats)."""
    H, W, S, R = 10, 20, 16, 30
    sides = np.arange(1, 5)
    lam = _lattice_field(H, W, 3.0)
    exact, cells = _exact_rungs(lam, sides)
    mu = exact[0]
    rng = np.random.default_rng(5)
    emitted = dict.fromkeys(range(S), 1)
    held, naive = [], []
    for _ in range(R):
        sets = _poisson_sets(lam, S, sides, rng)
        wm = written_map(sets, emitted, 1.0, cells, 2.0, 0.0, directional=False)
        actual = math.sqrt(np.mean((wm.lux[:, 0] - mu) ** 2)) / mu.mean()
        held.append(wm.error.total / actual)
        same = error_figure(sets, wm.choice, 0.0, wm.alpha)  # D̄² − se_D², same photons
        naive.append(same.error.total / actual)
    assert 0.92 <= np.median(held) <= 1.12
    assert np.quantile(held, 0.1) >= 0.8 and np.quantile(held, 0.9) <= 1.25
    assert np.median(naive) < np.median(held) - 0.05  # the bias guarded against is real


def test_fused_map_figure_is_honest_and_its_edge_error_lower():
    """The fused directional map (the raster recognised from its window areas) on the
    oblique step: its figure within 0.8–1.25 of its actual error over repeats, and its
    true error in the band along the step below the centred map's from the same photons;
    the default writes the fused map only with a figure clearly below the centred's."""
    H, W, S, R = 10, 20, 16, 30
    sides = np.arange(1, 5)
    lam = _lattice_field(H, W, 3.0)
    exact, cells = _exact_rungs(lam, sides)
    mu = exact[0]
    assert ici.raster_shape(cells) == (H, W)
    assert ici.raster_shape(cells[:, :-1]) is None and ici.raster_shape(cells[:1]) is None
    y, x = np.mgrid[0:H, 0:W]
    step = np.abs((2 * y + 1) - (0.3 * (2 * x + 1) + 6)) < 2 * 2.5  # ≤ 2.5 px from the step
    rng = np.random.default_rng(5)
    emitted = dict.fromkeys(range(S), 1)
    ratio, edge = [], []
    for _ in range(R):
        sets = _poisson_sets(lam, S, sides, rng)
        fused = written_map(sets, emitted, 1.0, cells, 2.0, 0.0, directional=True)
        centred = written_map(sets, emitted, 1.0, cells, 2.0, 0.0, directional=False)
        assert fused.choice.weights is not None and not hasattr(centred.choice, "weights")
        best = written_map(sets, emitted, 1.0, cells, 2.0, 0.0)  # the default
        f, c = fused.error.total, centred.error.total
        assert best.error.total == (f if f < FUSED_MARGIN * c else c)
        # the map says which it is, so a caller can ask for that one alone next time
        assert fused.fused and not centred.fused and best.fused == (f < FUSED_MARGIN * c)
        err = {k: (m.lux[:, 0] - mu).reshape(H, W) for k, m in
               (("fused", fused), ("centred", centred))}
        ratio.append(fused.error.total / (math.sqrt(np.mean(err["fused"] ** 2)) / mu.mean()))
        edge.append([math.sqrt(np.mean(err[k][step] ** 2)) for k in ("fused", "centred")])
    edge = np.array(edge)
    assert 0.9 <= np.median(ratio) <= 1.15
    assert np.quantile(ratio, 0.1) >= 0.8 and np.quantile(ratio, 0.9) <= 1.25
    assert np.mean(edge[:, 0] ** 2) < 0.9 * np.mean(edge[:, 1] ** 2)
    assert np.mean(edge[:, 0] < edge[:, 1]) >= 0.7  # in most repeats, not on average only


def test_held_out_blur_of_some_queries_is_theirs_of_all():
    """``queries=`` computes only those columns (the figure reads only the lit ones) and
    gives exactly the values of the full computation there."""
    rng = np.random.default_rng(3)
    S, J1, Q = 6, 4, 50
    rungs = {s: rng.gamma(3.0, 10.0, (J1, Q, 1)) for s in range(S)}
    emitted = {s: 1000 + 10 * s for s in range(S)}
    areas = np.linspace(1.0, 9.0, J1)[:, None] * np.ones((1, Q)) * 1e-4
    groups = [np.arange(0, S, 2), np.arange(1, S, 2)]
    full = held_out_blur(rungs, emitted, 0.02, areas, 2.0, groups)
    some = np.array([0, 7, 8, 30, 49])
    part = held_out_blur(rungs, emitted, 0.02, areas, 2.0, groups, queries=some)
    assert part.shape == full.shape
    np.testing.assert_array_equal(part[:, some], full[:, some])
    rest = np.setdiff1d(np.arange(Q), some)
    assert not part[:, rest].any()
    none = held_out_blur(rungs, emitted, 0.02, areas, 2.0, groups, queries=np.zeros(0, int))
    assert none.shape == full.shape and not none.any()
