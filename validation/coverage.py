"""Coverage of the regulation intervals and the verdicts' errors, on lamps with known answers.

``lightsim validate --coverage`` builds many synthetic low-beam intensity distributions
with a sharp cut-off (:func:`synthetic_lamp`), writes each to a Type A IES file (the
headlamp type) in a temporary folder, loads it as a user would (``load_scene(path)``: a
goniometric point source in front of the 25 m wall), runs the engine with detector
apertures at the rule sets' probes
(:func:`lightsim.luminaires.regulations.check.aperture_config`) and compares the results
with the exact answers: every probe's aperture mean of the file's intensity,

    I_true = ∫_aperture I(ω) dΩ / Ω,

integrated with ``quad`` × ``quad`` midpoints in (H, V) weighted by the exact
dΩ = sec²H sec²V / (1 + tan²H + tan²V)^{3/2} dH dV. The intensity is the one the source
samples: the file's bilinear interpolant :meth:`HVGrid.intensity_hv` (the goniometric
sampler draws exactly from it, see :mod:`~lightsim.emitters.polar`). The true value of
every rule — point, sum, zone maximum or minimum, relation ratio — and its true verdict
follow from these exact intensities through the same rule evaluation
(:func:`~lightsim.luminaires.regulations.evaluate` on one exact "set").

Reported, per photon count:

* the share of (lamp, point) evaluations whose 95 % interval covers the truth (target
  93–97 %), the worst single evaluation's bias in units of its interval half-width and
  the worst *point's* mean bias over the lamps (a systematic error shows there; for an
  unbiased estimator it is ≈ N(0, 1/(1.96²·n_lamps)));
* per kind of rule (point, sum, zone, relation): how often the interval covers the true
  value (for a relation: the ratio interval the true ratio) and the **wrong verdicts** — a
  "pass" where the truth fails or a "fail" where it passes. Each verdict is wrong with
  probability at most α/2 = 2.5 % whatever the truth (and far less when the truth is far
  from the limit), so the count is compared with α/2 × evaluations.

The shipped lamps (:func:`shipped_study`, ``--lamp FILE``) have no exact answer: a long
reference run (48 M photons by default; its per-set probe values kept in a folder of the
study's choosing or a temporary folder, never in the repository) stands in for it. A
rule's true verdict is known where the reference decides it at 99.9 % (it is left out of
the verdict count elsewhere); its value is the reference's, whose own error is
≈ √(photons / reference) of the runs', so the coverage there is slightly below nominal.

==================  =====  ================  =============================================
parameter           unit   default           meaning
==================  =====  ================  =============================================
lamps               –      40 (quick 4)      synthetic lamps
photons             –      1 000 000         photons per lamp (the CLI takes several)
aperture_deg        deg    0.15              detector aperture side
ruleset             –      r112-b-passing,   rule sets tested (the first one's points and
                           r149-b-passing    H-V make the point-coverage table)
spt                 –      False             Selective Photon Tracing aimed at the points
guide               –      False             importance-driven emission aimed at the test
                                             points and zones (``--guide points``)
quad                –      64                midpoints per aperture side for a point's truth
zone_quad           –      16                the same for zone samples
seed                –      1                 lamp parameters and photon sequences
seeds               –      8                 runs per shipped lamp and photon count
reference_photons   –      48 000 000        photons of a shipped lamp's reference run
==================  =====  ================  =============================================
"""

from __future__ import annotations

import hashlib
import json
import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import binom

from lightsim.engine.apertures import rect_solid_angle
from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.io.atomic import atomic_path
from lightsim.luminaires.photometric import HVGrid, hv_directions, read_ies, write_ies
from lightsim.luminaires.photometric.candela import hv_from_directions
from lightsim.luminaires.regulations import Probes, evaluate, load_ruleset, probe_points
from lightsim.luminaires.regulations.check import (
    aperture_config,
    regulation_check,
    split_rulesets,
)
from lightsim.luminaires.regulations.sequential import GuideTargets
from lightsim.render.frame import luminous
from lightsim.report import aperture_values
from lightsim.scene import SceneSettings, load_scene
from lightsim.simulate import SimulateOptions, load

__all__ = ["COVERAGE_BAND", "DEFAULT_RULESETS", "RULE_KINDS", "CoverageResult", "LampRun",
           "RuleOutcome", "ShippedStudy", "SptGain", "VerdictCount", "aperture_truth",
           "count_verdicts", "coverage_study", "distinct", "exact_truths", "reference_truths",
           "rule_outcomes", "run_lamp", "shipped_study", "simulate_checks", "spt_gain",
           "synthetic_lamp"]

