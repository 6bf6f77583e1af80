"""Frames per second against the number of Ray workers (paper Table 6).

For each worker count the benchmark measures *interaction* frames (shoot a new photon
batch into every set and render) and *walkthrough* frames (render the accumulated maps
only), the bytes the actors send to the server per frame (sub-image pixels and probe
values, never photons), and the parallel efficiency fps(N) / (N · fps(1)). The in-process
backend (``workers = 0``) measured in the same run is the baseline without Ray overhead.
"""

from __future__ import annotations

import time
from typing import Any

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session


def _fps(fn, frames: int) -> tuple[float, float]:
    """Frames per second and mean seconds per frame."""
    t0 = time.perf_counter()
    for _ in range(frames):
        fn()
    dt = time.perf_counter() - t0
    return frames / dt, dt / frames


def bench_scaling(scene, workers=(0, 1, 2), frame_photons: int = 50_000,
                  accumulate: int = 400_000, frames: int = 5, interleave: int = 4,
                  address: str | None = None, threads: int | None = 1
                  ) -> list[dict[str, Any]]:
    """Rows per worker count (see the module docstring).

    ``threads`` per worker (default 1, so N workers use N cores and the efficiency
    measures distribution alone; None = all cores divided among the workers).
    """
    rows: list[dict[str, Any]] = []
    cfg = RunConfig(frame_photons=frame_photons, interleave=interleave, threads=threads)
    for n in workers:
        with Session(scene, cfg, workers=n, address=address if n else None) as s:
            part = s.scene.surfaces[0].name
            s.frame()  # warm-up (compilation in every worker, embree build)

            def interaction(s=s, part=part) -> None:
                s.update(material=(part, {}))
                s.frame()

            fps_i, _ = _fps(interaction, frames)
            s.update(material=(part, {}))
            while sum(s.emitted_per_set().values()) < accumulate:
                s.frame(image=False)
            s.walkthrough()
            fps_w, _ = _fps(s.walkthrough, frames)
            nbytes = getattr(s.backend, "bytes_last_frame", 0)
            scene_bytes = getattr(s.backend, "scene_bytes", 0)
        rows.append({"workers": n, "backend": "in-process" if n == 0 else "ray",
                     "threads_per_worker": threads or "auto",
                     "interaction_fps": fps_i, "walkthrough_fps": fps_w,
                     "bytes_per_frame": nbytes, "scene_bytes_once": scene_bytes})
    one = next((r for r in rows if r["workers"] == 1), None)
    base = next((r for r in rows if r["workers"] == 0), None)
    for r in rows:
        if one is not None and r["workers"] >= 1:
            r["efficiency_interaction"] = r["interaction_fps"] / (r["workers"]
                                                                  * one["interaction_fps"])
            r["efficiency_walkthrough"] = r["walkthrough_fps"] / (r["workers"]
                                                                  * one["walkthrough_fps"])
        if base is not None:
            r["ratio_vs_in_process_interaction"] = r["interaction_fps"] / base["interaction_fps"]
            r["ratio_vs_in_process_walkthrough"] = r["walkthrough_fps"] / base["walkthrough_fps"]
    return rows
