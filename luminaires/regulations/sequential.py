"""Verdicts decided while the photons come in: the stopping rule of ``--until decided``.

A run with ``--until decided`` looks at its verdicts again and again as photons arrive and
stops at the first look where every rule of every requested rule set — points, sums, zone
maxima and minima, relations — is "pass" or "fail". Looking many times and stopping on
what one sees would make wrong verdicts more likely than the nominal α/2 if every look
used the plain 95 % intervals: each look is another chance for a bound to be wrong. The
rule here keeps every verdict's error at α/2 over all looks together.

Method: an error budget spent evenly over a fixed look schedule
---------------------------------------------------------------------
* **Looks** (:class:`LookSchedule`) come at photon counts fixed before the run: the
  run's first frame (``first_photons``), then every doubling, as long as they lie below
  the photon cap, and a last look at the cap (or wherever the run ends: a time cap, the
  memory, an interruption). That is K = ⌈log₂(cap / first)⌉ + 1 looks at most (12 for a
  200 k-photon frame and the default 400 M cap).
* **Budget.** Look k evaluates every rule (:func:`~lightsim.luminaires.regulations.
  evaluate`, the rules of the fixed-sample table) at the level 1 − α/K: each one-sided
  bound is wrong with probability at most α/(2K). Whatever happens at the other looks,
  the probability that *some* look's bound on a rule is wrong is at most K · α/(2K) =
  α/2 (Bonferroni over the looks; no independence between the looks is needed, and the
  looks share their photons).
* **Running intervals.** A rule's interval is the intersection of its intervals at every
  look so far (a confidence sequence: it holds at every look at once with probability ≥
  1 − α), and its verdict is read from that intersection. So a verdict, once decided,
  stays decided, and it is wrong with probability at most α/2 — the same promise as the
  fixed-sample table's, kept under the repeated looks.

Why this and not a spending sequence over infinitely many looks (α_k = α·6/(π²k²), or the
stitched boundaries of Howard et al. 2021): the run has a photon cap — ``--photons`` or
the default of :data:`DEFAULT_CAP_PHOTONS` — so the looks are finitely many and known in
advance, and an even split gives the late looks, where the hard rules decide, a far
larger share: α/12 each instead of α·6/(π²·81) = α/133 at the ninth look (51 M photons).
On a rule that needs N photons at the plain 95 % level, the looks cost about 3.0 × N
(normal bounds) or 3.5 × N (Student-t with 15 degrees of freedom) on average; the
6/(π²k²) sequence costs 4.4 × and 6.0 ×, and looking without a budget — invalid — 1.4 ×
(the doubling schedule's own overshoot).

Guiding
-------
With ``--guide points`` (:mod:`lightsim.engine.guiding`) the looks also steer the
photons: before the first frame towards every test point and zone (:class:`GuideTargets`,
one box each), after every look only towards the boxes of the rules still open
(:meth:`VerdictRule.steer`); a decided rule draws no more guided photons. The guide of a
frame is fixed before the frame is shot and every photon carries 1/p, so each look's
bounds hold at their level as without guiding, and the budget above is unchanged.

What a look cannot promise
--------------------------
* The per-look bounds are the table's (:class:`lightsim.report.IntensityEvidence`): the
  budget is exactly as good as they are at the level it asks.
* ``--aim`` places the apertures where each look's written map puts the cut-off: when the
  rounded shift changes between looks, the quantities change, and the rule set's running
  intervals start again from that look (its budget share already spent).
* An empty intersection means some bound was wrong; that rule starts again from the
  current look (counted in ``resets``).

Parameters
----------
==================  =====  ===================  =============================================
name                unit   default              meaning
==================  =====  ===================  =============================================
``confidence``      –      0.95                 every verdict is wrong with probability at
                                                most (1 − confidence)/2 over all looks
``first_photons``   –      the run's frame      photons of the first planned look
``cap_photons``     –      ``--photons``, else  photons of the last look; the budget is
                           4·10⁸                split over the looks up to it
``growth``          –      2                    photons between planned looks grow by this
==================  =====  ===================  =============================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lightsim.analysis import AnalysisReport
from lightsim.engine.guiding import run_targets, target_rows, targets_at
from lightsim.errors import InputError
from lightsim.render.frame import luminous
from lightsim.simulate import UNTIL_CAP_PHOTONS
from lightsim.wall import wall_m_from_deg

from .check import evaluate_probe_values, measure_probes, regulation_check, regulation_probes
from .evaluate import limit_verdict, probe_points
from .ruleset import RuleSet, load_ruleset

__all__ = ["DEFAULT_CAP_PHOTONS", "UNTIL_CHOICES", "GuideTargets", "LookSchedule", "OpenRule",
           "VerdictRule", "merge_row", "probe_regions"]

UNTIL_CHOICES = ("decided", "verdict")
"""What ``--until`` may name (:class:`VerdictRule`'s ``stop``)."""
DEFAULT_CAP_PHOTONS = UNTIL_CAP_PHOTONS
"""Photon cap of ``--until decided`` without ``--photons``: the looks are counted up to it
(a rule exactly at its limit never decides; the cap ends the run)."""
GROWTH = 2.0
"""Photons between two planned looks grow by this factor."""
MAX_LOOKS = 64
"""No schedule plans more looks than this (a guard; 2⁶³ photons would be needed)."""
RUNNING_KEYS = ("interval_cd", "max_interval_cd", "reference_interval_cd",
                "margin_interval_cd")
"""A row's intervals that are intersected over the looks (where the row has them)."""


@dataclass(frozen=True)
class LookSchedule:
    """The photon counts at which a run looks at its verdicts, fixed before it starts.

    Planned looks at ``first_photons`` · ``growth``^j below ``cap_photons``, and one last
    look at the end of the run: :attr:`looks` in all, each given α / :attr:`looks`.
    """

    first_photons: int
    cap_photons: int
    growth: float = GROWTH

    def __post_init__(self) -> None:
        if not (self.first_photons >= 1 and self.cap_photons >= 1):
            raise InputError(f"a look schedule needs ≥ 1 photon per look and cap, got "
                             f"{self.first_photons} and {self.cap_photons}")
        if not (math.isfinite(self.growth) and self.growth > 1.0):
            raise InputError(f"look growth must be > 1, got {self.growth}")

    def planned(self) -> tuple[int, ...]:
        """Photon counts of the planned looks (each below the cap)."""
        out: list[int] = []
        n = float(self.first_photons)
        while n < self.cap_photons and len(out) < MAX_LOOKS - 1:
            out.append(round(n))
            n *= self.growth
        return tuple(out)

    @property
    def looks(self) -> int:
        """Looks the budget is split over: the planned ones and the last."""
        return len(self.planned()) + 1

    def level(self, confidence: float) -> float:
        """Two-sided level of every look's intervals: 1 − (1 − confidence)/K."""
        return 1.0 - (1.0 - confidence) / self.looks

    def due(self, photons: int, last: int) -> bool:
        """Whether a call at ``photons`` (the last look at ``last``) is a planned look:
        a planned count lies in (last, photons]. Several in one step make one look (the
        others' shares stay unspent)."""
        return any(last < p <= photons for p in self.planned())


@dataclass(frozen=True)
class OpenRule:
    """A rule still undecided, and where its light is measured.

    Attributes
    ----------
    ruleset, name, kind : str
        The rule (kind: point, zone, sum, relation).
    apertures : tuple of int
        Indices into the run's detector apertures (``RunConfig.apertures``) of every
        probe the rule reads (empty when the run estimates by kNN).
    rects_deg : tuple of (h0, h1, v0, v1)
        Those apertures on the wall, in wall degrees, where they are read now (after
        any aim).
    points_deg : tuple of (h, v)
        The probe directions (deg, the aimed pattern's).
    regions_deg : tuple of (h0, h1, v0, v1)
        One rectangle per test point or zone the rule reads (a zone's: the box around
        its samples' apertures), in wall degrees: where ``--guide points`` sends photons.
    """

    ruleset: str
    name: str
    kind: str
    apertures: tuple[int, ...]
    rects_deg: tuple[tuple[float, float, float, float], ...]
    points_deg: tuple[tuple[float, float], ...]
    regions_deg: tuple[tuple[float, float, float, float], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"ruleset": self.ruleset, "name": self.name, "kind": self.kind,
                "apertures": list(self.apertures),
                "rects_deg": [list(r) for r in self.rects_deg],
                "points_deg": [list(p) for p in self.points_deg],
                "regions_deg": [list(r) for r in self.regions_deg]}


def _verdict_interval(row: dict[str, Any]) -> tuple[str, float | None, float | None]:
    """(key of the interval the verdict reads, its minimum, its maximum)."""
    if row.get("kind") == "relation":
        return "margin_interval_cd", *((None, 0.0) if row["op"] == "<=" else (0.0, None))
    lim = row.get("limit") or {}
    return "interval_cd", lim.get("min"), lim.get("max")


def merge_row(prev: dict[str, Any] | None, new: dict[str, Any], photons: int
              ) -> dict[str, Any]:
    """One rule's row after a look: ``new`` (the look's evaluation) with every interval
    intersected with ``prev``'s (the running row before it; None at the first look) and
    the verdict read from the intersection.

    Adds ``decided`` (pass or fail), ``decided_at_photons`` (the look that decided it;
    None while open) and ``resets`` (looks whose interval missed the running one, where
    the row started again)."""
    out = dict(new)
    reset = False
    if prev is not None:
        for key in RUNNING_KEYS:
            if key in new and key in prev:
                lo = max(float(prev[key][0]), float(new[key][0]))
                hi = min(float(prev[key][1]), float(new[key][1]))
                reset |= lo > hi
                out[key] = [lo, hi]
        if reset:  # some look's bound was wrong: start again from this look
            out = dict(new)
    if out.get("kind") == "relation":  # the ratio from the running sides
        (l_lo, l_hi), (r_lo, r_hi) = out["interval_cd"], out["reference_interval_cd"]
        out["ratio_interval"] = [float(l_lo / r_hi) if r_hi > 0 else None,
                                 float(l_hi / r_lo) if r_lo > 0 else None]
    key, mn, mx = _verdict_interval(out)
    lo, hi = out[key]
    out["verdict"] = limit_verdict(float(lo), float(hi), mn, mx)
    decided = out["verdict"] in ("pass", "fail")
    kept = (prev is not None and not reset and prev.get("decided")
            and prev.get("verdict") == out["verdict"])
    out["decided"] = decided
    out["decided_at_photons"] = (prev["decided_at_photons"] if kept
                                 else int(photons) if decided else None)
    out["resets"] = int((prev or {}).get("resets", 0)) + int(reset)
    return out


@dataclass
class _Check:
    """One rule set's part of the rule: what it reads and its running rows."""

    ruleset: str
    traffic: str
    aim: bool
    offset: int
    rules: RuleSet
    probes: Any = None
    rows: dict[str, dict[str, Any]] = field(default_factory=dict)
    shift_deg: float | None = None  # where the apertures were read at the last look
    hv: np.ndarray | None = None
    note: str | None = None  # why the last look could not evaluate (no cut-off to aim at)


class VerdictRule:
    """``--until decided``: a :class:`~lightsim.engine.server.StoppingRule` on the verdicts
    of one or more rule sets (see the module docstring).

    Build it, :meth:`add` every rule set (the regulation analyses do, before the run),
    :meth:`bind` it to the session with the photon cap, and hand it to
    :meth:`Session.run <lightsim.engine.server.Session.run>`. The session asks
    :meth:`satisfied` at its estimates; the rule looks at the verdicts where its
    :class:`LookSchedule` plans a look. After the run, :meth:`check` gives each rule set's
    table (a last look at the final photons first, if they are new), :meth:`undecided`
    the rules still open and their apertures, :meth:`summary` the record for
    ``summary.json``.

    Parameters
    ----------
    confidence : float
        Every verdict is wrong with probability at most (1 − confidence)/2 over all looks.
    growth : float
        Photons between planned looks grow by this factor.
    stop : str
        ``decided``: the run stops when every rule is decided. ``verdict``: when the
        lamp's verdict over every rule set is decided — some rule decided "fail" (the lamp
        fails whatever the others read), or every rule decided; the rules still open then
        read "uncertain".
    """

    def __init__(self, confidence: float = 0.95, growth: float = GROWTH,
                 stop: str = "decided") -> None:
        if not (0.0 < confidence < 1.0):
            raise InputError(f"confidence must lie in (0, 1), got {confidence}")
        if stop not in UNTIL_CHOICES:
            raise InputError(f"--until: choose one of {', '.join(UNTIL_CHOICES)}, not {stop!r}")
        self.stop = stop
        self.confidence = float(confidence)
        self.growth = float(growth)
        self.checks: list[_Check] = []
        self.session: Any = None
        self.schedule: LookSchedule | None = None
        self.last_photons = 0  # photons of the last look (or of the session when bound)
        self.looks: list[dict[str, Any]] = []
        self.steered: list[dict[str, Any]] = []  # guide targets set at the looks
        self.final_done = False

    # -- set-up ------------------------------------------------------------------------
    def add(self, ruleset: str, traffic: str = "right", aim: bool = False,
            offset: int = 0) -> int:
        """Register a rule set (its apertures start at ``offset`` in the run's); its index
        for :meth:`check`."""
        self.checks.append(_Check(ruleset, traffic, bool(aim), int(offset),
                                  load_ruleset(ruleset)))
        return len(self.checks) - 1

    def bind(self, session: Any, cap_photons: int, first_photons: int | None = None,
             from_photons: int | None = None) -> VerdictRule:
        """Read ``session`` from now on; plan the looks up to ``cap_photons`` from
        ``first_photons`` (default the session's frame). ``from_photons``: photons the
        running rows start after (default the session's now: a resumed run's photons
        so far are not looked at again)."""
        if not self.checks:
            raise InputError("--until decided needs a rule set to decide (--regulation)")
        if session.config.n_sets < 2:
            raise InputError("--until decided needs at least 2 interleave sets (-M ≥ 2): "
                             "the verdicts' intervals come from their spread")
        first = int(first_photons or session.config.frame_photons)
        self.session = session
        self.schedule = LookSchedule(first, int(cap_photons), self.growth)
        self.last_photons = int(session.photons_emitted() if from_photons is None
                                else from_photons)
        self.looks, self.steered, self.final_done = [], [], False
        frame = session.scene.wall
        for chk in self.checks:
            chk.probes = probe_points(chk.rules, chk.traffic, frame=frame.to_dict())
            chk.rows, chk.shift_deg, chk.note, chk.hv = {}, None, None, None
        if int(getattr(session, "frames", 0)) == 0:  # a resumed run keeps its guide rows
            self.steer_regions(self.all_regions())
        return self

    def all_regions(self) -> list[tuple[float, float, float, float]]:
        """Every test point's aperture and every zone's box of the rule sets (wall deg,
        unaimed): what the guide aims at before the first look."""
        size = float(self.session.config.aperture_deg)
        return [r for chk in self.checks for r in probe_regions(chk.probes, size)]

    # -- the StoppingRule protocol -------------------------------------------------------
    def satisfied(self, est: Any, frames: int) -> bool:
        """Look if the schedule plans a look at ``est.photons``; whether every rule is now
        decided. With ``--aim`` the look waits for the written map (``est.lux``): the
        probes' estimate asks for it by answering True, the map has the last word."""
        photons = int(est.photons)
        if self.due(photons):
            if any(c.aim for c in self.checks) and est.lux is None:
                return True  # the session draws the written map and asks again: the look
            self.look(photons, None if est.lux is None else luminous(est.lux))
        return self.finished()

    # -- looks ---------------------------------------------------------------------------
    def due(self, photons: int) -> bool:
        """Whether the schedule plans a look at ``photons`` (none planned yet between the
        last look and them)."""
        return self.schedule is not None and self.schedule.due(int(photons),
                                                                self.last_photons)

    def decided(self) -> bool:
        """Every rule of every rule set decided at the last look (False before any)."""
        return bool(self.looks) and all(
            chk.note is None and chk.rows and all(r["decided"] for r in chk.rows.values())
            for chk in self.checks)

    def lamp_verdict(self) -> str | None:
        """The lamp's verdict over every rule set at the last look: "fail" once some rule
        is decided fail, "pass" once every rule is decided pass, else None (open)."""
        rows = [r for chk in self.checks for r in chk.rows.values()]
        if any(r["decided"] and r["verdict"] == "fail" for r in rows):
            return "fail"
        return "pass" if self.decided() else None

    def finished(self) -> bool:
        """Whether the run may stop: every rule decided (``stop="decided"``), or the
        lamp's verdict decided (``stop="verdict"``)."""
        if self.stop == "verdict":
            return bool(self.looks) and self.lamp_verdict() is not None
        return self.decided()

    def level(self) -> float:
        """Two-sided level of every look's intervals (1 − α/K)."""
        if self.schedule is None:
            raise InputError("the verdict rule is not bound to a run")
        return self.schedule.level(self.confidence)

    def _aim_of(self, chk: _Check, lux: np.ndarray | None) -> tuple[dict[str, Any], Any]:
        """(aim record, hv) of a look: the cut-off on ``lux`` with ``--aim``, else none."""
        frame = self.session.scene.wall
        if chk.aim:
            if lux is None:
                raise InputError("--aim: no map to find the cut-off on")
            _rs, _probes, aim_info, hv = regulation_probes(chk.ruleset, chk.traffic,
                                                           frame, lux, True)
            return aim_info, hv
        if chk.hv is None:
            d = float(frame.distance_m)
            chk.hv = np.stack([wall_m_from_deg(chk.probes.h_deg, d),
                               wall_m_from_deg(chk.probes.v_deg, d)], axis=1)
        return {"applied": False, "dh_deg": 0.0, "dv_deg": 0.0}, chk.hv

    def look(self, photons: int, lux: np.ndarray | None = None) -> None:
        """A look at ``photons`` (the session's now; ``lux`` the luminous written map,
        needed with ``--aim``): every rule set evaluated at the look's level and merged
        into the running rows. Call it where :meth:`due` says (or :meth:`final_look`)."""
        level = self.level()
        frame = self.session.scene.wall
        for chk in self.checks:
            try:
                aim_info, hv = self._aim_of(chk, lux)
            except InputError as exc:  # no cut-off to aim at yet: nothing is decided
                chk.note, chk.rows, chk.shift_deg = str(exc), {}, None
                continue
            m = measure_probes(self.session, chk.rules, chk.probes, hv, aim_info, level,
                               chk.offset)
            results, _u, _cd = evaluate_probe_values(
                chk.rules, chk.probes, hv, m.values_lux, float(frame.distance_m),
                chk.traffic, level, m.count_stats)
            if chk.shift_deg is not None and m.shift_deg != chk.shift_deg:
                chk.rows = {}  # other apertures, other quantities: start again
            chk.shift_deg, chk.note = m.shift_deg, None
            for r in results:  # the running intervals hold at the run's confidence
                r["confidence"] = self.confidence
                if "side_confidence" in r:
                    r["side_confidence"] = 1.0 - 0.5 * (1.0 - self.confidence)
            chk.rows = {str(r["name"]): merge_row(chk.rows.get(str(r["name"])), r, photons)
                        for r in results}
        self.last_photons = int(photons)
        opened = self.undecided()
        self.looks.append({"photons": int(photons), "look": len(self.looks) + 1,
                           "level": level, "open": len(opened)})
        self.steer(opened)

    def steer(self, opened: list[OpenRule]) -> None:
        """With ``--guide points``, aim the photons of the next frames at the apertures
        the open rules read (points, a sum's points, a zone's samples, a relation's two
        sides); a decided rule's apertures stop drawing guided photons. Whatever the
        guide does, every look's intervals stay valid: the guide of a frame is fixed
        before the frame is shot, so each set's estimate stays unbiased and the sets'
        errors uncorrelated (the module docstring of :mod:`lightsim.engine.guiding`)."""
        self.steer_regions([r for o in opened for r in o.regions_deg])

    def steer_regions(self, regions: list[tuple[float, float, float, float]]) -> None:
        """Guide targets: ``regions`` (wall deg) from the session's next frame on, with
        ``--guide points`` (nothing otherwise, or when ``regions`` is empty: all decided,
        or no look could evaluate yet)."""
        cfg = getattr(self.session, "config", None)
        if (self.final_done or cfg is None or getattr(cfg, "guide", "off") != "points"
                or not cfg.apertures):
            return  # the last look steers nothing: no frame follows it
        rects = sorted(set(regions))
        now = targets_at(run_targets(cfg), int(self.session.frames))
        if not rects or (len(now) == len(rects) and np.array_equal(
                now, np.column_stack([np.asarray(rects), np.ones(len(rects))]))):
            return  # nothing open, or the targets in force already
        self.session.guide(np.asarray(rects, np.float64))
        self.steered.append({"photons": int(self.session.photons_emitted()),
                             "targets": len(rects)})

    def final_look(self, photons: int, lux: np.ndarray | None) -> None:
        """The last look, at the run's final photons, unless a look saw them already."""
        if self.final_done or photons <= self.last_photons:
            return
        self.final_done = True
        self.look(int(photons), lux)

    # -- results -------------------------------------------------------------------------
    def rows(self, index: int) -> list[dict[str, Any]]:
        """Rule set ``index``'s running rows (the last look's evaluation with the running
        intervals and verdicts, ``decided``, ``decided_at_photons``), in table order."""
        return list(self.checks[index].rows.values())

    def check(self, index: int, session: Any, lux: np.ndarray) -> dict[str, Any]:
        """Rule set ``index``'s regulation table after the run: the fixed-sample check
        (:func:`~lightsim.luminaires.regulations.check.regulation_check`: probe file,
        HV, Imax) with its rules' rows replaced by the running ones (a last look at the
        final photons first, if no look saw them) and a ``sequential`` record."""
        chk = self.checks[index]
        self.final_look(int(session.photons_emitted()), lux)
        reg = regulation_check(session, lux, chk.ruleset, chk.traffic, chk.aim,
                               self.confidence, chk.offset)
        rows = [chk.rows.get(str(r["name"]), {**r, "decided": False,
                                               "decided_at_photons": None, "resets": 0})
                if r.get("kind") != "measure" else r for r in reg["results"]]
        if chk.note is not None:  # the last look could not evaluate: nothing decided
            rows = [r if r.get("kind") == "measure" else
                    {**r, "verdict": "uncertain", "decided": False,
                     "decided_at_photons": None} for r in rows]
        reg["results"] = rows
        reg["sequential"] = self.table_record(index)
        return reg

    def table_record(self, index: int) -> dict[str, Any]:
        """``summary.json``'s ``sequential`` record of rule set ``index``'s table."""
        chk = self.checks[index]
        rows = list(chk.rows.values())
        opened = [r["name"] for r in rows if not r["decided"]]
        return {"rule": "decided", "confidence": self.confidence,
                "look_level": self.level(), "looks_planned": self.schedule.looks,
                "looks": len(self.looks), "decided": len(rows) - len(opened),
                "open": opened,
                "note": chk.note,
                "decided_at_photons": (max((r["decided_at_photons"] for r in rows),
                                           default=None) if rows and not opened else None)}

    def undecided(self) -> list[OpenRule]:
        """Every rule still open at the last look, with the apertures it reads (indices
        into the run's apertures, rectangles in wall degrees where they are read) — where
        more photons would decide it."""
        out = []
        layout = self.session.config if self.session is not None else None
        size = float(layout.aperture_deg) if layout is not None else 0.0
        for chk in self.checks:
            counted = bool(layout is not None and layout.apertures)
            shift = chk.shift_deg or 0.0
            for name, row in chk.rows.items():
                if row["decided"]:
                    continue
                idx = _probe_indices(chk, row)
                h = chk.probes.h_deg[idx]
                v = chk.probes.v_deg[idx] + shift
                rects = tuple((float(a - size / 2), float(a + size / 2), float(b - size / 2),
                               float(b + size / 2)) for a, b in zip(h, v, strict=True)
                              ) if counted else ()
                regions = tuple(_region(chk.probes.h_deg[i], chk.probes.v_deg[i] + shift,
                                        size) for i in _probe_groups(chk, row)
                                if len(i)) if counted else ()
                out.append(OpenRule(chk.rules.id, name, str(row.get("kind")),
                                    tuple(int(chk.offset + i) for i in idx) if counted
                                    else (), rects,
                                    tuple((float(a), float(b)) for a, b in
                                          zip(h, v, strict=True)), regions))
        return out

    def progress_text(self) -> str:
        """One line for a progress display: rules decided and the looks so far."""
        n = sum(len(c.rows) for c in self.checks)
        done = sum(r["decided"] for c in self.checks for r in c.rows.values())
        if not self.looks:
            return "verdicts: no look yet"
        return f"verdicts {done}/{n} decided (look {len(self.looks)})"

    def summary(self) -> dict[str, Any]:
        """``summary.json["until"]``: the budget, every look and the rules still open."""
        sch = self.schedule
        return {"rule": self.stop, "decided": self.decided(),
                "lamp_verdict": self.lamp_verdict(),
                # the run itself stopped on a look that decided what it waits for
                "stopped": self.stop if self.finished() and not self.final_done else None,
                "confidence": self.confidence,
                "method": "error budget α split evenly over the planned looks "
                          "(Bonferroni); running intersection of every look's intervals",
                "first_photons": None if sch is None else sch.first_photons,
                "cap_photons": None if sch is None else sch.cap_photons,
                "growth": self.growth,
                "looks_planned": None if sch is None else sch.looks,
                "look_level": None if sch is None else self.level(),
                "looks": list(self.looks),
                "photons": self.last_photons,
                "undecided": [o.to_dict() for o in self.undecided()],
                "guided": [dict(g) for g in self.steered],
                "notes": {c.rules.id: c.note for c in self.checks if c.note}}


@dataclass
class GuideTargets:
    """``--guide points`` with ``--regulation`` (an :class:`~lightsim.analysis.Analysis`):
    before the run, the guide targets become one box per test point or zone of every
    requested rule set (:func:`probe_regions`) instead of one per detector aperture — a
    zone is one target, not hundreds, so the guide's tables stay small; after it,
    ``summary.json["guide"]`` records them. ``--until decided`` then narrows them to the
    open rules at every look (:meth:`VerdictRule.steer`)."""

    rulesets: tuple[str, ...]
    traffic: str = "right"
    name: str = "guide"
    regions: list[tuple[float, float, float, float]] = field(default_factory=list)
    #: it reads no estimate after the run, so the run keeps no photon for it
    reads_photons = None

    def prepare(self, config: Any, scene: Any) -> Any:
        if config.guide != "points" or config.guide_targets or not config.apertures:
            return config
        frame = scene.wall.to_dict()
        self.regions = [r for rs in self.rulesets for r in probe_regions(
            probe_points(load_ruleset(rs), self.traffic, frame=frame),
            float(config.aperture_deg))]
        if not self.regions:
            return config
        return config.with_(guide_targets=target_rows(np.asarray(sorted(set(self.regions)))))

    def report(self, run: Any, out: Any) -> AnalysisReport:
        return AnalysisReport({"mode": "points", "targets": len(set(self.regions)),
                               "regions_deg": [list(r) for r in sorted(set(self.regions))]})


def _probe_groups(chk: _Check, row: dict[str, Any]) -> list[np.ndarray]:
    """Indices of the probes a rule's row reads, one array per test point or zone (a
    point's, a zone's samples, a sum's points, a relation's two sides)."""
    names = {"sum": row.get("points") or [],
             "relation": [row.get("lhs"), row.get("reference")]}.get(
        str(row.get("kind")), [row["name"]])
    return [np.asarray(chk.probes.indices(str(n)), np.int64) for n in names
            if n is not None]


def _probe_indices(chk: _Check, row: dict[str, Any]) -> np.ndarray:
    """Indices of every probe a rule's row reads (:func:`_probe_groups` joined)."""
    idx = _probe_groups(chk, row)
    return np.concatenate(idx).astype(np.int64) if idx else np.zeros(0, np.int64)


def probe_regions(probes: Any, size_deg: float) -> list[tuple[float, float, float, float]]:
    """One box (H₀, H₁, V₀, V₁ in deg) per test point or zone of ``probes`` (a
    :func:`~lightsim.luminaires.regulations.probe_points` result): a point's aperture of
    side ``size_deg``, a zone's samples' apertures together — the guide targets of
    ``--guide points``."""
    labels = np.asarray(probes.labels, dtype=object)
    return [_region(probes.h_deg[i], probes.v_deg[i], size_deg)
            for i in (np.flatnonzero(labels == name) for name in dict.fromkeys(probes.labels))]


def _region(h_deg: np.ndarray, v_deg: np.ndarray, size_deg: float
            ) -> tuple[float, float, float, float]:
    """The box (H₀, H₁, V₀, V₁ in deg) around apertures of side ``size_deg`` centred on
    the probes (``h_deg``, ``v_deg``): one point's aperture, or a zone's extent."""
    a = 0.5 * float(size_deg)
    return (float(np.min(h_deg) - a), float(np.max(h_deg) + a),
            float(np.min(v_deg) - a), float(np.max(v_deg) + a))