COVERAGE_BAND = (0.93, 0.97)
"""Target share of 95 % intervals that cover the truth."""
DEFAULT_RULESETS = "r112-b-passing,r149-b-passing"
"""Rule sets the studies test: R112's points and sums, R149's zones and relation."""
DEFAULT_CACHE = Path(tempfile.gettempdir()) / "lightsim-coverage"
"""Where a shipped lamp's reference run is kept unless the study is given a folder."""
CUTOFF_STEP_DEG = 15.0
"""Slope of the right-hand-traffic cut-off's rising part (R112: 15°)."""


def _axis(fine_lo: float, fine_hi: float, fine: float, lo: float, hi: float, coarse: float
          ) -> NDArray:
    a = np.arange(lo, fine_lo, coarse)
    b = np.arange(fine_lo, fine_hi + 1e-9, fine)
    c = np.arange(fine_hi + coarse, hi + 1e-9, coarse)
    return np.round(np.concatenate([a, b, c]), 9)


def lamp_intensity(h: NDArray, v: NDArray, p: dict[str, float]) -> NDArray:
    """Intensity (cd) of the synthetic low beam with parameters ``p`` at wall angles (deg).

    A hot spot and a wide spread below a sharp cut-off: flat at ``vc`` left of V-V,
    rising at 15° right of it by ``rise`` (right-hand traffic); above it a dim glare
    region ``glare`` × the spread that falls off upwards.
    """
    hot = p["I0"] * np.exp(-0.5 * ((h - p["h0"]) / p["sh"]) ** 2
                           - 0.5 * ((v - p["v0"]) / p["sv"]) ** 2)
    spread = p["I1"] * np.exp(-0.5 * (h / p["wh"]) ** 2 - 0.5 * ((v + 2.0) / p["wv"]) ** 2)
    cut = p["vc"] + np.clip(h, 0.0, p["rise"] / math.tan(math.radians(CUTOFF_STEP_DEG))
                            ) * math.tan(math.radians(CUTOFF_STEP_DEG))
    glare = p["glare"] * p["I1"] * np.exp(-0.5 * (h / p["wh"]) ** 2) * np.exp(
        -np.maximum(v - cut, 0.0) / 2.0)
    return np.where(v < cut, hot + spread, glare)


def synthetic_lamp(rng: np.random.Generator) -> tuple[Any, dict[str, float]]:
    """A random sharp cut-off low beam as a Type A :class:`HVGrid` and its parameters.

    Grid (Type A, the headlamp type: front hemisphere only): H every 0.25° within ±25°
    (5° out to ±90°), V every 0.1° within ±6° (1° to ±30°, 10° to ±90°). Each node's
    value is :func:`lamp_intensity` at the node's wall angles.
    """
    p = {"I0": rng.uniform(15e3, 35e3), "h0": rng.uniform(0.5, 2.5),
         "v0": rng.uniform(-2.0, -1.0), "sh": rng.uniform(2.0, 5.0),
         "sv": rng.uniform(0.8, 1.5), "I1": rng.uniform(2e3, 5e3),
         "wh": rng.uniform(12.0, 25.0), "wv": rng.uniform(2.0, 4.0),
         "vc": rng.uniform(-0.7, -0.4), "rise": rng.uniform(0.8, 1.2),
         "glare": rng.uniform(0.03, 0.1)}
    h_ax = _axis(-25.0, 25.0, 0.25, -90.0, 90.0, 5.0)
    v_ax = _axis(-30.0, 30.0, 1.0, -90.0, 90.0, 10.0)
    v_ax = np.unique(np.concatenate([v_ax, _axis(-6.0, 6.0, 0.1, -6.0, 6.0, 1.0)]))
    H, V = np.meshgrid(h_ax, v_ax, indexing="ij")
    d = hv_directions(H, V, "A")
    h, v = hv_from_directions(d)
    fwd = d[..., 2] > 1e-6  # H = ±90°, V = ±90° lie in the lamp's plane: zero there
    cd = np.where(fwd, lamp_intensity(np.nan_to_num(h), np.nan_to_num(v), p), 0.0)
    meta = {"luminaire": "lightsim synthetic low beam",
            "test": " ".join(f"{k}={val:.4g}" for k, val in p.items())}
    return HVGrid(h_ax, v_ax, cd, "A", None, meta), p


