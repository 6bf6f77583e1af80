"""Bulb-tolerance study: regulation pass rates when the filament sits off its nominal place.

A production bulb's filament is not where the drawing puts it. This module moves the lit
filament (the scene's emitter parts) inside a tolerance box — and optionally tilts it about
its own centre — simulates every sample with **common random numbers** (the same seed,
interleave sets and photon indices for every sample, so two samples differ by geometry and
not by photon noise), evaluates the regulation on each and reports per test point the pass
probability with a binomial (Clopper–Pearson) interval, the worst sample, and a plot of the
value against each offset.

Only the filament moves: reflector, bulb glass, shield cup and lens stay in place (the R37
tolerances place the filament relative to the bulb's reference plane; a cup that moved with
it would be a different study). The box is centred on the filament as the scene places it.

Parameters of :func:`run_tolerance`

================  =====  ==========  =========================================================
name              unit   default     meaning
================  =====  ==========  =========================================================
box               –      by bulb     :class:`ToleranceBox` (half-widths in m, tilt in °)
samples           –      50          Latin-hypercube samples over the box (plus the nominal)
seed              –      1           seed of the sampling design (the photon seed is the
                                     run configuration's, the same for every sample)
tilt              –      False       also tilt the filament (two angles about X and Y)
workers           –      0           0: samples one after another in this process; N ≥ 1:
                                     N Ray tasks, one sample each (in-process session)
confidence        –      0.95        level of the pass-probability intervals
================  =====  ==========  =========================================================

Every sample is evaluated as ``lightsim simulate`` evaluates a run: the same session
configuration (detector apertures of ``aperture`` degrees at the test points by default, as
``simulate --aperture``; 0 = the kNN estimate instead), the same per-set values, intervals
and rule evaluation (:func:`lightsim.luminaires.regulations.check.regulation_check`). The
nominal sample *is* a plain ``simulate`` run of the same photons and seed: same values,
intervals and verdicts (tested). A sample "passes" a test point when its value meets the
limit (``value_pass``); it passes "surely" when the whole 95 % interval does
(``sure_pass``, the regulation table's ``pass``), and fails surely when the whole interval
misses the limit (verdict ``fail``). With common random numbers the samples share their
photons, so the *differences* between samples are mostly geometric even when every single
interval is wide (less so with apertures: a 0.2 mm shift moves a reflected ray by more than
a 0.15° aperture, so aperture counts are partly re-drawn). A zone's value is the largest of
its probes' means, biased upwards by the probes' noise at few photons — the same bias
``simulate`` has at those photons.

Sensitivity (:func:`fit_sensitivity`): per test point, an ordinary least-squares plane
``value ≈ c + Σ b_j·offset_j`` through all samples (the nominal included), reported as cd
per 0.1 mm along X, Y, Z (and per 0.1° of tilt) with standard errors from the residuals,
and the shift along each axis alone at which the plane reaches the limit (``reach_mm``) —
the figure to set a production tolerance with. Common random numbers keep the photon noise
out of the slopes as far as the estimator allows; the residual RMS says how far that is.

Tolerance boxes (:data:`TOLERANCE_BOXES`) — ASSUMPTIONS. The UN R37 category sheets (H1/…,
H4/…, H7/…) define the filament position by the distance e of the filament from the
reference plane, the lateral offsets of the filament axis from the reference axis and
their production tolerances. The published R37 texts (EUR-Lex OJ L 297 of 13.11.2010, R37
up to Supplement 34 to the 03 series; E/ECE/324/Rev.1/Add.36/Rev.8, 2015) were available
only in part, without the H1, H4 and H7 sheets. The only sheet figures at hand are those
of category H17 (sheet H17/2, Supplement 39 to the 03 series,
E/ECE/324/Rev.1/Add.36/Rev.7/Amend.2): e = 28.5 +0.35/−0.15 mm for lamps of normal
production (+0.20/−0.0 for the standard lamp) — a different category, quoted only to show
that the assumed axial ±0.35 mm is of the right size. The half-widths below are engineering
estimates; replace them with the sheet values when at hand — ``--box DX,DY,DZ`` does so
without code changes.
"""

from __future__ import annotations

import csv
import io
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import beta, qmc

from lightsim.engine.ray_backend import import_ray, init_ray
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes
from lightsim.io.caption import add_caption, png_metadata, run_text
from lightsim.io.summary import write_json
from lightsim.luminaires.regulations import load_ruleset
from lightsim.luminaires.regulations.check import aperture_config, regulation_check, split_rulesets
from lightsim.luminaires.regulations.sequential import VerdictRule
from lightsim.render.frame import luminous
from lightsim.scene import EMITTER, Scene
from lightsim.simulate import UNTIL_CAP_PHOTONS, check_until, load

