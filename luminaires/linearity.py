"""Linearity step of ``lightsim design``: level the flat cut-off over annex 9's three scans.

UN R112 annex 9 makes two properties of the passing beam's cut-off the condition for aiming
the lamp instrumentally: its sharpness G (0.13–0.40) and its **linearity** — the
inflections of vertical scans at 1.5°, 2.5° and 3.5° from V-V, on the side away from the
step, lie within 0.2° of each other (:mod:`lightsim.render.cutoff`). In the footprint
model's objective (:mod:`lightsim.luminaires.facet_model`) linearity is one term among
forty, and a lamp it designs can miss it (0.26–0.28°, e.g., when one facet's image top
stands ~0.25° above the others at 3.5–4° L). The model cannot see
why: at the cut-off the whole lamp's kNN estimate is not the sum of the facets' (each
facet alone has a thirtieth of the photons and a blurrier edge), so a large part of the
edge sits in the model's fixed residual (measured: ~800 cd of 1 300 at 3.5° L, 0.5° D),
and the model moved the 3.5° L inflection by 0.01° for a facet shift that moved the
simulated lamp's by 0.36°. This step therefore asks for linearity alone, on the wall where
it is judged, with every candidate move **simulated**:

1. **Reference.** The whole lamp on the README demo's wall (``resolution``, 320 × 128,
   unaimed), ``photons`` photons, seed ``seed``: the three scans' inflections; nothing
   moves when their spread is within ``target_deg`` already.
2. **Candidates.** Every movable facet's footprint is measured on that wall
   (``footprint_photons`` each,
   :func:`~lightsim.luminaires.facet_model.measure_footprints`);
   the facets holding at least ``share_min`` of the light in a scan's *top window*
   (|h − h_s| ≤ 0.3°, v_s − 0.4° … v_s + 0.2° around that scan's inflection v_s) make the
   cut-off there; ``max_candidates`` of them may move, those of the scan farthest from
   the median first, then by share.
3. **Search.** Coordinate search on the candidates' vertical shifts, the scan farthest
   from the three's median first: each candidate in turn is moved by ``step_fractions`` ×
   its scan's distance to the median (|Δv| ≤ ``bound_deg``), each try a simulation of the whole
   lamp with the reference's seed and photons (common random numbers: the comparison sees
   geometry, not noise), and the best try is kept if it lowers

       J_lin = w · hinge((target − spread) / 0.2°)² + (every other term of the design's
               J on that map: the rules of every rule set with the interval the README
               demo is expected to show, sharpness, aim, reach, foreground)
               + κ · Σ_rules max(0, min(m_r⁰, c) − m_r)²

   (hinge(m) = max(0, −m)², w = ``weight``; m_r the log-margin of rule r, m_r⁰ its margin
   on the reference run, κ = ``keep``, c = ``keep_cap``: a rule may not lose the margin it
   had, up to c); every candidate is tried, also after the spread is within the target
   (a second scan's facet moved toward the median can give back what the first move
   cost a rule). The last term matters:
   a zone IV that passes by 0.2 % can become "uncertain" in the README demo once its
   cut-off is levelled (measured: 2 730 → 2 469 cd at 32 M photons).
3b. **Repair.** For the ``repair_rules`` rules that lost most (more than ``repair_min``),
   the ``repair_facets`` facets brightest at the rule's decisive probe (a point's place,
   a zone's extreme) are tried at ``repair_steps_deg`` from where they stand, kept as in
   3 if the spread stays within max(target, the levelled spread).
4. **Validation.** The start and the end lamp are simulated once more with a fresh seed;
   the shifts are kept only if the end lamp's spread and J_lin are lower there too.

Parameters (the fields of :class:`LinearitySettings`)

==================  =====  ===========  ==============================================
name                unit   default      meaning
==================  =====  ===========  ==============================================
photons             –      4 000 000    photons of every whole-lamp run
footprint_photons   –      500 000      photons per footprint run (candidates only)
resolution          px     320 × 128    check wall W × H (the README demo's)
target_deg          deg    0.12         spread asked for (annex 9 allows 0.2°)
share_min           1      0.05         top-window light share of a candidate
max_candidates      –      4            candidates that may move
step_fractions      1      ½, ¾, 1, 1¼  tries per candidate (× its scan's gap)
bound_deg           deg    0.5          largest |Δv| of one try
weight              –      10           w above
keep, keep_cap      –, 1   10, 0.2      κ and c above
repair_rules        –      2            rules repaired (those that lost most)
repair_facets       –      2            facets tried per repaired rule
repair_min          1      0.02         log-margin lost that asks for a repair
repair_steps_deg    deg    +0.05, +0.1, tries per repair facet, from where it stands
                           +0.2, −0.1
==================  =====  ===========  ==============================================
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.render.cutoff import LINEARITY_DEG, find_cutoff
from lightsim.wall import WallFrame, sample_wall

from .design_lamp import Layout, simulate_lamp, with_shifts, write_design
from .design_terms import Term, hinge, map_results, map_terms, ruleset_probes
from .facet_model import measure_footprints
from .regulations import load_ruleset
from .regulations.ruleset import iter_rule_names

__all__ = ["TOP_WINDOW_DEG", "LinearityResult", "LinearitySettings", "linearity_step",
           "top_window_shares"]

TOP_WINDOW_DEG = (0.3, 0.4, 0.2)
"""Half-width in H, depth under and height over a scan's inflection (deg) of the window
whose light makes the cut-off at that scan."""


@dataclass
class LinearityResult:
    """Outcome of :func:`linearity_step`.

    Attributes
    ----------
    spread_before_deg, spread_after_deg : float or None
        Spread of the three scans' inflections (deg) on the reference run and on the
        re-simulated lamp that was kept (the reference's when nothing was kept).
    inflections_before_deg, inflections_after_deg : list of float
        The scans' inflections (deg, V up), in the order of the scans.
    candidates : list of int
        Facet indices (the lamp's facet list) that were allowed to move (the moved ones
        first once kept).
    shifts_deg : list of float
        Δv (deg) of each moved facet, as kept (empty: nothing kept).
    accepted_step : float
        1 when the shifts were kept, 0 when not.
    remeasured : list of dict
        The fresh-seed check: ``seed``, and the start and end lamps' ``objective`` and
        ``spread_deg``.
    objective_start, objective_end : float
        J_lin of the reference run and of the search's best lamp (same seed).
    evaluations : int
        Simulated tries of the search.
    seconds : float
    """

    spread_before_deg: float | None
    spread_after_deg: float | None
    inflections_before_deg: list[float] = field(default_factory=list)
    inflections_after_deg: list[float] = field(default_factory=list)
    candidates: list[int] = field(default_factory=list)
    shifts_deg: list[float] = field(default_factory=list)
    accepted_step: float = 0.0
    remeasured: list[dict[str, Any]] = field(default_factory=list)
    objective_start: float = math.nan
    objective_end: float = math.nan
    evaluations: int = 0
    seconds: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (for the design record: a GLB's extras take no NaN, so an
        objective never computed is None)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in asdict(self).items()}


def _inflections(lux: np.ndarray, frame: Any, traffic: str) -> tuple[list[float], float | None]:
    """The annex-9 scans' inflections (deg, the scans that found one) and their spread."""
    cut = find_cutoff(lux, frame, traffic)
    return ([float(s.v_inflection_deg) for s in cut.scans if s.found], cut.spread_deg)


def top_window_shares(footprints: np.ndarray, total: np.ndarray, frame: Any,
                      scans: Sequence[tuple[float, float]]) -> np.ndarray:
    """Share of each footprint in each scan's top window.

    Parameters
    ----------
    footprints : ndarray, shape (K, H, W)
        Wall lux (lx) of each facet alone.
    total : ndarray, shape (H, W)
        Wall lux (lx) of the whole lamp.
    frame : WallFrame or dict
    scans : sequence of (h_deg, v_inflection_deg)

    Returns
    -------
    ndarray, shape (K, len(scans))
        Σ footprint / Σ total over the window (0 where the window holds no light).
    """
    wf = WallFrame.from_any(frame)
    hh, vv = np.meshgrid(wf.h_deg(), wf.v_deg())
    dh, below, above = TOP_WINDOW_DEG
    out = np.zeros((len(footprints), len(scans)))
    for j, (h_s, v_s) in enumerate(scans):
        win = (np.abs(hh - h_s) <= dh) & (vv >= v_s - below) & (vv <= v_s + above)
        tot = float(np.sum(np.maximum(total[win], 0.0)))
        if tot > 0:
            out[:, j] = np.maximum(footprints[:, win].sum(axis=1), 0.0) / tot
    return out


@dataclass
class Trial:
    """One simulated lamp of the search: J_lin, spread (deg), inflections (deg), wall lux
    (lx), the rules' log-margins, the margin each rule lost beyond what it may, shifts."""

    objective: float
    spread: float | None
    v: list[float]
    lux: np.ndarray
    margins: dict[str, float]
    lost: dict[str, float]
    shifts: dict[int, float]


def _deg(v: float | None) -> str:
    """An angle for the progress notes (``-`` when there is none)."""
    return "-" if v is None else f"{v:.3f}°"


def _rule_names(regulations: Sequence[str]) -> set[str]:
    """Term names of every rule of the rule sets, as the design's J names them (rules of
    the second and later sets carry the set's id)."""
    out = set()
    for i, name in enumerate(regulations):
        rs = load_ruleset(name)
        out |= {n if i == 0 else f"{n} ({rs.id})" for n in iter_rule_names(rs)}
    return out


def _rule_places(regulations: Sequence[str], lux: np.ndarray, frame: Any, traffic: str,
                 noise_cd: float) -> dict[str, tuple[float, float]]:
    """(h, v) deg of each rule's decisive probe (a point's place, a zone's extreme) on
    ``lux``, named as the design's J names them."""
    frame = WallFrame.from_any(frame).to_dict()
    out = {}
    for i, name in enumerate(regulations):
        rs, probes = ruleset_probes(name, traffic, frame)
        for r in map_results(rs, probes, lux, frame, traffic, noise_cd, 0.0):
            if r.get("h_deg") is not None and r.get("v_deg") is not None:
                out[r["name"] if i == 0 else f"{r['name']} ({rs.id})"] = (
                    float(r["h_deg"]), float(r["v_deg"]))
    return out


@dataclass(frozen=True)
class LinearitySettings:
    """Settings of :func:`linearity_step` (the module's parameter table).

    Attributes
    ----------
    photons : int
        Photons of every whole-lamp run.
    footprint_photons : int
        Photons per footprint run (candidates only).
    resolution : tuple of int
        Check wall W × H, px (the README demo's).
    seed : int
        Photon seed of the reference run and every try (``seed + 1``: the fresh-seed check).
    target_deg : float
        Spread of the three scans' inflections asked for, deg (annex 9 allows 0.2°).
    share_min : float
        Top-window light share that makes a facet a candidate.
    max_candidates : int
        Candidates that may move.
    step_fractions : tuple of float
        Tries per candidate, × its scan's distance to the median.
    bound_deg : float
        Largest |Δv| of one try, deg.
    weight : float
        w: weight of the linearity term in J_lin.
    keep, keep_cap : float
        κ and c: a rule may not lose the margin it had (up to c), at κ × the loss².
    repair_rules, repair_facets : int
        Rules repaired (those that lost most) and facets tried per repaired rule.
    repair_min : float
        Log-margin lost that asks for a repair.
    repair_steps_deg : tuple of float
        Tries per repair facet, deg, from where it stands.
    """

    photons: int = 4_000_000
    footprint_photons: int = 500_000
    resolution: tuple[int, int] = (320, 128)
    seed: int = 1
    target_deg: float = 0.12
    share_min: float = 0.05
    max_candidates: int = 4
    step_fractions: tuple[float, ...] = (0.5, 0.75, 1.0, 1.25)
    bound_deg: float = 0.5
    weight: float = 10.0
    keep: float = 10.0
    keep_cap: float = 0.2
    repair_rules: int = 2
    repair_facets: int = 2
    repair_min: float = 0.02
    repair_steps_deg: tuple[float, ...] = (0.05, 0.1, 0.2, -0.1)


def linearity_step(x: np.ndarray, layout: Layout, regulations: Sequence[str],
                   settings: LinearitySettings | None = None, *,
                   terms_kw: dict[str, Any] | None = None,
                   note: Callable[[str], None] | None = None) -> tuple[Layout, LinearityResult]:
    """Level the cut-off over the three annex-9 scans (see the module docstring).

    Parameters
    ----------
    x, layout
        The lamp (design vector and :class:`~lightsim.luminaires.design_lamp.Layout`, with
        its facet shifts).
    regulations : sequence of str
        Rule set ids; their rules are terms of J_lin.
    settings : LinearitySettings
        Photons, wall, seed and the search's tuning (default: :class:`LinearitySettings`).
    terms_kw : dict
        Keyword arguments of :func:`~lightsim.luminaires.design_terms.map_terms`
        (``safety``, ``reach_m``, ``smooth_max``, ``noise_cd``, ``foreground_m``,
        ``reach_weight``).

    Returns
    -------
    (Layout, LinearityResult)
        The layout with the kept shifts added to its facet shifts, and what was done.
    """
    st = LinearitySettings() if settings is None else settings
    t0 = time.perf_counter()
    kw = dict(terms_kw or {})
    regs = list(regulations)

    def say(text: str) -> None:
        if note is not None:
            note("linearity step: " + text)

    with tempfile.TemporaryDirectory(prefix="lightsim-linearity-") as tmp:
        glb = Path(tmp) / "level.glb"
        frame: Any = None

        def measure(dv: dict[int, float], s: int, m_ref: dict[str, float] | None
                    ) -> Trial:
            """The lamp with shifts ``dv`` (facet → Δv deg) simulated with seed ``s``;
            ``m_ref``: the rules' log-margins a rule may not lose (see ``keep``)."""
            nonlocal frame
            ks = sorted(dv)
            lay = with_shifts(layout, ks, np.array([[0.0, dv[k]] for k in ks]).reshape(-1, 2))
            write_design(glb, x, lay)
            _r, lux, frame = simulate_lamp(glb, regs[0], photons=st.photons,
                                           resolution=st.resolution, seed=s,
                                           traffic=layout.traffic, aim=False)
            lux = np.nan_to_num(np.asarray(lux, float))
            v, spread = _inflections(lux, frame, layout.traffic)
            terms = [t for t in map_terms(lux, frame, regs, layout.traffic, **kw)
                     if t.name != "linearity"]
            m = -10.0 if spread is None else (st.target_deg - spread) / LINEARITY_DEG
            terms.append(Term("linearity", m, st.weight * hinge(m), spread,
                              f"≤ {st.target_deg:g}° apart"))
            margins = {t.name: t.margin for t in terms if t.name in rule_names}
            lost = {n: min(m_ref[n], st.keep_cap) - mg for n, mg in margins.items()
                    if m_ref is not None and n in m_ref and mg < min(m_ref[n], st.keep_cap)}
            j = float(sum(t.penalty for t in terms)) + st.keep * sum(d * d for d in lost.values())
            return Trial(j, spread, v, lux, margins, lost, dict(dv))

        rule_names = _rule_names(regs)
        start = measure({}, st.seed, None)
        j0, spread0, v0, ref = start.objective, start.spread, start.v, start.lux
        result = LinearityResult(spread0, spread0, v0, v0, objective_start=j0)
        if spread0 is None or spread0 <= st.target_deg:
            say("no cut-off on every scan" if spread0 is None
                else f"spread {spread0:.3f}° already ≤ {st.target_deg:g}°")
            result.seconds = time.perf_counter() - t0
            return layout, result
        model = measure_footprints(x, layout, regs[0], photons=st.footprint_photons,
                                   resolution=st.resolution, seed=st.seed)
        cut0 = find_cutoff(ref, frame, layout.traffic)
        scans = [(s.h_deg, s.v_inflection_deg) for s in cut0.scans]
        share = top_window_shares(model.footprints, ref, frame, scans)
        # the scan farthest from the others' median first, its facets by share: the
        # outlying edge is the one to move (moving the others to it would shift the
        # cut-off's level near V, where the glare points are)
        med = float(np.median(v0))
        pairs = sorted(((abs(v0[j] - med), share[i, j], int(model.facets[i]), j)
                        for j in range(len(scans)) for i in range(len(model.facets))
                        if share[i, j] >= st.share_min), reverse=True)
        cand: list[tuple[int, int]] = []
        for _dev, _sh, k, j in pairs:
            if k not in [c[0] for c in cand] and len(cand) < st.max_candidates:
                cand.append((k, j))
        result.candidates = [k for k, _j in cand]
        say(f"scans {', '.join(f'{v:+.3f}°' for v in v0)} (spread {spread0:.3f}°), "
            f"J_lin {j0:.4f}; candidates (facet: scan, top-window share) "
            + ", ".join(f"{k}: {abs(scans[j][0]):g}°, "
                        f"{share[model.facets.index(k), j]:.2f}" for k, j in cand))
        m0 = start.margins
        cur = start

        def best_of(k: int, steps: Sequence[float], what: str,
                    spread_max: float = math.inf) -> None:
            """Simulate facet ``k`` moved by each of ``steps`` (deg) from where it stands;
            keep the best if it lowers J_lin (and its spread is at most ``spread_max``)."""
            nonlocal cur
            best = None
            for d in steps:
                trial = {**cur.shifts, k: cur.shifts.get(k, 0.0) + float(d)}
                t = measure(trial, st.seed, m0)
                result.evaluations += 1
                say(f"{what}: facet {k} {trial[k]:+.3f}°: scans "
                    + ", ".join(f"{q:+.3f}°" for q in t.v) + f", J_lin {t.objective:.4f}"
                    + (f"; lost: {', '.join(f'{n} {d:.3f}' for n, d in t.lost.items())}"
                       if t.lost else ""))
                if (len(t.v) == len(v0) and t.spread is not None and t.spread <= spread_max
                        and (best is None or t.objective < best.objective)):
                    best = t
            if best is not None and best.objective < cur.objective and best.spread is not None:
                cur = best

        # 1. level the outlying scans
        for k, jscan in cand:
            # each try moves the facet by a fraction of its scan's distance to the median
            gap = float(np.median(cur.v)) - cur.v[jscan]
            if abs(gap) < 0.02:
                continue
            # every candidate is tried, also once the spread is within the target: moving
            # a second scan's facets toward the median can give back what a rule lost to
            # the first (measured: lowering the 3.5° L facet cost zone IV at 0.86D 3.5° L,
            # raising the 1.5° L one gave some of it back)
            best_of(k, [float(np.clip(f * gap, -st.bound_deg, st.bound_deg))
                        for f in st.step_fractions], "level")
        # 2. repair the rules the levelling cost: the facets brightest at each rule's
        # decisive probe move a little up or down
        if cur.shifts:
            places = _rule_places(regs, cur.lux, frame, layout.traffic, kw.get("noise_cd", 0.0))
            # a repair may not undo the levelling
            level = max(st.target_deg, float(cur.spread))
            short = [n for n, d in sorted(cur.lost.items(), key=lambda t: -t[1])
                     if d > st.repair_min][:st.repair_rules]
            for name in short:
                if name not in places or cur.lost.get(name, 0.0) <= st.repair_min:
                    continue
                h, v = places[name]
                at = np.array([float(sample_wall(fp, frame, np.array([h]), np.array([v]),
                                                 outside=0.0)[0])
                               for fp in model.footprints])
                for i in np.argsort(-at, kind="stable")[:st.repair_facets]:
                    k = int(model.facets[i])
                    if cur.lost.get(name, 0.0) <= st.repair_min:
                        break
                    best_of(k, st.repair_steps_deg, f"repair {name}", level)
        result.objective_end = cur.objective
        if cur.shifts:
            # a fresh seed: the kept shifts must beat the start on other photons too
            a_ = measure({}, st.seed + 1, None)
            b_ = measure(cur.shifts, st.seed + 1, a_.margins)
            result.remeasured = [{"seed": st.seed + 1,
                                  "start": {"objective": a_.objective,
                                            "spread_deg": a_.spread},
                                  "end": {"objective": b_.objective, "spread_deg": b_.spread,
                                          "lost": b_.lost}}]
            ok = (a_.spread is not None and b_.spread is not None and b_.spread < a_.spread
                  and b_.objective < a_.objective)
            say(f"fresh seed {st.seed + 1}: spread {_deg(a_.spread)} → {_deg(b_.spread)}, "
                f"J_lin {a_.objective:.4f} → {b_.objective:.4f}: "
                + ("kept" if ok else "dropped"))
            if ok:
                ks = sorted(cur.shifts)
                layout = with_shifts(layout, ks,
                                      np.array([[0.0, cur.shifts[k]] for k in ks]))
                result.accepted_step = 1.0
                result.shifts_deg = [float(cur.shifts[k]) for k in ks]
                result.candidates = ks + [k for k, _j in cand if k not in cur.shifts]
                result.spread_after_deg = cur.spread
                result.inflections_after_deg = cur.v
    result.seconds = time.perf_counter() - t0
    return layout, result