def aperture_truth(grid: Any, h_deg: NDArray, v_deg: NDArray, size_deg: float,
                   quad: int = 64) -> NDArray:
    """Exact aperture-mean intensity (cd) of ``grid`` at the square apertures (deg).

    ``grid`` is any photometric grid with ``intensity_hv`` (the interpolant its sampler
    draws from); ``quad`` × ``quad`` midpoints per aperture, weighted by the exact dΩ.
    """
    u = (np.arange(quad) + 0.5) / quad - 0.5
    out = np.zeros(len(h_deg))
    for n, (hc, vc) in enumerate(zip(h_deg, v_deg, strict=True)):
        H, V = np.meshgrid(hc + size_deg * u, vc + size_deg * u)
        th, tv = np.tan(np.radians(H)), np.tan(np.radians(V))
        w = (1 + th**2) * (1 + tv**2) / (1 + th**2 + tv**2) ** 1.5
        omega = rect_solid_angle(hc - size_deg / 2, hc + size_deg / 2,
                                 vc - size_deg / 2, vc + size_deg / 2)
        out[n] = (float(np.sum(grid.intensity_hv(H, V) * w))
                  * math.radians(size_deg / quad) ** 2 / omega)
    return out


@dataclass(frozen=True)
class RuleOutcome:
    """One rule's result in one run next to its true value and verdict.

    For a relation ``value``, ``lo``, ``hi`` and ``truth`` are the ratio lhs / rhs and its
    interval; otherwise the quantity the verdict judges, in cd. ``truth_verdict`` is None
    where the truth is not known well enough (a reference run that does not decide).
    """

    ruleset: str
    name: str
    kind: str
    value: float
    lo: float
    hi: float
    verdict: str
    truth: float | None
    truth_verdict: str | None

    @property
    def covered(self) -> bool | None:
        """The interval holds the true value (None: no true value)."""
        if self.truth is None:
            return None
        return bool(self.lo <= self.truth <= self.hi)

    @property
    def decisive(self) -> bool:
        """A "pass" or "fail" judged against a known true verdict."""
        return self.verdict in ("pass", "fail") and self.truth_verdict in ("pass", "fail")

    @property
    def wrong(self) -> bool:
        """A "pass" where the truth fails or a "fail" where it passes."""
        return self.decisive and self.verdict != self.truth_verdict

    def to_dict(self) -> dict[str, Any]:
        return {"ruleset": self.ruleset, "name": self.name, "kind": self.kind,
                "value": self.value, "interval": [self.lo, self.hi],
                "verdict": self.verdict, "truth": self.truth,
                "truth_verdict": self.truth_verdict}


RULE_KINDS = ("point", "sum", "zone", "relation")
"""The kinds of rule the verdict study counts."""


def _quantity(r: dict[str, Any]) -> tuple[float, float, float]:
    """(value, lo, hi) of the quantity a result's verdict judges (a relation's ratio)."""
    if r["kind"] == "relation":
        lo, hi = r["ratio_interval"]
        value = r["ratio"]
        return (math.nan if value is None else float(value), 0.0 if lo is None else lo,
                math.inf if hi is None else hi)
    return float(r["value_cd"]), float(r["interval_cd"][0]), float(r["interval_cd"][1])


def rule_outcomes(ruleset: str, results: list[dict[str, Any]],
                  truths: dict[str, tuple[float | None, str | None]]) -> list[RuleOutcome]:
    """Pair a rule set's results (:func:`~lightsim.luminaires.regulations.evaluate`) with
    the true value and verdict of each rule (``truths`` by rule name)."""
    out = []
    for r in results:
        if r.get("kind") not in RULE_KINDS or r["name"] not in truths:
            continue
        value, lo, hi = _quantity(r)
        truth, verdict = truths[r["name"]]
        out.append(RuleOutcome(ruleset, str(r["name"]), str(r["kind"]), value, lo, hi,
                               str(r["verdict"]), truth, verdict))
    return out


def distinct(outcomes: list[RuleOutcome]) -> list[RuleOutcome]:
    """The outcomes of one run without repeats: a rule that two rule sets share (R112's
    and R149's B50L, zone III, the glare sums) counts once, not twice."""
    seen: set[tuple[Any, ...]] = set()
    out = []
    for o in outcomes:
        key = (o.kind, o.value, o.lo, o.hi, o.verdict, o.truth, o.truth_verdict)
        if key not in seen:
            seen.add(key)
            out.append(o)
    return out


