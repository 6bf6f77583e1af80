"""Test a beam against a rule set, with confidence intervals from independent estimates.

The engine estimates the intensity towards every probe direction once per interleave set
(M² independent photon maps), so each probe has S independent estimates and, with detector
apertures, photon statistics. This module

1. lists the probe directions of a rule set (:func:`probe_points`): its test points, plus
   zones sampled on a grid of ``spacing_deg`` (aligned to H-V) inside their polygons, on
   their edges and at their vertices, or along their lines;
2. turns the ``(S, P)`` per-set estimates into values with intervals and verdicts
   (:func:`evaluate`);
3. prints the results as a rich table (:func:`format_table`).

Verdicts
--------
Every rule compares a quantity — a point's intensity, a sum of points, a zone's maximum
(or minimum), a relation's ratio — with its limit through an interval on the quantity: the
rule **passes** when the whole interval is on the allowed side, **fails** when the whole
interval is beyond the limit, and is **uncertain** when the interval straddles it (so thin
evidence, a wide interval, gives "uncertain"). Each side of an interval is a one-sided
bound that is wrong with probability at most α/2 (2.5 % at 95 %), so a verdict "pass" or
"fail" is wrong with probability at most α/2 whatever the truth.

The bounds of one intensity or of a sum follow :class:`lightsim.report.IntensityEvidence`:
Student-t over the sets where they hold a photon per set or more, the weighted photon
count (a Fay–Feuer gamma interval with mid-p quantiles) where they are sparse, never below
0, with room for unseen heavy photons above. Combined quantities:

* **sum** ``1+2+3``: its per-set sums and the pooled photons of its points (one
  intensity, same rule) — never the sum of the points' intervals;
* **zone maximum** over n probes: upper bound max_i hi_i at α/2 per probe (the truth's
  maximum sits at one probe, whose bound holds with 1 − α/2), lower bound max_i lo_i with
  each lo_i at α/(2n) — a union (Bonferroni) bound over the zone's samples, since a
  data-chosen probe's lower bound must hold at all of them together. So "every point
  ≤ max" fails only when one probe is surely above at the union level, and "some point ≥
  min" passes only when one is surely above at that level. A zone minimum mirrors this;
* **relation** ``L op f·R`` (e.g. zone I ≤ 2·I(50R)): both sides' bounds at α/4 each
  (their intervals at 1 − α/2), L a point or the zone's maximum (for "≤"; its minimum for
  "≥": "every point" satisfies it), R a point or the zone's ``rhs_stat``. Then the ratio
  L/R lies in [L_lo / R_hi, L_hi / R_lo] and the margin L − f·R in [L_lo − f·R_hi,
  L_hi − f·R_lo], each side wrong with probability at most α/4 + α/4 = α/2 (a union
  bound over the two sides).

With a single set (S = 1) and no photon statistics no error can be estimated: intervals
collapse to the value and results carry ``"error_estimate": False``.

Parameters
----------
============  ======  ========  =====================================================
name          unit    default   meaning
============  ======  ========  =====================================================
traffic       –       "right"   "right" or "left" (positions mirrored h → −h)
spacing_deg   deg     0.25      zone sampling step
values_cd     cd      –         (S, P) per-set intensity estimates, P = len(probes)
confidence    1       0.95      two-sided confidence level of the intervals
count_stats   –       None      (4, P) photon statistics of the probes (apertures)
frame         –       None      wall frame: drop probes the wall does not cover
============  ======  ========  =====================================================
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from rich.table import Table
from rich.text import Text

from lightsim.errors import InputError
from lightsim.report import IntensityEvidence
from lightsim.wall import WallFrame

from .ruleset import Geometry, Relation, RuleSet, SumRule, check_traffic

__all__ = [
    "VERDICT_STYLES",
    "Probes",
    "evaluate",
    "format_position",
    "format_table",
    "limit_verdict",
    "probe_points",
    "unevaluated_rules",
]

VERDICT_STYLES = {"pass": "bold green", "fail": "bold red", "uncertain": "bold yellow"}
"""Rich styles of the three verdicts."""


@dataclass(frozen=True)
class Probes:
    """The directions at which a rule set needs intensity estimates.

    Attributes
    ----------
    h_deg, v_deg : ndarray, shape (P,)
        Angular positions in degrees (traffic mirroring already applied).
    labels : tuple of str, length P
        The point or zone each probe belongs to.
    ruleset_id, traffic : str
        What the probes were made for.
    spacing_deg : float
        Zone sampling step in degrees.
    dropped : mapping of str to str
        Points/zones without probes and why (incomplete data, outside the wall).
    clipped : mapping of str to int
        Zones tested only in part: how many of their samples lay outside the wall.
    """

    h_deg: NDArray
    v_deg: NDArray
    labels: tuple[str, ...]
    ruleset_id: str
    traffic: str
    spacing_deg: float
    dropped: Mapping[str, str] = field(default_factory=dict)
    clipped: Mapping[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.labels)

    def indices(self, name: str) -> NDArray:
        """Indices of the probes of point/zone ``name`` (empty if it has none)."""
        return np.flatnonzero(np.asarray(self.labels, dtype=object) == name)

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form."""
        return {"ruleset": self.ruleset_id, "traffic": self.traffic,
                "spacing_deg": self.spacing_deg, "h_deg": self.h_deg.tolist(),
                "v_deg": self.v_deg.tolist(), "labels": list(self.labels),
                "dropped": dict(self.dropped), "clipped": dict(self.clipped)}


