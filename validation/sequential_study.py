"""Wrong verdicts under repeated looks: ``--until decided`` against plain peeking.

A run that stops once every verdict is decided looks at its verdicts many times. This
module counts how often such a run decides wrongly, on rules whose truth is known, and
compares it with the nominal rate α/2 per decided verdict (2.5 % at 95 %):

* :func:`simulated_looks` — no tracing: photon counts of known intensities are drawn as
  Poisson processes per interleave set, looked at on the schedule of
  :class:`~lightsim.luminaires.regulations.sequential.LookSchedule` and judged by the
  product's own rule evaluation (:func:`~lightsim.luminaires.regulations.evaluate` and
  :func:`~lightsim.luminaires.regulations.sequential.merge_row`). Rules sit exactly at,
  just inside and just outside their limits — the hardest cases. The same draws are also
  judged by *peeking*: the plain 95 % table at every look, stopping at the first look
  where everything is decided. Peeking inflates the wrong verdicts; the rule must not.
* :func:`until_study` — the real thing: synthetic Type A lamps
  (:func:`~lightsim.validation.coverage.synthetic_lamp`) simulated with ``--until
  decided`` (point source, detector apertures), every decided verdict compared with the
  exact one (:func:`~lightsim.validation.coverage.exact_truths`).

Parameters
----------
==================  =====  ========  ====================================================
name                unit   default   meaning
==================  =====  ========  ====================================================
runs                –      400       simulated runs (:func:`simulated_looks`)
sets                –      16        interleave sets S
first_count         –      4         photons a probe of :data:`STUDY_LIMIT_CD` catches
                                     (all sets) at the first look
looks               –      10        planned looks (doubling) + the last
confidence          –      0.95      the verdicts' confidence
lamps, seeds        –      4, 2      synthetic lamps × photon seeds (:func:`until_study`)
guide               –      False     with ``--guide points`` (:func:`until_study`)
cap_photons         –      4·10⁶     photon cap of every lamp run
==================  =====  ========  ====================================================
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import binom

from lightsim.luminaires.analyses import for_options
from lightsim.luminaires.photometric import read_ies, write_ies
from lightsim.luminaires.regulations import evaluate, load_ruleset, probe_points
from lightsim.luminaires.regulations.sequential import LookSchedule, merge_row
from lightsim.simulate import SimulateOptions, run_simulation
from lightsim.validation.coverage import (
    DEFAULT_RULESETS,
    RULE_KINDS,
    aperture_truth,
    distinct,
    exact_truths,
    rule_outcomes,
    synthetic_lamp,
)

__all__ = ["STUDY_LIMIT_CD", "STUDY_RULES", "LookStudy", "UntilRun", "UntilStudy",
           "simulated_looks", "study_truths", "until_study"]

STUDY_LIMIT_CD = 100.0
"""The limit of every rule of the simulated rule set (cd)."""

STUDY_RULES = """\
schema = "lightsim-ruleset-1"
id = "sequential-study"
title = "Rules at, inside and outside their limits (simulated looks)"
version = "1"
source = "lightsim.validation.sequential_study"
traffic = "right"

[[point]]
name = "at-max"
h = 0.0
v = 0.0
max = 100

[[point]]
name = "at-min"
h = 1.0
v = 0.0
min = 100

[[point]]
name = "below-max"
h = 2.0
v = 0.0
max = 100

[[point]]
name = "above-max"
h = 3.0
v = 0.0
max = 100

[[point]]
name = "above-min"
h = 4.0
v = 0.0
min = 100

[[point]]
name = "dim"
h = 5.0
v = 0.0
max = 100

[[zone]]
name = "zone-at-max"
polygon = [[6.0, 0.0], [6.5, 0.0], [6.5, 0.5], [6.0, 0.5]]
max = 100

[[sum]]
name = "sum-at-min"
points = ["at-max", "at-min"]
min = 200

