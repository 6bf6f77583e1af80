"""The error figure over the beam's interior (``--error-region interior``,
lightsim.render.region): the distance transform against scipy's, the interior of a round
beam, the fall-backs, and the figure's honesty against the exact paraboloid."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.render import ici
from lightsim.render import written_map as written
from lightsim.render.edt import squared_distance
from lightsim.render.region import interior, restriction
from lightsim.validation.bench.peer import CASES, truth_of


@pytest.mark.parametrize("shape,cell", [((64, 64), (1.0, 1.0)), ((33, 70), (0.3, 1.7)),
                                        ((7, 1), (1.0, 1.0)), ((1, 9), (2.0, 2.0)),
                                        ((20, 31), (1.0, 4.0))])
def test_distance_transform_is_scipys(shape, cell):
    rng = np.random.default_rng(3)
    for frac in (0.01, 0.3, 0.95):
        unlit = rng.random(shape) < frac
        unlit.flat[rng.integers(unlit.size)] = True  # at least one
        d2 = squared_distance(unlit, *cell)
        ref = distance_transform_edt(~unlit, sampling=cell)
        np.testing.assert_allclose(np.sqrt(d2), ref, rtol=1e-12, atol=1e-12)


def _disc(n: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    c = np.arange(n) + 0.5 - n / 2
    r = np.hypot(*np.meshgrid(c, c))
    return (r < radius).ravel(), r.ravel()


@pytest.mark.parametrize("scale", [1e-30, 1.0, 1e30])
def test_interior_of_a_round_beam_is_its_inner_80_percent(scale):
    lit, r = _disc(64, 25.0)
    got = interior(lit, (64, 64), (scale, scale))
    inner = r < 0.8 * 25.0
    assert got.sum() > 0 and not (got & ~lit).any()
    # within one pixel ring of r < 0.8 R (2π·20 ≈ 126 pixels in that ring)
    assert (got ^ inner).sum() <= 0.5 * 2 * np.pi * 20
    assert r[got].max() <= 0.8 * 25 + 1.0 and r[lit & ~got].min() >= 0.8 * 25 - 1.0


def test_interior_fall_backs_and_the_wall_border():
    for mask in (np.zeros(256, bool), np.ones(256, bool)):  # nothing unlit / nothing lit
        np.testing.assert_array_equal(interior(mask, (16, 16), (1.0, 1.0)), mask)
    line = np.zeros((16, 16), bool)
    line[:, 7:9] = True  # two cells wide: nothing 0.2 R_eq deep → every lit cell
    np.testing.assert_array_equal(interior(line.ravel(), (16, 16), (1.0, 1.0)), line.ravel())
    # a beam cut by the wall: the border is no edge, only the dark side is
    half = np.zeros((20, 40), bool)
    half[:, :30] = True
    got = interior(half.ravel(), (20, 40), (1.0, 1.0)).reshape(20, 40)
    depth = 0.2 * np.sqrt(half.sum() / np.pi)
    assert got[:, 0].all() and got[0, :20].all()  # the wall's edges stay interior
    assert not got[:, 30 - int(np.ceil(depth)):].any()
    with pytest.raises(ValueError, match="lit flags"):
        interior(np.ones(5, bool), (2, 2), (1.0, 1.0))
    assert restriction("lit", (2, 2), (1.0, 1.0)) is None
    with pytest.raises(ValueError, match="error region"):
        restriction("rim", (2, 2), (1.0, 1.0))
    with pytest.raises(InputError):
        RunConfig(error_region="rim")


def test_interior_figure_is_honest_on_the_paraboloid():
    """The written map's figure over the interior against the exact pixel means over the
    inner 80 % of the beam (the peer bench's score), and the lit figure against the lit
    pixels, from the same photons: each reads its own region's true error."""
    case = CASES["paraboloid"](64)
    truth = truth_of(case)
    got = {}
    for region in ("lit", "interior"):
        session = Session(case.scene, RunConfig(seed=4, error_region=region))
        est = session.run(photons=600_000, probes=False)
        lux = est.lux[..., 0]
        got[region] = (est.error.total, truth.error(lux, "inner" if region == "interior"
                                                    else "lit"))
        session.close()
    for region, (figure, actual) in got.items():
        assert 0.75 * actual <= figure <= 1.5 * actual, (region, figure, actual)
    # the map is the same (chosen on the lit pixels); the interior is its better part
    assert got["interior"][0] < 0.8 * got["lit"][0]


@pytest.mark.parametrize("estimator", ["knn", "bin"])
def test_probe_figure_reads_the_interior_too(estimator):
    """On a wall too large for the map check at every estimate the run's figures come
    from the grid probes (ICI rungs there, or the kNN/bin probe estimates): the interior
    is taken on the probe raster, and its figure is below the lit one."""
    case = CASES["paraboloid"](128)  # 128 × 128 pixels > 4 per grid probe
    figures = {}
    for region in ("lit", "interior"):
        session = Session(case.scene, RunConfig(seed=2, error_region=region,
                                                estimator=estimator))
        assert not session.map_check_is_cheap()
        session.shoot(400_000)
        est = session.estimate_at_probes()
        figures[region] = est.error.total
        session.close()
    assert all(np.isfinite(v) and v > 0 for v in figures.values())
    assert figures["interior"] < figures["lit"]


def test_tile_labels_cover_the_raster_in_row_order():
    got = written.tile_labels((5, 10), 4).reshape(5, 10)
    assert got[0, 0] == got[3, 3] == 0 and got[0, 4] == 1 and got[0, 9] == 2
    assert got[4, 0] == 3 and got[4, 9] == 5  # the cut last row and column of tiles
    assert len(np.unique(got)) == 6


def _clumped_sets(lam: np.ndarray, S: int, sides: np.ndarray, clump: int, rng
                  ) -> dict[int, np.ndarray]:
    """Every set's rungs from Poisson events that each leave one unit of power in the same
    half-pixel cell of ``clump`` × ``clump`` neighbouring pixels: neighbouring pixels'
    counts are correlated (as the windows' sharing of photons, and QMC sets' stratified
    counts, make them), with the mean field ``lam`` per cell and set."""
    H, W = lam.shape[0] // 2, lam.shape[1] // 2
    rows, cols = np.divmod(np.arange(H * W), W)
    out = {}
    for s in range(S):
        ev = rng.poisson(lam / clump**2).astype(float)
        power = sum(np.roll(ev, (2 * i, 2 * j), (0, 1))
                    for i in range(clump) for j in range(clump))
        sums, cells = ici.window_sums(power[..., None], rows, cols, sides)
        out[s] = sums / cells[..., None]
    return out


@pytest.mark.parametrize("clump", [1, 3])
def test_region_blur_standard_error_matches_its_scatter(clump, monkeypatch):
    """The region's blur standard error (batch means over tiles) against the scatter of
    the blur estimate over repeats, on a smooth beam's interior (no blur to speak of):
    with independent pixels and with pixels whose counts are correlated over 3 × 3
    neighbours. The Gaussian per-pixel formula, which ignores the correlation, reads
    about half the scatter there: a bound of blur + 2 s.e. would then not be one."""
    H = W = 48
    S, R = 16, 30
    y, x = np.mgrid[0:2 * H, 0:2 * W] + 0.5
    lam = 2.0 * np.exp(-((x - W) ** 2 + (y - H) ** 2) / W**2)  # ≈ 8 photons/pixel/set
    sides = np.arange(1, 5)
    rows, cols = np.divmod(np.arange(H * W), W)
    inner = np.hypot(rows - H / 2 + 0.5, cols - W / 2 + 0.5) < 0.3 * W
    cells = ici.window_cells(H, W, rows, cols, sides) * 0.25
    emitted = dict.fromkeys(range(S), 1)

    def spread(tiles_min: int) -> tuple[float, float]:
        monkeypatch.setattr(written, "TILES_MIN", tiles_min)
        rng = np.random.default_rng(3)
        figs = [written.written_map(_clumped_sets(lam, S, sides, clump, rng), emitted,
                                    1.0, cells, 2.0, 0.1, directional=True,
                                    restrict=lambda m: m & inner).figure for _ in range(R)]
        b2 = np.array([f.bias2 for f in figs])
        return float(np.mean([f.bias2_se for f in figs])), float(b2.std(ddof=1))

    se, sd = spread(16)
    assert 0.75 * sd <= se <= 1.35 * sd, (se, sd)
    if clump > 1:  # the formula (never enough tiles) misses the correlation
        se_formula, sd_formula = spread(10**9)
        assert sd_formula == pytest.approx(sd)  # the same estimates, only their s.e.
        assert se_formula < 0.7 * sd