# ---- zone sampling ---------------------------------------------------------------------
def _on_segment(px: NDArray, py: NDArray, a: tuple[float, float], b: tuple[float, float],
                tol: float) -> NDArray:
    ax, ay = a
    bx, by = b
    dx, dy = bx - ax, by - ay
    L2 = dx * dx + dy * dy
    t = np.clip(((px - ax) * dx + (py - ay) * dy) / L2, 0.0, 1.0) if L2 > 0 else 0.0
    qx, qy = ax + t * dx, ay + t * dy
    return (px - qx) ** 2 + (py - qy) ** 2 <= tol * tol


def _inside_polygon(px: NDArray, py: NDArray, poly: Sequence[tuple[float, float]],
                    tol: float = 1e-9) -> NDArray:
    """Points inside or on the boundary of ``poly`` (even-odd rule)."""
    inside = np.zeros(px.shape, dtype=bool)
    n = len(poly)
    for i in range(n):
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % n]
        crosses = (y1 > py) != (y2 > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xint = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (px < xint)
    for i in range(n):
        inside |= _on_segment(px, py, poly[i], poly[(i + 1) % n], tol)
    return inside


def _sample_segment(a: tuple[float, float], b: tuple[float, float], spacing: float
                    ) -> NDArray:
    length = float(np.hypot(b[0] - a[0], b[1] - a[1]))
    n = max(1, int(np.ceil(length / spacing - 1e-9)))
    t = np.linspace(0.0, 1.0, n + 1)
    return np.column_stack([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])])


def _zone_samples(g: Geometry, spacing: float) -> NDArray:
    if g.line:
        return _sample_segment(g.line[0], g.line[1], spacing)
    poly = np.asarray(g.polygon, dtype=float)
    lo = np.floor(poly.min(axis=0) / spacing) * spacing
    hi = np.ceil(poly.max(axis=0) / spacing) * spacing
    hs = np.arange(round((hi[0] - lo[0]) / spacing) + 1) * spacing + lo[0]
    vs = np.arange(round((hi[1] - lo[1]) / spacing) + 1) * spacing + lo[1]
    H, V = np.meshgrid(hs, vs)
    mask = _inside_polygon(H, V, g.polygon)
    pts = [np.column_stack([H[mask], V[mask]])]
    n = len(g.polygon)
    for i in range(n):  # edges and vertices, so thin parts and corners are tested too
        pts.append(_sample_segment(g.polygon[i], g.polygon[(i + 1) % n], spacing))
    allp = np.concatenate(pts)
    _, keep = np.unique(np.round(allp, 9), axis=0, return_index=True)
    return allp[np.sort(keep)]