def exact_truths(rs: Any, probes: Any, truth_cd: NDArray
                 ) -> dict[str, tuple[float | None, str | None]]:
    """True value and verdict of every rule from the exact probe intensities: the rule
    evaluation on one exact set (its intervals collapse to the value)."""
    out: dict[str, tuple[float | None, str | None]] = {}
    for r in evaluate(rs, probes, truth_cd[None, :]):
        value = _quantity(r)[0]
        out[str(r["name"])] = (None if math.isnan(value) else value, str(r["verdict"]))
    return out


@dataclass(frozen=True)
class LampRun:
    """One lamp: per-set aperture intensities and the exact answers at its points, and
    every rule's outcome against its exact truth."""

    names: tuple[str, ...]
    h_deg: NDArray
    v_deg: NDArray
    per_set_cd: NDArray  # (S, P)
    interval_cd: NDArray  # (P, 2) as the regulation table reports it
    n_eff: NDArray  # (P,) photons counted in each aperture (effective number)
    truth_cd: NDArray  # (P,)
    seconds: float
    rules: tuple[RuleOutcome, ...] = ()


def point_apertures(ruleset: str, traffic: str, frame: Any
                    ) -> tuple[tuple[str, ...], NDArray, NDArray, NDArray]:
    """The rule set's points (plus H-V): names, H, V and their probe indices."""
    rs = load_ruleset(ruleset)
    probes = probe_points(rs, traffic, frame=frame.to_dict())
    kinds = {g.name: g.kind for g in rs.geometries}
    idx = [i for i, lab in enumerate(probes.labels) if kinds.get(lab) == "point"]
    idx.append(len(probes))  # H-V, appended by aperture_config
    names = tuple(probes.labels[i] for i in idx[:-1]) + ("HV",)
    h = np.append(probes.h_deg, 0.0)[idx]
    v = np.append(probes.v_deg, 0.0)[idx]
    return names, h, v, np.asarray(idx)


def run_lamp(path: str | Path, photons: int, *, aperture_deg: float = 0.15,
             ruleset: str = DEFAULT_RULESETS, traffic: str = "right", spt: bool = False,
             seed: int = 1, quad: int = 64, config: RunConfig | None = None,
             confidence: float = 0.95, zone_quad: int = 16, guide: bool = False) -> LampRun:
    """Simulate the IES file at ``path`` as a point source, measure its test points and
    judge every rule of ``ruleset`` (one id or several, comma-separated) as
    ``lightsim simulate --regulation`` does, next to the exact answers (``guide``: with
    ``--guide points``)."""
    scene = load_scene(str(path), SceneSettings(resolution=(160, 64)))
    cfg = config or RunConfig(seed=seed, estimator="bin", frame_photons=250_000)
    if guide:
        cfg = cfg.with_(guide="points")
    names_rs = split_rulesets(ruleset)
    offsets = []
    for rs_name in names_rs:
        offsets.append(len(cfg.apertures))
        cfg = aperture_config(cfg, rs_name, traffic, scene.wall, aperture_deg, spt=spt)
    if guide:  # one target per point or zone, as simulate --guide points aims
        cfg = GuideTargets(tuple(names_rs), traffic).prepare(cfg, scene)
    names, h, v, idx = point_apertures(names_rs[0], traffic, scene.wall)
    t0 = time.perf_counter()
    session = Session(scene, cfg)
    try:
        while sum(session.emitted_per_set().values()) < photons:
            session.shoot(session.frame_photons(photons))  # the last frame partial
        ap = aperture_values(session, 0.0, confidence)
        cd = ap["cd"][:, idx]
        interval = ap["intervals_cd"][idx]
        n_eff = ap["n_eff"][idx]
        lux = luminous(session.final_image(probes=False).lux)
        checks = [regulation_check(session, lux, rs_name, traffic, False, confidence, off)
                  for rs_name, off in zip(names_rs, offsets, strict=True)]
    finally:
        session.close()
    seconds = time.perf_counter() - t0
    grid = read_ies(path)
    rules: list[RuleOutcome] = []
    for reg in checks:
        probes = reg["_probes"]
        exact = aperture_truth(grid, probes.h_deg, probes.v_deg, aperture_deg, zone_quad)
        rs = load_ruleset(reg["ruleset"])
        rules += rule_outcomes(reg["ruleset"], reg["results"],
                               exact_truths(rs, probes, exact))
    return LampRun(names, h, v, cd, interval, n_eff,
                   aperture_truth(grid, h, v, aperture_deg, quad), seconds,
                   tuple(distinct(rules)))


