"""Aiming the lamp in an interactive session: embree rebuild against moving the wall.

Both ways give the aimed lamp's pattern on the wall: the old one rotates every part but the
wall by R (yaw H, then pitch V about the origin) and hands the session a new scene, whose
embree scene is rebuilt; the new one moves the wall and its pixel frame by R⁻¹
(``Session.update(wall_transform=R⁻¹)``): the lamp's BVH and packed triangles are kept.
Each row is the median of ``repeats`` updates (``Session.update`` alone, then one frame of
``frame_photons`` to show the session still works).

==================  =====  =======  ==================================================
parameter           unit   default  meaning
==================  =====  =======  ==================================================
``repeats``         –      5        aim changes per way (alternated)
``frame_photons``   –      20000    photons of the frame shot after each change
==================  =====  =======  ==================================================
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.scene import WALL, Scene
from lightsim.view.editor import aim_matrix

#: 4×4 lamp aim: yaw by H (towards world −X), then pitch by V (up) about the origin —
#: the view's own aim, so the bench times exactly what the view does
aim_rotation = aim_matrix


def rotated_lamp(scene: Scene, m: np.ndarray) -> Scene:
    parts = [p if p.role == WALL else p.transformed(m) for p in scene.parts]
    return Scene(parts, scene.wall, scene.source, list(scene.warnings), scene.channels)


def bench_aim(scene: Scene, repeats: int = 5, frame_photons: int = 20_000,
              seed: int = 1) -> list[dict[str, Any]]:
    """Rows: seconds per aim change, rebuilding vs moving the wall (module docstring)."""
    cfg = RunConfig(frame_photons=frame_photons, interleave=1, seed=seed)
    rebuild, moved, frames_r, frames_m = [], [], [], []
    with Session(scene, cfg) as s:
        s.frame()
        for k in range(max(1, repeats)):
            m = aim_rotation(1.0 + k, -0.5 * k)
            t0 = time.perf_counter()
            s.update(scene=rotated_lamp(scene, m))
            rebuild.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            s.frame()
            frames_r.append(time.perf_counter() - t0)
            s.update(scene=scene)
            t0 = time.perf_counter()
            s.update(wall_transform=np.linalg.inv(m))
            moved.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            s.frame()
            frames_m.append(time.perf_counter() - t0)
            s.update(wall_transform=m)
    load = os.getloadavg()[0]
    t_r, t_m = float(np.median(rebuild)), float(np.median(moved))
    return [
        {"what": "aim: new scene (embree rebuilt)", "update_s": t_r,
         "frame_s": float(np.median(frames_r)), "speedup": 1.0, "load_average": load},
        {"what": "aim: wall_transform (embree kept)", "update_s": t_m,
         "frame_s": float(np.median(frames_m)), "speedup": t_r / max(t_m, 1e-12),
         "load_average": load},
    ]