def probe_points(ruleset: RuleSet, traffic: str = "right", spacing_deg: float = 0.25,
                 frame: Any = None) -> Probes:
    """Directions (deg) the engine must estimate to test ``ruleset``.

    Parameters
    ----------
    ruleset : RuleSet
        As loaded by :func:`~lightsim.luminaires.regulations.load_ruleset`.
    traffic : {"right", "left"}, default "right"
        Traffic side; positions are mirrored (h → −h) when it differs from the file's.
    spacing_deg : float, default 0.25
        Zone sampling step in degrees (grid aligned to H-V, plus edges and vertices).
    frame : WallFrame or mapping, optional
        If given, probes outside the span of the wall image's pixel centres are dropped
        (zones keep the probes that the wall covers and are reported with
        ``probes_outside_wall``; a point outside is dropped whole).

    Returns
    -------
    Probes
        Points first (file order), then zone samples.
    """
    traffic = check_traffic(traffic)
    if not (np.isfinite(spacing_deg) and spacing_deg > 0):
        raise InputError(f"spacing_deg must be > 0, got {spacing_deg!r}")
    rs = ruleset.for_traffic(traffic)
    limits = None
    if frame is not None:
        wf = WallFrame.from_any(frame)
        h = wf.h_deg()
        v = wf.v_deg()
        limits = (h.min(), h.max(), v.min(), v.max())
    hs: list[NDArray] = []
    vs: list[NDArray] = []
    labels: list[str] = []
    dropped: dict[str, str] = {}
    clipped: dict[str, int] = {}
    for g in rs.geometries:
        if not g.complete:
            dropped[g.name] = g.note or "incomplete data"
            continue
        pts = np.array([[g.h, g.v]]) if g.kind == "point" else _zone_samples(g, spacing_deg)
        if limits is not None:
            eps = 1e-9
            ok = ((pts[:, 0] >= limits[0] - eps) & (pts[:, 0] <= limits[1] + eps)
                  & (pts[:, 1] >= limits[2] - eps) & (pts[:, 1] <= limits[3] + eps))
            if not ok.all():
                ext = (f"the wall covers H {limits[0]:.2f}..{limits[1]:.2f}°, "
                       f"V {limits[2]:.2f}..{limits[3]:.2f}°")
                if g.kind == "point" or not ok.any():
                    dropped[g.name] = f"outside the wall ({ext})"
                    continue
                clipped[g.name] = int((~ok).sum())
            pts = pts[ok]
        hs.append(pts[:, 0])
        vs.append(pts[:, 1])
        labels.extend([g.name] * len(pts))
    h_all = np.concatenate(hs) if hs else np.zeros(0)
    v_all = np.concatenate(vs) if vs else np.zeros(0)
    return Probes(h_deg=h_all, v_deg=v_all, labels=tuple(labels), ruleset_id=rs.id,
                  traffic=traffic, spacing_deg=float(spacing_deg), dropped=dropped,
                  clipped=clipped)


# ---- statistics -------------------------------------------------------------------------
@dataclass(frozen=True)
class _Stat:
    """A quantity's estimate and bounds (cd), and the probe it was read at."""

    mean: float
    lo: float
    hi: float
    probe: int = -1


def _point(ev: IntensityEvidence, i: int, tail: float) -> _Stat:
    b = ev.each([i], tail, tail)
    return _Stat(float(b.mean[0]), float(b.lo[0]), float(b.hi[0]), int(i))


def _extreme(ev: IntensityEvidence, idx: NDArray, stat: str, tail: float) -> _Stat:
    """Bounds of the maximum (``stat="max"``) or minimum of the intensities at probes
    ``idx``, each side wrong with probability at most ``tail`` (module docstring: the
    side that picks a probe by the data holds at ``tail/n`` per probe)."""
    per = ev.each(idx, tail, tail)
    n = len(idx)
    union = per if n == 1 else ev.each(idx, tail / n, tail / n)
    if stat == "max":
        k = int(np.argmax(per.mean))
        return _Stat(float(per.mean[k]), float(np.max(union.lo)), float(np.max(per.hi)),
                     int(idx[k]))
    k = int(np.argmin(per.mean))
    return _Stat(float(per.mean[k]), float(np.min(per.lo)), float(np.min(union.hi)),
                 int(idx[k]))


def _limit_state(lo: float, hi: float, min_: float | None, max_: float | None
                 ) -> list[str]:
    states = []
    if min_ is not None:
        states.append("pass" if lo >= min_ else "fail" if hi < min_ else "uncertain")
    if max_ is not None:
        states.append("pass" if hi <= max_ else "fail" if lo > max_ else "uncertain")
    return states


