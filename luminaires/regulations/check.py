"""Regulation checks of a run: test points measured per interleave set, verdicts with
intervals, ``probes.npz`` for re-evaluation, and the :class:`RegulationAnalysis` that
``lightsim simulate --regulation`` hands to the run.

:func:`regulation_check` asks every interleave set for its estimate at the rule set's
test points and zone samples, so each value comes with a confidence interval from the
independent sets; the per-set values are saved in ``probes.npz`` so that
``lightsim report`` can re-evaluate (or evaluate another rule set's limits) without
shooting again.

======================  =====  =========  ===============================================
parameter               unit   default    meaning
======================  =====  =========  ===============================================
``ruleset``             –      –          rule-set id or file (:mod:`lightsim.luminaires.
                                          regulations`), e.g. ``r112-b-passing``
``traffic``             –      right      right- or left-hand traffic (mirrors H)
``aim``                 –      off        shift the pattern so the cut-off inflection sits
                                          at 0.57° D (R112 annex 9) before testing
``confidence``          –      0.95       two-sided level of the intervals
``aperture``            deg    0.15       side of the square detector aperture of every
                                          test point (0: kNN density estimate instead)
``aim_reach``           deg    1.5        how far the apertures can follow ``--aim``
``aim_substeps``        –      5          aim resolution: aperture / 5 = 0.03°
``imax_raster``         deg    see below  H −20…20°, V −6…4° (within the wall) tiled with
                                          apertures for Imax
======================  =====  =========  ===============================================

Test points as a goniophotometer measures them (default). Every interleave set counts the
wall photons inside a square aperture of side ``aperture`` around each test point and zone
sample (``lightsim.engine.apertures``): I = flux / solid angle, unbiased per set, so the
Student-t interval over the sets is an interval for the aperture's mean intensity. The
default 0.15° is the angular size of a 65 mm square receiver at 25 m — the receiver size
we recall from the ECE headlamp regulations' measuring conditions (not confirmed against
the regulation text here: check it, or pass ``--aperture``). A smaller aperture resolves a
cut-off more finely but catches fewer photons (wider intervals).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.special import stdtrit

from lightsim import options
from lightsim.analysis import AnalysisReport, FinishedRun
from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path
from lightsim.render.cutoff import find_cutoff
from lightsim.render.frame import luminous
from lightsim.report import IntensityEvidence, aperture_values
from lightsim.simulate import SimulateOptions
from lightsim.wall import WallFrame, candela_from_lux, lux_from_candela, wall_m_from_deg

from .evaluate import evaluate, format_table, probe_points, unevaluated_rules
from .ruleset import RuleSet, load_ruleset

__all__ = ["DEFAULT_APERTURE_DEG", "PROBES_FILE", "RegulationAnalysis", "aperture_config",
           "evaluate_probe_values", "format_regulation", "probes_file", "public",
           "recheck_from_probes", "regulation_check", "regulation_key",
           "regulation_probes", "regulation_tables", "save_probes", "split_rulesets"]

PROBES_FILE = "probes.npz"

DEFAULT_APERTURE_DEG = 0.15
"""Side of the square detector aperture (deg): 65 mm at 25 m."""
AIM_REACH_DEG = 1.5
AIM_SUBSTEPS = 5
IMAX_RASTER_DEG = (-20.0, 20.0, -6.0, 4.0)
MEASURE_NAMES = {"HV": "HV", "Imax": "Imax"}
"""Names of the reported rows (suffixed when a rule set has rules of that name)."""


def _frame_dict(frame: Any) -> dict[str, Any]:
    return frame.to_dict() if hasattr(frame, "to_dict") else dict(frame)


def regulation_probes(ruleset: str, traffic: str, frame: Any, lux: np.ndarray, aim: bool
                      ) -> tuple[Any, Any, dict[str, Any], np.ndarray]:
    """Probe directions for ``ruleset`` and their wall positions in the *unaimed* pattern.

    Returns
    -------
    rs, probes, aim_info, hv : RuleSet, Probes, dict, (P, 2) wall metres
    """
    rs = load_ruleset(ruleset)
    fd = _frame_dict(frame)
    cut = find_cutoff(lux, fd, traffic)
    dv = 0.0
    if aim:
        if not cut.found:
            raise InputError(f"--aim: {cut.message}")
        dv = float(cut.aim_dv_deg)
    probes = probe_points(rs, traffic, frame=fd)
    d = float(fd["distance_m"])
    # aiming moves the pattern up by dv: the aimed value at v is the unaimed one at v − dv
    hv = np.stack([wall_m_from_deg(probes.h_deg, d), wall_m_from_deg(probes.v_deg - dv, d)],
                  axis=1)
    aim_info = {"applied": bool(aim), "dh_deg": 0.0, "dv_deg": dv, "cutoff": cut.to_dict()}
    return rs, probes, aim_info, hv


def evaluate_probe_values(rs: Any, probes: Any, hv: np.ndarray, values_lux: np.ndarray,
                          distance_m: float, traffic: str, confidence: float = 0.95,
                          count_stats: np.ndarray | None = None
                          ) -> tuple[list[dict[str, Any]], list[dict[str, str]], np.ndarray]:
    """Per-set lux at the probes (S, P) → candela → verdicts with intervals (with the
    probes' photon statistics ``count_stats`` (4, P) where they were counted)."""
    cd = candela_from_lux(values_lux, hv[:, 0][None, :], hv[:, 1][None, :], distance_m)
    results = evaluate(rs, probes, cd, traffic=traffic, confidence=confidence,
                       count_stats=count_stats)
    return results, unevaluated_rules(rs, probes), cd


def aperture_config(config: Any, ruleset: str, traffic: str, frame: Any,
                    aperture_deg: float | None = DEFAULT_APERTURE_DEG, aim: bool = False,
                    spt: bool = False) -> Any:
    """``config`` with the detector apertures of ``ruleset``'s probes (before the run).

    Apertures: every probe of :func:`~lightsim.luminaires.regulations.probe_points`, then
    H-V; the Imax raster; with ``aim`` strips reaching ±``AIM_REACH_DEG``; with ``spt``
    the rule set's *points* are the Selective Photon Tracing targets. Apertures already
    in ``config`` (another rule set of the same run) are kept and these are appended
    after them: :func:`aperture_offset` tells a rule set where its own begin.
    """
    if aperture_deg is None or aperture_deg == 0:
        return config
    options.lookup(SimulateOptions, "aperture").check(aperture_deg)  # the option table's range
    rs = load_ruleset(ruleset)
    fd = _frame_dict(frame)
    probes = probe_points(rs, traffic, frame=fd)
    h = np.append(probes.h_deg, 0.0)
    v = np.append(probes.v_deg, 0.0)
    kinds = {g.name: g.kind for g in rs.geometries}
    targets = tuple(i for i, lab in enumerate(probes.labels) if kinds.get(lab) == "point")
    h0, h1, v0, v1 = WallFrame.from_any(fd).extent_deg()
    r = IMAX_RASTER_DEG
    raster = (max(r[0], h0), min(r[1], h1), max(r[2], v0), min(r[3], v1))
    if raster[1] - raster[0] < aperture_deg or raster[3] - raster[2] < aperture_deg:
        raster = None
    before = tuple(config.apertures)
    if before and (float(config.aperture_deg) != float(aperture_deg)
                   or bool(config.aperture_shift_deg) != bool(aim)):
        raise InputError("rule sets of one run share one aperture size and --aim")
    offset = len(before)
    targets = tuple(offset + t for t in targets) if spt else ()
    return config.with_(apertures=before + tuple(zip(h.tolist(), v.tolist(), strict=True)),
                        aperture_deg=float(aperture_deg),
                        aperture_shift_deg=AIM_REACH_DEG if aim else 0.0,
                        aperture_substeps=AIM_SUBSTEPS if aim else 1,
                        aperture_targets=tuple(config.aperture_targets) + targets,
                        aperture_raster=raster)


def _own_apertures(ap: dict[str, Any], offset: int, n: int) -> dict[str, Any]:
    """:func:`aperture_values` restricted to one rule set's ``n`` probes + H-V, which
    start at aperture ``offset`` (several rule sets share a run's apertures)."""
    cut = slice(offset, offset + n + 1)
    return {**ap, "cd": ap["cd"][:, cut], "intervals_cd": ap["intervals_cd"][cut],
            "count_stats": ap["count_stats"][:, cut], "n_eff": ap["n_eff"][cut]}


def _stat_row(name: str, h: float, v: float, samples: np.ndarray, bounds: Any, note: str,
              confidence: float) -> dict[str, Any]:
    """A reported (not limited) row: the mean of the per-set values ``samples`` and the
    interval of ``bounds`` (:class:`~lightsim.report.Bounds` of that one intensity)."""
    S = len(samples)
    mean = float(np.mean(samples))
    if bounds.counted[0]:
        lo, hi = float(bounds.lo[0]), float(bounds.hi[0])
    else:  # Student-t over the sets, never below 0, room for unseen heavy photons
        half = (float(stdtrit(S - 1, 0.5 + confidence / 2) * np.std(samples, ddof=1)
                      / math.sqrt(S)) if S > 1 else 0.0)
        lo = max(mean - half, 0.0)
        hi = max(mean + half, float(bounds.unseen[0])) if S > 1 else mean
    return {"name": name, "kind": "measure", "h_deg": float(h), "v_deg": float(v),
            "value_cd": mean, "interval_cd": [lo, hi], "limit": {},
            "verdict": "info", "certainty": "sure", "note": note, "source": "lightsim",
            "error_estimate": S > 1, "confidence": float(confidence)}


def measure_rows(ap: dict[str, Any], dv_deg: float, confidence: float) -> list[dict[str, Any]]:
    """HV and Imax rows (value, direction, interval) from :func:`aperture_values`.

    HV's interval is its aperture's (the rule of :class:`~lightsim.report.
    IntensityEvidence`). Imax is the raster tile with the largest mean over the sets;
    its interval is that tile's Student-t one (the maximum of noisy tiles is biased
    upwards by about the tiles' noise).
    """
    tail = (1.0 - confidence) / 2.0
    hv = IntensityEvidence(ap["cd"][:, -1:], ap["count_stats"][:, -1:])
    rows = [_stat_row(MEASURE_NAMES["HV"], 0.0, 0.0, ap["cd"][:, -1], hv.each([0], tail, tail),
                      "intensity towards H-V (aperture count)", confidence)]
    tiles = ap["tiles"]
    if tiles.size:
        mean = tiles.mean(axis=0)
        i, k = np.unravel_index(int(np.argmax(mean)), mean.shape)
        tile = IntensityEvidence(tiles[:, i, k][:, None]).each([0], tail, tail)
        rows.append(_stat_row(MEASURE_NAMES["Imax"], ap["tile_h_deg"][i],
                              ap["tile_v_deg"][k] + dv_deg, tiles[:, i, k], tile,
                              "largest aperture-tile mean over the raster", confidence))
    return rows


def regulation_check(session, lux: np.ndarray, ruleset: str, traffic: str = "right",
                     aim: bool = False, confidence: float = 0.95, offset: int = 0
                     ) -> dict[str, Any]:
    """Evaluate a rule set on a finished session.

    With the run's detector apertures (:func:`aperture_config`; this rule set's start at
    aperture ``offset``) the test points are the per-set aperture counts; without, every
    set's kNN estimate at the probes.
    """
    frame = session.scene.wall
    rs, probes, aim_info, hv = regulation_probes(ruleset, traffic, frame, lux, aim)
    m = measure_probes(session, rs, probes, hv, aim_info, confidence, offset)
    results, unevaluated, cd = evaluate_probe_values(rs, probes, hv, m.values_lux,
                                                     frame.distance_m, traffic, confidence,
                                                     m.count_stats)
    return {"ruleset": rs.id, "title": rs.title, "version": rs.version, "traffic": traffic,
            "confidence": confidence, "aim": aim_info, "method": m.method,
            "results": results + m.extra, "unevaluated": unevaluated, "_probes": probes,
            "_hv": hv, "_values_lux": m.values_lux, "_cd": cd,
            "_count_stats": m.count_stats}


@dataclass(frozen=True)
class ProbeMeasure:
    """What a session measured at a rule set's probes (:func:`measure_probes`).

    Attributes
    ----------
    values_lux : ndarray, shape (S, P)
        Per-set values at the probes as wall lux (a point source's lux for apertures).
    count_stats : ndarray, shape (4, P), or None
        The apertures' photon statistics (None for kNN estimates).
    extra : list of dict
        The HV and Imax rows (apertures only).
    method : dict
        ``summary.json``'s ``method`` of the table (aperture layout or kNN).
    shift_deg : float
        The vertical shift the apertures were read at (deg; −aim, rounded to a bin).
    """

    values_lux: np.ndarray
    count_stats: np.ndarray | None
    extra: list[dict[str, Any]]
    method: dict[str, Any]
    shift_deg: float = 0.0


def measure_probes(session, rs: RuleSet, probes: Any, hv: np.ndarray,
                   aim_info: dict[str, Any], confidence: float = 0.95, offset: int = 0
                   ) -> ProbeMeasure:
    """Per-set values at rule set ``rs``'s probes now: the detector apertures from aperture
    ``offset`` on when the run counts them (shifted by the aim ``aim_info["dv_deg"]``,
    which gains ``aperture_dv_deg``), else every set's kNN estimate at ``hv`` (wall m
    from H-V)."""
    frame = session.scene.wall
    cfg = session.config
    if cfg.apertures and len(cfg.apertures) >= offset + len(probes) + 1:
        ap = _own_apertures(aperture_values(session, -aim_info["dv_deg"], confidence),
                            offset, len(probes))
        # the aimed value at v is the unaimed one at v − dv: apertures shift by −dv,
        # rounded to a strip bin (aperture / AIM_SUBSTEPS)
        if aim_info.get("applied"):
            aim_info["aperture_dv_deg"] = -ap["shift_deg"]
        cd = ap["cd"][:, :-1]
        values = lux_equivalent(cd, hv, frame.distance_m)
        taken = {g.name for g in rs.geometries}
        extra = [r if r["name"] not in taken else {**r, "name": f"{r['name']} (measured)"}
                 for r in measure_rows(ap, -ap["shift_deg"], confidence)]
        method = {"name": "aperture", **ap["layout"].to_dict(),
                  "spt_targets": len(cfg.aperture_targets)}
        return ProbeMeasure(values, ap["count_stats"][:, :-1], extra, method,
                            float(ap["shift_deg"]))
    # probes take wall coordinates (from the wall centre), hv is from H-V
    stats = session.probe(hv + np.asarray(frame.hv_offset_m)) if len(hv) else None
    values = (luminous(stats.values) if stats is not None
              else np.zeros((session.config.n_sets, 0)))
    return ProbeMeasure(values, None, [], {"name": "knn"})


def lux_equivalent(cd: np.ndarray, hv: np.ndarray, distance_m: float) -> np.ndarray:
    """Candela at the probes → the wall lux a point source there gives (I·D/r³), so that
    probes.npz keeps one unit whichever way the values were measured."""
    return lux_from_candela(cd, hv[:, 0][None, :], hv[:, 1][None, :], distance_m)


def public(reg: dict[str, Any]) -> dict[str, Any]:
    """The JSON part of a regulation check (drops the arrays)."""
    return {k: v for k, v in reg.items() if not k.startswith("_")}


def probes_file(ruleset: str | None = None) -> str:
    """``probes.npz`` for a run's first rule set, ``probes-ID.npz`` for a further one."""
    return PROBES_FILE if ruleset is None else f"probes-{Path(ruleset).stem}.npz"


def save_probes(out: Path, reg: dict[str, Any], name: str = PROBES_FILE) -> Path:
    """Write the per-set probe values of a regulation check to ``out/name``."""
    probes = reg["_probes"]
    path = Path(out) / name
    with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
        np.savez(fh, h_deg=probes.h_deg, v_deg=probes.v_deg,
                 labels=np.asarray(probes.labels, dtype=str), hv_m=reg["_hv"],
                 values_lux=reg["_values_lux"], ruleset=np.asarray(reg["ruleset"]),
                 count_stats=(np.full((4, len(probes)), np.nan)
                              if reg.get("_count_stats") is None else reg["_count_stats"]),
                 traffic=np.asarray(reg["traffic"]), aim_dv_deg=reg["aim"]["dv_deg"])
    return path


def recheck_from_probes(out: Path, summary: dict[str, Any], lux: np.ndarray,
                        ruleset: str | None = None, confidence: float = 0.95
                        ) -> dict[str, Any]:
    """Re-evaluate a finished run's regulation from ``probes.npz`` (no shooting); a
    ``ruleset`` that was the run's second or later set is read from its own
    ``probes-ID.npz``."""
    path = Path(out) / PROBES_FILE
    if ruleset and (Path(out) / probes_file(ruleset)).exists():
        path = Path(out) / probes_file(ruleset)
    if not path.exists():
        raise InputError(f"{out}: no {PROBES_FILE}: run simulate with --regulation first")
    try:
        data = np.load(path, allow_pickle=False)
        old = str(data["ruleset"])
        traffic = str(data["traffic"])
        dv = float(data["aim_dv_deg"])
        values, hv = data["values_lux"], data["hv_m"]
        count = data["count_stats"] if "count_stats" in data else None
    except (KeyError, ValueError, OSError) as exc:
        raise InputError(f"{path}: corrupt probe file ({exc})") from None
    rs = load_ruleset(ruleset or old)
    probes = probe_points(rs, traffic, frame=summary["wall"])
    if ruleset and rs.id != old:
        raise InputError(f"{PROBES_FILE} holds the probes of '{old}', not '{rs.id}': run "
                         f"simulate --regulation {rs.id}")
    if len(probes) != values.shape[1]:
        raise InputError(f"{PROBES_FILE} does not match rule set '{rs.id}' (changed file?)")
    if count is not None and not np.isfinite(count).all():
        count = None  # a kNN run's file: no photon statistics
    results, unevaluated, _ = evaluate_probe_values(
        rs, probes, hv, values, float(summary["wall"]["distance_m"]), traffic, confidence,
        count)
    prev = summary.get(regulation_key(rs.id, summary), {})
    measures = [r for r in prev.get("results", []) if r.get("kind") == "measure"]
    out = {"ruleset": rs.id, "title": rs.title, "version": rs.version, "traffic": traffic,
           "confidence": confidence,
           "aim": prev.get("aim", {"applied": dv != 0.0, "dh_deg": 0.0, "dv_deg": dv}),
           "method": prev.get("method", {"name": "knn"}),
           "results": results + measures, "unevaluated": unevaluated}
    seq = prev.get("sequential") if prev.get("ruleset") == rs.id else None
    if seq is not None:
        if float(prev.get("confidence", 0.95)) == float(confidence):
            # --until decided: the verdicts were decided over the run's looks, which the
            # final photons alone cannot repeat: the run's table stands
            return {**out, "results": prev["results"], "sequential": seq}
        out["sequential_note"] = (
            f"re-evaluated at {confidence:.0%} from the run's final photons as one fixed "
            "sample: the run's --until decided verdicts hold at "
            f"{float(prev.get('confidence', 0.95)):.0%} over its looks, these do not")
    return out


def format_regulation(reg: dict[str, Any]):
    """A rich table of the verdicts (for the terminal)."""
    aim = reg.get("aim", {})
    note = f", aimed {aim['dv_deg']:+.2f}° V" if aim.get("applied") else ""
    ci = aim.get("cutoff_interval_deg")
    if aim.get("applied") and ci:
        note += f" (cut-off found at {0.5 * (ci[0] + ci[1]):+.3f}° ± {0.5 * (ci[1] - ci[0]):.3f}°)"
    seq = reg.get("sequential")
    if seq:  # --until decided: the intervals hold over every look of the run
        note += (f"; decided {seq['decided']} of {seq['decided'] + len(seq['open'])} "
                 f"over {seq['looks']} looks")
    title = (f"{reg['ruleset']} ({reg['traffic']}-hand traffic{note}; "
             f"{int(reg['confidence'] * 100)}% intervals)")
    if reg.get("sequential_note"):
        title += f"\n{reg['sequential_note']}"
    return format_table(reg["results"], title=title, unevaluated=reg.get("unevaluated"))


def regulation_key(ruleset: str, summary: dict[str, Any]) -> str:
    """The ``summary.json`` key of ``ruleset``'s table: ``regulation`` for the run's
    first rule set, ``regulation:ID`` for a further one."""
    key = f"regulation:{ruleset}"
    return key if key in summary else "regulation"


def regulation_tables(summary: dict[str, Any]) -> list[dict[str, Any]]:
    """Every rule set's table of a run's summary, in the order they were asked for."""
    return [v for k, v in summary.items()
            if (k == "regulation" or k.startswith("regulation:")) and isinstance(v, dict)]


def split_rulesets(text: str) -> list[str]:
    """``--regulation a,b``: the rule sets named, in order, without repeats."""
    names = [t.strip() for t in str(text).split(",")]
    if not all(names):
        raise InputError(f"--regulation '{text}': an empty rule set name in the list")
    return list(dict.fromkeys(names))


@dataclass
class RegulationAnalysis:
    """``--regulation``: apertures at the rule set's test points before the run, the
    verdict table and ``probes.npz`` after it (an :class:`~lightsim.analysis.Analysis`).

    Loading the rule set at construction makes an unknown one fail before any work.
    Several rule sets in one run are several analyses: the first is named
    ``regulation`` and writes ``probes.npz``, a further one ``regulation:ID`` and
    ``probes-ID.npz``; each counts its own apertures, appended to the run's.

    ``until`` (``--until decided``): the :class:`~lightsim.luminaires.regulations.
    sequential.VerdictRule` every rule set of the run shares. Each analysis registers its
    rule set with it in :meth:`prepare`, the run is handed it (:meth:`stopping_rule`), and
    the table then holds its running verdicts (:meth:`report`).
    """

    ruleset: str
    traffic: str = "right"
    aim: bool = False
    aperture_deg: float | None = DEFAULT_APERTURE_DEG
    spt_points: bool = False
    confidence: float = 0.95
    name: str = "regulation"
    until: Any = None
    rules: RuleSet = field(init=False, repr=False)
    offset: int = field(default=0, init=False)  # where this set's apertures start
    index: int = field(default=-1, init=False)  # this rule set's place in ``until``
    last: dict[str, Any] | None = field(default=None, init=False, repr=False,
                                        compare=False)  # the last table (--provenance)

    def __post_init__(self) -> None:
        self.rules = load_ruleset(self.ruleset)

    @property
    def reads_photons(self) -> str | None:
        """The option that makes the check read kNN estimates at its test points after
        the run (``--aperture 0``; None: it reads its detector apertures only)."""
        return "--aperture 0" if not self.aperture_deg else None

    @property
    def probes_name(self) -> str:
        """The probe file this analysis writes."""
        return (PROBES_FILE if self.name == "regulation"
                else probes_file(self.name.split(":", 1)[1]))

    def prepare(self, config: Any, scene: Any) -> Any:
        """Detector apertures (and SPT targets) at the test points; the rule set joins
        the stopping rule (``until``)."""
        self.offset = len(config.apertures)
        if self.until is not None:
            self.index = self.until.add(self.ruleset, self.traffic, self.aim, self.offset)
        return aperture_config(config, self.ruleset, self.traffic, scene.wall,
                               self.aperture_deg, self.aim, self.spt_points)

    def stopping_rule(self, session: Any, cap_photons: int) -> Any:
        """The run's stopping rule bound to ``session`` (None without ``until``; the
        first rule set of the run binds the shared rule, the others return it too)."""
        if self.until is None:
            return None
        if self.until.session is not session:
            self.until.bind(session, cap_photons)
        return self.until

    def stop_summary(self) -> dict[str, Any] | None:
        """``summary.json["until"]`` (None without ``until``)."""
        return None if self.until is None else self.until.summary()

    def stop_progress(self) -> str:
        """The stopping rule's progress line ("" without ``until``)."""
        return "" if self.until is None else self.until.progress_text()

    def report(self, run: FinishedRun, out: Path) -> AnalysisReport:
        """Verdicts with intervals; the probe file in ``out``."""
        if self.until is not None and self.index >= 0 and self.until.session is run.session:
            reg = self.until.check(self.index, run.session, run.lux)
        else:
            reg = regulation_check(run.session, run.lux, self.ruleset, self.traffic,
                                   self.aim, self.confidence, self.offset)
        path = save_probes(out, reg, self.probes_name)
        self.last = reg  # read by --provenance (the same rows, not evaluated twice)
        summary = public(reg)
        if summary.get("aim", {}).get("applied"):
            summary["aim"]["cutoff_interval_deg"] = run.cutoff.get("v_cutoff_interval_deg")
        return AnalysisReport(summary, marks=reg["results"], files=[path])
