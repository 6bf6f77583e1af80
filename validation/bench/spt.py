"""Caustic photon yield with plain sampling and with Selective Photon Tracing (Table 4).

The yield is the fraction of emitted photons whose path is caustic (at least one
specular bounce, then a diffuse surface). Plain sampling measured in the same run is the
baseline. SPT's first pass samples every cell once (it knows nothing yet); the
*refined* column is the yield of the passes after it, which is what SPT delivers once
its pilots have found the caustic generators.
"""

from __future__ import annotations

import time
from typing import Any

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session


def _run(scene, spt: bool, photons: int, frame_photons: int, seed: int) -> dict[str, float]:
    cfg = RunConfig(frame_photons=frame_photons, interleave=4, spt=spt, seed=seed,
                    estimator="radius")
    with Session(scene, cfg) as s:
        t0 = time.perf_counter()
        s.frame(image=False)
        first = s.backend.stats()
        n1 = sum(v["emitted"] for v in first.values())
        c1 = sum(v["caustic"] for v in first.values())
        s.run(photons=photons)
        stats = s.backend.stats()
        dt = time.perf_counter() - t0
    n = sum(v["emitted"] for v in stats.values())
    c = sum(v["caustic"] for v in stats.values())
    return {"yield": c / n, "refined_yield": (c - c1) / max(n - n1, 1), "photons": n,
            "caustic_per_s": c / dt}


def bench_spt(scenes: dict[str, Any], photons: int = 400_000, frame_photons: int = 100_000,
              seed: int = 3) -> list[dict[str, Any]]:
    rows = []
    for name, scene in scenes.items():
        plain = _run(scene, False, photons, frame_photons, seed)
        spt = _run(scene, True, photons, frame_photons, seed)
        rows.append({"scene": name, "plain_yield": plain["yield"],
                     "spt_yield": spt["yield"], "spt_refined_yield": spt["refined_yield"],
                     "improvement": spt["refined_yield"] / max(plain["yield"], 1e-12),
                     "caustic_photons_per_s_plain": plain["caustic_per_s"],
                     "caustic_photons_per_s_spt": spt["caustic_per_s"]})
    return rows