def _combine_all(states: Iterable[str]) -> str:
    """Every check must hold: fail if any fails, pass if all pass."""
    s = list(states)
    if "fail" in s:
        return "fail"
    return "pass" if all(x == "pass" for x in s) else "uncertain"


def limit_verdict(lo: float, hi: float, min_: float | None, max_: float | None) -> str:
    """The verdict of an interval [lo, hi] against a minimum and/or a maximum: "pass"
    when it lies wholly on the allowed side of every limit, "fail" when wholly beyond
    one, else "uncertain" (the rule of every row, module docstring)."""
    return _combine_all(_limit_state(lo, hi, min_, max_))


def _limit_dict(min_: float | None, max_: float | None) -> dict[str, float]:
    out = {}
    if min_ is not None:
        out["min"] = float(min_)
    if max_ is not None:
        out["max"] = float(max_)
    return out


def _f(x: Any) -> float:
    return float(x)


def _ratio(num: float, den: float) -> float | None:
    """num / den, None where den ≤ 0 (an unbounded ratio)."""
    return float(num / den) if den > 0 else None


# ---- evaluation -------------------------------------------------------------------------
def _base(name: str, kind: str, h: float | None, v: float | None, st: _Stat,
          limit: dict[str, float], verdict: str, rule: Any, error_estimate: bool
          ) -> dict[str, Any]:
    return {"name": name, "h_deg": None if h is None else _f(h),
            "v_deg": None if v is None else _f(v), "value_cd": _f(st.mean),
            "interval_cd": [_f(st.lo), _f(st.hi)], "limit": limit, "verdict": verdict,
            "kind": kind, "certainty": rule.certainty, "note": rule.note,
            "source": rule.source, "error_estimate": error_estimate}


def _eval_point(g: Geometry, idx: NDArray, ev: IntensityEvidence, tail: float,
                h: NDArray, v: NDArray, err: bool) -> dict[str, Any]:
    st = _point(ev, int(idx[0]), tail)
    verdict = _combine_all(_limit_state(st.lo, st.hi, g.min, g.max))
    return _base(g.name, "point", h[st.probe], v[st.probe], st, _limit_dict(g.min, g.max),
                 verdict, g, err)


def _eval_zone(g: Geometry, idx: NDArray, ev: IntensityEvidence, tail: float,
               h: NDArray, v: NDArray, err: bool) -> dict[str, Any]:
    st = _extreme(ev, idx, g.stat or "max", tail)
    verdict = _combine_all(_limit_state(st.lo, st.hi, g.min, g.max))
    out = _base(g.name, "zone", h[st.probe], v[st.probe], st, _limit_dict(g.min, g.max),
                verdict, g, err)
    out["stat"] = g.stat
    out["n_probes"] = len(idx)
    # the zone's maximum with its direction and interval, whatever the limited statistic
    top = st if g.stat == "max" else _extreme(ev, idx, "max", tail)
    out.update({"max_cd": _f(top.mean), "max_h_deg": _f(h[top.probe]),
                "max_v_deg": _f(v[top.probe]), "max_interval_cd": [_f(top.lo), _f(top.hi)]})
    if g.polygon:
        out["polygon_deg"] = [[_f(a), _f(b)] for a, b in g.polygon]
    if g.line:
        out["line_deg"] = [[_f(a), _f(b)] for a, b in g.line]
    return out


def _eval_sum(s: SumRule, probes: Probes, ev: IntensityEvidence, tail: float, err: bool
              ) -> dict[str, Any]:
    cols = [int(probes.indices(p)[0]) for p in s.points]
    b = ev.total(cols, tail, tail)
    st = _Stat(float(b.mean[0]), float(b.lo[0]), float(b.hi[0]))
    verdict = _combine_all(_limit_state(st.lo, st.hi, s.min, s.max))
    out = _base(s.name, "sum", None, None, st, _limit_dict(s.min, s.max), verdict, s, err)
    out["points"] = list(s.points)
    return out


def _side(ev: IntensityEvidence, rs: RuleSet, probes: Probes, name: str, stat: str,
          tail: float) -> _Stat:
    """A relation side: a point, or a zone reduced to its ``stat``."""
    idx = probes.indices(name)
    if rs.geometry(name).kind == "zone":
        return _extreme(ev, idx, stat, tail)
    return _point(ev, int(idx[0]), tail)


