"""``lightsim bench adb``: a traffic sequence composed and judged from per-source maps,
against re-tracing one frame of the same lamp in the same run; and the memory a
``--per-source`` run costs against a plain one.

=================  =====  =========  ========================================================
name               unit   default    meaning
=================  =====  =========  ========================================================
``run_dir``        –      none       a ``simulate --per-source`` run; none: the shipped matrix
                                     lamp is run here (one frame, 640×256)
``frames``         –      1000       frames of the sequence (an oncoming car from 400 m to
                                     30 m and a preceding car at 80 m)
``memory_photons`` –      0          > 0: also run the matrix lamp with and without
                                     ``--per-source`` at this many photons in child
                                     processes and compare their peak memory (RSS)
``TARGET_S``       s      1          the sequence's budget on 2 cores
``MEMORY_RATIO``   –      1.5        the memory target: per-source ≤ this × plain
=================  =====  =========  ========================================================
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.luminaires.adb import AdbSettings, read_traffic, run_adb
from lightsim.persource import read_per_source
from lightsim.scene import SceneSettings, load_scene
from lightsim.simulate import SimulateOptions, run_simulation

__all__ = ["MEMORY_RATIO", "TARGET_S", "bench_adb"]

TARGET_S = 1.0
MEMORY_RATIO = 1.5
MATRIX = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "matrix.glb"
RESOLUTION = (640, 256)

_SEQUENCE = """
[road]
mount_height_m = 0.65
lane_width_m = 3.5

[[vehicle]]
name = "oncoming car"
kind = "oncoming"
approach_m = [400.0, 30.0]
frames = {frames}

[[vehicle]]
name = "car ahead"
kind = "preceding"
distance_m = 80.0
"""

# the child's own peak (VmHWM: ru_maxrss would keep the parent's peak across exec)
_MEMORY = """
import sys
from lightsim.simulate import SimulateOptions, run_simulation
run_simulation(SimulateOptions(scene_path=sys.argv[1], photons=int(sys.argv[2]),
               out_dir=sys.argv[3], resolution=(640, 256), per_source=sys.argv[4] == "1",
               outputs=("json",)))
with open("/proc/self/status") as f:
    print(next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")))
"""


def _retrace_one_frame(scene_path: Path) -> float:
    """Seconds to trace and insert one frame of photons (the second: the first loads the
    kernels) of the lamp at the bench resolution."""
    scene = load_scene(str(scene_path), SceneSettings(resolution=RESOLUTION))
    with Session(scene, RunConfig()) as session:
        session.shoot()
        t0 = time.perf_counter()
        session.shoot()
        return time.perf_counter() - t0


def _peak_rss_kb(scene: Path, photons: int, out: Path, per_source: bool) -> int:
    res = subprocess.run([sys.executable, "-c", _MEMORY, str(scene), str(photons), str(out),
                          "1" if per_source else "0"], capture_output=True, text=True,
                         check=True)
    return int(res.stdout.strip().splitlines()[-1])


def bench_adb(run_dir: str | Path | None = None, frames: int = 1000,
              memory_photons: int = 0) -> list[dict[str, Any]]:
    """Time the sequence and the one-frame re-trace (and the memory, if asked)."""
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmpd = Path(tmp)
        if run_dir is None:
            run_dir = tmpd / "run"
            run_simulation(SimulateOptions(scene_path=str(MATRIX), out_dir=str(run_dir),
                                           resolution=RESOLUTION, per_source=True,
                                           outputs=("json",)))
        t_trace = _retrace_one_frame(MATRIX)
        rows.append({"step": "re-trace one frame (baseline)", "seconds": t_trace,
                     "ratio": 1.0, "frames": 1})
        seq = tmpd / "sequence.toml"
        seq.write_text(_SEQUENCE.format(frames=int(frames)))
        t0 = time.perf_counter()
        maps = read_per_source(run_dir)
        t_load = time.perf_counter() - t0
        traffic = read_traffic(seq)
        t0 = time.perf_counter()
        result = run_adb(maps, traffic, AdbSettings())
        t_all = time.perf_counter() - t0
        rows.append({"step": "read per-source maps", "seconds": t_load,
                     "ratio": t_load / t_trace, "frames": 0})
        rows.append({"step": f"compose and judge {frames} frames (levels, verdicts, "
                     "residual)", "seconds": t_all, "ratio": t_all / t_trace,
                     "frames": frames, "within_target": t_all <= TARGET_S})
        rows.append({"step": "  of which after the screen tables", "seconds": result.seconds,
                     "ratio": result.seconds / t_trace, "frames": frames})
        if memory_photons > 0:
            plain = _peak_rss_kb(MATRIX, memory_photons, tmpd / "plain", False)
            per = _peak_rss_kb(MATRIX, memory_photons, tmpd / "per", True)
            rows.append({"step": f"peak memory, plain run of {memory_photons:,} photons",
                         "MB": plain / 1024.0, "ratio": 1.0, "frames": 0})
            rows.append({"step": "peak memory, the same with --per-source", "MB": per / 1024.0,
                         "ratio": per / plain, "frames": 0,
                         "within_target": per <= MEMORY_RATIO * plain})
    return rows
