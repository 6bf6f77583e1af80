"""Exactness of the photon-map kNN and fixed-radius queries against brute force.

Every structure must return the same neighbour sets as an exhaustive search (up to ties at
the k-th distance) with identical squared distances, on random, clustered, planar,
coincident and caustic-like photon sets, including k > N, N = 0, radius cut-offs and the
normal filter. Distances are in m (squared: m²).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from lightsim.photonmap import HashGrid, KdTree, MedianKdTree, UniformGrid
from lightsim.photonmap.kdtree import INSERT_SLACK
from lightsim.validation.bench.photonmap import caustic_ring_set, clustered_set

# --------------------------------------------------------------------------- brute force


def brute_d2(points: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Squared distances (Q, N) computed as the kernels do: float64 from float32 photons."""
    p = points.astype(np.float64)
    dx = p[None, :, 0] - queries[:, None, 0]
    dy = p[None, :, 1] - queries[:, None, 1]
    dz = p[None, :, 2] - queries[:, None, 2]
    return dx * dx + dy * dy + dz * dz


def brute_mask(points: np.ndarray, queries: np.ndarray, max_radius: float,
               normals: np.ndarray | None = None, qnormals: np.ndarray | None = None,
               normal_cos: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """(d² (Q, N), mask of counted photons) for the given cut-off and normal filter."""
    d2 = brute_d2(points, queries)
    mask = d2 <= max_radius * max_radius
    if normals is not None and qnormals is not None:
        n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
        qn = qnormals / np.linalg.norm(qnormals, axis=1, keepdims=True)
        mask &= (qn @ n.T.astype(np.float64)) >= normal_cos
    return d2, mask


def assert_knn_exact(d2: np.ndarray, idx: np.ndarray, points: np.ndarray,
                     queries: np.ndarray, k: int, max_radius: float = np.inf,
                     normals: np.ndarray | None = None, qnormals: np.ndarray | None = None,
                     normal_cos: float = 0.5) -> None:
    """Assert (d2, idx) are the exact k nearest counted photons (ties at r_k aside)."""
    bd2, mask = brute_mask(points, queries, max_radius, normals, qnormals, normal_cos)
    assert d2.shape == (len(queries), k) and idx.shape == (len(queries), k)
    assert d2.dtype == np.float32 and idx.dtype == np.int64
    for q in range(len(queries)):
        cand = np.flatnonzero(mask[q])
        vals = bd2[q, cand]
        m = min(k, cand.size)
        part = np.argpartition(vals, m - 1)[:m] if 0 < m < cand.size else np.arange(m)
        order = cand[part[np.argsort(vals[part], kind="stable")]]
        expect = bd2[q, order[:m]].astype(np.float32)
        np.testing.assert_array_equal(d2[q, :m], expect, err_msg=f"query {q}")
        assert np.all(np.isinf(d2[q, m:])) and np.all(idx[q, m:] == -1)
        got = idx[q, :m]
        assert len(set(got.tolist())) == m, "duplicate neighbours"
        np.testing.assert_array_equal(bd2[q, got].astype(np.float32), d2[q, :m])
        assert mask[q, got].all(), "a filtered-out photon was returned"
        if m:
            # all photons strictly closer than the k-th distance must be present
            kth = bd2[q, order[m - 1]]
            closer = set(cand[bd2[q, cand] < kth].tolist())
            assert closer <= set(got.tolist())


# --------------------------------------------------------------------------- data sets


def _random(n: int = 4000, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).random((n, 3)).astype(np.float32)


def _clustered(n: int = 4000) -> np.ndarray:
    return clustered_set(n, n_clusters=30, seed=3)[0]


def _planar(n: int = 4000) -> np.ndarray:
    p = _random(n, 4)
    p[:, 1] = 2.5  # all on the plane y = 2.5 (zero extent in y)
    return p


def _coincident(n: int = 100_000) -> np.ndarray:
    p = np.full((n + 40, 3), 0.25, np.float32)
    p[n:] = _random(40, 5)
    return p


def _caustic(n: int = 20_000) -> np.ndarray:
    return caustic_ring_set(n, seed=6)[0]


SETS: dict[str, Callable[[], np.ndarray]] = {
    "random": _random, "clustered": _clustered, "planar": _planar,
    "coincident": _coincident, "caustic": _caustic,
}

STRUCTURES: dict[str, Callable[..., object]] = {  # (positions, normals=None) -> index
    "middle": lambda p, n=None: KdTree(p, n),
    "middle-leaf1": lambda p, n=None: KdTree(p, n, leaf_size=1),
    "median": lambda p, n=None: MedianKdTree(p, n),
    "grid-lo": lambda p, n=None: UniformGrid(p, n, photons_per_cell=32),
    "grid-hi": lambda p, n=None: UniformGrid(p, n, photons_per_cell=4),
    "grid-hashed": lambda p, n=None: UniformGrid(p, n, photons_per_cell=2, max_cells=1024),
}


def _queries(points: np.ndarray, n: int = 120, seed: int = 7) -> np.ndarray:
    """Random queries over the (slightly enlarged) box, some on photons, some far away."""
    rng = np.random.default_rng(seed)
    lo = points.min(axis=0).astype(np.float64)
    hi = points.max(axis=0).astype(np.float64)
    pad = 0.1 * (hi - lo).max() + 1e-3
    q = lo - pad + (hi - lo + 2 * pad) * rng.random((n, 3))
    q[: n // 4] = points[rng.integers(0, len(points), n // 4)]  # exactly on photons
    q[-3:] = [[50.0, -40.0, 30.0], [-1e4, 0.0, 0.0], [0.0, 1e3, -1e3]]
    return q


@pytest.fixture(scope="module", params=list(SETS))
def photon_set(request: pytest.FixtureRequest) -> tuple[str, np.ndarray, np.ndarray]:
    points = SETS[request.param]()
    return request.param, points, _queries(points)


@pytest.mark.parametrize("structure", list(STRUCTURES))
@pytest.mark.parametrize("k", [1, 16])
def test_knn_matches_brute_force(photon_set: tuple[str, np.ndarray, np.ndarray],
                                 structure: str, k: int) -> None:
    _, points, queries = photon_set
    index = STRUCTURES[structure](points)
    d2, idx = index.query(queries, k)
    assert_knn_exact(d2, idx, points, queries, k)


@pytest.mark.parametrize("structure", list(STRUCTURES))
def test_knn_max_radius_cutoff(structure: str) -> None:
    points = _clustered()
    queries = _queries(points)
    lo, hi = points.min(axis=0), points.max(axis=0)
    radius = 0.03 * float((hi - lo).max())
    d2, idx = STRUCTURES[structure](points).query(queries, 24, max_radius=radius)
    assert_knn_exact(d2, idx, points, queries, 24, max_radius=radius)
    assert (np.isinf(d2[:, -1]) | (d2[:, -1] <= np.float32(radius**2))).all()
    assert np.isinf(d2).any(), "the cut-off should leave some rows short"


@pytest.mark.parametrize("structure", list(STRUCTURES))
def test_k_larger_than_n_returns_all(structure: str) -> None:
    points = _random(30, 8)
    queries = _queries(points, 20)
    d2, idx = STRUCTURES[structure](points).query(queries, 50)
    assert_knn_exact(d2, idx, points, queries, 50)
    assert (idx[:, :30] >= 0).all() and (idx[:, 30:] == -1).all()


@pytest.mark.parametrize("make", [
    lambda: KdTree(), lambda: MedianKdTree(), lambda: UniformGrid(),
    lambda: KdTree(np.zeros((0, 3), np.float32)), lambda: UniformGrid(np.zeros((0, 3))),
])
def test_empty_structures_find_nothing(make: Callable[[], object]) -> None:
    index = make()
    assert len(index) == 0
    q = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    d2, idx = index.query(q, 5)
    assert d2.shape == (2, 5) and np.isinf(d2).all() and (idx == -1).all()
    res = index.query_radius(q, 1.0)
    assert res.offsets.tolist() == [0, 0, 0] and res.indices.size == 0
    est = index.estimate(q, k=4)
    assert (est.E == 0).all() and (est.count == 0).all()


def test_empty_hashgrid_finds_nothing() -> None:
    grid = HashGrid(0.5)
    res = grid.query_radius(np.zeros((3, 3)))
    assert res.offsets.tolist() == [0, 0, 0, 0]
    assert (grid.estimate_radius(np.zeros((3, 3))).E == 0).all()


@pytest.mark.parametrize("structure", list(STRUCTURES))
def test_normal_filter_skips_disagreeing_photons(structure: str) -> None:
    # two coincident sheets: one faces +z, the other −z (a thin wall seen from both sides)
    rng = np.random.default_rng(9)
    sheet = rng.random((3000, 3)).astype(np.float32)
    sheet[:, 2] = 0.0
    points = np.concatenate([sheet, sheet + np.float32([0.0, 0.0, 1e-4])])
    normals = np.zeros_like(points)
    normals[:3000, 2] = 1.0
    normals[3000:, 2] = -1.0
    normals[:, 0] = 0.2 * rng.standard_normal(6000)  # tilt: dot stays far from 0.5
    queries = _queries(points, 60)
    qn = np.tile([0.0, 0.0, 1.0], (len(queries), 1))
    qn[::2, 2] = -1.0
    index = STRUCTURES[structure](points, normals)
    d2, idx = index.query(queries, 12, normals=qn, normal_cos=0.5)
    assert_knn_exact(d2, idx, points, queries, 12, normals=normals, qnormals=qn)
    facing = np.where(qn[:, 2:3] > 0, idx < 3000, idx >= 3000)
    assert facing.all(), "photons of the other side leaked through the wall"


# --------------------------------------------------------------------------- radius queries


RADIUS_STRUCTURES: dict[str, Callable[[np.ndarray, float], object]] = {
    "middle": lambda p, r: KdTree(p),
    "median": lambda p, r: MedianKdTree(p),
    "grid-hi": lambda p, r: UniformGrid(p),
    "grid-hashed": lambda p, r: UniformGrid(p, photons_per_cell=2, max_cells=1024),
    "hash": lambda p, r: HashGrid(r, p),
}


@pytest.mark.parametrize("structure", list(RADIUS_STRUCTURES))
@pytest.mark.parametrize("set_name", ["clustered", "planar", "caustic", "coincident"])
def test_radius_query_matches_brute_force(structure: str, set_name: str) -> None:
    points = SETS[set_name]()
    if set_name == "coincident":
        points = points[-2000:]  # keep the result lists small
    queries = _queries(points, 80)
    lo, hi = points.min(axis=0), points.max(axis=0)
    radius = 0.02 * float((hi - lo).max()) + 1e-4
    res = RADIUS_STRUCTURES[structure](points, radius).query_radius(queries, radius)
    bd2 = brute_d2(points, queries)
    assert res.offsets.shape == (len(queries) + 1,)
    for q in range(len(queries)):
        got = res.indices[res.offsets[q]:res.offsets[q + 1]]
        expect = np.flatnonzero(bd2[q] <= radius * radius)
        np.testing.assert_array_equal(np.sort(got), expect)
        np.testing.assert_array_equal(res.d2[res.offsets[q]:res.offsets[q + 1]],
                                      bd2[q, got].astype(np.float32))


# --------------------------------------------------------------------------- insertion


@pytest.mark.parametrize("set_name", ["clustered", "caustic", "planar"])
def test_incremental_tree_answers_like_one_built_at_once(set_name: str) -> None:
    points = SETS[set_name]()
    queries = _queries(points)
    whole = KdTree(points)
    grown = KdTree()
    for batch in np.array_split(points, 10):
        grown.add(batch)
    assert len(grown) == len(points)
    d_whole, _ = whole.query(queries, 20)
    d_grown, i_grown = grown.query(queries, 20)
    np.testing.assert_array_equal(d_grown, d_whole)
    assert_knn_exact(d_grown, i_grown, points, queries, 20)  # indices in insertion order


def _check_tree_invariants(tree: KdTree, max_leaf: int | None = None) -> None:
    """Slot ranges, boxes, child order and leaf sizes (≤ ``max_leaf``, default the
    leaf size; a tree grown by insertions splits above INSERT_SLACK · leaf_size)."""
    lay = tree.layout
    child, box, start, end = lay.child, lay.box, lay.start, lay.end
    leaves = np.flatnonzero(child < 0)
    # leaf ranges partition the slots
    order = leaves[np.lexsort((end[leaves], start[leaves]))]  # empty leaves first
    assert start[order[0]] == 0 and end[order[-1]] == len(tree)
    np.testing.assert_array_equal(start[order[1:]], end[order[:-1]])
    pts = lay.positions
    for nd in leaves:
        p = pts[start[nd]:end[nd]]
        if len(p):
            assert (p >= box[nd, :3]).all() and (p <= box[nd, 3:]).all()
            too_full = len(p) > (max_leaf or tree.leaf_size)
            assert not too_full or np.ptp(p, axis=0).max() == 0, "overfull leaf"
    inner = np.flatnonzero(child >= 0)
    assert (child[inner] > inner).all()
    for c in (child[inner], child[inner] + 1):
        assert (box[inner, :3] <= box[c, :3]).all() and (box[inner, 3:] >= box[c, 3:]).all()
    assert np.array_equal(np.sort(tree.layout.indices), np.arange(len(tree)))


def test_tree_invariants_after_insertions() -> None:
    points = np.concatenate([_caustic(), _planar(3000) + 1.0, _coincident(5000)])
    tree = KdTree(leaf_size=6)
    for batch in np.array_split(points, 7):
        tree.add(batch)
        _check_tree_invariants(tree, INSERT_SLACK * tree.leaf_size)
    _check_tree_invariants(KdTree(points))
    _check_tree_invariants(MedianKdTree(points))


def test_median_add_rebuilds_and_keeps_indices() -> None:
    points = _clustered()
    queries = _queries(points)
    tree = MedianKdTree(points[:1000])
    tree.add(points[1000:])
    d2, idx = tree.query(queries, 10)
    assert_knn_exact(d2, idx, points, queries, 10)


def test_grid_add_keeps_indices_and_normals() -> None:
    points = _clustered()
    normals = np.tile(np.float32([0.0, 1.0, 0.0]), (len(points), 1))
    queries = _queries(points)
    grid = UniformGrid(points[:1500], normals[:1500])
    grid.add(points[1500:], normals[1500:])
    d2, idx = grid.query(queries, 10, normals=np.tile([0.0, 1.0, 0.0], (len(queries), 1)))
    assert_knn_exact(d2, idx, points, queries, 10)