def _eval_relation(r: Relation, rs: RuleSet, probes: Probes, ev: IntensityEvidence,
                   tail: float, err: bool) -> dict[str, Any]:
    # both sides at half the error each (a union bound): the verdict keeps α/2
    side_tail = tail / 2.0
    # a zone lhs must satisfy the relation at every point: its maximum for "≤"
    lhs = _side(ev, rs, probes, r.lhs, "max" if r.op == "<=" else "min", side_tail)
    rhs = _side(ev, rs, probes, r.rhs, r.rhs_stat, side_tail)
    # each side's value: the mean of its probe's per-set values
    lhs, rhs = (_Stat(float(ev.per_set[:, [st.probe]].mean(axis=0)[0]), st.lo, st.hi,
                      st.probe) for st in (lhs, rhs))
    f = r.factor
    m_lo, m_hi = lhs.lo - f * rhs.hi, lhs.hi - f * rhs.lo
    # the margin's estimate: the mean of the per-set margins at the lhs's worst probe
    lhs_idx = probes.indices(r.lhs)
    margins = ev.per_set[:, lhs_idx] - f * ev.per_set[:, rhs.probe][:, None]
    margin = margins.mean(axis=0)[int(np.flatnonzero(lhs_idx == lhs.probe)[0])]
    verdict = _combine_all(_limit_state(m_lo, m_hi, *((None, 0.0) if r.op == "<="
                                                      else (0.0, None))))
    ref = f * rhs.mean
    limit = {"max": _f(ref)} if r.op == "<=" else {"min": _f(ref)}
    out = _base(r.name, "relation", probes.h_deg[lhs.probe], probes.v_deg[lhs.probe], lhs,
                limit, verdict, r, err)
    out.update({"lhs": r.lhs, "op": r.op, "factor": _f(f), "reference": r.rhs,
                "reference_cd": _f(rhs.mean),
                "reference_interval_cd": [_f(rhs.lo), _f(rhs.hi)],
                "reference_h_deg": _f(probes.h_deg[rhs.probe]),
                "reference_v_deg": _f(probes.v_deg[rhs.probe]),
                "margin_cd": _f(margin),
                "margin_interval_cd": [_f(m_lo), _f(m_hi)],
                "ratio": _ratio(lhs.mean, rhs.mean),
                "ratio_interval": [_ratio(lhs.lo, rhs.hi), _ratio(lhs.hi, rhs.lo)],
                "side_confidence": _f(1.0 - 2.0 * side_tail)})
    return out


def _skip_reason(rs: RuleSet, probes: Probes, names: Iterable[str]) -> str | None:
    for n in names:
        if n in probes.dropped:
            return f"'{n}': {probes.dropped[n]}"
        if len(probes.indices(n)) == 0:
            return f"'{n}' has no probes"
    return None


def unevaluated_rules(ruleset: RuleSet, probes: Probes) -> list[dict[str, str]]:
    """Rules that :func:`evaluate` cannot test with these probes, and why.

    Returns
    -------
    list of dict
        ``{"name", "kind", "reason", "certainty"}`` per rule left out (incomplete data or
        directions outside the wall).
    """
    rs = ruleset.for_traffic(probes.traffic)
    out = []
    for g in rs.geometries:
        if g.has_limits and (reason := _skip_reason(rs, probes, [g.name])):
            out.append({"name": g.name, "kind": g.kind, "reason": reason,
                        "certainty": g.certainty})
    for s in rs.sums:
        if reason := _skip_reason(rs, probes, s.points):
            out.append({"name": s.name, "kind": "sum", "reason": reason,
                        "certainty": s.certainty})
    for r in rs.relations:
        reason = None if r.complete else (r.note or "incomplete data")
        reason = reason or _skip_reason(rs, probes, [r.lhs, r.rhs])
        if reason:
            out.append({"name": r.name, "kind": "relation", "reason": reason,
                        "certainty": r.certainty})
    return out


