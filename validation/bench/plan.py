"""What each stage the scene plan leaves out would cost (the plan's benchmark).

For every stage the plan can omit, the same run is timed twice in one process — with the
plan's choice and with the stage forced on — and the row reports seconds per frame of
both and the saving (forced ÷ planned). Stages: RGB channels on a grey scene, recording
photons on every diffuse surface (needed only by camera views), Selective Photon Tracing
where plain sampling already has a high caustic yield, and the camera pass.
"""

from __future__ import annotations

import time
from typing import Any

from lightsim.engine.config import RunConfig
from lightsim.engine.plan import make_plan
from lightsim.engine.server import Session
from lightsim.render.camera import PinholeCamera


def _per_frame(scene, cfg: RunConfig, frames: int, camera=None) -> float:
    with Session(scene, cfg, camera=camera is not None) as s:
        s.frame(image=False, camera=camera)  # warm-up
        t0 = time.perf_counter()
        for _ in range(frames):
            s.frame(image=True, camera=camera)
        return (time.perf_counter() - t0) / frames


def bench_plan(scene, frame_photons: int = 100_000, frames: int = 3, repeats: int = 3
               ) -> list[dict[str, Any]]:
    """Rows: stage, planned s/frame, forced s/frame, saving (see module docstring).

    Planned and forced runs alternate ``repeats`` times and the best of each counts, so a
    change in the machine's load does not favour one side.
    """
    base = RunConfig(frame_photons=frame_photons, interleave=4)
    plan = make_plan(scene, base)
    planned_cfg = base.with_(spt=plan.spt)
    wall = scene.wall
    cam = PinholeCamera(position=(0.0, 0.5, -1.0), look_at=tuple(wall.centre),
                        fov_deg=40, resolution=(320, 240))
    yield_txt = f"{plan.pilot_yield:.0%}" if plan.pilot_yield is not None else "n/a"
    cases = [
        ("RGB channels", base.with_(channels=3, spt=plan.spt), None,
         "one luminous channel" if plan.channels == 1 else "scene is coloured"),
        ("photons on every diffuse surface", base.with_(record="all", spt=plan.spt), None,
         "wall photons only"),
        ("selective photon tracing", base.with_(spt=not plan.spt), None,
         f"SPT {'on' if plan.spt else 'off'} (pilot caustic yield {yield_txt})"),
        ("camera pass (320×240)", planned_cfg, cam, "no camera requested"),
    ]
    rows = []
    for stage, cfg, camera, why in cases:
        planned, forced = [], []
        for _ in range(repeats):
            planned.append(_per_frame(scene, planned_cfg, frames))
            forced.append(_per_frame(scene, cfg, frames, camera))
        rows.append({"stage": stage, "planned": why, "planned_s_per_frame": min(planned),
                     "forced_s_per_frame": min(forced),
                     "saving": min(forced) / min(planned)})
    return rows