@dataclass
class VerdictCount:
    """Interval coverage and wrong verdicts of one kind of rule over many runs."""

    evaluations: int = 0
    with_truth: int = 0
    covered: int = 0
    decisive: int = 0
    wrong: int = 0
    uncertain: int = 0

    def add(self, o: RuleOutcome) -> None:
        self.evaluations += 1
        if o.covered is not None:
            self.with_truth += 1
            self.covered += int(o.covered)
        self.decisive += int(o.decisive)
        self.wrong += int(o.wrong)
        self.uncertain += int(o.verdict == "uncertain")

    def nominal(self, confidence: float = 0.95) -> float:
        """Wrong verdicts the nominal rate allows on average: α/2 per evaluation."""
        return 0.5 * (1.0 - confidence) * self.evaluations

    def allowed(self, confidence: float = 0.95, level: float = 0.999) -> int:
        """The most wrong verdicts the nominal rate explains: the ``level`` quantile of
        Binomial(evaluations, α/2)."""
        return int(binom.ppf(level, self.evaluations, 0.5 * (1.0 - confidence)))

    def to_dict(self) -> dict[str, Any]:
        return {"evaluations": self.evaluations, "with_truth": self.with_truth,
                "covered": self.covered, "decisive": self.decisive, "wrong": self.wrong,
                "uncertain": self.uncertain, "nominal_wrong": self.nominal(),
                "coverage": self.covered / self.with_truth if self.with_truth else None}


def count_verdicts(outcomes: list[RuleOutcome]) -> dict[str, VerdictCount]:
    """:class:`VerdictCount` per kind of rule (``RULE_KINDS`` order)."""
    out = {k: VerdictCount() for k in RULE_KINDS}
    for o in outcomes:
        out[o.kind].add(o)
    return out


@dataclass
class CoverageResult:
    """Coverage of the per-point 95 % intervals over lamps × points, and every rule's
    coverage and wrong verdicts (``rules``, by kind)."""

    lamps: int
    photons: int
    aperture_deg: float
    spt: bool
    evaluations: int
    covered: int
    worst_bias: float  # |mean − truth| / half-width, worst single evaluation
    worst_bias_point: str
    worst_mean_bias: float  # mean over lamps of (mean − truth)/half-width, worst point
    worst_mean_point: str
    seconds: float
    per_point: dict[str, dict[str, float]] = field(default_factory=dict)
    rules: dict[str, VerdictCount] = field(default_factory=dict)
    wrong_examples: list[RuleOutcome] = field(default_factory=list)
    guide: bool = False

    @property
    def rate(self) -> float:
        return self.covered / self.evaluations if self.evaluations else float("nan")

    @property
    def wrong_verdicts(self) -> int:
        """Wrong verdicts over every rule of every lamp."""
        return sum(c.wrong for c in self.rules.values())

    def band(self, z: float = 3.0) -> tuple[float, float]:
        """Accepted coverage: the 93–97 % target widened to 0.95 ± z binomial standard
        errors when there are too few evaluations to resolve it."""
        se = math.sqrt(0.95 * 0.05 / max(self.evaluations, 1))
        return min(COVERAGE_BAND[0], 0.95 - z * se), max(COVERAGE_BAND[1], 0.95 + z * se)

    def to_dict(self) -> dict[str, Any]:
        return {"lamps": self.lamps, "photons": self.photons,
                "aperture_deg": self.aperture_deg, "spt": self.spt, "guide": self.guide,
                "evaluations": self.evaluations, "covered": self.covered,
                "rate": self.rate, "worst_bias_halfwidths": self.worst_bias,
                "worst_bias_point": self.worst_bias_point,
                "worst_mean_bias_halfwidths": self.worst_mean_bias,
                "worst_mean_point": self.worst_mean_point, "seconds": self.seconds,
                "per_point": self.per_point,
                "rules": {k: c.to_dict() for k, c in self.rules.items()},
                "wrong_verdicts": self.wrong_verdicts,
                "wrong_examples": [o.to_dict() for o in self.wrong_examples]}


