"""Photon-tracing throughput against raw embree (paper Tables 2 and 3).

For one scene the benchmark shoots photons with the full tracer (emission, embree casts,
numba surface interaction, compaction, bookkeeping) and then casts *the same number of
rays* as the photons needed, with random origins inside the luminaire's bounding box
and random directions, through the bare :class:`~lightsim.raycast.RayCaster` — the raw
ray rate of embree in the same scene, measured in the same run. The ratio of the two
ray rates is the cost of everything that is not ray casting.

The two are timed in alternation, ``repeats`` pairs, and the ratio is the median of the
pairs' ratios: on a shared machine the load changes between runs, and a pair measured
back to back sees about the same load (the load average is in the rows). On a machine
loaded far beyond its cores the wall clock mostly measures waiting for a core, so the
rows also give the ratio of CPU seconds (process time, all threads): the cost of the
work itself, and the ratio of the fastest tracing run to the fastest raw run (the pair
members that waited least for a core).
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from lightsim.raycast import RayCaster
from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.tracer import PhotonTracer


def _timed(fn) -> tuple[float, Any]:
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def bench_tracer(scene, photons: int = 500_000, repeats: int = 3, threads: int | None = None,
                 seed: int = 7) -> list[dict[str, Any]]:
    """Rows: photon tracing and raw embree on the same scene (see module docstring)."""
    tracer = PhotonTracer(scene, threads=threads)
    idx = np.arange(photons, dtype=np.int64)
    pts = halton_points(idx, digit_permutations(seed, 0, None))
    keys = photon_keys(seed, 0, 0, idx)
    tracer.trace_points(pts[:1000], keys[:1000])  # compile/warm up
    res = tracer.trace_points(pts, keys)
    rays = res.rays

    # raw embree: as many random rays, from inside the lamp's bounding box
    lamp = np.concatenate([p.vertices for p in scene.parts if p.role != "wall"])
    lo, hi = lamp.min(axis=0), lamp.max(axis=0)
    rng = np.random.default_rng(seed)
    o = (lo + (hi - lo) * rng.random((rays, 3))).astype(np.float32)
    d = rng.normal(size=(rays, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    caster = RayCaster(scene.triangles, threads=threads)
    caster.intersect(o[:1000], d[:1000])
    pairs = []
    for _ in range(max(1, repeats)):
        c0 = time.process_time()
        t_trace, _ = _timed(lambda: tracer.trace_points(pts, keys))
        c1 = time.process_time()
        t_raw, _ = _timed(lambda: caster.intersect(o, d))
        c2 = time.process_time()
        pairs.append((t_trace, t_raw, os.getloadavg()[0], (c2 - c1) / max(c1 - c0, 1e-9)))
    caster.close()
    tracer.close()
    t_trace = float(np.median([p[0] for p in pairs]))
    t_raw = float(np.median([p[1] for p in pairs]))
    ratio = float(np.median([p[1] / p[0] for p in pairs]))
    # the fastest of each: the run that waited least for a core (robust on a loaded box)
    min_ratio = float(min(p[1] for p in pairs) / min(p[0] for p in pairs))
    load = float(np.median([p[2] for p in pairs]))
    cpu_ratio = float(np.median([p[3] for p in pairs]))
    return [
        {"what": "photon tracing", "photons": photons, "rays": rays,
         "rays_per_photon": rays / photons, "seconds": t_trace,
         "photons_per_s": photons / t_trace, "rays_per_s": rays / t_trace,
         "ratio_vs_raw_embree": ratio, "cpu_ratio_vs_raw_embree": cpu_ratio,
         "min_time_ratio_vs_raw_embree": min_ratio,
         "wall_photons_per_emitted": len(res.records) / photons, "load_average": load},
        {"what": "raw embree (random rays)", "photons": 0, "rays": rays,
         "rays_per_photon": 0.0, "seconds": t_raw, "photons_per_s": 0.0,
         "rays_per_s": rays / t_raw, "ratio_vs_raw_embree": 1.0,
         "cpu_ratio_vs_raw_embree": 1.0, "min_time_ratio_vs_raw_embree": 1.0,
         "wall_photons_per_emitted": 0.0,
         "load_average": load},
    ]


def stage_rows(scene, photons: int = 500_000, threads: int | None = 1, repeats: int = 3,
               seed: int = 7) -> list[dict[str, Any]]:
    """Where photon tracing spends its time: rows per stage of the tracer.

    The tracer is run ``repeats`` times with its stage clock on
    (:attr:`~lightsim.tracer.PhotonTracer.stages`); the run with the shortest wall time is
    reported. Stages are summed over chunks and threads (thread-seconds): *emit* (sample
    points → rays), *start* (the wavefront's arrays), *cast* (embree, with the re-cast of
    false self-hits), *bounce* (the interaction kernel with the exact wall, records,
    ledger, compaction, and its buffers); *rest* is threads × wall time minus the stages
    (Python, collecting batches, the per-group ledger, and any thread waiting).
    """
    tracer = PhotonTracer(scene, threads=threads)
    idx = np.arange(photons, dtype=np.int64)
    pts = halton_points(idx, digit_permutations(seed, 0, None))
    keys = photon_keys(seed, 0, 0, idx)
    tracer.trace_points(pts[:1000], keys[:1000])  # compile/warm up
    best = None
    for _ in range(max(1, repeats)):
        tracer.stages = {}
        wall, res = _timed(lambda: tracer.trace_points(pts, keys))
        if best is None or wall < best[0]:
            best = (wall, dict(tracer.stages), res.rays)
    tracer.close()
    wall, stages, rays = best
    total = wall * tracer.threads
    stages["rest"] = max(0.0, total - sum(stages.values()))
    load = float(os.getloadavg()[0])
    return [{"stage": k, "thread_seconds": v, "share": v / total,
             "ns_per_ray": 1e9 * v / max(rays, 1), "ns_per_photon": 1e9 * v / photons,
             "photons": photons, "rays": rays, "threads": tracer.threads,
             "photons_per_s": photons / wall, "load_average": load}
            for k, v in stages.items()]
