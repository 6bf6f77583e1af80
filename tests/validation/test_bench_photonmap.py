"""The photon-map benchmark core (Table 5 rows, insertion study) on tiny photon sets.

Only structure and consistency are checked here (no timing assertions): every method
row is present with positive times, cKDTree's own ratio is 1, the synthetic sets have the
documented shapes, and the JSON output carries the rows.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from lightsim.photonmap import KdTree
from lightsim.validation.bench import photonmap as bench
from lightsim.validation.bench.photonmap import child_peak_rss


def test_synthetic_sets_shapes_and_units() -> None:
    pos, nrm, pw = bench.caustic_ring_set(10_000, flux=1000.0)
    assert pos.shape == (10_000, 3) and pos.dtype == np.float32
    assert np.all(pos[:, 2] == 25.0)  # on the wall plane
    assert np.all(np.hypot(pos[:, 0], pos[:, 1]) <= 1.0 + 1e-6)  # inside the ring
    np.testing.assert_allclose(nrm, np.tile([0, 0, -1], (10_000, 1)))
    assert pw.shape == (10_000, 1)
    assert np.isclose(pw.sum(dtype=np.float64), 1000.0, rtol=1e-5)  # lm in all
    # the caustic concentrates photons: the densest 1 % of a 100 × 100 raster holds far
    # more than 1 % of the photons
    hist, _, _ = np.histogram2d(pos[:, 0], pos[:, 1], bins=100)
    top = np.sort(hist.ravel())[::-1][:100].sum()
    assert top > 0.05 * 10_000
    c_pos, c_nrm, c_pw = bench.clustered_set(5000)
    assert c_pos.shape == (5000, 3) and np.allclose(np.linalg.norm(c_nrm, axis=1), 1.0)
    assert c_pw.shape == (5000, 1)


def test_query_image_spans_the_two_largest_extents() -> None:
    pos, nrm, _ = bench.caustic_ring_set(5000)
    q, qn = bench.query_image(pos, nrm, 8, 6)
    assert q.shape == (48, 3) and qn.shape == (48, 3)
    assert np.all(q[:, 2] == 25.0)
    assert q[:, 0].min() == pos[:, 0].min() and q[:, 0].max() == pos[:, 0].max()
    np.testing.assert_allclose(qn, np.tile([0.0, 0.0, -1.0], (48, 1)))


def test_table5_rows_and_json(tmp_path: Path) -> None:
    sets = {"ring": bench.caustic_ring_set(4000, seed=3),
            "clusters": bench.clustered_set(3000, n_clusters=10, seed=4)}
    out = tmp_path / "pm.json"
    result = bench.run(sets, width=16, height=12, batches=5, repeats=1, threads=1,
                       json_path=out, show=False)
    rows = result["table5"]
    assert [r["method"] for r in rows] == bench.METHODS * 2
    for row in rows:
        assert row["build_ms"] > 0 and row["query_ms"] > 0 and row["estimate_ms"] > 0
        assert row["queries"] == 16 * 12 and row["threads"] == 1
        for key in ("ratio_vs_ckdtree", "build_ratio_vs_ckdtree",
                    "estimate_ratio_vs_ckdtree"):
            assert np.isfinite(row[key]) and row[key] > 0
        if row["method"] == "ckdtree":
            assert row["ratio_vs_ckdtree"] == 1.0
    hash_rows = [r for r in rows if r["method"] == "hash"]
    assert all(r["radius_m"] > 0 for r in hash_rows)
    incr = result["insert_vs_rebuild"]
    assert incr["set"] == "ring" and incr["batches"] == 5
    assert incr["insert_ms"] > 0 and incr["rebuild_ms"] > 0
    doc = json.loads(out.read_text())
    assert doc["benchmark"] == "photonmap" and len(doc["rows"]) == len(rows) + 1


def test_knn_rate_rows() -> None:
    rows = bench.knn_rate({"ring": bench.caustic_ring_set(3000)}, k=8, width=10, height=10,
                          repeats=1, threads=1)
    assert [r["method"] for r in rows] == ["middle", "ckdtree"]
    assert all(r["queries_per_s"] > 0 for r in rows)


def test_goal_rows_and_memory_rows_on_a_tiny_set() -> None:
    rows = bench.goal_rows(20_000, k=8, width=16, height=12, batches=5, repeats=1,
                           threads=1)
    assert [r["goal"] for r in rows] == ["≥ 1.5", "≤ 0.25"]
    for r in rows:
        assert r["ours_ms"] > 0 and r["baseline_ms"] > 0 and r["ratio"] > 0
    pos, nrm, pw = bench.caustic_ring_set(20_000)
    mem = bench.stored_bytes(pos, nrm, pw, batches=5)
    assert len(mem) == 2
    for r in mem:  # the pre-flight model bounds what the trees really hold
        assert 40 < r["bytes_per_photon"] <= r["model_bytes_per_photon"]


def test_incremental_tree_keeps_tight_leaf_boxes_and_exact_knn() -> None:
    """Insertion grows leaf boxes by the new photons only: the tree must be the one a
    rescan gives (same nodes, exact same kNN answers)."""
    pos, nrm, pw = bench.caustic_ring_set(30_000, seed=4)
    tree = KdTree(pos[:3000], nrm[:3000], pw[:3000])
    for a in range(3000, 30_000, 3000):
        tree.add(pos[a:a + 3000], nrm[a:a + 3000], pw[a:a + 3000])
    box = tree.layout.box
    leaf = tree.layout.child < 0
    for nd in np.flatnonzero(leaf & (tree.layout.end > tree.layout.start)):
        p = tree.layout.positions[tree.layout.start[nd]:tree.layout.end[nd]]
        np.testing.assert_array_equal(box[nd, :3], p.min(axis=0))  # tight, not just bounding
        np.testing.assert_array_equal(box[nd, 3:], p.max(axis=0))
    q = pos[::97].astype(np.float64)
    d2, _ = tree.query(q, 16)
    dk, _ = cKDTree(pos).query(q, 16)
    np.testing.assert_allclose(np.sqrt(d2), dk, rtol=1e-6, atol=1e-7)


def test_child_peak_rss_is_the_childs_not_the_parents():
    """A parent holding a large allocation: the peak RSS of a small child it starts is the
    child's own (Linux hands a forked child its parent's high-water mark)."""
    big = np.ones(600 * 2**20 // 8)  # 600 MiB, touched
    kib, code, _ = child_peak_rss([sys.executable, "-c", "import numpy as np; "
                                   "a = np.ones(200 * 2**20 // 8)"])
    assert code == 0 and big[-1] == 1.0
    assert 200 * 1024 <= kib < 450 * 1024  # its 200 MiB array and an interpreter
    kib, code, _ = child_peak_rss([sys.executable, "-c", "import sys; sys.exit(3)"])
    assert code == 3 and kib < 100 * 1024