def coverage_study(lamps: int = 40, photons: int = 1_000_000, *, aperture_deg: float = 0.15,
                   ruleset: str = DEFAULT_RULESETS, spt: bool = False, seed: int = 1,
                   confidence: float = 0.95, quad: int = 64, zone_quad: int = 16,
                   progress: Callable[[int, LampRun], None] | None = None,
                   guide: bool = False) -> CoverageResult:
    """Run ``lamps`` synthetic lamps and count interval coverage and wrong verdicts (see
    the module docstring); ``guide``: every run with ``--guide points``."""
    if lamps < 1 or photons < 1000:
        raise ValueError("coverage study needs ≥ 1 lamp and ≥ 1000 photons")
    rng = np.random.default_rng([seed, 0xC0FE])
    t0 = time.perf_counter()
    cover, bias, names_all = [], [], []
    outcomes: list[RuleOutcome] = []
    with tempfile.TemporaryDirectory(prefix="lightsim-coverage-") as tmp:
        for n in range(lamps):
            grid, _ = synthetic_lamp(rng)
            path = Path(tmp) / f"lamp{n:03d}.ies"
            write_ies(path, grid)
            run = run_lamp(path, photons, aperture_deg=aperture_deg, ruleset=ruleset,
                           spt=spt, seed=seed + n, quad=quad, confidence=confidence,
                           zone_quad=zone_quad, guide=guide)
            mean = run.per_set_cd.mean(axis=0)
            lo, hi = run.interval_cd[:, 0], run.interval_cd[:, 1]
            err = mean - run.truth_cd
            cover.append((lo <= run.truth_cd) & (run.truth_cd <= hi))
            # bias in units of the interval's half-width on the truth's side
            half = np.where(err > 0, mean - lo, hi - mean)
            with np.errstate(divide="ignore", invalid="ignore"):
                b = np.where(half > 0, err / half, np.where(err == 0, 0.0, np.inf))
            bias.append(b)
            names_all.append(run.names)
            outcomes += run.rules
            if progress is not None:
                progress(n, run)
            path.unlink()
    cov = np.concatenate(cover)
    b_all = np.concatenate(bias)
    names = np.concatenate([np.asarray(nm) for nm in names_all])
    k = int(np.argmax(np.abs(b_all)))
    per_point: dict[str, dict[str, float]] = {}
    for nm in dict.fromkeys(names.tolist()):
        sel = names == nm
        finite = b_all[sel][np.isfinite(b_all[sel])]
        per_point[nm] = {"coverage": float(cov[sel].mean()),
                         "mean_bias_halfwidths": float(finite.mean()) if finite.size
                         else float("nan"),
                         "infinite": int((~np.isfinite(b_all[sel])).sum())}
    worst_pt = max(per_point, key=lambda q: abs(per_point[q]["mean_bias_halfwidths"])
                   if math.isfinite(per_point[q]["mean_bias_halfwidths"]) else math.inf)
    return CoverageResult(lamps, photons, aperture_deg, spt, int(cov.size),
                          int(cov.sum()), float(abs(b_all[k])), str(names[k]),
                          float(per_point[worst_pt]["mean_bias_halfwidths"]), worst_pt,
                          time.perf_counter() - t0, per_point, count_verdicts(outcomes),
                          [o for o in outcomes if o.wrong], guide)


# ---- shipped lamps against a long reference run -------------------------------------------
REFERENCE_PHOTONS = 48_000_000
"""Photons of a shipped lamp's reference run."""
REFERENCE_CONFIDENCE = 0.999
"""Level at which the reference must decide a rule for its verdict to count as the truth."""
REFERENCE_SEED = 10_001
"""Seed of the reference runs (apart from the studied runs' seeds 1, 2, …)."""
SHIPPED_RESOLUTION = (320, 128)
"""Wall pixels of the shipped-lamp runs (the apertures do not depend on them)."""


def simulate_checks(lamp: str | Path, photons: int, *, ruleset: str = DEFAULT_RULESETS,
                    seed: int = 1, confidence: float = 0.95,
                    resolution: tuple[int, int] = SHIPPED_RESOLUTION,
                    aperture_deg: float = 0.15, guide: bool = False
                    ) -> dict[str, dict[str, Any]]:
    """``lightsim simulate LAMP --photons N --regulation RULESET --seed S`` in this
    process, with the binning estimator (the apertures and verdicts do not depend on the
    map's estimator): every rule set's regulation check
    (:func:`~lightsim.luminaires.regulations.check.regulation_check`) by rule set id."""
    opts = SimulateOptions(str(lamp), photons=int(photons), resolution=tuple(resolution),
                           regulation=ruleset, aperture=aperture_deg,
                           config={"seed": int(seed), "estimator": "bin",
                                   "guide": "points" if guide else "off"})
    scene = load(opts)
    config, offsets = opts.run_config(), []
    rulesets = split_rulesets(ruleset)
    for rs in rulesets:
        offsets.append(len(config.apertures))
        config = aperture_config(config, rs, opts.traffic, scene.wall, opts.aperture)
    session = Session(scene, config, workers=0, regulation=ruleset)
    try:
        lux = luminous(session.run(photons=opts.photons).lux)
        return {rs: regulation_check(session, lux, rs, opts.traffic, False, confidence, off)
                for rs, off in zip(rulesets, offsets, strict=True)}
    finally:
        session.close()


