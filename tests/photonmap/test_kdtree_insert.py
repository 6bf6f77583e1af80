"""Insertion into a kd-tree leaves the same tree as before the in-slot-order merge.

The digests below are of every array of trees grown by the reference insertion (a
gather through a slot → old slot plan, the batch scattered afterwards and the node
arrays renumbered into new ones): positions, normals, powers, insertion
indices, boxes, children, ranges, depths and the split axes and planes of the inner
nodes (a leaf's axis and plane are never read, nor set). The cases cover a tree with top
levels and one without (a first batch too small for them), normals or none, 1 and 3
power channels, a batch of one photon, coincident stacks, a batch far outside the
tree's box, and the parallel and the serial kernels.
"""

from __future__ import annotations

import hashlib
import itertools

import numpy as np
import pytest

import lightsim.photonmap.kdtree as kd
from lightsim.photonmap import KdTree
from lightsim.validation.bench.photonmap import caustic_ring_set


def _batches(case: str) -> tuple[int, list[tuple[np.ndarray, np.ndarray | None, np.ndarray]]]:
    """(channels, batches) of a case, made here from fixed seeds."""
    pos, nrm, pw = caustic_ring_set(20_000, seed=4)
    if case == "ring-c3":
        pw3 = np.repeat(pw, 3, axis=1) * np.array([1, 2, 3], np.float32)
        cuts = [0, 4000, 4001, 7000, 12000, 12500, 20000]
        return 3, [(pos[a:b], nrm[a:b], pw3[a:b]) for a, b in itertools.pairwise(cuts)]
    if case == "small-first":
        cuts = [0, 5, 6, 900, 901, 6000, 6100, 15000]
        return 1, [(pos[a:b], None, pw[a:b]) for a, b in itertools.pairwise(cuts)]
    # coincident stacks, a batch far outside the box, a single photon
    stack = np.repeat(pos[:40], 30, axis=0)
    far = pos[1000:1400] + np.float32(100.0)
    return 1, [(pos[:3000], nrm[:3000], pw[:3000]), (stack, nrm[:1200], pw[:1200]),
               (far, nrm[:400], pw[:400]), (pos[3000:3001], nrm[:1], pw[:1]),
               (np.repeat(pos[5:6], 200, axis=0), nrm[:200], pw[:200]),
               (pos[4000:16000], nrm[4000:16000], pw[4000:16000])]


def _state(tree: KdTree) -> dict[str, np.ndarray]:
    """Every array that defines the tree (inner nodes' axes and planes only)."""
    lay = tree.layout
    inner = lay.child >= 0
    return {"positions": lay.positions, "normals": lay.normals, "powers": lay.powers,
            "indices": lay.indices, "boxes": lay.box, "children": lay.child,
            "starts": lay.start, "ends": lay.end, "depths": lay.depth,
            "axes": lay.dim[inner], "planes": lay.split[inner],
            "sizes": np.array([len(tree), tree.n_nodes, tree.depth], np.int64)}


