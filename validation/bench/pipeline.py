"""Pipeline efficiency: ``simulate``'s photons/s against ``bench tracer``'s on one scene.

Issue 15 goal 2: a run should spend its time tracing. For one scene and thread count the
benchmark alternates, ``repeats`` times, (a) the tracer alone — exactly what ``lightsim
bench tracer`` times: :meth:`PhotonTracer.trace_points` on pre-generated Halton points —
and (b) a whole :meth:`Session.run` with the CLI's default run configuration, from the
first shot to the final written map (sampling, tracing, insertion, the error estimates,
the final image). The ratio (b)/(a) of each pair is measured back to back, so machine
load moves both; the table gives every pair and the median, and where the run's time
went: ``sample_s`` (the frames' sample points: Halton, SPT passes), ``trace_s`` (the
tracer inside the run), ``insert_s`` (the rest of shooting: sorting, stores),
``estimate_s`` (the error estimates during the run), ``final_s`` (the final map).

With Selective Photon Tracing the run traces other photons than the bare tracer's plain
Halton points (SPT refines the caustic cells: more photons take the mirror, so a photon
costs more rays), so photons/s compare unlike work there. ``ray_ratio`` (rays/s of the
run over the tracer's) and ``trace_share`` (the run's own tracer time over its time)
compare like with like.

=================  =====  ===========  ===============================================
parameter          unit   default      meaning
=================  =====  ===========  ===============================================
``photons``        –      1 000 000    photons of both the tracer call and the run
``repeats``        –      3            (tracer, run) pairs
``threads``        –      all cores    ray-casting and numba threads of both
``frame_photons``  –      200 000      photons per frame of the run (CLI default)
=================  =====  ===========  ===============================================
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.tracer import PhotonTracer


def _trace_rate(tracer: PhotonTracer, pts: np.ndarray, keys: np.ndarray
                ) -> tuple[float, float]:
    """(photons/s, rays/s) of one bare tracer call."""
    t0 = time.perf_counter()
    res = tracer.trace_points(pts, keys)
    dt = time.perf_counter() - t0
    return len(pts) / dt, res.rays / dt


def _run(scene, config: RunConfig, photons: int) -> dict[str, Any]:
    """One timed Session.run (the session's own clock: first shot to final map)."""
    render = 0.0
    estimates = 0

    def tally(est) -> None:
        nonlocal render, estimates
        if "render" in est.timings:
            estimates += 1
            render += est.timings["render"] + est.timings.get("assemble", 0.0)

    with Session(scene, config) as s:
        est = s.run(photons=photons, callback=tally, probes=False)  # as `simulate` does
        final = est.timings.get("render", 0.0) + est.timings.get("assemble", 0.0)
        # shooting (sampling, tracing, insertion) of every frame: the rest of the run
        tot = s.shoot_totals
        return {"photons": est.photons, "seconds": est.seconds, "frames": s.frames,
                "estimates": estimates, "shoot_s": est.seconds - render - final,
                "estimate_s": render, "final_s": final, "sample_s": tot.sample_s,
                "trace_s": tot.trace_s, "rays": tot.rays}


def bench_pipeline(scene, config: RunConfig | None = None, photons: int = 1_000_000,
                   repeats: int = 3, threads: int | None = None, seed: int = 7
                   ) -> list[dict[str, Any]]:
    """Rows: one per (tracer, run) pair, then the medians (see the module docstring)."""
    config = (config or RunConfig()).with_(threads=threads)
    tracer = PhotonTracer(scene, threads=threads)
    idx = np.arange(photons, dtype=np.int64)
    pts = halton_points(idx, digit_permutations(seed, 0, None))
    keys = photon_keys(seed, 0, 0, idx)
    tracer.trace_points(pts[:1000], keys[:1000])  # compile / warm up
    _run(scene, config.with_(frame_photons=max(config.n_sets, 20_000)), 40_000)  # warm up
    rows: list[dict[str, Any]] = []
    for r in range(repeats):
        trace, trace_rays = _trace_rate(tracer, pts, keys)
        run = _run(scene, config, photons)
        rate = run["photons"] / run["seconds"]
        rays = run["rays"] / run["seconds"]
        rows.append({"what": f"pair {r + 1}", "tracer_photons_per_s": trace,
                     "simulate_photons_per_s": rate, "ratio": rate / trace,
                     "ray_ratio": rays / trace_rays,
                     "trace_share": run["trace_s"] / run["seconds"],
                     "frames": run["frames"], "estimates": run["estimates"],
                     "sample_s": run["sample_s"], "trace_s": run["trace_s"],
                     "insert_s": run["shoot_s"] - run["sample_s"] - run["trace_s"],
                     "estimate_s": run["estimate_s"], "final_s": run["final_s"],
                     "run_s": run["seconds"]})
    tracer.caster.close()
    med = {k: float(np.median([row[k] for row in rows])) for k in rows[0] if k != "what"}
    rows.append({"what": "median", **med})
    return rows


def load_average() -> str:
    """The 1/5/15-minute load averages (the machine is shared: say how loaded)."""
    try:
        return ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "unknown"
