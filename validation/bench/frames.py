"""Frames per second against resolution, interaction and walkthrough (paper Table 7).

*Interaction* frames shoot a new batch of photons into every set (the scene just changed,
accumulation restarts) and render the image; *walkthrough* frames only query the
accumulated photon maps, assemble and filter (the camera moved; no shooting). Both run in
one process (``--workers 0``). The baseline of each row is the 640×480 row of the same
scene measured in the same run: the paper's claim is that the frame rate scales nearly
linearly with the number of pixels.
"""

from __future__ import annotations

import time
from typing import Any

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session

RESOLUTIONS = ((640, 480), (800, 600), (1024, 768), (1280, 960))


def _rate(fn, frames: int) -> float:
    t0 = time.perf_counter()
    for _ in range(frames):
        fn()
    return frames / (time.perf_counter() - t0)


def bench_frames(scene_builder, name: str, resolutions=RESOLUTIONS, frame_photons: int = 50_000,
                 accumulate: int = 500_000, frames: int = 3, interleave: int = 4,
                 **config: Any) -> list[dict[str, Any]]:
    """Rows of frames/s per resolution for one scene.

    Parameters
    ----------
    scene_builder : callable (W, H) → Scene
        Builds the scene with a wall/detector of the given resolution.
    frame_photons : int
        Photons per interaction frame (all sets).
    accumulate : int
        Photons accumulated before the walkthrough frames.
    """
    rows: list[dict[str, Any]] = []
    base = None
    for w, h in resolutions:
        scene = scene_builder((w, h))
        cfg = RunConfig(frame_photons=frame_photons, interleave=interleave, **config)
        with Session(scene, cfg) as s:
            s.frame()  # warm-up: compilation, embree build, caches

            def interaction() -> None:
                s.update(material=(s.scene.surfaces[0].name, {}))  # discard photons
                s.frame()

            fps_inter = _rate(interaction, frames)
            s.update(material=(s.scene.surfaces[0].name, {}))
            while sum(s.emitted_per_set().values()) < accumulate:
                s.frame(image=False)
            s.walkthrough()
            fps_walk = _rate(s.walkthrough, frames)
            photons = sum(s.emitted_per_set().values())
        row = {"scene": name, "resolution": f"{w}x{h}", "pixels": w * h,
               "interaction_fps": fps_inter, "walkthrough_fps": fps_walk,
               "walkthrough_photons": photons}
        if base is None:
            base = row
        row["pixels_ratio"] = w * h / base["pixels"]
        row["walkthrough_slowdown"] = base["walkthrough_fps"] / fps_walk
        row["interaction_slowdown"] = base["interaction_fps"] / fps_inter
        rows.append(row)
    return rows
