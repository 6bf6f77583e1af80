"""``lightsim bench photonmap``: paper Tables 5 and 1 on photons traced in our scenes."""

from __future__ import annotations

import click

from lightsim.cli.bench_tracer import example_headlight
from lightsim.errors import InputError
from lightsim.validation.bench.table import print_table, write_json


def traced_wall_photons(scene, n_photons: int, seed: int = 11):
    """(positions, normals, powers in lm) of the photons a scene puts on its wall."""
    import numpy as np

    from lightsim.sampling import digit_permutations, halton_points, photon_keys
    from lightsim.tracer import PhotonTracer

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


def embree_rate(scene, rays: int = 1_000_000, seed: int = 5) -> float:
    """Raw embree rays/s of random rays from inside the luminaire's bounding box."""
    import time

    import numpy as np

    from lightsim.raycast import RayCaster

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


@click.command("photonmap")
@click.option("--moderate", type=int, default=200_000, show_default=True,
              help="Photons emitted for the moderate photon maps.")
@click.option("--large", type=int, default=2_000_000, show_default=True,
              help="Photons emitted for the large photon maps.")
@click.option("--k", "k", type=int, default=64, show_default=True)
@click.option("--repeats", type=int, default=3, show_default=True)
@click.option("--synthetic", is_flag=True, help="Use the synthetic caustic sets instead.")
@click.option("--goals", is_flag=True,
              help="Only the issue-15 ratios (1 M-photon kNN vs cKDTree, insertion vs "
                   "rebuild) and the memory table.")
@click.option("--rss-photons", type=int, default=16_000_000, show_default=True,
              help="Photons of the `simulate` run whose peak RSS the memory table shows "
                   "(0: skip that run).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(moderate: int, large: int, k: int, repeats: int, synthetic: bool, goals: bool,
            rss_photons: int, json_path: str | None) -> None:
    """Build/query ms per structure vs cKDTree (Table 5) and kNN/s vs embree rays/s (Table 1).

    Photon sets: the wall photons of the shipped headlight and the floor photons of the
    RING scene, each from a moderate and a large number of emitted photons. Then the
    memory table: bytes per stored photon and the peak RSS of a `simulate` run.
    """
    from lightsim.validation.bench import photonmap as pm
    from lightsim.validation.scenes import paper

    if rss_photons < 0:
        raise InputError(f"--rss-photons must be ≥ 0, got {rss_photons}")
    if goals:
        rows = pm.goal_rows(k=k, repeats=repeats)
        print_table("Photon maps: the issue's ratios (same run)", rows, pm.GOAL_COLUMNS)
        memory = _memory(rss_photons)
        if json_path:
            write_json(json_path, "photonmap-goals", rows + memory, meta={"k": k})
        return

    scenes = {"headlight": paper.build("headlight"), "ring": paper.build("ring")}
    if synthetic:
        sets = pm.synthetic_sets()
    else:
        sets = {}
        for name, scene in scenes.items():
            for label, n in (("moderate", moderate), ("large", large)):
                sets[f"{name}-{label}"] = traced_wall_photons(scene, n)
    result = pm.run(sets, k=k, repeats=repeats, show=True)
    rows = result["table5"]
    # Table 1: kNN queries/s next to raw embree rays/s in the same scene
    table1 = []
    for name, scene in scenes.items():
        rays = embree_rate(scene)
        for r in rows:
            if r["set"].startswith(name) and r["method"] in ("middle", "ckdtree"):
                table1.append({"scene": name, "set": r["set"], "photons": r["photons"],
                               "k": r["k"], "method": r["method"],
                               "knn_queries_per_s": r["queries_per_s"],
                               "embree_rays_per_s": rays,
                               "rays_per_knn_query": rays / r["queries_per_s"]})
    print_table("Table 1: kNN queries/s vs raw embree rays/s in the same scene", table1)
    memory = _memory(rss_photons)
    if json_path:
        write_json(json_path, "photonmap", rows + [{"method": "insert-vs-rebuild",
                                                   **result["insert_vs_rebuild"]}] + table1
                   + memory, meta={"k": k, "moderate": moderate, "large": large})


def _memory(rss_photons: int) -> list[dict]:
    """Bytes per stored photon (1 M ring photons) and the peak RSS of a headlight run."""
    from lightsim.validation.bench import photonmap as pm

    pos, nrm, pw = pm.caustic_ring_set(1_000_000)
    rows = pm.stored_bytes(pos, nrm, pw)
    if rss_photons:
        rows.append(pm.simulate_peak_rss(example_headlight(), rss_photons))
    print_table("Memory: bytes per stored photon; peak RSS of `simulate` vs the pre-flight "
                "estimate", rows, pm.MEMORY_COLUMNS)
    return rows