def _digests(case: str) -> dict[str, str]:
    """Per array: sha256 (first 16 hex digits) of its dtype, shape and bytes after every
    batch of the case."""
    channels, batches = _batches(case)
    tree = KdTree(channels=channels)
    hashes: dict[str, hashlib._Hash] = {}
    for p, n, w in batches:
        tree.add(p, n, w)
        for name, a in _state(tree).items():
            a = np.ascontiguousarray(a)
            h = hashes.setdefault(name, hashlib.sha256())
            h.update(str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return {name: h.hexdigest()[:16] for name, h in hashes.items()}


# the reference insertion's digests (module docstring), made by _digests
REFERENCE_DIGESTS: dict[str, dict[str, str]] = {
    "ring-c3": {
        "positions": "f7a7f3ab58257bf9",
        "normals": "9f99c5c917eb40b4",
        "powers": "6cc729fd397c43d2",
        "indices": "d9eaacac0f7a99de",
        "boxes": "77842dd5cb745068",
        "children": "c09c6095d817d22d",
        "starts": "fb78ef252aa57a0b",
        "ends": "427f33e8a8bc70d9",
        "depths": "315534af8ae4a2ff",
        "axes": "ff024e87e06de872",
        "planes": "85e3a0b9855203b8",
        "sizes": "ae644ce65dfff8b2",
    },
    "small-first": {
        "positions": "4cb8e7bf529accde",
        "normals": "2f4e149c3d75e42d",
        "powers": "fb82695fbef4c8b8",
        "indices": "aefd72f97fc5adc1",
        "boxes": "f4f1758b995a7fa2",
        "children": "320506965eeac71e",
        "starts": "ee93e2114d834eb3",
        "ends": "241a5ee3542384d0",
        "depths": "24a0ccd470f65b59",
        "axes": "362bd7f9444d6527",
        "planes": "6d7d01fbe4dd1939",
        "sizes": "73d023f4b36bd3c3",
    },
    "stacks": {
        "positions": "9511a9bc5065ddc3",
        "normals": "9c082ed85486a36d",
        "powers": "b86bcb50f72ee1a8",
        "indices": "9de6b96f12152e7e",
        "boxes": "c324067613907c55",
        "children": "e1e80c5326e73fd3",
        "starts": "525be808d7d34fda",
        "ends": "d99f8b074f8a2453",
        "depths": "a65762db936430c4",
        "axes": "6ba99a03e12812ea",
        "planes": "c0497433d5aefc95",
        "sizes": "915bae89387776b2",
    },
}


@pytest.mark.parametrize("serial_below", [0, 10**9])
@pytest.mark.parametrize("case", ["ring-c3", "small-first", "stacks"])
def test_grown_tree_is_bit_identical_to_the_reference(case: str, serial_below: int,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    # 0: every kernel with a serial twin runs its parallel version; 10⁹: the serial one
    monkeypatch.setattr(kd, "SERIAL_BELOW", serial_below)
    got = _digests(case)
    want = REFERENCE_DIGESTS[case]
    assert got.keys() == want.keys()
    assert [k for k in want if got[k] != want[k]] == []


def test_insertions_of_empty_coincident_and_tiny_batches_stay_exact() -> None:
    """Empty batches change nothing; k > N, coincident photons and one-photon batches
    give the exact neighbours (brute force) from a grown tree."""
    rng = np.random.default_rng(7)
    stack = np.zeros((300, 3), np.float32) + np.float32(0.5)
    tree = KdTree()
    tree.add(np.zeros((0, 3), np.float32))
    assert len(tree) == 0
    tree.add(stack[:1])
    tree.add(np.zeros((0, 3), np.float32))
    tree.add(stack[1:])
    for p in rng.random((5, 3)).astype(np.float32):
        tree.add(p[None])
    tree.add(rng.random((2000, 3)).astype(np.float32))
    before = _state(tree)
    tree.add(np.zeros((0, 3), np.float32))
    for name, a in _state(tree).items():
        np.testing.assert_array_equal(a, before[name], err_msg=name)
    pts = np.concatenate([stack, np.zeros((0, 3), np.float32)])
    all_pts = np.empty((len(tree), 3), np.float32)
    all_pts[tree.layout.indices] = tree.layout.positions  # insertion order
    np.testing.assert_array_equal(all_pts[:300], pts)
    q = np.array([[0.5, 0.5, 0.5], [0.1, 0.9, 0.3], [5.0, 5.0, 5.0]])
    k = len(tree) + 10  # k > N: every photon, then +inf / −1
    d2, idx = tree.query(q, k)
    full = ((all_pts.astype(np.float64)[None] - q[:, None]) ** 2).sum(axis=2)
    n = len(tree)
    np.testing.assert_array_equal(d2[:, :n], np.sort(full, axis=1).astype(np.float32))
    assert np.isinf(d2[:, n:]).all()
    for r in range(len(q)):
        assert sorted(idx[r, :n].tolist()) == list(range(n))
