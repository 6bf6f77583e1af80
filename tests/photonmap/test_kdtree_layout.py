"""kd-tree layout: depth-first node order, the one-pass merge of an insertion, and the
rank sort of kNN results (and its quicksort fallback for k > 128).

Exactness is checked against brute force (float64 squared distances from the float32
photons, as the kernels compute them), including exact ties at the k-th distance.
"""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.photonmap import KdTree, MedianKdTree, UniformGrid
from lightsim.photonmap.common import RANK_SORT_MAX
from lightsim.validation.bench.photonmap import caustic_ring_set


def _brute(points: np.ndarray, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    p = points.astype(np.float64)
    d2 = ((p[None, :, :] - queries[:, None, :]) ** 2).sum(axis=2)
    return d2, np.sort(d2, axis=1)[:, :k].astype(np.float32)


def _tied_points() -> np.ndarray:
    """A lattice (many exactly equal distances) plus coincident stacks."""
    g = np.arange(8, dtype=np.float32) * np.float32(0.25)
    lattice = np.stack(np.meshgrid(g, g, g[:3]), axis=-1).reshape(-1, 3)
    stacks = np.repeat(lattice[::17], 40, axis=0)
    return np.concatenate([lattice, stacks])


@pytest.mark.parametrize("k", [RANK_SORT_MAX - 1, RANK_SORT_MAX, RANK_SORT_MAX + 72])
@pytest.mark.parametrize("make", [KdTree, MedianKdTree, UniformGrid])
def test_sorted_results_exact_on_both_sides_of_the_rank_sort_limit(make: type, k: int) -> None:
    points = _tied_points()
    rng = np.random.default_rng(3)
    queries = np.concatenate([points[rng.integers(0, len(points), 20)].astype(np.float64),
                              rng.random((20, 3)) * 2.0 - 0.2])
    d2, idx = make(points).query(queries, k)
    full, expect = _brute(points, queries, k)
    np.testing.assert_array_equal(d2, expect)
    assert (np.diff(d2, axis=1) >= 0).all()
    for q in range(len(queries)):
        assert len(set(idx[q].tolist())) == k
        np.testing.assert_array_equal(full[q, idx[q]].astype(np.float32), d2[q])
        # every photon strictly closer than the k-th is present
        kth = np.sort(full[q])[k - 1]
        assert set(np.flatnonzero(full[q] < kth).tolist()) <= set(idx[q].tolist())


def _depth_first_ids(tree: KdTree) -> np.ndarray:
    """Ids in the order a depth-first walk (pair first, then left, then right) numbers
    them, as a check of the stored numbering."""
    child = tree.layout.child
    order = [0]
    stack = [0]
    while stack:
        nd = stack.pop()
        c = child[nd]
        if c >= 0:
            order.extend([c, c + 1])
            stack.extend([c + 1, c])
    return np.array(order)


@pytest.mark.parametrize("batches", [1, 9])
def test_nodes_are_numbered_depth_first_after_build_and_insertions(batches: int) -> None:
    pos, nrm, pw = caustic_ring_set(30_000, seed=4)
    tree = KdTree(leaf_size=6)
    for part in np.array_split(np.arange(len(pos)), batches):
        tree.add(pos[part], nrm[part], pw[part])
        np.testing.assert_array_equal(_depth_first_ids(tree), np.arange(tree.n_nodes))
    # a walk (left subtree before right) meets the leaves in slot order, each range
    # following the previous one: what the merge of the next insertion relies on
    child = tree.layout.child
    walk, stack = [], [0]
    while stack:
        nd = stack.pop()
        if child[nd] < 0:
            walk.append(nd)
        else:
            stack.extend([child[nd] + 1, child[nd]])
    walk = np.array(walk)
    np.testing.assert_array_equal(tree.layout.end[walk[:-1]], tree.layout.start[walk[1:]])
    assert tree.layout.start[walk[0]] == 0 and tree.layout.end[walk[-1]] == len(tree)


def test_insertion_carries_normals_powers_and_indices_with_their_photons() -> None:
    rng = np.random.default_rng(8)
    pos, nrm, _ = caustic_ring_set(20_000, seed=5)
    pw = rng.random((len(pos), 3)).astype(np.float32)  # distinct per photon and channel
    tree = KdTree(leaf_size=4, channels=3)
    for part in np.array_split(np.arange(len(pos)), 7):
        tree.add(pos[part], nrm[part], pw[part])
    perm = tree.layout.indices
    np.testing.assert_array_equal(tree.layout.positions, pos[perm])
    np.testing.assert_array_equal(tree.layout.powers, pw[perm])
    unit = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    np.testing.assert_allclose(tree.layout.normals, unit[perm], atol=1e-6)
    # density estimates see the same photons as a tree built at once
    q = np.concatenate([pos[:50], pos[-50:]]).astype(np.float64)
    built = KdTree(pos, nrm, pw, leaf_size=4, channels=3)
    np.testing.assert_allclose(tree.estimate(q, k=16).E, built.estimate(q, k=16).E, rtol=1e-12)


def test_insertion_splits_a_leaf_only_past_the_slack_and_then_down_to_leaf_size() -> None:
    rng = np.random.default_rng(11)
    pts = rng.random((9, 3)).astype(np.float32)
    tree = KdTree(pts[:4], leaf_size=4)
    assert tree.n_nodes == 1
    tree.add(pts[4:8])  # 8 = INSERT_SLACK · leaf_size photons: still one leaf
    assert tree.n_nodes == 1 and len(tree) == 8
    tree.add(pts[8:])  # 9 > 8: split until every leaf holds ≤ leaf_size
    child = tree.layout.child
    leaves = np.flatnonzero(child < 0)
    assert tree.n_nodes > 1
    assert (tree.layout.end[leaves] - tree.layout.start[leaves]).max() <= 4
    d2, _ = tree.query(pts.astype(np.float64), 3)
    _, expect = _brute(pts, pts.astype(np.float64), 3)
    np.testing.assert_array_equal(d2, expect)


def test_leaves_split_after_insertions_keep_their_slots_boxes_and_planes() -> None:
    """Full leaves of a grown tree are split in a compact copy and mapped back to their
    slots: the leaves still tile the slots in order, every box is the tight box of its
    photons, every split plane separates its children, and queries stay exact."""
    pos, nrm, _ = caustic_ring_set(30_000, seed=9)
    pw = np.random.default_rng(3).random((len(pos), 2)).astype(np.float32)
    tree = KdTree(leaf_size=5, channels=2)
    for part in np.array_split(np.arange(len(pos)), 9):
        tree.add(pos[part], nrm[part], pw[part])
    m = tree.n_nodes
    child, start, end = tree.layout.child, tree.layout.start, tree.layout.end
    box, dim, split = tree.layout.box, tree.layout.dim, tree.layout.split
    leaves = np.flatnonzero(child < 0)
    order = leaves[np.lexsort((end[leaves], start[leaves]))]
    assert start[order[0]] == 0 and end[order[-1]] == len(pos)
    np.testing.assert_array_equal(start[order[1:]], end[order[:-1]])
    pts = tree.layout.positions
    for nd in range(m):
        s, e = start[nd], end[nd]
        if e > s:
            np.testing.assert_array_equal(box[nd, :3], pts[s:e].min(axis=0))
            np.testing.assert_array_equal(box[nd, 3:], pts[s:e].max(axis=0))
        c = child[nd]
        if c >= 0:
            a = dim[nd]
            assert end[c] == start[c + 1] and start[c] == s and end[c + 1] == e
            assert np.all(pts[start[c]:end[c], a] < split[nd])
            assert np.all(pts[start[c + 1]:end[c + 1], a] >= split[nd])
    np.testing.assert_array_equal(tree.layout.powers, pw[tree.layout.indices])
    q = pos[::301].astype(np.float64)
    d2, _ = tree.query(q, 7)
    _, expect = _brute(pos, q, 7)
    np.testing.assert_array_equal(d2, expect)
