"""Estimates at a few points from the photons near them (lightsim.photonmap.near): the
same photons as the whole map's, the same floor, so the same estimates to rounding."""

import numpy as np
import pytest

from lightsim.engine.photonset import DeferredPhotonMap
from lightsim.photonmap.density import PhotonMap
from lightsim.photonmap.near import NearGrid


def _beam(rng, n, scale=1.0, offset=0.0):
    """Photons on a wall (z = offset) with a bright spot, unit normals, powers."""
    pts = np.empty((n, 3), np.float32)
    spot = rng.random(n) < 0.6
    pts[:, :2] = np.where(spot[:, None], rng.normal(0.0, 0.1, (n, 2)), rng.uniform(-1, 1, (n, 2)))
    pts[:, :2] *= scale
    pts[:, 2] = offset
    nrm = np.tile(np.float32([0, 0, 1]), (n, 1))
    pw = rng.uniform(0.5, 1.5, (n, 1)) * scale ** 2
    return pts, nrm, pw


def _scans(scale=1.0, offset=0.0):
    """Query points along three short vertical lines (like the cut-off scans)."""
    v = np.linspace(-0.4, 0.3, 71)
    q = np.array([(h, y, 0.0) for h in (-0.15, -0.25, -0.35) for y in v])
    q[:, :2] *= scale
    q[:, 2] = offset
    return q.astype(np.float32)


@pytest.mark.parametrize("scale", [1.0, 1e-30, 1e30])
def test_near_photons_are_a_superset_of_those_within_the_radius(scale):
    rng = np.random.default_rng(1)
    pts, _, _ = _beam(rng, 50_000, scale)
    q = _scans(scale)
    r = 0.03 * scale
    bounds = np.array([np.inf] * 3 + [-np.inf] * 3)
    picked = NearGrid(q, r).select(pts, bounds)
    d2 = ((pts[:, None, :2].astype(np.float64) - q[None, :, :2]) ** 2).sum(-1)
    within = np.flatnonzero((d2 <= r * r).any(axis=1))
    assert np.all(np.isin(within, picked))
    assert np.all(np.diff(picked) > 0)  # in the photons' order
    assert len(picked) < 0.5 * len(pts)  # and far fewer than all of them
    np.testing.assert_array_equal(bounds[:3], pts.min(axis=0))
    np.testing.assert_array_equal(bounds[3:], pts.max(axis=0))


def test_near_grid_edge_cases():
    q = np.zeros((1, 3))
    grid = NearGrid(q, 1.0)
    bounds = np.array([np.inf] * 3 + [-np.inf] * 3)
    assert len(grid.select(np.zeros((0, 3), np.float32), bounds)) == 0  # no photons
    same = np.zeros((5, 3), np.float32)  # coincident with the query
    np.testing.assert_array_equal(grid.select(same, bounds), np.arange(5))
    far = np.array([[3.5, 0, 0], [np.float32(3e38), 0, 0]], np.float32)
    assert len(grid.select(far, bounds)) == 0
    spread = np.array([[0, 0, 0], [1e6, 1e6, 1e6]])  # queries far apart: cells grow
    big = NearGrid(spread, 1e-3)
    assert big.marked.size <= 1 << 22 and big.cell >= 1e-3
    assert len(big.select(np.float32([[1e6, 1e6, 1e6 + 5e-4]]), bounds)) == 1
    for bad in (0.0, -1.0, np.inf, np.nan):
        with pytest.raises(ValueError):
            NearGrid(q, bad)
    with pytest.raises(ValueError):
        NearGrid(np.zeros((0, 3)), 1.0)


@pytest.mark.parametrize("kw", [
    {"k": 64, "max_radius": 0.03, "min_radius": 0.005},
    {"k": 16, "max_radius": 0.02, "min_radius": 0.0, "kernel": "cone"},
    {"k": 500, "max_radius": 0.01, "min_radius": 0.0},  # k > photons within the radius
])
def test_deferred_map_estimates_at_few_points_from_the_near_photons(kw):
    rng = np.random.default_rng(2)
    pts, nrm, pw = _beam(rng, 120_000)
    q = _scans()
    qn = np.tile(np.float32([0, 0, 1]), (len(q), 1))
    whole, deferred = PhotonMap("middle"), DeferredPhotonMap("middle", 1)
    for lo in range(0, len(pts), 30_000):  # four frames
        whole.add(pts[lo:lo + 30_000], nrm[lo:lo + 30_000], pw[lo:lo + 30_000])
        deferred.add(pts[lo:lo + 30_000], nrm[lo:lo + 30_000], pw[lo:lo + 30_000])
    a = whole.estimate(q, qn, **kw)
    b = deferred.estimate(q, qn, **kw)
    assert len(deferred.map) == 0  # the whole map was not built
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_allclose(a.r, b.r, rtol=1e-12)
    np.testing.assert_allclose(a.E, b.E, rtol=1e-12, atol=0)
    if kw.get("kernel", "box") == "box":  # summed in the same order: bit for bit
        np.testing.assert_array_equal(a.E, b.E)
    # every point: the whole map is built (and kept) when the near photons are most of it
    side = np.linspace(-1, 1, 101)  # 0.02 apart: every cell near a point
    grid_q = np.stack(np.meshgrid(side, side), -1).reshape(-1, 2)
    grid_q = np.concatenate([grid_q, np.zeros((len(grid_q), 1))], 1).astype(np.float32)
    grid_n = np.tile(qn[:1], (len(grid_q), 1))
    c = deferred.estimate(grid_q, grid_n, **kw)
    assert len(deferred.map) == len(pts)
    np.testing.assert_allclose(c.E, whole.estimate(grid_q, grid_n, **kw).E, rtol=1e-12)


def test_deferred_map_without_photons_near_the_points():
    rng = np.random.default_rng(3)
    pts, nrm, pw = _beam(rng, 10_000)
    deferred = DeferredPhotonMap("middle", 1)
    deferred.add(pts, nrm, pw)
    q = np.float32([[5.0, 5.0, 0.0]])
    res = deferred.estimate(q, np.float32([[0, 0, 1]]), k=8, max_radius=0.1, min_radius=0.0)
    ref = PhotonMap("middle")
    ref.add(pts, nrm, pw)
    want = ref.estimate(q, np.float32([[0, 0, 1]]), k=8, max_radius=0.1, min_radius=0.0)
    np.testing.assert_array_equal(res.E, want.E)
    np.testing.assert_array_equal(res.r, want.r)


def test_probes_every_frame_switch_to_the_built_map():
    """A probe after every frame would select from all photons each time; once those
    selections have read LOCAL_SCANS times the stored photons the whole map is built
    (and then grows by insertion), so repeated probes cost no more than a few builds."""
    rng = np.random.default_rng(5)
    q = _scans()
    qn = np.tile(np.float32([0, 0, 1]), (len(q), 1))
    deferred = DeferredPhotonMap("middle", 1)
    built_at = None
    for frame in range(40):
        deferred.add(*_beam(rng, 5_000))
        deferred.estimate(q, qn, k=16, max_radius=0.03)
        if built_at is None and len(deferred.map):
            built_at = frame
    assert built_at is not None and built_at < 40
    assert deferred._scanned <= DeferredPhotonMap.LOCAL_SCANS * 5_000 * (built_at + 1)
    assert len(deferred.map) == 40 * 5_000
