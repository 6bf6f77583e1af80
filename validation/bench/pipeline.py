"""Pipeline efficiency: ``simulate``'s photons/s against ``bench tracer``'s on one scene.

A run should spend its time tracing. For one scene and thread count the
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
costs more rays), so ``ratio`` compares unlike work there. ``ratio_same_photons``
compares like with like: the bare tracer is also timed on the very photons a run traced
(points, keys and SPT weights recorded from one untimed run, traced in one call, as
``bench tracer`` does), and the run's photons/s are divided by that rate. ``ray_ratio``
(rays/s of the run over the plain tracer's) and ``trace_share`` (the run's own tracer
time over its time) are the other like-with-like views; ``cpu_ratio_same_photons`` is
``ratio_same_photons`` in CPU-seconds (all threads, ``time.process_time``): what the run
costs the machine beyond tracing, less moved by other jobs than the wall clock (note
that the session's whole process is counted: its clock starts before set-up).
``frames_ratio_same_photons`` leaves the run's one final map out (``final_s``: written
once, whatever the photons): the frames' own pipeline — sampling, tracing, insertion,
the error estimates — against the tracer. At 1 M photons the final map is ~11 % of a
run; at 10 M, ~1.5 %, and the two ratios meet.

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


class StageRecorder:
    """Wraps the run's tracers' ``trace_points`` to keep what each frame traced (the run
    is unchanged: the call goes through)."""

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []

    def wrap(self, tracer: PhotonTracer) -> None:
        inner = tracer.trace_points

        def trace_points(points, keys, weight=None, **kw):
            self.calls.append((np.asarray(points), np.asarray(keys),
                               None if weight is None else np.asarray(weight)))
            return inner(points, keys, weight, **kw)

        tracer.trace_points = trace_points  # type: ignore[method-assign]

    def photons(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The run's photons in order: points, keys, weights (1 without SPT)."""
        pts = np.concatenate([c[0] for c in self.calls])
        keys = np.concatenate([c[1] for c in self.calls])
        w = np.concatenate([np.ones(len(c[0])) if c[2] is None else c[2]
                            for c in self.calls])
        return pts, keys, w


def timed_run(scene, config: RunConfig, photons: int, record: StageRecorder | None = None
              ) -> dict[str, Any]:
    """One timed Session.run (the session's own clock: first shot to final map);
    ``record`` keeps the photons its frames traced."""
    render = 0.0
    estimates = 0

    def tally(est) -> None:
        nonlocal render, estimates
        if "render" in est.timings:
            estimates += 1
            render += est.timings["render"] + est.timings.get("assemble", 0.0)

    with Session(scene, config) as s:
        if record is not None:
            for client in getattr(s.backend, "clients", ()):
                record.wrap(client.photons.tracer)
        c0 = time.process_time()
        est = s.run(photons=photons, callback=tally, probes=False)  # as `simulate` does
        cpu = time.process_time() - c0
        final = est.timings.get("render", 0.0) + est.timings.get("assemble", 0.0)
        # shooting (sampling, tracing, insertion) of every frame: the rest of the run
        tot = s.shoot_totals
        return {"photons": est.photons, "seconds": est.seconds, "frames": s.frames,
                "estimates": estimates, "shoot_s": est.seconds - render - final,
                "estimate_s": render, "final_s": final, "sample_s": tot.sample_s,
                "trace_s": tot.trace_s, "rays": tot.rays, "cpu_s": cpu}


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
    timed_run(scene, config.with_(frame_photons=max(config.n_sets, 20_000)), 40_000)  # warm up
    # the run's own photons (SPT's refined cells included), for a like-with-like baseline
    rec = StageRecorder()
    timed_run(scene, config, photons, rec)
    same_pts, same_keys, same_w = rec.photons()
    rows: list[dict[str, Any]] = []
    for r in range(repeats):
        trace, trace_rays = _trace_rate(tracer, pts, keys)
        c0, t0 = time.process_time(), time.perf_counter()
        same = tracer.trace_points(same_pts, same_keys, same_w)
        same_rate = len(same_pts) / (time.perf_counter() - t0)
        same_cpu = time.process_time() - c0
        del same
        run = timed_run(scene, config, photons)
        run_cpu = run["cpu_s"]
        rate = run["photons"] / run["seconds"]
        rays = run["rays"] / run["seconds"]
        rows.append({"what": f"pair {r + 1}", "tracer_photons_per_s": trace,
                     "simulate_photons_per_s": rate, "ratio": rate / trace,
                     "tracer_same_photons_per_s": same_rate,
                     "ratio_same_photons": rate / same_rate,
                     "frames_ratio_same_photons": run["photons"]
                     / max(run["seconds"] - run["final_s"], 1e-12) / same_rate,
                     # CPU-seconds per photon, tracer over run (all threads; the process's
                     # own work, so less moved by other jobs than the wall-clock ratio)
                     "cpu_ratio_same_photons": (same_cpu / len(same_pts))
                     / max(run_cpu / run["photons"], 1e-12),
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
