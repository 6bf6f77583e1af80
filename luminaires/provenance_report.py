"""``--provenance``: every regulation rule's light broken down by the path it took.

An :class:`~lightsim.analysis.Analysis` next to the rule sets' tables: before the run it
asks the sets to keep path signatures and count them in the detector apertures
(:mod:`lightsim.provenance`); after it, for every rule of every rule set it splits the
quantity the rule reads into path classes:

=============  ================================================================
rule kind      quantity split
=============  ================================================================
point          the point's aperture intensity
zone           the aperture of the zone sample that governs the verdict (the one
               the table reports: the maximum for a "≤" zone, the minimum for "≥")
sum            the sum of its points' apertures (``1+2+3``)
measure HV     the H-V aperture (Imax: not split, a raster tile)
relation       not split (its two sides are their own rows)
=============  ================================================================

Each class has its value (cd, mean over the interleave sets), its Student-t interval
over the sets and its share; the classes add up to the table's value (``sum_cd``; the
same photons split, so to rounding). ``summary.json["provenance"]`` holds the tables;
``lightsim report --provenance RULE RUN_DIR`` prints one.

=================  =====  ========  ====================================================
parameter          unit   default   meaning
=================  =====  ========  ====================================================
``confidence``     –      0.95      two-sided level of the class intervals
``min_share``      –      0.02      classes below this share are pooled as "other"
``top``            –      8         classes listed per rule at most (the rest: "other")
=================  =====  ========  ====================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rich.table import Table

from lightsim.analysis import AnalysisReport, FinishedRun
from lightsim.engine.apertures import layout_from_config
from lightsim.errors import InputError
from lightsim.provenance import PATH_LENGTH, PathElements, class_values, share_table

from .regulations.check import RegulationAnalysis, regulation_check

__all__ = ["ProvenanceAnalysis", "failing_breakdowns", "format_breakdown", "rule_breakdown"]


def _quantities(reg: dict[str, Any], offset: int) -> list[tuple[str, list[int]]]:
    """(rule name, aperture indices adding up to the value the rule reads) per splittable
    row of a regulation table ``reg`` whose apertures start at ``offset``."""
    probes = reg["_probes"]
    out = []
    for row in reg["results"]:
        name, kind = row["name"], row.get("kind")
        if kind in ("point", "zone"):
            idx = np.asarray(probes.indices(name))
            if len(idx) == 0:
                continue
            if kind == "zone" and row.get("h_deg") is not None:
                d = ((probes.h_deg[idx] - row["h_deg"]) ** 2
                     + (probes.v_deg[idx] - row["v_deg"]) ** 2)
                idx = idx[[int(np.argmin(d))]]
            out.append((name, [offset + int(idx[0])]))
        elif kind == "sum":
            members = [np.asarray(probes.indices(p)) for p in name.split("+")]
            if all(len(m) for m in members):
                out.append((name, [offset + int(m[0]) for m in members]))
        elif kind == "measure" and name == "HV":
            out.append((name, [offset + len(probes)]))
    return out


@dataclass
class ProvenanceAnalysis:
    """``--provenance`` for the run's rule sets (see the module docstring)."""

    regulations: list[RegulationAnalysis]
    confidence: float = 0.95
    name: str = "provenance"
    min_share: float = 0.02
    top: int = 8
    tables: dict[str, Any] = field(default_factory=dict, init=False)

    def prepare(self, config: Any, scene: Any) -> Any:
        """Path signatures kept and counted per aperture."""
        return config.with_(path_length=PATH_LENGTH)

    def report(self, run: FinishedRun, out: Path) -> AnalysisReport:
        session = run.session
        per_set = session.backend.paths()
        stats = session.backend.stats()
        sets = sorted(stats)
        emitted = np.array([stats[s]["emitted"] for s in sets], np.float64)
        layout = layout_from_config(session.config, session.scene.wall.distance_m)
        elements = PathElements.from_scene(session.scene)
        rulesets: dict[str, Any] = {}
        for an in self.regulations:
            reg = regulation_check(session, run.lux, an.ruleset, an.traffic, an.aim,
                                   an.confidence, an.offset)
            quantities = _quantities(reg, an.offset)
            shift = -float(reg["aim"]["dv_deg"])
            labels, values = class_values({s: per_set.get(s) for s in sets}, emitted,
                                          layout, elements, shift,
                                          [q for _, q in quantities])
            rows = {r["name"]: r for r in reg["results"]}
            rules = {}
            for q, (name, _) in enumerate(quantities):
                classes = share_table(labels, values, q, self.confidence, self.min_share,
                                      self.top)
                row = rows[name]
                total = float(values[:, :, q].sum(axis=1).mean()) if len(sets) else 0.0
                rules[name] = {"kind": row.get("kind"), "verdict": row.get("verdict"),
                               "h_deg": row.get("h_deg"), "v_deg": row.get("v_deg"),
                               "value_cd": row.get("value_cd"),
                               "interval_cd": row.get("interval_cd"),
                               "sum_cd": total, "classes": classes}
            rulesets[reg["ruleset"]] = rules
        summary = {"confidence": self.confidence, "path_length": PATH_LENGTH,
                   "parts": sorted({elements.part_name(e) for e in range(len(elements.names))}
                                   | set(elements.emitters)),
                   "rulesets": rulesets}
        self.tables = summary
        return AnalysisReport(summary)


