"""``lightsim bench verdicts``: time and photons until every verdict is decided
(``simulate --until decided``), with uniform emission and with ``--guide points``, side by
side on the same lamps, seeds and caps, in one run.

=================  =====  ==============  ==================================================
name               unit   default         meaning
=================  =====  ==============  ==================================================
``lamps``          –      every one       which of :data:`LAMPS` to run
``cap_photons``    –      48 000 000      each run's photon cap (the README's budget)
``seed``           –      7               photon seed, the same for both runs of a lamp
``resolution``     px     320×128         wall pixels (the README's)
``TARGET_S``       s      5               the README lamp decided within this, on 2 cores
=================  =====  ==============  ==================================================

Lamps (:data:`LAMPS`): the shipped low beam (``lowbeam.glb``, R112 and R149 class B, the
README's command), the shipped headlight (``headlight.glb``, R112 class B) and a
goniometric lamp — a synthetic Type A low beam with a sharp cut-off written to an IES
file (:func:`~lightsim.validation.coverage.synthetic_lamp`, seed 1), R112 and R149.

Rows: one per lamp and emission — seconds of simulation (the run's own ``seconds``),
photons, looks, whether every verdict was decided before the cap and the rules still
open (their names in the JSON rows); the ratio is the guided run's seconds over the
uniform run's (the baseline, measured in the same run).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.luminaires.analyses import for_options
from lightsim.luminaires.photometric import write_ies
from lightsim.simulate import SimulateOptions, run_simulation
from lightsim.validation.coverage import synthetic_lamp

__all__ = ["COLUMNS", "LAMPS", "TARGET_S", "bench_verdicts"]

TARGET_S = 5.0
#: the printed columns (the JSON rows hold ``open_rules`` too)
COLUMNS = ("lamp", "emission", "seconds", "photons", "looks", "decided", "open", "ratio")
EXAMPLES = Path(__file__).resolve().parents[2] / "luminaires" / "examples"
#: name: (scene, rule sets); "typeA" is written at run time
LAMPS: dict[str, tuple[str, str]] = {
    "lowbeam": (str(EXAMPLES / "lowbeam.glb"), "r112-b-passing,r149-b-passing"),
    "headlight": (str(EXAMPLES / "headlight.glb"), "r112-b-passing"),
    "typeA": ("", "r112-b-passing,r149-b-passing"),
}


def _scene(name: str, tmp: Path) -> str:
    if name != "typeA":
        return LAMPS[name][0]
    grid, _p = synthetic_lamp(np.random.default_rng(1))
    path = tmp / "typeA.ies"
    write_ies(path, grid)
    return str(path)


def run_until(scene: str, regulation: str, guide: str, *, cap_photons: int, seed: int,
              resolution: tuple[int, int], out: Path) -> dict[str, Any]:
    """One ``simulate --until decided`` run; its row (seconds, photons, looks, decided,
    rules open)."""
    opts = SimulateOptions(scene, out_dir=str(out), photons=int(cap_photons),
                           resolution=tuple(resolution), regulation=regulation,
                           until="decided", outputs=("json",),
                           config={"seed": int(seed), "guide": guide})
    s = run_simulation(opts, analyses=for_options(opts)).summary
    u = s.get("until") or {}
    return {"seconds": float(s.get("seconds") or 0.0), "photons": int(s.get("photons") or 0),
            "looks": len(u.get("looks") or []), "decided": bool(u.get("decided")),
            "open": len(u.get("undecided") or []),
            "open_rules": [f"{o['ruleset']}:{o['name']}" for o in u.get("undecided") or []]}


def bench_verdicts(lamps: Sequence[str] | None = None, *, cap_photons: int = 48_000_000,
                   seed: int = 7, resolution: tuple[int, int] = (320, 128),
                   note: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Every lamp decided uniform and guided (module docstring); the rows."""
    names = list(LAMPS) if not lamps else list(lamps)
    bad = [n for n in names if n not in LAMPS]
    if bad:
        raise InputError(f"unknown lamp {', '.join(bad)}; known: {', '.join(LAMPS)}")
    if cap_photons < 1:
        raise InputError(f"--photons must be ≥ 1, got {cap_photons}")
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="lightsim-bench-") as tmp:
        work = Path(tmp)
        for name in names:
            scene, regulation = _scene(name, work), LAMPS[name][1]
            base = None
            for guide in ("off", "points"):
                if note is not None:
                    note(f"{name}: {'guided' if guide == 'points' else 'uniform'} …")
                row = run_until(scene, regulation, guide, cap_photons=cap_photons,
                                seed=seed, resolution=resolution,
                                out=work / f"{name}-{guide}")
                base = row["seconds"] if base is None else base
                rows.append({"lamp": name, "emission": "uniform" if guide == "off"
                             else "guided", **row,
                             "ratio": row["seconds"] / base if base > 0 else float("nan")})
    return rows
