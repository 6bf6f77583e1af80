"""Photon-map benchmark: the paper's Table 5 (build/query per structure) and Table 1 (kNN/s).

Günther, Wald & Slusallek (2004), Table 5 times the build of each acceleration structure
and the query of a complete 640×480 image with k = 64 for two photon-map sizes per scene.
This module measures the same rows on named photon sets, next to scipy's ``cKDTree``
measured in the same run with the same number of threads (``workers=`` for cKDTree,
``numba.set_num_threads`` for ours), plus the section 5.4 claim that accumulating photons
by insertion is far cheaper than rebuilding after every batch.

Query image: a ``width × height`` grid over the set's bounding box in the plane of its
two largest extents (at the middle of the third), with the set's dominant normal as query
normal. Times are the best of ``repeats`` runs (``time.perf_counter``) after a warm-up
that compiles every numba kernel.

Row fields (one dict per set × method)
--------------------------------------
==============================  ====  =====================================================
field                           unit  meaning
==============================  ====  =====================================================
``set``, ``method``             —     photon set name; structure (``ckdtree`` = baseline)
``photons``, ``queries``, ``k``  —     sizes of the run
``build_ms``                    ms    build (``middle-incr``: sum of 25 insertions)
``query_ms``                    ms    kNN of all queries returning (d², index) arrays —
                                      the work ``cKDTree.query`` does; ``hash``: the
                                      fixed-radius neighbour lists
``estimate_ms``                 ms    the whole density image (ours: fused kernel;
                                      cKDTree: query + numpy sum; ``hash``: fixed radius)
``queries_per_s``               1/s   queries / query time (Table 1)
``ratio_vs_ckdtree``            —     cKDTree query_ms / this query_ms (> 1: faster)
``build_ratio_vs_ckdtree``      —     cKDTree build_ms / this build_ms (> 1: faster)
``estimate_ratio_vs_ckdtree``   —     cKDTree estimate_ms / this estimate_ms
``radius_m``                    m     ``hash`` only: the fixed radius (median r_64)
==============================  ====  =====================================================
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numba
import numpy as np
from scipy.spatial import cKDTree

from lightsim.engine.config import RunConfig
from lightsim.engine.memory import bytes_per_photon, estimate_run, index_bytes
from lightsim.photonmap import (
    GRID_PRESETS,
    HashGrid,
    KdTree,
    MedianKdTree,
    UniformGrid,
)
from lightsim.photonmap.kdtree import DEFAULT_LEAF_SIZE
from lightsim.raycast import RayCaster
from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.tracer import PhotonTracer
from lightsim.validation.bench.table import print_table, write_json

PhotonSet = tuple[np.ndarray, np.ndarray, np.ndarray]  # positions (m), normals, powers (lm)

#: rows of Table 5, in order (``middle-incr``: built by inserting 25 batches)
METHODS = ["median", "middle", "middle-incr", "grid-lo", "grid-hi", "hash", "ckdtree"]

TABLE5_COLUMNS = ["set", "photons", "method", "build_ms", "query_ms", "estimate_ms",
                  "queries_per_s", "build_ratio_vs_ckdtree", "ratio_vs_ckdtree",
                  "estimate_ratio_vs_ckdtree"]


# =========================================================================== synthetic sets
def caustic_ring_set(n: int, *, radius: float = 1.0, background: float = 0.2,
                     wall_z: float = 25.0, flux: float = 1000.0, seed: int = 0) -> PhotonSet:
    """Photons of a ring (coffee-cup) caustic on the plane z = ``wall_z`` (m).

    Parallel light along +x is reflected once by the inside of a cylinder of ``radius``
    (m); photons land uniformly along each reflected ray inside the disc, whose envelope
    is the nephroid caustic with its sharp cusp at (radius/2, 0). A fraction
    ``background`` of the photons is spread uniformly over the disc (diffuse light).
    Normals face the lamp (−z); every photon carries ``flux / n`` lm.
    """
    rng = np.random.default_rng(seed)
    n_bg = round(background * n)
    n_c = n - n_bg
    y = radius * (2.0 * rng.random(n_c) - 1.0)
    hit = np.stack([np.sqrt(radius**2 - y**2), y], axis=1)
    inward = -hit / radius
    d_in = np.array([1.0, 0.0])
    refl = d_in - 2.0 * (inward @ d_in)[:, None] * inward
    chord = -2.0 * np.einsum("ij,ij->i", hit, refl)  # distance to the far wall of the ring
    caustic = hit + (chord * rng.random(n_c))[:, None] * refl
    rho = radius * np.sqrt(rng.random(n_bg))
    phi = 2.0 * np.pi * rng.random(n_bg)
    diffuse = np.stack([rho * np.cos(phi), rho * np.sin(phi)], axis=1)
    xy = np.concatenate([caustic, diffuse])[rng.permutation(n)]
    pos = np.empty((n, 3), np.float32)
    pos[:, :2] = xy
    pos[:, 2] = wall_z
    nrm = np.zeros((n, 3), np.float32)
    nrm[:, 2] = -1.0
    return pos, nrm, np.full((n, 1), flux / max(n, 1), np.float32)


def clustered_set(n: int, *, n_clusters: int = 200, extent: float = 4.0, flux: float = 1000.0,
                  seed: int = 0) -> PhotonSet:
    """Photons in 3-D Gaussian clusters whose sizes span three decades (m).

    Cluster centres are uniform in a cube of edge ``extent``; cluster standard deviations
    are log-uniform in [1e-3, 1]·extent/10; cluster weights are Zipf-like, so dense and
    sparse regions meet. Normals scatter around +y (a bumpy floor); Φ = ``flux / n`` lm.
    """
    rng = np.random.default_rng(seed)
    centres = rng.random((n_clusters, 3)) * extent
    sigma = extent / 10.0 * 10.0 ** rng.uniform(-3.0, 0.0, n_clusters)
    weight = 1.0 / np.arange(1, n_clusters + 1)
    which = rng.choice(n_clusters, size=n, p=weight / weight.sum())
    pos = (centres[which] + rng.standard_normal((n, 3)) * sigma[which, None]).astype(np.float32)
    nrm = np.array([0.0, 1.0, 0.0]) + 0.3 * rng.standard_normal((n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return pos, nrm.astype(np.float32), np.full((n, 1), flux / max(n, 1), np.float32)


def synthetic_sets(n_large: int = 1_000_000, n_small: int = 100_000,
                   seed: int = 0) -> dict[str, PhotonSet]:
    """The default benchmark sets: a large and a small ring caustic, a clustered 3-D set."""
    return {
        f"ring-{_count_name(n_large)}": caustic_ring_set(n_large, seed=seed),
        f"ring-{_count_name(n_small)}": caustic_ring_set(n_small, seed=seed + 1),
        f"clusters-{_count_name(n_small)}": clustered_set(n_small, seed=seed + 2),
    }


def _count_name(n: int) -> str:
    if n >= 1_000_000 and n % 1_000_000 == 0:
        return f"{n // 1_000_000}M"
    if n >= 1000 and n % 1000 == 0:
        return f"{n // 1000}k"
    return str(n)


def query_image(positions: np.ndarray, normals: np.ndarray | None, width: int = 640,
                height: int = 480) -> tuple[np.ndarray, np.ndarray]:
    """Query points (width·height, 3) over the photons' bounding box, and their normals.

    The grid spans the two largest extents of the box (row-major, row 0 at the low end),
    at the middle of the third; the query normal is the photons' mean normal (or the
    third axis when the normals cancel out).
    """
    lo = positions.min(axis=0).astype(np.float64)
    hi = positions.max(axis=0).astype(np.float64)
    a_u, a_v, a_w = np.argsort(hi - lo)[::-1]
    u = np.linspace(lo[a_u], hi[a_u], width)
    v = np.linspace(lo[a_v], hi[a_v], height)
    uu, vv = np.meshgrid(u, v)
    pts = np.empty((width * height, 3))
    pts[:, a_u] = uu.ravel()
    pts[:, a_v] = vv.ravel()
    pts[:, a_w] = 0.5 * (lo[a_w] + hi[a_w])
    normal = np.zeros(3)
    if normals is not None and len(normals):
        normal = normals.astype(np.float64).mean(axis=0)
    if np.linalg.norm(normal) < 1e-3:
        normal = np.zeros(3)
        normal[a_w] = 1.0
    normal /= np.linalg.norm(normal)
    return pts, np.tile(normal, (width * height, 1))


# ====================================================================== timing functions
def _best(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    """Best wall time (s) of ``repeats`` calls and the last result."""
    best = np.inf
    result = None
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def warm_up() -> None:
    """Compile every numba kernel the benchmark uses (on a tiny set)."""
    pos, nrm, pw = caustic_ring_set(2000, seed=99)
    q, qn = query_image(pos, nrm, 8, 6)
    for tree in (KdTree(pos[:1000], nrm[:1000], pw[:1000]),
                 MedianKdTree(pos, nrm, pw)):
        tree.add(pos[1000:], nrm[1000:], pw[1000:])
        tree.query(q, 8)
        tree.estimate(q, qn, k=8)
        tree.query_radius(q, 0.1)
    for grid in (UniformGrid(pos, nrm, pw), UniformGrid(pos, nrm, pw, max_cells=16),
                 HashGrid(0.1, pos, nrm, pw)):
        grid.query(q, 8)
        grid.estimate(q, qn, k=8)
        grid.query_radius(q, 0.1)
        grid.estimate_radius(q, qn, radius=0.1)


def _ckdtree_estimate(tree: cKDTree, powers: np.ndarray, q: np.ndarray, k: int,
                      workers: int) -> np.ndarray:
    """Box-kernel density image from cKDTree neighbours (numpy), for the baseline row."""
    d, i = tree.query(q, k, workers=workers)
    kk = min(k, powers.shape[0])
    d = d.reshape(len(q), -1)[:, :kk]
    i = i.reshape(len(q), -1)[:, :kk]
    r2 = np.maximum(d[:, -1], 1e-12) ** 2
    return powers[i, 0].sum(axis=1) / (np.pi * r2)


# =========================================================================== measurements
def insert_vs_rebuild(positions: np.ndarray, normals: np.ndarray | None, powers: np.ndarray,
                      *, batches: int = 25, leaf_size: int = DEFAULT_LEAF_SIZE,
                      repeats: int = 3) -> dict[str, Any]:
    """Cost of accumulating ``batches`` batches by insertion vs rebuilding after each.

    Returns ``insert_ms`` (sum of the insertions into one growing tree), ``rebuild_ms``
    (sum of building a new tree from all photons so far after every batch; each the best
    of ``repeats``, the two alternated) and
    ``insert_over_rebuild`` = insert_ms / rebuild_ms (section 5.4: should be small).
    """
    cuts = np.linspace(0, positions.shape[0], batches + 1).astype(np.int64)

    def nrm(a: int, b: int) -> np.ndarray | None:
        return None if normals is None else normals[a:b]

    def insert() -> KdTree:
        tree = KdTree(leaf_size=leaf_size, channels=powers.shape[1])
        for a, b in itertools.pairwise(cuts):
            tree.add(positions[a:b], nrm(a, b), powers[a:b])
        return tree

    def rebuild() -> None:
        for b in cuts[1:]:
            KdTree(positions[:b], nrm(0, b), powers[:b], leaf_size=leaf_size,
                   channels=powers.shape[1])

    # A/B alternated (as the kNN ratio of goal_rows): a load change on this shared
    # machine then hits both sides instead of only the one timed during it
    t_insert = t_rebuild = np.inf
    for _ in range(max(1, repeats)):
        t_insert = min(t_insert, _best(insert, 1)[0])
        t_rebuild = min(t_rebuild, _best(rebuild, 1)[0])
    return {"photons": int(positions.shape[0]), "batches": batches,
            "insert_ms": 1e3 * t_insert, "rebuild_ms": 1e3 * t_rebuild,
            "insert_over_rebuild": t_insert / t_rebuild}


def _table5_set(name: str, photon_set: PhotonSet, *, k: int, width: int, height: int,
                batches: int, repeats: int, threads: int, leaf_size: int,
                methods: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Rows of one photon set, keyed by method (see :func:`table5`)."""
    pos, nrm, pw = photon_set
    q, qn = query_image(pos, nrm, width, height)
    n = int(pos.shape[0])
    channels = pw.shape[1]
    rows: dict[str, dict[str, Any]] = {}

    def record(method: str, build_s: float, query_s: float, estimate_s: float,
               **extra: Any) -> None:
        rows[method] = {"set": name, "photons": n, "queries": len(q), "k": k,
                        "threads": threads, "method": method, "build_ms": 1e3 * build_s,
                        "query_ms": 1e3 * query_s, "estimate_ms": 1e3 * estimate_s,
                        "queries_per_s": len(q) / query_s, **extra}

    def run_index(method: str, build: Callable[[], Any]) -> Any:
        t_build, index = _best(build, repeats)
        t_query, _ = _best(lambda: index.query(q, k), repeats)
        t_est, _ = _best(lambda: index.estimate(q, qn, k=k), repeats)
        record(method, t_build, t_query, t_est)
        return index

    def incremental() -> KdTree:
        tree = KdTree(leaf_size=leaf_size, channels=channels)
        for a, b in itertools.pairwise(np.linspace(0, n, batches + 1).astype(np.int64)):
            tree.add(pos[a:b], nrm[a:b], pw[a:b])
        return tree

    if "median" in methods:
        run_index("median", lambda: MedianKdTree(pos, nrm, pw, leaf_size=leaf_size,
                                                 channels=channels))
    middle = None
    if "middle" in methods or "hash" in methods:
        middle = run_index("middle", lambda: KdTree(pos, nrm, pw, leaf_size=leaf_size,
                                                    channels=channels))
    if "middle-incr" in methods:
        run_index("middle-incr", incremental)
    for preset in ("lo", "hi"):
        if f"grid-{preset}" in methods:
            grid = run_index(f"grid-{preset}", lambda p=preset: UniformGrid(
                pos, nrm, pw, photons_per_cell=GRID_PRESETS[p], channels=channels))
            rows[f"grid-{preset}"]["cell_size_m"] = grid.cell_size
            rows[f"grid-{preset}"]["hashed"] = grid.hashed
    if "hash" in methods and middle is not None:
        d2, _ = middle.query(q, k)
        rk = np.sqrt(d2[:, -1][np.isfinite(d2[:, -1])])
        radius = float(np.median(rk)) if rk.size else 1.0
        t_build, hgrid = _best(lambda: HashGrid(radius, pos, nrm, pw, channels=channels),
                               repeats)
        t_query, _ = _best(lambda: hgrid.query_radius(q), repeats)
        t_est, _ = _best(lambda: hgrid.estimate_radius(q, qn), repeats)
        record("hash", t_build, t_query, t_est, radius_m=radius)
    if "middle" not in methods:
        rows.pop("middle", None)
    if "ckdtree" in methods:
        t_build, ck = _best(lambda: cKDTree(pos), repeats)
        t_query, _ = _best(lambda: ck.query(q, k, workers=threads), repeats)
        t_est, _ = _best(lambda: _ckdtree_estimate(ck, pw, q, k, threads), repeats)
        record("ckdtree", t_build, t_query, t_est)
        base = rows["ckdtree"]
        for row in rows.values():
            row["build_ratio_vs_ckdtree"] = base["build_ms"] / row["build_ms"]
            row["ratio_vs_ckdtree"] = base["query_ms"] / row["query_ms"]
            row["estimate_ratio_vs_ckdtree"] = base["estimate_ms"] / row["estimate_ms"]
    return rows