[[relation]]
name = "at-min <= at-max"
lhs = "at-min"
op = "<="
factor = 1.0
rhs = "at-max"
"""
"""The simulated rule set: limits of 100 cd (a relation at its limit included)."""

#: true intensity (cd) of every point of :data:`STUDY_RULES` (zone probes: 100)
STUDY_TRUTH = {"at-max": 100.0, "at-min": 100.0, "below-max": 92.0, "above-max": 108.0,
               "above-min": 108.0, "dim": 20.0}


def study_truths(rs: Any, probes: Any) -> tuple[np.ndarray, dict[str, str]]:
    """(true intensity of every probe in cd, true verdict of every rule) of the simulated
    rule set: a rule exactly at its limit passes (limits are inclusive)."""
    truth = np.array([STUDY_TRUTH.get(lab, STUDY_LIMIT_CD) for lab in probes.labels])
    verdicts = {str(r["name"]): str(r["verdict"])
                for r in evaluate(rs, probes, truth[None, :])}
    return truth, verdicts


@dataclass
class LookStudy:
    """Wrong verdicts of simulated runs, the stopping rule's and peeking's.

    ``decided`` and ``wrong`` count (run, rule) pairs whose final verdict is pass or fail,
    and of those the ones against the truth, by rule name."""

    runs: int
    looks: int
    confidence: float
    decided: dict[str, int] = field(default_factory=dict)
    wrong: dict[str, int] = field(default_factory=dict)
    peek_decided: dict[str, int] = field(default_factory=dict)
    peek_wrong: dict[str, int] = field(default_factory=dict)
    stopped_early: int = 0
    wrong_looks: dict[str, list[int]] = field(default_factory=dict)  # look that decided

    @property
    def nominal(self) -> float:
        """The per-verdict rate the rule promises, (1 − confidence)/2."""
        return 0.5 * (1.0 - self.confidence)

    def wrong_total(self, peek: bool = False) -> int:
        return sum((self.peek_wrong if peek else self.wrong).values())

    def rate(self, name: str, peek: bool = False) -> float:
        """Wrong verdicts per run of rule ``name`` (an undecided one is never wrong)."""
        return (self.peek_wrong if peek else self.wrong).get(name, 0) / max(self.runs, 1)

    def allowed(self, level: float = 0.999) -> int:
        """The most wrong verdicts of one rule the nominal rate explains over the runs:
        the ``level`` quantile of Binomial(runs, α/2)."""
        return int(binom.ppf(level, self.runs, self.nominal))

    def to_dict(self) -> dict[str, Any]:
        return {"runs": self.runs, "looks": self.looks, "confidence": self.confidence,
                "nominal_rate": self.nominal, "decided": self.decided, "wrong": self.wrong,
                "peek_decided": self.peek_decided, "peek_wrong": self.peek_wrong,
                "stopped_early": self.stopped_early, "wrong_looks": self.wrong_looks}


def _stats(counts: np.ndarray, worth: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-set values (S, P) cd and photon statistics (4, P) of equal-weight photons:
    ``counts`` (S, P) per set, each photon worth ``worth`` cd of the pooled mean."""
    S = counts.shape[0]
    per_set = counts * worth * S
    n = counts.sum(axis=0).astype(np.float64)
    mean = per_set.mean(axis=0)
    return per_set, np.stack([n, np.full(n.shape, worth), np.full(n.shape, worth), mean])


def simulated_looks(runs: int = 400, *, sets: int = 16, first_count: float = 4.0,
                    looks: int = 10, confidence: float = 0.95, seed: int = 1,
                    progress: Callable[[int], None] | None = None) -> LookStudy:
    """Simulate ``runs`` runs of the study's rule set (:data:`STUDY_RULES`) on the look
    schedule and count wrong verdicts, with the stopping rule and with peeking (module
    docstring).

    Photons arrive per set as Poisson processes: a probe of intensity I catches on
    average I / :data:`STUDY_LIMIT_CD` × ``first_count`` photons (all sets) by the first
    look and twice as many by every next one; every photon is worth the same.
    """
    if runs < 1 or sets < 2 or looks < 2 or not first_count > 0:
        raise ValueError("a look study needs ≥ 1 run, ≥ 2 sets, ≥ 2 looks, photons > 0")
    with tempfile.TemporaryDirectory(prefix="lightsim-looks-") as tmp:
        path = Path(tmp) / "sequential-study.toml"
        path.write_text(STUDY_RULES)
        rs = load_ruleset(path)
    probes = probe_points(rs)
    truth, verdicts = study_truths(rs, probes)
    schedule = LookSchedule(1, 2 ** (looks - 1))  # counts 1, 2, 4, …: looks − 1 + last
    counts_at = [*schedule.planned(), schedule.cap_photons]
    level = schedule.level(confidence)
    rng = np.random.default_rng([seed, 0x5E9])
    study = LookStudy(runs, schedule.looks, confidence)
    rate = truth / STUDY_LIMIT_CD * first_count / sets  # per set at the first look
    for run in range(runs):
        counts = np.zeros((sets, len(probes)))
        rows: dict[str, dict[str, Any]] = {}
        peek: dict[str, str] | None = None
        done = 0
        for k, n in enumerate(counts_at):
            counts += rng.poisson(rate[None, :] * (n - done), size=counts.shape)
            done = n
            worth = STUDY_LIMIT_CD / (first_count * n)  # one photon's share of the mean
            per_set, stats = _stats(counts, worth)
            res = evaluate(rs, probes, per_set, confidence=level, count_stats=stats)
            rows = {str(r["name"]): merge_row(rows.get(str(r["name"])), r, n) for r in res}
            if peek is None:  # peeking: the plain table, frozen where all is decided
                plain = evaluate(rs, probes, per_set, confidence=confidence,
                                 count_stats=stats)
                if all(r["verdict"] != "uncertain" for r in plain) or k == len(counts_at) - 1:
                    peek = {str(r["name"]): str(r["verdict"]) for r in plain}
            if all(r["decided"] for r in rows.values()):
                study.stopped_early += int(k < len(counts_at) - 1)
                break
        for name, row in rows.items():
            _count(study.decided, study.wrong, name, str(row["verdict"]), verdicts[name])
            if row["decided"] and row["verdict"] != verdicts[name]:
                look = counts_at.index(row["decided_at_photons"]) + 1
                study.wrong_looks.setdefault(name, []).append(look)
        for name, v in (peek or {}).items():
            _count(study.peek_decided, study.peek_wrong, name, v, verdicts[name])
        if progress is not None:
            progress(run)
    return study