def rule_breakdown(summary: dict[str, Any], rule: str, part: str | None = None
                   ) -> list[tuple[str, dict[str, Any]]]:
    """The breakdowns of ``rule`` in a run's ``summary.json`` (one per rule set naming
    it), classes limited to those meeting ``part`` if given.

    Raises
    ------
    InputError
        The run was made without ``--provenance``, no rule set has ``rule``, or ``part``
        is not a part of the lamp.
    """
    prov = summary.get("provenance")
    if not isinstance(prov, dict) or "rulesets" not in prov:
        raise InputError("this run was made without --provenance: run lightsim simulate "
                         "--provenance --regulation … to break its rules down by path")
    if part is not None and part not in prov.get("parts", []):
        raise InputError(f"no part '{part}' in the lamp (parts: "
                         f"{', '.join(prov.get('parts', []))})")
    found = [(rs, rules[rule]) for rs, rules in prov["rulesets"].items() if rule in rules]
    if not found:
        names = sorted({r for rules in prov["rulesets"].values() for r in rules})
        raise InputError(f"no rule '{rule}' in the run's rule sets (rules: "
                         f"{', '.join(names)})")
    if part is None:
        return found
    out = []
    for rs, b in found:
        keep = [c for c in b["classes"] if _meets(c["class"], part)]
        out.append((rs, {**b, "classes": keep}))
    return out


def _meets(label: str, part: str) -> bool:
    steps = [s.split(" (")[0].split(" facet ")[0].removesuffix(" TIR")
             for s in label.split(" → ")]
    return part in steps


def _cd(x: float) -> str:
    return f"{x:,.4g}" if abs(x) < 1e4 else f"{x:,.0f}"


def format_breakdown(ruleset: str, rule: str, b: dict[str, Any]) -> Table:
    """A rich table of one rule's path classes."""
    lo, hi = b.get("interval_cd") or (float("nan"), float("nan"))
    title = (f"{ruleset} {rule}: {_cd(b['value_cd'])} cd [{_cd(lo)}, {_cd(hi)}] "
             f"({b.get('verdict')}); classes add up to {_cd(b['sum_cd'])} cd")
    t = Table(title=title, title_justify="left")
    t.add_column("path class")
    t.add_column("cd", justify="right")
    t.add_column("interval (cd)", justify="right")
    t.add_column("share", justify="right")
    for c in b["classes"]:
        name = c["class"] + (f" ({c['classes']} classes)" if "classes" in c else "")
        t.add_row(name, _cd(c["value_cd"]),
                  f"[{_cd(c['interval_cd'][0])}, {_cd(c['interval_cd'][1])}]",
                  f"{c['share']:.1%}")
    return t


def failing_breakdowns(summary: dict[str, Any]) -> list[Table]:
    """Tables of every failing or uncertain rule of a ``--provenance`` run."""
    prov = summary.get("provenance") or {}
    return [format_breakdown(rs, name, b)
            for rs, rules in (prov.get("rulesets") or {}).items()
            for name, b in rules.items() if b.get("verdict") in ("fail", "uncertain")]