def evaluate(ruleset: RuleSet, probes: Probes, values_cd: ArrayLike,
             traffic: str | None = None, confidence: float = 0.95,
             intervals_cd: ArrayLike | None = None, count_stats: ArrayLike | None = None
             ) -> list[dict[str, Any]]:
    """Test per-set intensity estimates against a rule set.

    Parameters
    ----------
    ruleset : RuleSet
        The rule set the probes were made for.
    probes : Probes
        From :func:`probe_points` (same rule set).
    values_cd : array_like, shape (S, P) or (P,)
        Intensity estimates in cd: one row per independent set (interleave set), one column
        per probe. A 1-D array is one set (no error estimate).
    traffic : {"right", "left"}, optional
        Must match ``probes.traffic`` if given.
    confidence : float, default 0.95
        Two-sided confidence level of the intervals (module docstring).
    intervals_cd : array_like, shape (P, 2), optional
        Probe intervals (cd) given by the caller (e.g. a model's expected intervals):
        where both bounds are finite they replace the computed ones for points, zones and
        relations, as they are (no union bound can be applied to them); sums keep the
        per-set statistics.
    count_stats : array_like, shape (4, P), optional
        Photon statistics of the probes (detector apertures), as
        :func:`~lightsim.engine.apertures.count_statistics` gives them: effective photons,
        one photon's worth, the heaviest photon's worth and the mean (cd). With them the
        sparse probes, sums, zones and relations get photon-count bounds
        (:class:`lightsim.report.IntensityEvidence`).

    Returns
    -------
    list of dict
        One JSON-serialisable dict per testable rule, in file order (points, zones, sums,
        relations), with keys ``name, h_deg, v_deg, value_cd, interval_cd, limit, verdict``
        (verdict ``"pass" | "fail" | "uncertain"``; limit ``{"min": cd, "max": cd}`` with
        the present bounds) plus ``kind, certainty, note, source, error_estimate`` and
        per kind: zones ``stat, n_probes, probes_outside_wall, polygon_deg | line_deg``
        (value at the extreme probe, interval of the limited statistic; a zone partly
        outside the wall is tested where the wall covers it) and ``max_cd, max_h_deg,
        max_v_deg, max_interval_cd`` (the zone's maximum: the probe with the largest mean
        and the maximum's interval); sums ``points`` (h/v are None); relations ``lhs, op,
        factor, reference, reference_cd, reference_interval_cd, margin_cd,
        margin_interval_cd, ratio, ratio_interval, side_confidence`` (value and interval
        of the lhs at its worst probe, limit = factor × reference; both sides' intervals
        at ``side_confidence``; a ratio bound is None where unbounded). Rules that cannot
        be tested are reported by :func:`unevaluated_rules`.

    Raises
    ------
    InputError
        Shape mismatch, non-finite values, traffic mismatch or a bad confidence level.
    """
    if probes.ruleset_id != ruleset.id:
        raise InputError(f"probes were made for rule set '{probes.ruleset_id}', "
                         f"not '{ruleset.id}'")
    if traffic is not None and check_traffic(traffic) != probes.traffic:
        raise InputError(f"probes were made for {probes.traffic}-hand traffic, "
                         f"not {traffic}-hand")
    if not (0.0 < confidence < 1.0):
        raise InputError(f"confidence must be between 0 and 1, got {confidence!r}")
    values = np.asarray(values_cd, dtype=float)
    if values.ndim == 1:
        values = values[None, :]
    if values.ndim != 2 or values.shape[1] != len(probes):
        raise InputError(f"values_cd must have shape (sets, {len(probes)}), "
                         f"got {np.shape(values_cd)}")
    if values.shape[0] < 1:
        raise InputError("values_cd has no sets")
    bad = ~np.isfinite(values).all(axis=0)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"values_cd has non-finite estimates at probe {k} "
                         f"('{probes.labels[k]}' at H {probes.h_deg[k]:.2f}°, "
                         f"V {probes.v_deg[k]:.2f}°)")
    rs = ruleset.for_traffic(probes.traffic)
    n_sets = values.shape[0]
    err = n_sets >= 2
    ev = IntensityEvidence(values, None if count_stats is None else count_stats,
                           None if intervals_cd is None else intervals_cd)
    tail = (1.0 - confidence) / 2.0
    results: list[dict[str, Any]] = []
    for kind in ("point", "zone"):
        for g in rs.geometries:
            if g.kind != kind or not g.has_limits or _skip_reason(rs, probes, [g.name]):
                continue
            idx = probes.indices(g.name)
            fn = _eval_point if kind == "point" else _eval_zone
            res = fn(g, idx, ev, tail, probes.h_deg, probes.v_deg, err)
            if kind == "zone":
                res["probes_outside_wall"] = int(probes.clipped.get(g.name, 0))
            results.append(res)
    for s in rs.sums:
        if not _skip_reason(rs, probes, s.points):
            results.append(_eval_sum(s, probes, ev, tail, err))
    for r in rs.relations:
        if r.complete and not _skip_reason(rs, probes, [r.lhs, r.rhs]):
            results.append(_eval_relation(r, rs, probes, ev, tail, err))
    for res in results:
        res["traffic"] = probes.traffic
        res["confidence"] = float(confidence)
    return results


