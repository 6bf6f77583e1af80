"""Pipeline efficiency: ``simulate``'s photons/s against ``bench tracer``'s on one scene.

Issue 15 goal 2: a run should spend its time tracing. For one scene and thread count the
benchmark alternates, ``repeats`` times, (a) the tracer alone — exactly what ``lightsim
bench tracer`` times: :meth:`PhotonTracer.trace_points` on pre-generated Halton points —
and (b) a whole :meth:`Session.run` with the CLI's default run configuration, from the
first shot to the final written map (sampling, tracing, insertion, the error estimates,
the final image). The ratio (b)/(a) of each pair is measured back to back, so machine
load moves both; the table gives every pair and the median, and where the run's time
went: ``shoot_s`` (sampling, tracing, insertion), ``estimate_s`` (the error estimates
during the run), ``final_s`` (the final map).

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


def _trace_rate(tracer: PhotonTracer, pts: np.ndarray, keys: np.ndarray) -> float:
    t0 = time.perf_counter()
    tracer.trace_points(pts, keys)
    return len(pts) / (time.perf_counter() - t0)


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
        return {"photons": est.photons, "seconds": est.seconds, "frames": s.frames,
                "estimates": estimates, "shoot_s": est.seconds - render - final,
                "estimate_s": render, "final_s": final}


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
        trace = _trace_rate(tracer, pts, keys)
        run = _run(scene, config, photons)
        rate = run["photons"] / run["seconds"]
        rows.append({"what": f"pair {r + 1}", "tracer_photons_per_s": trace,
                     "simulate_photons_per_s": rate, "ratio": rate / trace,
                     "frames": run["frames"], "estimates": run["estimates"],
                     "shoot_s": run["shoot_s"], "estimate_s": run["estimate_s"],
                     "final_s": run["final_s"], "run_s": run["seconds"]})
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
