"""Checking a designed lamp as the README demo does, and choosing among restarts.

A design run's own report reads its lamp at the model's few photons (a few million on a
coarse wall), where the faint points and zone maxima are too noisy to say whether the
demo's 95 % intervals will clear every limit; and the footprint-model optimiser is
sensitive to its start (a small change of seed or option can give a different lamp).
``lightsim design --restarts N`` therefore designs N lamps (seeds ``seed``, ``seed + 1``, …)
and keeps the one whose check runs — ``simulate`` with the demo's settings at several
photon seeds — pass best: the fewest rows not "pass", then the largest smallest margin,
then the lowest design J.

Parameters of :func:`check_lamp`

==============  =====  ==============  ================================================
name            unit   default         meaning
==============  =====  ==============  ================================================
photons         –      32 000 000      photons of each check run (the README demo's)
resolution      px     320×128         wall pixels W×H (the README demo's)
seeds           –      (1, 2, 3)       photon seeds of the check runs
aperture        deg    0.15            detector aperture of the test points (simulate's)
until           –      None            "decided": each check run stops when every verdict
                                       is decided (``photons`` is then its cap)
==============  =====  ==============  ================================================
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lightsim.errors import InputError
from lightsim.simulate import SimulateOptions, run_simulation

from .analyses import for_options
from .design_terms import rule_interval

__all__ = ["LampCheck", "check_lamp", "choose", "rule_margin"]


@dataclass
class LampCheck:
    """Check runs of one lamp.

    Attributes
    ----------
    not_passing : list of (seed, rule set, rule, verdict)
        Every row of every check run whose verdict is neither "pass" nor "info", and
        ("annex 9", "linearity") for a run whose cut-off's three scans lie more than 0.2°
        apart.
    min_margin : float
        Smallest log-margin over all rows and runs (:func:`rule_margin`; > 0: every
        interval clears its limit).
    rows : int
        Rows with a limit checked (over all runs).
    seconds : list of float
        Simulation time of each run, s.
    photons : list of int
        Photons of each run (less than the budget where ``until`` stopped it).
    """

    not_passing: list[tuple[int, str, str, str]] = field(default_factory=list)
    min_margin: float = math.inf
    rows: int = 0
    seconds: list[float] = field(default_factory=list)
    photons: list[int] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        # JSON has no infinities: an unbounded margin is kept as the text "inf"/"-inf"
        m = self.min_margin
        return {"not_passing": [list(t) for t in self.not_passing],
                "min_margin": m if math.isfinite(m) else str(m),
                "rows": self.rows, "seconds": self.seconds, "photons": self.photons}


def rule_margin(row: dict[str, Any]) -> float:
    """Log-margin of one regulation row by its 95 % interval: ln(lo / min) for a minimum,
    ln(max / hi) for a maximum, the smaller of the two; ``inf`` without a limit. A zone is
    judged at its brightest probe (``max_interval_cd``) for a maximum."""
    lim = row.get("limit") or {}
    lo, hi = rule_interval(row)
    m = math.inf
    if lim.get("min"):
        if not lo > 0:  # NaN or no light: the minimum is not met
            return -math.inf
        m = min(m, math.log(lo / float(lim["min"])))
    if lim.get("max"):
        if math.isnan(hi):
            return -math.inf
        if hi > 0:
            m = min(m, math.log(float(lim["max"]) / hi))
    return m


def check_lamp(glb: str | Path, regulation: str, *, photons: int = 32_000_000,
               resolution: tuple[int, int] = (320, 128), seeds: Sequence[int] = (1, 2, 3),
               traffic: str = "right", aperture: float = 0.15, aim: bool = False,
               note: Callable[[str], None] | None = None, until: str | None = None
               ) -> LampCheck:
    """``lightsim simulate GLB --photons … --resolution … --regulation … --seed S`` for
    every seed (in this process, nothing written but a temporary folder), collected;
    ``until="decided"``: each run stops when its verdicts are decided (``--until
    decided``, ``photons`` the cap — deterministic for a seed, so a design stays
    reproducible)."""
    out = LampCheck()
    work = Path(tempfile.mkdtemp(prefix="lightsim-check-"))
    try:
        for s in seeds:
            opts = SimulateOptions(str(glb), out_dir=str(work / f"seed{s}"), photons=photons,
                                   resolution=tuple(resolution), regulation=regulation,
                                   traffic=traffic, aperture=aperture, aim=aim,
                                   outputs=("json",), config={"seed": int(s)}, until=until)
            try:
                sim = run_simulation(opts, analyses=for_options(opts))
            except InputError as exc:  # e.g. no cut-off to aim at: the worst lamp
                out.not_passing.append((int(s), regulation, "check", f"error: {exc}"))
                out.min_margin = -math.inf
                if note is not None:
                    note(f"check seed {s}: {exc}")
                continue
            summary = sim.summary
            out.seconds.append(float(summary.get("seconds") or 0.0))
            out.photons.append(int(summary.get("photons") or 0))
            bad = 0
            for key in (k for k in summary if k.startswith("regulation")):
                table = summary[key]
                for row in table["results"]:
                    if row.get("verdict") == "info" or not row.get("limit"):
                        continue
                    out.rows += 1
                    out.min_margin = min(out.min_margin, rule_margin(row))
                    if row["verdict"] != "pass":
                        bad += 1
                        out.not_passing.append((int(s), str(table["ruleset"]),
                                                str(row["name"]), str(row["verdict"])))
            # annex 9's linearity is a condition of the lamp too (the cut-off's three
            # scans within 0.2°), though not a row of the rule sets' tables
            cut = summary.get("cutoff") or {}
            if cut.get("linear") is False:
                bad += 1
                out.not_passing.append((int(s), "annex 9", "linearity",
                                        f"fail ({float(cut.get('spread_deg') or 0):.3f}°)"))
            if note is not None:
                note(f"check seed {s}: {bad} rows not passing, {out.seconds[-1]:.0f} s, "
                     f"{out.photons[-1]:,} photons")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return out


def choose(checks: Sequence[LampCheck], objectives: Sequence[float]) -> int:
    """Index of the best lamp: fewest rows not passing, then the largest smallest margin,
    then the lowest design J (NaN last)."""
    if not checks or len(checks) != len(objectives):
        raise ValueError("choose: one check and one objective per lamp")

    def key(i: int) -> tuple[int, float, float]:
        j = objectives[i]
        return (len(checks[i].not_passing), -checks[i].min_margin,
                j if math.isfinite(j) else math.inf)

    return min(range(len(checks)), key=key)
