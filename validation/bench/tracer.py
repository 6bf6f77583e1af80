"""Photon-tracing throughput against raw embree (paper Tables 2 and 3).

For one scene the benchmark shoots photons with the full tracer (emission, embree casts,
numba surface interaction, compaction, bookkeeping) and then casts *the same number of
rays* as the photons needed, with random origins inside the luminaire's bounding box
and random directions, through the bare :class:`~lightsim.raycast.RayCaster` — the raw
ray rate of embree in the same scene, measured in the same run. The ratio of the two
ray rates is the cost of everything that is not ray casting.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from lightsim.raycast import RayCaster
from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.tracer import PhotonTracer


def _best(fn, repeats: int) -> tuple[float, Any]:
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def bench_tracer(scene, photons: int = 500_000, repeats: int = 3, threads: int | None = None,
                 seed: int = 7) -> list[dict[str, Any]]:
    """Rows: photon tracing and raw embree on the same scene (see module docstring)."""
    tracer = PhotonTracer(scene, threads=threads)
    idx = np.arange(photons, dtype=np.int64)
    pts = halton_points(idx, digit_permutations(seed, 0, None))
    keys = photon_keys(seed, 0, 0, idx)
    tracer.trace_points(pts[:1000], keys[:1000])  # compile/warm up
    t_trace, res = _best(lambda: tracer.trace_points(pts, keys), repeats)
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
    t_raw, _ = _best(lambda: caster.intersect(o, d), repeats)
    caster.close()
    tracer.caster.close()
    photon_rate = photons / t_trace
    ray_rate = rays / t_trace
    raw_rate = rays / t_raw
    return [
        {"what": "photon tracing", "photons": photons, "rays": rays,
         "rays_per_photon": rays / photons, "seconds": t_trace,
         "photons_per_s": photon_rate, "rays_per_s": ray_rate,
         "ratio_vs_raw_embree": ray_rate / raw_rate,
         "wall_photons_per_emitted": len(res.records) / photons},
        {"what": "raw embree (random rays)", "photons": 0, "rays": rays,
         "rays_per_photon": 0.0, "seconds": t_raw, "photons_per_s": 0.0,
         "rays_per_s": raw_rate, "ratio_vs_raw_embree": 1.0,
         "wall_photons_per_emitted": 0.0},
    ]