def _count(decided: dict[str, int], wrong: dict[str, int], name: str, verdict: str,
           truth: str) -> None:
    decided.setdefault(name, 0)
    wrong.setdefault(name, 0)
    if verdict in ("pass", "fail"):
        decided[name] += 1
        wrong[name] += int(verdict != truth)


# ---- synthetic lamps, traced ---------------------------------------------------------------
@dataclass(frozen=True)
class UntilRun:
    """One ``--until decided`` run of a synthetic lamp: photons used, whether everything
    was decided, and every rule's outcome against its exact truth."""

    lamp: int
    seed: int
    photons: int
    decided: bool
    seconds: float
    outcomes: tuple[Any, ...]

    @property
    def wrong(self) -> int:
        return sum(o.wrong for o in self.outcomes)

    @property
    def decisive(self) -> int:
        return sum(o.verdict in ("pass", "fail") and o.truth_verdict in ("pass", "fail")
                   for o in self.outcomes)


@dataclass
class UntilStudy:
    """Every run of :func:`until_study`."""

    runs: list[UntilRun]
    confidence: float = 0.95

    @property
    def wrong(self) -> int:
        return sum(r.wrong for r in self.runs)

    @property
    def decisive(self) -> int:
        return sum(r.decisive for r in self.runs)

    def allowed(self, level: float = 0.999) -> int:
        """The most wrong verdicts the nominal rate α/2 explains over the decisive ones."""
        return int(binom.ppf(level, max(self.decisive, 1), 0.5 * (1.0 - self.confidence)))

    def to_dict(self) -> dict[str, Any]:
        return {"runs": [{"lamp": r.lamp, "seed": r.seed, "photons": r.photons,
                          "decided": r.decided, "seconds": r.seconds, "wrong": r.wrong,
                          "decisive": r.decisive} for r in self.runs],
                "wrong": self.wrong, "decisive": self.decisive,
                "nominal_wrong": 0.5 * (1.0 - self.confidence) * self.decisive}


def until_study(lamps: int = 4, seeds: int = 2, *, cap_photons: int = 4_000_000,
                ruleset: str = DEFAULT_RULESETS, seed: int = 1, zone_quad: int = 16,
                resolution: tuple[int, int] = (160, 64), guide: bool = False,
                progress: Callable[[UntilRun], None] | None = None) -> UntilStudy:
    """Simulate ``lamps`` synthetic lamps at ``seeds`` photon seeds each with ``--until
    decided`` (capped at ``cap_photons``; ``guide``: with ``--guide points``) and judge
    every verdict against the exact one."""
    if lamps < 1 or seeds < 1 or cap_photons < 1000:
        raise ValueError("an until study needs ≥ 1 lamp, ≥ 1 seed and ≥ 1000 photons")
    rng = np.random.default_rng([seed, 0xDEC1])
    out: list[UntilRun] = []
    with tempfile.TemporaryDirectory(prefix="lightsim-until-") as tmp:
        for n in range(lamps):
            grid, _ = synthetic_lamp(rng)
            path = write_ies(Path(tmp) / f"lamp{n:03d}.ies", grid)
            truths: dict[str, Any] = {}
            for s in range(seeds):
                opts = SimulateOptions(str(path), out_dir=str(Path(tmp) / f"run{n}-{s}"),
                                       photons=int(cap_photons), resolution=resolution,
                                       regulation=ruleset, until="decided",
                                       outputs=("json",),
                                       config={"seed": int(seed + 100 * n + s),
                                               "estimator": "bin",
                                               "guide": "points" if guide else "off"})
                summary = run_simulation(opts, analyses=for_options(opts)).summary
                outcomes = []
                for key in (k for k in summary if k.startswith("regulation")):
                    table = summary[key]
                    rs_id = str(table["ruleset"])
                    if rs_id not in truths:
                        truths[rs_id] = _exact(rs_id, table, path, zone_quad, summary)
                    outcomes += rule_outcomes(rs_id, table["results"], truths[rs_id])
                until = summary["until"]
                run = UntilRun(n, s, int(until["photons"]), bool(until["decided"]),
                               float(summary["seconds"]),
                               tuple(o for o in distinct(outcomes) if o.kind in RULE_KINDS))
                out.append(run)
                if progress is not None:
                    progress(run)
    return UntilStudy(out)


def _exact(rs_id: str, table: dict[str, Any], lamp: Path, zone_quad: int,
           summary: dict[str, Any]) -> dict[str, tuple[float | None, str | None]]:
    """Exact value and verdict of every rule of ``rs_id`` for the lamp file."""
    rs = load_ruleset(rs_id)
    probes = probe_points(rs, table["traffic"], frame=summary["wall"])
    exact = aperture_truth(read_ies(lamp), probes.h_deg, probes.v_deg,
                           float(table["method"].get("size_deg", 0.15)), zone_quad)
    return exact_truths(rs, probes, exact)
