"""``lightsim bench provenance``: what ``--provenance`` costs, measured in one run.

The same simulation (lamp, rule set, photons, seed) is run without and with path
signatures, alternating, in this process; each run's wall-clock time and its peak of
traced memory (NumPy's arrays and Python's objects, :mod:`tracemalloc`, in a second pass
of the same run) are compared with the run without.

=============  =====  ==============  ====================================================
name           unit   default         meaning
=============  =====  ==============  ====================================================
``lamp``       –      lowbeam.glb     the shipped lamp simulated
``ruleset``    –      r112-b-passing  the rule set whose points are split
``photons``    –      1 000 000       photons per run
``repeats``    –      1               timed runs per variant (the median is reported)
``TIME_X``     ×      1.3             target: time with / without
``MEMORY_X``   ×      1.5             target: peak memory with / without
=============  =====  ==============  ====================================================
"""

from __future__ import annotations

import statistics
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Any

from lightsim.luminaires.analyses import for_options
from lightsim.simulate import SimulateOptions, run_simulation

__all__ = ["MEMORY_X", "TIME_X", "bench_provenance"]

TIME_X = 1.3
MEMORY_X = 1.5
LAMP = Path(__file__).parents[2] / "luminaires" / "examples" / "lowbeam.glb"


def _run(lamp: Path, ruleset: str, photons: int, provenance: bool, traced: bool
         ) -> tuple[float, int]:
    """(seconds, peak traced bytes or 0) of one run into a scratch folder."""
    with tempfile.TemporaryDirectory() as tmp:
        opts = SimulateOptions(scene_path=str(lamp), photons=photons, regulation=ruleset,
                               provenance=provenance, out_dir=tmp, outputs=("json",))
        analyses = for_options(opts)
        if traced:
            tracemalloc.start()
        t0 = time.perf_counter()
        try:
            run_simulation(opts, analyses=analyses)
            seconds = time.perf_counter() - t0
            peak = tracemalloc.get_traced_memory()[1] if traced else 0
        finally:
            if traced:
                tracemalloc.stop()
    return seconds, peak


def bench_provenance(photons: int = 1_000_000, ruleset: str = "r112-b-passing",
                     lamp: str | Path = LAMP, repeats: int = 1) -> list[dict[str, Any]]:
    """Rows without (the baseline) and with ``--provenance``: seconds, peak MB, ratios."""
    _run(Path(lamp), ruleset, 20_000, True, False)  # compile the kernels first
    times: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(max(1, repeats)):
        for prov in (False, True):
            times[prov].append(_run(Path(lamp), ruleset, photons, prov, False)[0])
    peak = {prov: _run(Path(lamp), ruleset, photons, prov, True)[1] for prov in (False, True)}
    base_t, base_m = statistics.median(times[False]), peak[False]
    rows = []
    for prov in (False, True):
        t = statistics.median(times[prov])
        rows.append({"run": "--provenance" if prov else "without (baseline)",
                     "photons": photons, "seconds": t, "time_ratio": t / base_t,
                     "peak_MB": peak[prov] / 2**20, "memory_ratio": peak[prov] / base_m,
                     "target": (f"≤ {TIME_X:g}× time, ≤ {MEMORY_X:g}× memory" if prov
                                else "")})
    return rows
