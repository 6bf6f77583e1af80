"""``lightsim bench road``: how long the road evaluation of a finished run takes, against
the run's own load time (reading ``summary.json`` and ``wall_lux.exr``), measured in the
same process.

=============  =====  =======  ===========================================================
name           unit   default  meaning
=============  =====  =======  ===========================================================
``run_dir``    –      –        a finished run (``lightsim simulate``; with ``--road`` it
                               has per-set maps and the evaluation has intervals)
``repeats``    –      3        timed repetitions (the median is reported)
``TARGET_S``   s      2        the evaluation's time budget on 2 cores
=============  =====  =======  ===========================================================

Rows: load (the baseline), evaluation of the five approaches with the sensitivity study
(pitch ±0.5°, height ±0.1 m, re-projected: photons traced 0), and the plots; each with
its ratio to the load time.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from lightsim.io.exr import read_exr
from lightsim.io.summary import read_json
from lightsim.road_evaluation import RoadSettings, evaluate_road, load_far_field, write_road

__all__ = ["TARGET_S", "bench_road"]

TARGET_S = 2.0


def _median(fn, repeats: int) -> tuple[float, Any]:
    times, out = [], None
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def bench_road(run_dir: str | Path, repeats: int = 3) -> list[dict[str, Any]]:
    """Time loading, evaluating and plotting the road evaluation of ``run_dir``."""
    run = Path(run_dir)
    t_load, _ = _median(lambda: (read_json(run / "summary.json"),
                                 read_exr(run / "wall_lux.exr")), repeats)
    far = load_far_field(run)
    settings = RoadSettings()
    t_eval, ev = _median(lambda: evaluate_road(far, settings), repeats)
    with tempfile.TemporaryDirectory() as tmp:  # the run folder is left as it is
        t_plot, _ = _median(lambda: write_road(Path(tmp), ev), 1)
    t_full, _ = _median(lambda: evaluate_road(load_far_field(run), settings), repeats)
    rows = [
        {"step": "load run (baseline)", "seconds": t_load, "ratio": 1.0,
         "sets": far.n_sets, "photons_traced": 0},
        {"step": "load + evaluate (5 approaches, sensitivity)", "seconds": t_full,
         "ratio": t_full / t_load, "sets": far.n_sets, "photons_traced": 0,
         "within_target": t_full <= TARGET_S},
        {"step": "evaluate only", "seconds": t_eval, "ratio": t_eval / t_load,
         "sets": far.n_sets, "photons_traced": 0},
        {"step": "plots + road.json", "seconds": t_plot, "ratio": t_plot / t_load,
         "sets": far.n_sets, "photons_traced": 0},
    ]
    return rows