def table5(sets: Mapping[str, PhotonSet], *, k: int = 64, width: int = 640, height: int = 480,
           batches: int = 25, repeats: int = 3, threads: int | None = None,
           leaf_size: int = DEFAULT_LEAF_SIZE, methods: Sequence[str] | None = None,
           ) -> list[dict[str, Any]]:
    """Build and query times per structure and photon set (Table 5), with cKDTree rows.

    Parameters
    ----------
    sets : mapping of name → (positions (n, 3) m, normals (n, 3), powers (n, C) lm)
        Photon sets to measure.
    k : int
        Neighbours per query (paper: 64).
    width, height : int
        Query image size (paper: 640 × 480).
    batches : int
        Batches of the incrementally built ``middle-incr`` row.
    repeats : int
        Each time is the best of this many runs.
    threads : int, optional
        Threads for numba and cKDTree (default: numba's configured count).
    leaf_size : int
        kd-tree leaf size.
    methods : sequence of str, optional
        Subset of :data:`METHODS` (default: all).

    Returns
    -------
    list of dict
        One row per (set, method) in :data:`METHODS` order; fields in the module docstring.
    """
    threads = int(threads or numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(threads)
    methods = list(methods or METHODS)
    warm_up()
    rows: list[dict[str, Any]] = []
    for name, photon_set in sets.items():
        set_rows = _table5_set(name, photon_set, k=k, width=width, height=height,
                               batches=batches, repeats=repeats, threads=threads,
                               leaf_size=leaf_size, methods=methods)
        rows.extend(set_rows[m] for m in METHODS if m in set_rows)
    return rows


def knn_rate(sets: Mapping[str, PhotonSet], *, k: int = 64, width: int = 640,
             height: int = 480, repeats: int = 3, threads: int | None = None,
             ) -> list[dict[str, Any]]:
    """kNN queries per second of the middle-split tree and cKDTree (Table 1's left half)."""
    return [{"set": r["set"], "photons": r["photons"], "k": r["k"], "method": r["method"],
             "queries_per_s": r["queries_per_s"], "ratio_vs_ckdtree": r["ratio_vs_ckdtree"]}
            for r in table5(sets, k=k, width=width, height=height, repeats=repeats,
                            threads=threads, methods=["middle", "ckdtree"])]


def run(sets: Mapping[str, PhotonSet] | None = None, *, k: int = 64, width: int = 640,
        height: int = 480, batches: int = 25, repeats: int = 3, threads: int | None = None,
        json_path: str | os.PathLike | None = None, show: bool = True,
        ) -> dict[str, Any]:
    """Run Table 5 and the insertion study, print them, optionally write JSON.

    ``sets`` defaults to :func:`synthetic_sets`; the insertion study uses the largest set.
    Returns ``{"table5": rows, "insert_vs_rebuild": row}``.
    """
    sets = dict(sets) if sets is not None else synthetic_sets()
    rows = table5(sets, k=k, width=width, height=height, batches=batches, repeats=repeats,
                  threads=threads)
    largest = max(sets, key=lambda s: sets[s][0].shape[0])
    pos, nrm, pw = sets[largest]
    incr = {"set": largest, **insert_vs_rebuild(pos, nrm, pw, batches=batches,
                                                 repeats=repeats)}
    if show:
        print_table(f"Photon maps (Table 5): {width}×{height} queries, k = {k}, "
                    f"{rows[0]['threads'] if rows else threads} threads", rows, TABLE5_COLUMNS)
        print_table("Accumulation (section 5.4): insert vs rebuild after every batch",
                    [incr])
    if json_path is not None:
        write_json(json_path, "photonmap", rows + [{"method": "insert-vs-rebuild", **incr}],
                   meta={"k": k, "width": width, "height": height, "batches": batches,
                         "repeats": repeats})
    return {"table5": rows, "insert_vs_rebuild": incr}


# =========================================================================== photons of a scene
def traced_wall_photons(scene: Any, n_photons: int, seed: int = 11) -> PhotonSet:
    """(positions in m, normals, powers in lm) of the photons a scene puts on its wall,
    from ``n_photons`` emitted (Halton points, 500 000 at a time)."""
    tracer = PhotonTracer(scene, record="wall")
    pos, nrm, pw = [], [], []
    for lo in range(0, n_photons, 500_000):
        idx = np.arange(lo, min(n_photons, lo + 500_000), dtype=np.int64)
        res = tracer.trace_points(halton_points(idx, digit_permutations(seed, 0, None)),
                                  photon_keys(seed, 0, 0, idx))
        pos.append(res.records.position)
        nrm.append(res.records.normal)
        pw.append(res.records.power[:, :1] / n_photons)
    tracer.caster.close()
    return np.concatenate(pos), np.concatenate(nrm), np.concatenate(pw).astype(np.float32)


def embree_rate(scene: Any, rays: int = 1_000_000, seed: int = 5) -> float:
    """Raw embree rays/s (best of 3) of random rays from inside the luminaire's bounding
    box."""
    lamp = np.concatenate([p.vertices for p in scene.parts if p.role != "wall"])
    lo, hi = lamp.min(axis=0), lamp.max(axis=0)
    rng = np.random.default_rng(seed)
    o = (lo + (hi - lo) * rng.random((rays, 3))).astype(np.float32)
    d = rng.normal(size=(rays, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    caster = RayCaster(scene.triangles)
    caster.intersect(o[:1000], d[:1000])
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        caster.intersect(o, d)
        best = min(best, time.perf_counter() - t0)
    caster.close()
    return rays / best


def table1(scenes: Mapping[str, Any], table5_rows: Sequence[dict[str, Any]]
           ) -> list[dict[str, Any]]:
    """Paper Table 1: the kNN queries/s of the ``middle`` and ``ckdtree`` rows of
    :func:`table5` (sets named ``<scene>-…``) next to raw embree rays/s in the same scene
    (:func:`embree_rate`)."""
    rows = []
    for name, scene in scenes.items():
        rays = embree_rate(scene)
        for r in table5_rows:
            if r["set"].startswith(name) and r["method"] in ("middle", "ckdtree"):
                rows.append({"scene": name, "set": r["set"], "photons": r["photons"],
                             "k": r["k"], "method": r["method"],
                             "knn_queries_per_s": r["queries_per_s"],
                             "embree_rays_per_s": rays,
                             "rays_per_knn_query": rays / r["queries_per_s"]})
    return rows


# =========================================================================== memory
MEMORY_COLUMNS = ["what", "photons", "bytes_per_photon", "model_bytes_per_photon",
                  "peak_rss_mb", "estimate_mb", "estimate_over_rss", "seconds"]


def stored_bytes(positions: np.ndarray, normals: np.ndarray | None, powers: np.ndarray,
                 batches: int = 25) -> list[dict[str, Any]]:
    """Bytes per stored photon of real kd-trees (their arrays' ``nbytes``), built at once
    and by ``batches`` insertions, next to :func:`lightsim.engine.memory.bytes_per_photon`."""
    n = int(positions.shape[0])
    cuts = np.linspace(0, n, batches + 1).astype(np.int64)
    built = KdTree(positions, normals, powers, channels=powers.shape[1])
    incr = KdTree(channels=powers.shape[1])
    for a, b in itertools.pairwise(cuts):
        incr.add(positions[a:b], None if normals is None else normals[a:b], powers[a:b])
    model = bytes_per_photon(powers.shape[1], normals is not None)
    return [{"what": f"kd-tree {label}", "photons": n,
             "bytes_per_photon": index_bytes(tree) / max(n, 1),
             "model_bytes_per_photon": model}
            for label, tree in (("built", built), (f"{batches} insertions", incr))]


#: runs argv[1:] with stdout discarded and prints its peak RSS (KiB, wait4's rusage);
#: exits with its exit code
_SPAWN_MAXRSS = (
    "import os, subprocess, sys\n"
    "p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL)\n"
    "_, status, usage = os.wait4(p.pid, 0)\n"
    "print(usage.ru_maxrss, flush=True)\n"
    "sys.exit(os.waitstatus_to_exitcode(status))\n")


def child_peak_rss(cmd: Sequence[str]) -> tuple[float, int, str]:
    """(peak RSS in KiB, exit code, stderr) of command ``cmd`` (stdout discarded).

    Run through a small spawner: Linux hands a child the high-water RSS of the memory it
    was forked (or vfork-ed) from, so a ``simulate`` started by this bench — which holds
    gigabytes of trees by then — reported the bench's own peak (10 GB for a run whose
    peak was 1.3 GB); the spawner's child starts from the spawner's few MB."""
    proc = subprocess.run([sys.executable, "-c", _SPAWN_MAXRSS, *cmd], capture_output=True,
                          check=False)
    out = proc.stdout.decode().split()
    return (float(out[-1]) if out else float("nan"), proc.returncode,
            proc.stderr.decode(errors="replace"))


def simulate_peak_rss(scene_path: str | os.PathLike, photons: int,
                      resolution: tuple[int, int] = (640, 256), frame_photons: int = 1_000_000,
                      extra_args: Sequence[str] = ()) -> dict[str, Any]:
    """Peak RSS (``wait4`` rusage of the child) of ``lightsim simulate SCENE --photons N``
    next to the pre-flight estimate of the same run."""
    W, H = resolution
    with tempfile.TemporaryDirectory(prefix="lightsim-rss-") as tmp:
        cmd = [sys.executable, "-m", "lightsim.cli", "simulate", str(scene_path),
               "--photons", str(int(photons)), "--resolution", f"{W}x{H}", "--quiet",
               "--frame-photons", str(int(frame_photons)), "--out", tmp, *extra_args]
        t0 = time.perf_counter()
        maxrss_kib, returncode, err = child_peak_rss(cmd)
        dt = time.perf_counter() - t0
        summary = {}
        if returncode == 0:
            with open(os.path.join(tmp, "summary.json")) as fh:
                summary = json.load(fh)
    cfg = RunConfig()
    est = estimate_run(int(photons), resolution, channels=3, n_sets=cfg.n_sets,
                       frame_photons=frame_photons)
    rss = maxrss_kib * 1024.0  # Linux: KiB
    kept = summary.get("energy_lm", {})
    return {"what": f"simulate {os.path.basename(str(scene_path))} {W}x{H}",
            "photons": int(photons), "peak_rss_mb": rss / 2**20,
            "estimate_mb": est.total / 2**20, "estimate_over_rss": est.total / rss,
            "seconds": dt, "exit_code": returncode,
            "wall_lm": kept.get("wall"), "note": err.strip().splitlines()[-1][:160]
            if returncode else ""}


def memory_rows(rss_photons: int, scene_path: str | os.PathLike) -> list[dict[str, Any]]:
    """Bytes per stored photon (1 M ring-caustic photons, :func:`stored_bytes`) and, unless
    ``rss_photons`` is 0, the peak RSS of a ``simulate`` run of ``scene_path``
    (:func:`simulate_peak_rss`); columns :data:`MEMORY_COLUMNS`."""
    pos, nrm, pw = caustic_ring_set(1_000_000)
    rows = stored_bytes(pos, nrm, pw)
    if rss_photons:
        rows.append(simulate_peak_rss(scene_path, rss_photons))
    return rows


# =========================================================================== headline ratios
GOAL_COLUMNS = ["what", "photons", "k", "ours_ms", "baseline_ms", "ratio", "goal"]


def goal_rows(n: int = 1_000_000, *, k: int = 64, width: int = 640, height: int = 480,
              batches: int = 25, repeats: int = 3, threads: int | None = None,
              leaf_size: int = DEFAULT_LEAF_SIZE, seed: int = 0) -> list[dict[str, Any]]:
    """The two headline photon-map ratios on the ``n``-photon ring caustic, each
    measured against its baseline in the same run (best of ``repeats``, A/B alternated so
    that a load change hits both): kNN queries of the middle-split tree vs
    ``cKDTree.query`` (goal ≥ 1.5×) and 25 insertions vs rebuilding after every batch
    (goal ≤ 0.25)."""
    threads = int(threads or numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(threads)
    warm_up()
    pos, nrm, pw = caustic_ring_set(n, seed=seed)
    q, _ = query_image(pos, nrm, width, height)
    tree = KdTree(pos, nrm, pw, leaf_size=leaf_size)
    ck = cKDTree(pos)
    t_ours, t_ck = np.inf, np.inf
    for _ in range(max(1, repeats)):
        t_ours = min(t_ours, _best(lambda: tree.query(q, k), 1)[0])
        t_ck = min(t_ck, _best(lambda: ck.query(q, k, workers=threads), 1)[0])
    incr = insert_vs_rebuild(pos, nrm, pw, batches=batches, leaf_size=leaf_size,
                             repeats=repeats)
    return [{"what": f"kNN query {width}×{height} (middle vs cKDTree, {threads} threads)",
             "photons": n, "k": k, "ours_ms": 1e3 * t_ours, "baseline_ms": 1e3 * t_ck,
             "ratio": t_ck / t_ours, "goal": "≥ 1.5"},
            {"what": f"{batches} insertions vs rebuild after every batch", "photons": n,
             "k": k, "ours_ms": incr["insert_ms"], "baseline_ms": incr["rebuild_ms"],
             "ratio": incr["insert_over_rebuild"], "goal": "≤ 0.25"}]