def _file_digest(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def reference_truths(lamp: str | Path, *, ruleset: str = DEFAULT_RULESETS,
                     photons: int = REFERENCE_PHOTONS, cache_dir: str | Path,
                     aperture_deg: float = 0.15,
                     progress: Callable[[str], None] | None = None
                     ) -> dict[str, dict[str, tuple[float | None, str | None]]]:
    """True value and verdict of every rule of a shipped lamp from a long reference run,
    by rule set id and rule name (the verdict None where the reference does not decide
    at ``REFERENCE_CONFIDENCE``).

    The run is made once; its per-set probe values and photon statistics are kept in
    ``cache_dir`` (an ``.npz`` keyed by the lamp file's contents and the settings) and
    evaluated by the current rules each time they are read."""
    key = json.dumps([_file_digest(lamp), ruleset, int(photons), REFERENCE_SEED,
                      list(SHIPPED_RESOLUTION), aperture_deg])
    digest = hashlib.sha256(key.encode()).hexdigest()[:12]
    path = Path(cache_dir) / f"reference-{Path(lamp).stem}-{digest}.npz"
    rulesets = split_rulesets(ruleset)
    if not path.exists():
        if progress is not None:
            progress(f"reference run of {Path(lamp).name}: {photons:,} photons "
                     f"(kept in {path})")
        checks = simulate_checks(lamp, photons, ruleset=ruleset, seed=REFERENCE_SEED,
                                 aperture_deg=aperture_deg)
        arrays: dict[str, Any] = {"key": np.asarray(key)}
        for n, rs in enumerate(rulesets):
            reg = checks[rs]
            arrays[f"cd{n}"] = reg["_cd"]
            arrays[f"count{n}"] = (np.full((4, reg["_cd"].shape[1]), np.nan)
                                   if reg["_count_stats"] is None else reg["_count_stats"])
            arrays[f"probes{n}"] = np.asarray(json.dumps(reg["_probes"].to_dict()))
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
    data = np.load(path, allow_pickle=False)
    out: dict[str, dict[str, tuple[float | None, str | None]]] = {}
    for n, rs_name in enumerate(rulesets):
        rs = load_ruleset(rs_name)
        d = json.loads(str(data[f"probes{n}"]))
        probes = Probes(h_deg=np.asarray(d["h_deg"]), v_deg=np.asarray(d["v_deg"]),
                        labels=tuple(d["labels"]), ruleset_id=d["ruleset"],
                        traffic=d["traffic"], spacing_deg=d["spacing_deg"],
                        dropped=d["dropped"], clipped=d["clipped"])
        results = evaluate(rs, probes, data[f"cd{n}"], confidence=REFERENCE_CONFIDENCE,
                           count_stats=data[f"count{n}"])
        out[rs.id] = {}
        for r in results:
            if r.get("kind") not in RULE_KINDS:
                continue
            value = _quantity(r)[0]
            verdict = r["verdict"] if r["verdict"] in ("pass", "fail") else None
            out[rs.id][str(r["name"])] = (None if math.isnan(value) else value, verdict)
    return out


@dataclass
class ShippedStudy:
    """Wrong verdicts and coverage of one shipped lamp at one photon count over seeds."""

    lamp: str
    photons: int
    seeds: int
    reference_photons: int
    seconds: float
    rules: dict[str, VerdictCount]
    wrong_examples: list[RuleOutcome] = field(default_factory=list)

    @property
    def wrong_verdicts(self) -> int:
        return sum(c.wrong for c in self.rules.values())

    def to_dict(self) -> dict[str, Any]:
        return {"lamp": self.lamp, "photons": self.photons, "seeds": self.seeds,
                "reference_photons": self.reference_photons, "seconds": self.seconds,
                "rules": {k: c.to_dict() for k, c in self.rules.items()},
                "wrong_verdicts": self.wrong_verdicts,
                "wrong_examples": [o.to_dict() for o in self.wrong_examples]}


def shipped_study(lamp: str | Path, photons: int, seeds: int = 8, *,
                  ruleset: str = DEFAULT_RULESETS,
                  reference_photons: int = REFERENCE_PHOTONS,
                  cache_dir: str | Path | None = None, aperture_deg: float = 0.15,
                  progress: Callable[[str], None] | None = None,
                  guide: bool = False) -> ShippedStudy:
    """Run a shipped lamp ``seeds`` times at ``photons`` and judge every verdict against
    the reference run's (see the module docstring). ``cache_dir`` keeps the reference
    (default: a folder in the system's temporary directory)."""
    if seeds < 1 or photons < 1000:
        raise ValueError("a shipped-lamp study needs ≥ 1 seed and ≥ 1000 photons")
    cache = Path(cache_dir) if cache_dir is not None else DEFAULT_CACHE
    truths = reference_truths(lamp, ruleset=ruleset, photons=reference_photons,
                              cache_dir=cache, aperture_deg=aperture_deg, progress=progress)
    t0 = time.perf_counter()
    outcomes: list[RuleOutcome] = []
    for seed in range(1, seeds + 1):
        res = simulate_checks(lamp, photons, ruleset=ruleset, seed=seed,
                              aperture_deg=aperture_deg, guide=guide)
        outcomes += distinct([o for rs, reg in res.items()
                              for o in rule_outcomes(rs, reg["results"], truths.get(rs, {}))])
        if progress is not None:
            progress(f"{Path(lamp).name} {photons:,} photons, seed {seed}/{seeds}: "
                     f"{sum(o.wrong for o in outcomes)} wrong verdicts so far")
    return ShippedStudy(str(lamp), int(photons), seeds, int(reference_photons),
                        time.perf_counter() - t0, count_verdicts(outcomes),
                        [o for o in outcomes if o.wrong])


GLARE_POINTS = ("B50L", "1", "2", "3", "4", "5", "6", "7", "8")
"""The dim points above the cut-off where few photons land (SPT's target)."""


@dataclass
class SptGain:
    """Interval widths with and without test-point SPT for the same photons (and time)."""

    lamps: int
    photons: int
    width_plain: dict[str, float]  # mean relative 95 % width (hi − lo)/truth per point
    width_spt: dict[str, float]
    seconds_plain: float
    seconds_spt: float
    coverage_plain: float
    coverage_spt: float

    def glare_ratio(self) -> float:
        """Mean over the glare points of width(plain) / width(SPT): > 1 means SPT pays."""
        r = [self.width_plain[p] / self.width_spt[p] for p in GLARE_POINTS
             if p in self.width_plain and self.width_spt.get(p, 0) > 0]
        return float(np.mean(r)) if r else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {"lamps": self.lamps, "photons": self.photons,
                "width_plain": self.width_plain, "width_spt": self.width_spt,
                "seconds_plain": self.seconds_plain, "seconds_spt": self.seconds_spt,
                "coverage_plain": self.coverage_plain, "coverage_spt": self.coverage_spt,
                "glare_width_ratio": self.glare_ratio()}


def spt_gain(lamps: int = 4, photons: int = 1_000_000, *, aperture_deg: float = 0.15,
             seed: int = 1, quad: int = 48) -> SptGain:
    """Run the same synthetic lamps with and without SPT aimed at the test points."""
    rng = np.random.default_rng([seed, 0x5B7])
    widths: dict[bool, dict[str, list[float]]] = {False: {}, True: {}}
    secs = {False: 0.0, True: 0.0}
    cov: dict[bool, list[bool]] = {False: [], True: []}
    with tempfile.TemporaryDirectory(prefix="lightsim-spt-") as tmp:
        for n in range(lamps):
            grid, _ = synthetic_lamp(rng)
            path = Path(tmp) / f"lamp{n:03d}.ies"
            write_ies(path, grid)
            for spt in (False, True):
                run = run_lamp(path, photons, aperture_deg=aperture_deg, spt=spt,
                               seed=seed + n, quad=quad)
                secs[spt] += run.seconds
                lo, hi = run.interval_cd[:, 0], run.interval_cd[:, 1]
                cov[spt].extend(((lo <= run.truth_cd) & (run.truth_cd <= hi)).tolist())
                for name, w, t in zip(run.names, hi - lo, run.truth_cd, strict=True):
                    if t > 0:
                        widths[spt].setdefault(name, []).append(float(w / t))
    mean = {k: {p: float(np.mean(v)) for p, v in d.items()} for k, d in widths.items()}
    return SptGain(lamps, photons, mean[False], mean[True], secs[False], secs[True],
                   float(np.mean(cov[False])), float(np.mean(cov[True])))
