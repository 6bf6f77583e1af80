"""Termination and input checks of the photon maps on degenerate photon sets.

Millions of coincident photons, photons on a plane or a line, exponentially clustered
coordinates and far-away queries must neither hang nor lose exactness; NaN/inf positions
are rejected with a one-line :class:`~lightsim.errors.InputError`. Units: m.
"""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.photonmap import KdTree, MedianKdTree, PhotonMap, UniformGrid


def _brute(points: np.ndarray, queries: np.ndarray, k: int) -> np.ndarray:
    p = points.astype(np.float64)
    d2 = ((p[None, :, :] - queries[:, None, :]) ** 2).sum(axis=-1)
    return np.sort(d2, axis=1)[:, :k].astype(np.float32)


@pytest.mark.parametrize("make", [KdTree, MedianKdTree])
def test_million_coincident_points_make_one_leaf(make: type) -> None:
    n = 1_000_000
    pts = np.full((n, 3), 3.5, np.float32)
    tree = make(pts)
    assert tree.n_nodes == 1 and tree.depth == 0  # zero extent: never split
    tree.add(pts[:1000])
    assert len(tree) == n + 1000 and tree.n_nodes == 1
    d2, idx = tree.query(np.array([[3.5, 3.5, 3.5], [4.0, 3.5, 3.5]]), 5)
    assert (d2[0] == 0).all() and (d2[1] == np.float32(0.25)).all()
    assert len(set(idx[0].tolist())) == 5 and (idx >= 0).all()


def test_coincident_clusters_split_only_between_them() -> None:
    n = 500_000
    pts = np.zeros((2 * n, 3), np.float32)
    pts[n:] = [1.0, 2.0, 3.0]
    tree = KdTree(pts)
    leaves = np.flatnonzero(tree.layout.child < 0)
    sizes = (tree.layout.end - tree.layout.start)[leaves]
    assert sorted(sizes[sizes > 0].tolist()) == [n, n]
    grid = UniformGrid(pts)
    d2, _ = grid.query(np.array([[0.0, 0.0, 0.1]]), 3)
    np.testing.assert_array_equal(d2, np.float32([[0.01, 0.01, 0.01]]))


def test_exponentially_clustered_coordinates_terminate_and_stay_exact() -> None:
    # x = 2^-i down to float32 subnormals: every middle split peels off one point
    x = (2.0 ** -np.arange(150)).astype(np.float32)
    pts = np.zeros((x.size, 3), np.float32)
    pts[:, 0] = x
    tree = KdTree(pts, leaf_size=1)
    assert tree.depth <= 2 * x.size
    q = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [1e-30, 0.0, 0.0]])
    d2, _ = tree.query(q, 7)
    np.testing.assert_array_equal(d2, _brute(pts, q, 7))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_planar_sets_never_split_the_flat_axis(axis: int) -> None:
    rng = np.random.default_rng(21)
    pts = rng.random((50_000, 3)).astype(np.float32)
    pts[:, axis] = 7.0
    tree = KdTree(pts, leaf_size=4)
    inner = np.flatnonzero(tree.layout.child >= 0)
    assert not (tree.layout.dim[inner] == axis).any()
    q = rng.random((50, 3)) * 1.2 - 0.1
    q[:, axis] = 7.0
    np.testing.assert_array_equal(tree.query(q, 9)[0], _brute(pts, q, 9))
    grid = UniformGrid(pts)
    assert grid.n_cells < 4 * len(pts)  # a 2-D grid, not a 3-D one
    np.testing.assert_array_equal(grid.query(q, 9)[0], _brute(pts, q, 9))


def test_points_on_a_line() -> None:
    pts = np.zeros((20_000, 3), np.float32)
    pts[:, 1] = np.linspace(-5.0, 5.0, 20_000, dtype=np.float32)
    q = np.array([[0.0, 0.01, 0.0], [1.0, 6.0, 0.0], [0.0, -5.0, 0.5]])
    for index in (KdTree(pts), MedianKdTree(pts), UniformGrid(pts, photons_per_cell=32)):
        np.testing.assert_array_equal(index.query(q, 11)[0], _brute(pts, q, 11))


def test_far_away_queries_are_finite() -> None:
    rng = np.random.default_rng(22)
    pts = rng.random((5000, 3)).astype(np.float32)
    q = np.array([[1e18, -1e18, 0.0], [0.0, 0.0, 1e15]])  # d² still fits float32
    for index in (KdTree(pts), UniformGrid(pts), UniformGrid(pts, max_cells=16)):
        d2, idx = index.query(q, 4)
        assert (idx >= 0).all() and np.isfinite(d2).all()
        np.testing.assert_array_equal(d2, _brute(pts, q, 4))


@pytest.mark.parametrize("make", [KdTree, MedianKdTree, UniformGrid])
def test_nan_and_inf_positions_are_rejected(make: type) -> None:
    pts = np.random.default_rng(23).random((100, 3)).astype(np.float32)
    index = make(pts)
    bad = pts.copy()
    bad[[3, 7, 9], 1] = np.nan
    bad[50, 2] = np.inf
    with pytest.raises(InputError, match=r"4 of 100 points have NaN or infinite") as err:
        make(bad)
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="4 of 100"):
        index.add(bad)
    assert len(index) == 100  # a rejected batch leaves the map unchanged
    with pytest.raises(InputError, match="overflow float32"):
        make(np.array([[1e39, 0.0, 0.0]]))
    with pytest.raises(InputError, match=r"expected an \(n, 3\) array"):
        make(np.zeros((5, 2)))


def test_photon_map_rejects_nan_for_every_structure() -> None:
    bad = np.zeros((10, 3), np.float32)
    bad[0, 0] = np.nan
    for structure in ("middle", "median", "grid-lo", "grid-hi", "hash"):
        with pytest.raises(InputError, match="1 of 10"):
            PhotonMap(structure).add(bad)


def test_huge_extent_grid_is_hashed_and_exact() -> None:
    pts = np.zeros((1000, 3), np.float32)
    pts[:, 0] = np.linspace(0.0, 1e6, 1000, dtype=np.float32)
    pts[:500, 1] = 1e-3 * np.arange(500, dtype=np.float32)
    grid = UniformGrid(pts, photons_per_cell=1, max_cells=2**8)
    assert grid.hashed
    q = np.array([[5e5, 0.0, 0.0], [0.0, 0.2, 0.0]])
    np.testing.assert_array_equal(grid.query(q, 5)[0], _brute(pts, q, 5))