__all__ = [
    "TOLERANCE_BOXES",
    "PointStats",
    "SampleResult",
    "Sensitivity",
    "ToleranceBox",
    "ToleranceStudy",
    "box_for_scene",
    "clopper_pearson",
    "displace_emitters",
    "fit_sensitivity",
    "run_sample",
    "run_tolerance",
    "sample_design",
    "study_from_dict",
    "summarise",
    "write_study",
]

MM = 1e-3


@dataclass(frozen=True)
class ToleranceBox:
    """Where a production filament may sit relative to its nominal position.

    Attributes
    ----------
    category : str
        Bulb category (``"H4"``).
    half_m : tuple of 3 float
        Half-widths of the box along the lamp axes X (lateral), Y (up), Z (axial), in m.
    tilt_deg : float
        Half-width of the filament-axis tilt about X and about Y, in degrees.
    source : str
        Where the figures come from.
    """

    category: str
    half_m: tuple[float, float, float]
    tilt_deg: float
    source: str


_ASSUMED = ("ASSUMPTION: engineering estimate of the UN R37 category-sheet production "
            "tolerance; the H1/H4/H7 sheets were not at hand (see "
            "lightsim.validation.tolerance, docs/guides/tolerance.md)")

#: Assumed boxes by bulb category (see the module docstring).
TOLERANCE_BOXES: dict[str, ToleranceBox] = {
    "H1": ToleranceBox("H1", (0.20 * MM, 0.20 * MM, 0.25 * MM), 1.0, _ASSUMED),
    "H4": ToleranceBox("H4", (0.20 * MM, 0.20 * MM, 0.35 * MM), 1.0, _ASSUMED),
    "H7": ToleranceBox("H7", (0.20 * MM, 0.20 * MM, 0.25 * MM), 1.0, _ASSUMED),
}


def box_for_scene(scene: Any, category: str | None = None) -> ToleranceBox:
    """The tolerance box of the scene's bulb (``extras.lightsim.bulb`` of its emitter) or of
    ``category``; :class:`InputError` when neither names a known category."""
    name = category
    if name is None:
        for p in scene.emitters:
            ls = (p.extras or {}).get("lightsim") or {}
            if ls.get("bulb"):
                name = str(ls["bulb"])
                break
    if name is None:
        raise InputError("the scene's emitter names no bulb: give --bulb H1|H4|H7 or --box")
    cat = str(name).upper().split("-")[0]
    if cat not in TOLERANCE_BOXES:
        raise InputError(f"no tolerance box for bulb {name!r}; known: "
                         f"{', '.join(TOLERANCE_BOXES)} (or give --box DX,DY,DZ in mm)")
    return TOLERANCE_BOXES[cat]


def sample_design(box: ToleranceBox, samples: int, seed: int = 1,
                  tilt: bool = False, centre_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
                  ) -> np.ndarray:
    """Latin-hypercube offsets over the box, the box centre (the nominal) first.

    ``centre_m`` shifts the whole box (m): a bulb holder that misplaces every bulb.

    Returns
    -------
    ndarray, shape (samples + 1, 5)
        Columns dx, dy, dz (m) and tilt about X, about Y (degrees; zero without ``tilt``).
    """
    if not isinstance(samples, int | np.integer) or samples < 1:
        raise InputError(f"--samples must be a whole number ≥ 1, got {samples!r}")
    d = 5 if tilt else 3
    u = qmc.LatinHypercube(d=d, seed=seed).random(int(samples))
    half = np.array([*box.half_m, box.tilt_deg, box.tilt_deg][:d])
    x = np.zeros((samples + 1, 5))
    x[1:, :d] = (2.0 * u - 1.0) * half
    c = np.asarray(centre_m, float)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise InputError(f"the box centre needs 3 finite numbers (m), got {centre_m!r}")
    x[:, :3] += c
    return x