# ---- terminal table ---------------------------------------------------------------------
def _fmt_angle(x: float, pos: str, neg: str, zero: str) -> str:
    if abs(x) < 5e-4:
        return zero
    return f"{abs(x):.4g}{pos if x > 0 else neg}"


def format_position(h_deg: float | None, v_deg: float | None) -> str:
    """Regulation-style position, e.g. ``"0.86D 1.72R"``, ``"H-V"``, ``""`` for none."""
    if h_deg is None or v_deg is None:
        return ""
    v = _fmt_angle(v_deg, "U", "D", "H")
    h = _fmt_angle(h_deg, "R", "L", "V")
    return "H-V" if (v, h) == ("H", "V") else f"{v} {h}"


def _fmt_cd(x: float) -> str:
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:.3g}"


def format_table(results: Sequence[Mapping[str, Any]], title: str | None = None,
                 unevaluated: Sequence[Mapping[str, str]] | None = None) -> Any:
    """A :class:`rich.table.Table` of evaluation results with coloured verdicts.

    Parameters
    ----------
    results : sequence of dict
        From :func:`evaluate`.
    title : str, optional
        Table title.
    unevaluated : sequence of dict, optional
        From :func:`unevaluated_rules`; listed in the caption.

    Returns
    -------
    rich.table.Table
        Print it with a rich ``Console``. Verdict colours: pass green, fail red,
        uncertain yellow; less-sure rules are marked with ``*``.
    """
    conf = next((r.get("confidence") for r in results if "confidence" in r), 0.95)
    table = Table(title=title)
    table.add_column("rule")
    table.add_column("kind")
    table.add_column("position")
    table.add_column("value cd", justify="right")
    table.add_column(f"{conf:.0%} interval cd", justify="right")
    table.add_column("limit cd", justify="right")
    table.add_column("verdict")
    less = False
    sides = None
    for r in results:
        lim = r.get("limit", {})
        parts = []
        if "min" in lim:
            parts.append(f"≥ {_fmt_cd(lim['min'])}")
        if "max" in lim:
            parts.append(f"≤ {_fmt_cd(lim['max'])}")
        lo, hi = r["interval_cd"]
        name = str(r["name"])
        if r.get("certainty") == "less-sure":
            name += " *"
            less = True
        if r.get("kind") == "relation":
            # the limit is factor × reference (the verdict's threshold); the reference's own
            # value and interval follow in brackets: the verdict compares both intervals
            op = r["op"].replace("<=", "≤").replace(">=", "≥")
            ref_lo, ref_hi = r.get("reference_interval_cd") or (r["reference_cd"],) * 2
            parts = [f"{op} {r['factor']:g}·{r['reference']} = "
                     f"{_fmt_cd(r['factor'] * r['reference_cd'])} "
                     f"({r['reference']} {_fmt_cd(r['reference_cd'])}, "
                     f"{_fmt_cd(ref_lo)} – {_fmt_cd(ref_hi)})"]
            side = r.get("side_confidence")
            if side is not None and r.get("error_estimate", True):
                sides = side
        verdict = str(r["verdict"])
        table.add_row(name, str(r.get("kind", "")), format_position(r["h_deg"], r["v_deg"]),
                      _fmt_cd(r["value_cd"]), f"{_fmt_cd(lo)} – {_fmt_cd(hi)}",
                      ", ".join(parts), Text(verdict, style=VERDICT_STYLES.get(verdict, "")))
    caption = []
    if less:
        caption.append("* less-sure data: verify against the regulation text")
    if sides is not None:
        caption.append(f"relations: both sides' intervals at {sides:.1%}, so that the "
                       f"verdict holds at {conf:.0%}")
    for u in unevaluated or ():
        caption.append(f"not tested: {u['name']} ({u['reason']})")
    if caption:
        table.caption = "\n".join(caption)
    return table