def _rotation(ax_deg: float, ay_deg: float) -> np.ndarray:
    a, b = math.radians(ax_deg), math.radians(ay_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    return ry @ rx


def displace_emitters(scene: Any, offset: np.ndarray) -> Any:
    """A new scene whose emitter parts are tilted about their own centre (bounding-box
    centre) by ``offset[3:5]`` degrees (about X, then Y) and moved by ``offset[:3]`` m."""
    off = np.asarray(offset, float)
    if off.shape != (5,) or not np.all(np.isfinite(off)):
        raise InputError(f"a filament offset needs 5 finite numbers, got {offset!r}")
    rot = _rotation(off[3], off[4])
    parts = []
    for p in scene.parts:
        if p.role == EMITTER and p.vertices is not None and len(p.vertices):
            c = 0.5 * (p.vertices.min(axis=0) + p.vertices.max(axis=0))
            m = np.eye(4)
            m[:3, :3] = rot
            m[:3, 3] = c - rot @ c + off[:3]
            p = p.transformed(m)
        parts.append(p)
    return Scene(parts, scene.wall, scene.source, list(scene.warnings), scene.channels)


@dataclass
class SampleResult:
    """One sample of the study.

    Attributes
    ----------
    offset : list of 5 float
        dx, dy, dz (m), tilt about X and Y (°).
    names : list of str
        Test points (rule names), in the rule set's order.
    value_cd, lo_cd, hi_cd : list of float
        Value and 95 % interval per test point, in cd.
    value_pass, sure_pass : list of bool
        The value meets the limit / the whole interval does (verdict ``pass``).
    verdicts : list of str
        The regulation table's verdicts.
    seconds : float
        Wall-clock time of the sample, in s.
    photons : int or None
        ``--until decided``: photons the sample took until every verdict was decided (or
        its cap); None without it.
    decided : bool or None
        ``--until``: what the rule waits for was decided — every verdict (``decided``),
        the lamp's verdict (``verdict``); False: the cap came first.
    """

    offset: list[float]
    names: list[str]
    value_cd: list[float]
    lo_cd: list[float]
    hi_cd: list[float]
    value_pass: list[bool]
    sure_pass: list[bool]
    verdicts: list[str]
    limits: list[dict[str, float]] = field(default_factory=list)
    seconds: float = 0.0
    photons: int | None = None
    decided: bool | None = None


#: what a sample records only with ``--until decided`` (tolerance.json keeps its form
#: without it)
UNTIL_FIELDS = ("photons", "decided")


def _meets(value: float, limit: dict[str, float]) -> bool:
    lo, hi = limit.get("min"), limit.get("max")
    return ((lo is None or value >= lo) and (hi is None or value <= hi)) and math.isfinite(value)


def run_sample(opts: Any, offset: np.ndarray, scene: Any = None) -> SampleResult:
    """Simulate one displaced filament with ``opts`` (a :class:`SimulateOptions` with
    ``regulation`` and a ``photons`` budget) in this process and evaluate the rule set.

    The session is built exactly as :func:`lightsim.simulate.run_simulation` builds it
    (same configuration, apertures and seed), so the nominal sample reproduces a plain run.
    """
    t0 = time.perf_counter()
    base = scene if scene is not None else load(opts)
    moved = displace_emitters(base, offset)
    rulesets = split_rulesets(opts.regulation)
    # several rule sets: each appends its apertures to the run's, as simulate's analyses do
    config, offsets = opts.run_config(), []
    for rs in rulesets:
        offsets.append(len(config.apertures))
        config = aperture_config(config, rs, opts.traffic, moved.wall, opts.aperture,
                                 opts.aim, opts.spt_points)
    check_until(opts, config)
    session = Session(moved, config, workers=0, regulation=opts.regulation,
                      farfield=bool(opts.ies or opts.ldt))
    rule, photons = None, opts.photons
    if opts.until is not None:  # each sample stops when its verdicts are decided
        photons = opts.photons if opts.photons is not None else UNTIL_CAP_PHOTONS
        rule = VerdictRule(stop=opts.until)
        for rs, off in zip(rulesets, offsets, strict=True):
            rule.add(rs, opts.traffic, opts.aim, off)
        rule.bind(session, photons)
    try:
        est = session.run(photons=photons, seconds=opts.seconds,
                          target_error=opts.target_error, rule=rule)
        lux = luminous(est.lux)
        failed = None
        rows = []
        for i, (rs, off) in enumerate(zip(rulesets, offsets)):
            try:
                reg = (rule.check(i, session, lux) if rule is not None else
                       regulation_check(session, lux, rs, opts.traffic, opts.aim, offset=off))
            except InputError as exc:
                if not opts.aim:
                    raise
                # a lamp whose cut-off cannot be found cannot be aimed: it fails every point
                # (the values shown are the unaimed ones)
                failed = f"not aimable: {exc}"
                reg = regulation_check(session, lux, rs, opts.traffic, False, offset=off)
            prefix = f"{rs}:" if len(rulesets) > 1 else ""
            rows += [dict(r, name=prefix + str(r["name"])) for r in reg["results"]
                     if r.get("limit") and r.get("verdict") != "info"]
        used = int(session.photons_emitted()) if rule is not None else None
        decided = (failed is None and rule.finished()) if rule is not None else None
    finally:
        session.close()
    if failed is not None:
        return SampleResult(
            offset=[float(v) for v in offset], names=[str(r["name"]) for r in rows],
            value_cd=[float(r["value_cd"]) for r in rows],
            lo_cd=[float(r["interval_cd"][0]) for r in rows],
            hi_cd=[float(r["interval_cd"][1]) for r in rows],
            value_pass=[False] * len(rows), sure_pass=[False] * len(rows),
            verdicts=[failed] * len(rows), limits=[dict(r["limit"]) for r in rows],
            seconds=time.perf_counter() - t0, photons=used, decided=decided)
    return SampleResult(
        offset=[float(v) for v in offset],
        names=[str(r["name"]) for r in rows],
        value_cd=[float(r["value_cd"]) for r in rows],
        lo_cd=[float(r["interval_cd"][0]) for r in rows],
        hi_cd=[float(r["interval_cd"][1]) for r in rows],
        value_pass=[_meets(float(r["value_cd"]), r["limit"]) for r in rows],
        sure_pass=[r["verdict"] == "pass" for r in rows],
        verdicts=[str(r["verdict"]) for r in rows],
        limits=[dict(r["limit"]) for r in rows],
        seconds=time.perf_counter() - t0, photons=used, decided=decided,
    )


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact binomial interval of a pass probability: k passes out of n samples."""
    if n <= 0:
        return (0.0, 1.0)
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else float(beta.ppf(0.5 * a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - 0.5 * a, k + 1, n - k))
    return (lo, hi)


#: Offset axes of the design, their unit and the step the sensitivity is quoted per.
AXES = ("dx", "dy", "dz", "tilt_x", "tilt_y")
_STEP = np.array([0.1 * MM, 0.1 * MM, 0.1 * MM, 0.1, 0.1])  # 0.1 mm, 0.1 mm, 0.1 mm, 0.1°, 0.1°


@dataclass
class Sensitivity:
    """Least-squares plane through a test point's values over the samples.

    Attributes
    ----------
    axes : list of str
        The offsets the plane was fitted on (``dx, dy, dz`` and, with tilt, ``tilt_x,
        tilt_y``); an axis that does not vary over the samples is left out.
    per_step_cd : list of float
        Slope per axis, in cd per 0.1 mm (translations) or per 0.1° (tilts).
    se_cd : list of float
        Standard error of each slope (same unit; NaN when the samples do not exceed the
        fitted parameters; slopes too are NaN when there are fewer samples than
        parameters).
    centre_cd : float
        The plane's value at the box centre, in cd.
    rms_cd : float
        RMS residual of the samples about the plane, in cd (photon noise, and curvature).
    r2 : float
        Fraction of the samples' variance the plane explains (1 − RSS/TSS; NaN when the
        values do not vary). A low value says the point is noise-limited or not linear in
        the offsets (a zone maximum that jumps when filament images cross its edge): read
        the plot, not the slopes.
    reach_mm : list of float or None
        Per translation axis: the signed shift from the box centre, along that axis alone,
        at which the plane meets the nearest limit, in mm (0 when the plane's centre value
        already misses it); None when the slope is not resolved (|slope| < 2 standard
        errors) or the axis is not a translation.
    samples : int
        Samples with a finite value the plane was fitted to.
    """

    axes: list[str]
    per_step_cd: list[float]
    se_cd: list[float]
    centre_cd: float
    rms_cd: float
    reach_mm: list[float | None]
    samples: int
    r2: float = math.nan


def fit_sensitivity(offsets: np.ndarray, values: np.ndarray, limit: dict[str, float],
                    centre: np.ndarray | None = None) -> Sensitivity:
    """Fit ``value ≈ c + Σ b_j·(offset_j − centre_j)`` by ordinary least squares.

    Parameters
    ----------
    offsets : ndarray, shape (N, 5)
        dx, dy, dz (m) and tilt about X, Y (°) of every sample.
    values : ndarray, shape (N,)
        The test point's value per sample, in cd (non-finite values are left out).
    limit : dict
        ``{"min": cd, "max": cd}`` (either may be missing), for ``reach_mm``.
    centre : ndarray, shape (5,), optional
        The box centre the intercept refers to, in the units of ``offsets`` (default: the
        first sample's offset).

    Returns
    -------
    Sensitivity
    """
    off = np.asarray(offsets, float)
    val = np.asarray(values, float)
    ok = np.isfinite(val) & np.all(np.isfinite(off), axis=1)
    off, val = off[ok], val[ok]
    c = np.asarray(off[0] if centre is None and len(off) else
                   (np.zeros(5) if centre is None else centre), float)
    cols = [j for j in range(5) if len(off) and np.ptp(off[:, j]) > 0]
    x = np.column_stack([np.ones(len(off))] + [(off[:, j] - c[j]) / _STEP[j] for j in cols])
    n, p = x.shape
    if n < p:  # fewer samples than parameters: the plane is not determined
        return Sensitivity([AXES[j] for j in cols], [math.nan] * len(cols),
                           [math.nan] * len(cols), math.nan, math.nan,
                           [None] * len(cols), int(n), math.nan)
    coef, *_ = np.linalg.lstsq(x, val, rcond=None)
    resid = val - x @ coef
    rms = float(np.sqrt(np.mean(resid ** 2)))
    tss = float(np.sum((val - val.mean()) ** 2))
    r2 = 1.0 - float(resid @ resid) / tss if tss > 0 else math.nan
    if n > p:
        s2 = float(resid @ resid) / (n - p)
        se = np.sqrt(np.maximum(np.diag(s2 * np.linalg.pinv(x.T @ x)), 0.0))
    else:
        se = np.full(p, math.nan)
    at_centre = float(coef[0])
    reach: list[float | None] = []
    for k, j in enumerate(cols, start=1):
        b = float(coef[k])
        if j > 2 or not (math.isfinite(se[k]) and abs(b) >= 2.0 * se[k]) or b == 0.0:
            reach.append(None)
            continue
        if not _meets(at_centre, limit):
            reach.append(0.0)
            continue
        steps = [(lim - at_centre) / b for key in ("min", "max")
                 if (lim := limit.get(key)) is not None]
        reach.append(float(min(steps, key=abs) * _STEP[j] / MM) if steps else None)
    return Sensitivity(axes=[AXES[j] for j in cols],
                       per_step_cd=[float(b) for b in coef[1:]],
                       se_cd=[float(v) for v in se[1:]], centre_cd=at_centre, rms_cd=rms,
                       reach_mm=reach, samples=int(n), r2=r2)


@dataclass
class PointStats:
    """Pass statistics of one test point over the samples (the nominal excluded).

    Attributes
    ----------
    name : str
    limit : dict
        ``{"min": cd, "max": cd}`` (either may be missing).
    nominal_cd : float
        Value of the nominal (undisplaced) sample, in cd.
    nominal_verdict : str
    pass_rate : float
        Fraction of samples whose value meets the limit.
    pass_interval : tuple of 2 float
        Clopper–Pearson interval of ``pass_rate`` at the study's confidence.
    sure_pass_rate : float
        Fraction of samples whose whole 95 % interval meets the limit (verdict ``pass``).
    worst_cd : float
        The value of the sample with the smallest relative margin, in cd.
    worst_offset : list of 5 float
        Its offset (m, m, m, °, °).
    worst_margin : float
        Its relative margin (value/min − 1 or 1 − value/max; negative = fails).
    sure_fail_rate : float
        Fraction of samples whose whole interval misses the limit (verdict ``fail``).
    sensitivity : Sensitivity or None
        The least-squares plane of the value over all samples (:func:`fit_sensitivity`).
    """

    name: str
    limit: dict[str, float]
    nominal_cd: float
    nominal_verdict: str
    pass_rate: float
    pass_interval: tuple[float, float]
    sure_pass_rate: float
    worst_cd: float
    worst_offset: list[float]
    worst_margin: float
    sure_fail_rate: float = math.nan
    sensitivity: Sensitivity | None = None


def _margin(value: float, limit: dict[str, float]) -> float:
    """Relative margin to the limit (negative when failing), dimensionless."""
    m = math.inf
    if limit.get("min") is not None and limit["min"] > 0:
        m = min(m, value / limit["min"] - 1.0)
    if limit.get("max") is not None and limit["max"] > 0:
        m = min(m, 1.0 - value / limit["max"])
    return m if math.isfinite(m) else 0.0


@dataclass
class ToleranceStudy:
    """The whole study: box, design, every sample and the per-point statistics."""

    scene: str
    regulation: str
    box: ToleranceBox
    centre_m: list[float]
    tilt: bool
    seed: int
    photons: int | None
    confidence: float
    samples: list[SampleResult]
    points: list[PointStats]
    limits: dict[str, dict[str, float]] = field(default_factory=dict)
    seconds: float = 0.0
    workers: int = 0
    aperture_deg: float | None = None
    until: str | None = None

    @property
    def nominal(self) -> SampleResult:
        return self.samples[0]

    def all_pass_rate(self) -> tuple[float, tuple[float, float]]:
        """Fraction of samples (nominal excluded) meeting every limit, with its interval."""
        rest = self.samples[1:]
        k = sum(all(s.value_pass) for s in rest)
        return (k / len(rest) if rest else math.nan,
                clopper_pearson(k, len(rest), self.confidence))

    def to_dict(self) -> dict[str, Any]:
        rate, ci = self.all_pass_rate()
        return {"scene": self.scene, "regulation": self.regulation, "box": asdict(self.box),
                "centre_m": self.centre_m,
                "tilt": self.tilt, "seed": self.seed, "photons": self.photons,
                "confidence": self.confidence, "seconds": self.seconds,
                "workers": self.workers, "aperture_deg": self.aperture_deg,
                "method": "aperture" if self.aperture_deg else "knn",
                "units": {"offset": "m (dx, dy, dz), deg (tilt about X, Y)",
                          "intensity": "cd",
                          "sensitivity": "cd per 0.1 mm (dx, dy, dz), per 0.1 deg (tilts)",
                          "reach": "mm"},
                "all_points_pass_rate": rate, "all_points_pass_interval": list(ci),
                "points": [asdict(p) for p in self.points],
                "samples": [self._sample_dict(s) for s in self.samples],
                **({"until": self.until, "photons_used": self.photons_used()}
                   if self.until else {})}

    def _sample_dict(self, s: SampleResult) -> dict[str, Any]:
        d = asdict(s)
        if not self.until:  # without --until decided the samples keep their form
            for k in UNTIL_FIELDS:
                d.pop(k, None)
        return d

    def photons_used(self) -> dict[str, Any] | None:
        """``--until decided``: photons per sample (min, median, max, total) and how
        many samples decided every verdict before the cap; None without it."""
        used = [s.photons for s in self.samples if s.photons is not None]
        if not self.until or not used:
            return None
        return {"min": int(min(used)), "median": float(np.median(used)),
                "max": int(max(used)), "total": int(sum(used)),
                "decided": int(sum(bool(s.decided) for s in self.samples)),
                "samples": len(self.samples)}


def study_from_dict(doc: dict[str, Any]) -> ToleranceStudy:
    """A study back from its ``tolerance.json`` (:meth:`ToleranceStudy.to_dict`): the
    samples as stored, the per-point statistics recomputed by :func:`summarise`."""
    try:
        samples = [SampleResult(**{**s, **{k: [math.nan if v is None else float(v)
                                                 for v in s[k]]
                                             for k in ("value_cd", "lo_cd", "hi_cd")}})
                   for s in doc["samples"]]
        box = ToleranceBox(**{**doc["box"], "half_m": tuple(doc["box"]["half_m"])})
        limits = dict(zip(samples[0].names, samples[0].limits))
        conf = float(doc["confidence"])
        return ToleranceStudy(
            scene=doc["scene"], regulation=doc["regulation"], box=box,
            centre_m=list(doc["centre_m"]), tilt=bool(doc["tilt"]), seed=int(doc["seed"]),
            photons=doc["photons"], confidence=conf, samples=samples,
            points=summarise(samples, limits, conf), limits=limits,
            seconds=float(doc.get("seconds", 0.0)), workers=int(doc.get("workers", 0)),
            aperture_deg=doc.get("aperture_deg"), until=doc.get("until"))
    except (KeyError, TypeError, IndexError, ValueError) as exc:
        raise InputError(f"not a tolerance study ({type(exc).__name__}: {exc})") from None


def summarise(samples: list[SampleResult], limits: dict[str, dict[str, float]],
              confidence: float) -> list[PointStats]:
    """Per-point statistics over ``samples[1:]`` (``samples[0]`` is the nominal); the
    sensitivity plane uses every sample, the nominal included."""
    nom, rest = samples[0], samples[1:]
    offsets = np.array([s.offset for s in samples], float)
    out = []
    for i, name in enumerate(nom.names):
        lim = limits[name]
        vals = np.array([s.value_cd[i] for s in rest]) if rest else np.zeros(0)
        k = sum(s.value_pass[i] for s in rest)
        sure = sum(s.sure_pass[i] for s in rest)
        failed = sum(s.verdicts[i] == "fail" for s in rest)
        margins = [_margin(v, lim) for v in vals]
        j = int(np.argmin(margins)) if margins else -1
        n = len(rest)
        out.append(PointStats(
            name=name, limit=lim, nominal_cd=nom.value_cd[i],
            nominal_verdict=nom.verdicts[i],
            pass_rate=k / n if n else math.nan,
            pass_interval=clopper_pearson(k, n, confidence),
            sure_pass_rate=sure / n if n else math.nan,
            worst_cd=float(vals[j]) if n else nom.value_cd[i],
            worst_offset=rest[j].offset if n else nom.offset,
            worst_margin=float(margins[j]) if n else _margin(nom.value_cd[i], lim),
            sure_fail_rate=failed / n if n else math.nan,
            sensitivity=fit_sensitivity(offsets, np.array([s.value_cd[i] for s in samples]),
                                        lim, offsets[0])))
    return out


def _ray_map(fn: Callable[..., SampleResult], opts: Any, offsets: np.ndarray, workers: int,
             address: str | None, progress: Callable[[int, SampleResult], None] | None
             ) -> list[SampleResult]:
    """Run the samples as independent Ray tasks, at most ``workers`` at a time."""
    ray = import_ray()
    started = init_ray(address, workers)
    try:
        task = ray.remote(num_cpus=1)(fn)
        opts_ref = ray.put(opts)
        pending = {task.remote(opts_ref, off): i for i, off in enumerate(offsets)}
        out: list[SampleResult | None] = [None] * len(offsets)
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            i = pending.pop(done[0])
            out[i] = ray.get(done[0])
            if progress is not None:
                progress(i, out[i])
        return [o for o in out if o is not None]
    finally:
        if started:
            ray.shutdown()


def run_tolerance(opts: Any, *, samples: int = 50, seed: int = 1, tilt: bool = False,
                  box: ToleranceBox | None = None, workers: int = 0,
                  centre_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
                  address: str | None = None, confidence: float = 0.95,
                  progress: Callable[[int, SampleResult], None] | None = None
                  ) -> ToleranceStudy:
    """Run the study (see the module docstring).

    Parameters
    ----------
    opts : SimulateOptions
        The run every sample repeats (scene, ``regulation``, ``photons``, resolution, seed
        in ``config``); its ``workers`` is ignored (samples are the parallel unit).
    samples : int
        Latin-hypercube samples (the nominal is run in addition).
    centre_m : tuple of 3 float
        Offset of the box centre from the scene's filament position, in m (default none).
    """
    if opts.regulation is None:
        raise InputError("a tolerance study needs --regulation RULESET")
    for rs in split_rulesets(opts.regulation):
        load_ruleset(rs)
    if (opts.photons is None and opts.seconds is None and opts.target_error is None
            and opts.until is None):
        raise InputError("a tolerance study needs a photon budget (--photons N)")
    if opts.seconds is not None:
        raise InputError("--time makes samples differ in photon count: use --photons")
    if not (0 < confidence < 1):
        raise InputError(f"confidence must lie in (0, 1), got {confidence}")
    if workers < 0:
        raise InputError(f"--workers must be ≥ 0, got {workers}")
    opts = replace(opts, workers=0, address=None)
    check_until(opts, opts.run_config())
    t0 = time.perf_counter()
    scene = load(opts)
    box = box or box_for_scene(scene)
    offsets = sample_design(box, samples, seed, tilt, centre_m)
    if workers or address:
        results = _ray_map(run_sample, opts, offsets, max(1, workers), address, progress)
    else:
        results = []
        for i, off in enumerate(offsets):
            results.append(run_sample(opts, off, scene))
            if progress is not None:
                progress(i, results[-1])
    limits = dict(zip(results[0].names, results[0].limits))
    study = ToleranceStudy(scene=str(opts.scene_path), regulation=opts.regulation, box=box,
                           centre_m=[float(c) for c in centre_m],
                           tilt=tilt, seed=seed, photons=opts.photons,
                           confidence=confidence, samples=results,
                           points=summarise(results, limits, confidence), limits=limits,
                           seconds=time.perf_counter() - t0, workers=workers,
                           aperture_deg=float(opts.aperture) if opts.aperture else None,
                           until=opts.until)
    return study


# ---------------------------------------------------------------------------------------
# outputs
# ---------------------------------------------------------------------------------------


def write_study(study: ToleranceStudy, out_dir: str | os.PathLike) -> list[Path]:
    """Write ``tolerance.json``, ``tolerance.csv`` (one row per sample and point) and
    ``tolerance.png`` (value against each offset, one panel row per test point), atomically.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "tolerance.json", study.to_dict())
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["sample", "dx_mm", "dy_mm", "dz_mm", "tilt_x_deg", "tilt_y_deg", "point",
                "value_cd", "lo_cd", "hi_cd", "value_pass", "verdict"])
    for k, s in enumerate(study.samples):
        o = s.offset
        for i, name in enumerate(s.names):
            w.writerow([k, f"{o[0] / MM:.4f}", f"{o[1] / MM:.4f}", f"{o[2] / MM:.4f}",
                        f"{o[3]:.4f}", f"{o[4]:.4f}", name, f"{s.value_cd[i]:.6g}",
                        f"{s.lo_cd[i]:.6g}", f"{s.hi_cd[i]:.6g}", int(s.value_pass[i]),
                        s.verdicts[i]])
    write_bytes(out / "tolerance.csv", buf.getvalue().encode())
    _plot(study, out / "tolerance.png")
    return [out / "tolerance.json", out / "tolerance.csv", out / "tolerance.png"]


def tolerance_caption(study: ToleranceStudy) -> str:
    """The plot's caption: lamp, rule set and version, seed, photons, samples."""
    photons = "photons until the verdicts settle" if study.photons is None else \
        f"{study.photons:,} photons per sample"
    sets = []
    for rs in split_rulesets(study.regulation):
        try:
            sets.append(f"{rs} ({load_ruleset(rs).version})")
        except InputError:  # a rule set file gone since the study ran
            sets.append(rs)
    return run_text(Path(study.scene).name, "tolerance study, rule set " + "; ".join(sets),
                    f"seed {study.seed} · {photons} · {len(study.samples) - 1} samples · "
                    f"error figure: {study.confidence:.0%} intervals per sample")


def _plot(study: ToleranceStudy, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes_used = [0, 1, 2] + ([3, 4] if study.tilt else [])
    labels = ["dx (mm)", "dy (mm)", "dz (mm)", "tilt X (°)", "tilt Y (°)"]
    scale = [1 / MM, 1 / MM, 1 / MM, 1.0, 1.0]
    pts = study.points
    fig, axs = plt.subplots(len(pts), len(axes_used), squeeze=False,
                            figsize=(2.6 * len(axes_used), 1.5 * len(pts) + 0.8))
    off = np.array([s.offset for s in study.samples])
    for i, p in enumerate(pts):
        vals = np.array([s.value_cd[i] for s in study.samples])
        lo = np.array([s.lo_cd[i] for s in study.samples])
        hi = np.array([s.hi_cd[i] for s in study.samples])
        ok = np.array([s.value_pass[i] for s in study.samples])
        sens = p.sensitivity
        for j, a in enumerate(axes_used):
            ax = axs[i, j]
            x = off[:, a] * scale[a]
            # each sample's 95 % interval (what one simulate run of it would quote)
            ax.vlines(x, lo, hi, colors="0.75", lw=0.5, zorder=1)
            ax.scatter(x[ok], vals[ok], s=6, c="tab:green", zorder=2)
            ax.scatter(x[~ok], vals[~ok], s=6, c="tab:red", zorder=2)
            ax.scatter(x[:1], vals[:1], s=20, marker="x", c="k", zorder=3)
            if sens is not None and AXES[a] in sens.axes:
                k = sens.axes.index(AXES[a])
                b = sens.per_step_cd[k] / (_STEP[a] * scale[a])  # cd per plotted unit
                xs = np.array([np.min(x), np.max(x)])
                ax.plot(xs, sens.centre_cd + b * (xs - x[0]), color="tab:blue", lw=0.8,
                        zorder=2)
            for key, style in (("min", "--"), ("max", ":")):
                if p.limit.get(key) is not None:
                    ax.axhline(p.limit[key], color="0.4", ls=style, lw=0.8)
            ax.tick_params(labelsize=6)
            if j == 0:
                ax.set_ylabel(f"{p.name} (cd)", fontsize=7)
            if i == len(pts) - 1:
                ax.set_xlabel(labels[a], fontsize=7)
            if i == 0 and j == 0:
                ax.set_title(f"{Path(study.scene).name} {study.regulation}: "
                             f"{len(study.samples) - 1} samples (x = nominal; red fails; "
                             "grey: 95 % interval; blue: least-squares slope)",
                             fontsize=7, loc="left")
    caption = tolerance_caption(study)
    add_caption(fig, caption)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, metadata=png_metadata(caption))
    plt.close(fig)
    write_bytes(path, buf.getvalue())
