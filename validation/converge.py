"""Error against run time (``lightsim converge``): every estimator on the same scene.

For a list of time budgets each estimator runs one :class:`~lightsim.engine.server.Session`
that keeps accumulating photons; after each budget its image is compared with

* the **exact answer** (``analytic:NAME`` targets: the exact pixel means of
  :mod:`lightsim.validation.scenes.analytic`), or
* a **reference run** ``reference_factor`` × longer than the longest budget (scene files),
  made with the ``bin`` estimator, which measures pixel means without blur; its own noise
  is measured from its interleave sets (probe points at every pixel) and subtracted in
  quadrature from the mean squared error (``rmse_corrected``).

Timings are the Session's own clock (shooting, photon-map insertion, probe estimates and
one final image), with the Session set-up (scene plan, embree build) reported apart and
numba compilation done beforehand in a warm-up. When one Session serves several budgets,
the earlier budgets' final images are not charged to the later ones.

Metrics over the **lit region** (exact or reference ≥ ``lit_fraction`` × its maximum,
the same rule as the tool's own error estimate):

* ``rmse`` (lx) and ``rel_rmse`` = rmse / mean E;
* ``rel_l1`` = Σ |E − E_exact| / Σ E_exact;
* ``est_rel_error``: what the tool itself estimated (:attr:`Estimate.rel_error`: the
  spread of the interleave sets plus the blur bias measured against their pixel windows;
  none with a single set). The ratio estimated / actual shows whether the estimate is
  honest (≈ 1), misses error (< 1) or is too cautious (> 1).

The time to reach 5 %, 2 % and 1 % (of ``rel_rmse``; ``rel_l1`` in the JSON) is
interpolated log-log between the first budget that reaches it and the one before.

=====================  =====  ====================  =========================================
parameter              unit   default               meaning
=====================  =====  ====================  =========================================
``budgets``            s      0.25 … 8 (×2)         time budgets (``--full``: 0.25 … 64)
``estimators``         –      every ``SPECS``       the lines of :data:`SPECS` (their labels)
``frame_photons``      –      50 000                photons per frame (all sets): small frames
                                                    resolve short budgets
``lit_fraction``       –      0.1                   lit region threshold
``reference_factor``   –      20                    reference run length / longest budget
``resolution``         px     scene's               wall pixels for scene files (160 × 64)
``seed``               –      1
=====================  =====  ====================  =========================================
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path, write_text
from lightsim.io.caption import add_caption, png_metadata, run_text
from lightsim.io.summary import write_json
from lightsim.materials import DIFFUSE
from lightsim.render.frame import luminous
from lightsim.scene import Scene, SceneSettings, load_scene
from lightsim.validation.scenes import analytic as an

QUICK_BUDGETS = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
FULL_BUDGETS = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)
THRESHOLDS = (0.05, 0.02, 0.01)


@dataclass(frozen=True)
class EstimatorSpec:
    """One line of the study: a label and the RunConfig settings that make it."""

    label: str
    settings: dict[str, Any]
    needs_specular: bool = False


#: the study's estimators, the one list ``lightsim converge --estimator`` offers
SPECS: tuple[EstimatorSpec, ...] = (
    EstimatorSpec("knn M=4", {"estimator": "knn", "interleave": 4, "spt": False}),
    EstimatorSpec("knn M=4 rk", {"estimator": "knn", "interleave": 4, "spt": False,
                                 "bandwidth": "knn"}),
    EstimatorSpec("knn M=1", {"estimator": "knn", "interleave": 1, "spt": False}),
    EstimatorSpec("bin", {"estimator": "bin", "interleave": 4, "spt": False}),
    EstimatorSpec("radius", {"estimator": "radius", "interleave": 4, "spt": False}),
    EstimatorSpec("knn M=4 SPT", {"estimator": "knn", "interleave": 4, "spt": True},
                  needs_specular=True),
)


def spec_by_label(label: str) -> EstimatorSpec:
    for s in SPECS:
        if s.label.replace(" ", "").lower() == label.replace(" ", "").lower():
            return s
    raise InputError(f"unknown estimator '{label}' (known: "
                     f"{', '.join(s.label.replace(' ', '') for s in SPECS)})")


# ------------------------------------------------------------------------------------------
# Targets
# ------------------------------------------------------------------------------------------

@dataclass
class Target:
    """The scene of the study and what it is compared with."""

    name: str
    scene: Scene
    exact_px: np.ndarray | None = None     # (H, W) lx, analytic targets
    ref_px: np.ndarray | None = None       # (H, W) lx, reference run
    ref_se: np.ndarray | None = None       # (H, W) lx, reference standard error
    reference: dict[str, Any] = field(default_factory=dict)

    @property
    def truth(self) -> np.ndarray:
        t = self.exact_px if self.exact_px is not None else self.ref_px
        assert t is not None
        return t

    @property
    def specular(self) -> bool:
        return any(p.material.kind != DIFFUSE for p in self.scene.surfaces if p.role != "wall")


ANALYTIC_TARGETS: dict[str, Callable[[], an.AnalyticScene]] = {
    "isotropic": an.isotropic_case,
    "paraboloid": an.paraboloid_case,
    "slab": an.slab_case,
    "slab-absorbing": lambda: an.slab_case(sigma=10.0),
    "lambertian": an.lambertian_case,
    "shield": an.shield_case,
    # a point source at the focus of a small paraboloid mirror (f = 20 mm, rim 30 mm),
    # 0.94 mm pixels: the beam's interior converges long before its rim
    "paraboloid-fine": lambda: an.paraboloid_case(
        f=0.02, rim=0.03, reflectance=0.88, wall_distance=0.5, wall_size=0.06,
        resolution=(64, 64), radial=128, azimuthal=512),
}


def analytic_target(name: str, resolution: tuple[int, int] | None = None) -> Target:
    """``analytic:NAME`` → the analytic scene and its exact pixel means."""
    if name not in ANALYTIC_TARGETS:
        raise InputError(f"no exact lux map for 'analytic:{name}' (choose from "
                         f"{', '.join(ANALYTIC_TARGETS)})")
    case = ANALYTIC_TARGETS[name]()
    scene = case.scene
    if resolution is not None:
        scene = Scene(scene.parts, case.frame.with_resolution(*resolution), scene.source,
                      scene.warnings, scene.channels)
        case.scene = scene
    assert case.exact is not None
    exact_px = (case.pixel_means(case.frame) if case.pixel_means is not None
                else an.pixel_average(case.exact, case.frame))
    return Target(f"analytic:{name}", scene, exact_px=exact_px)


def _probe_all_pixels(frame) -> np.ndarray:
    h, v = frame.pixel_centres()
    hh, vv = np.meshgrid(h, v)
    return np.stack([hh.ravel(), vv.ravel()], axis=1)


def reference_run(target: Target, seconds: float | None, seed: int, frame_photons: int,
                  progress: Callable[[str], None] | None = None,
                  photons: int | None = None) -> None:
    """Fill ``target.ref_px``/``ref_se`` with a long ``bin`` run (probes at every pixel):
    ``seconds`` long, or ``photons`` photons when given."""
    frame = target.scene.wall
    assert frame is not None
    W, H = frame.resolution
    cfg = RunConfig(seed=seed + 7919, interleave=4, estimator="bin",
                    frame_photons=frame_photons)
    if progress:
        progress(f"reference: bin, {photons:,} photons" if photons is not None
                 else f"reference: bin, {seconds:.0f} s")
    with Session(target.scene, cfg, extra_probes=_probe_all_pixels(frame)) as s:
        est = s.run(photons=photons) if photons is not None else s.run(seconds=seconds)
        grid = s.grid_count
    vals = luminous(est.probes.values[:, grid:, :])  # (S, H·W)
    S = vals.shape[0]
    target.ref_px = luminous(est.lux)
    target.ref_se = (vals.std(axis=0, ddof=1) / math.sqrt(S)).reshape(H, W)
    target.reference = {"estimator": "bin", "interleave": 4, "seconds": est.seconds,
                        "photons": int(est.photons), "rel_error": est.rel_error,
                        "seed": cfg.seed}


def scene_target(path: str, resolution: tuple[int, int] = (160, 64), **load_kw: Any) -> Target:
    scene = load_scene(path, SceneSettings(resolution=resolution, **load_kw))
    return Target(str(path), scene)


def resolve_target(spec: str, resolution: tuple[int, int] | None = None) -> Target:
    """``analytic:NAME`` or a scene file."""
    if spec.startswith("analytic:"):
        return analytic_target(spec.split(":", 1)[1], resolution)
    return scene_target(spec, resolution or (160, 64))


# ------------------------------------------------------------------------------------------
# Metrics
# ------------------------------------------------------------------------------------------

def lit_mask(truth: np.ndarray, lit_fraction: float = 0.1, robust: bool = False
             ) -> np.ndarray:
    """Pixels at ≥ ``lit_fraction`` × the maximum; ``robust`` uses the 99.9th percentile
    instead (a noisy reference: one hot pixel must not set the scale)."""
    top = float(np.percentile(truth, 99.9) if robust else np.max(truth))
    return truth >= lit_fraction * top


def error_metrics(lux: np.ndarray, truth: np.ndarray, lit: np.ndarray,
                  truth_var: np.ndarray | None = None) -> dict[str, float]:
    """RMSE (lx), relative RMSE and relative L1 over ``lit``.

    ``truth_var`` (lx²), the noise variance of a reference, is subtracted from the mean
    squared error (``rmse_corrected``): E[(E − E_ref)²] = MSE + Var(E_ref).
    """
    d = lux[lit] - truth[lit]
    mean_t = float(truth[lit].mean())
    mse = float(np.mean(d * d))
    out = {"rmse_lx": math.sqrt(mse), "rel_rmse": math.sqrt(mse) / mean_t,
           "rel_l1": float(np.abs(d).sum() / truth[lit].sum()), "mean_lit_lx": mean_t}
    if truth_var is not None:
        mc = max(mse - float(truth_var[lit].mean()), 0.0)
        out["rmse_corrected_lx"] = math.sqrt(mc)
        out["rel_rmse_corrected"] = math.sqrt(mc) / mean_t
        out["reference_rel_noise"] = math.sqrt(float(truth_var[lit].mean())) / mean_t
    return out


def time_to_reach(seconds: Sequence[float], errors: Sequence[float | None], level: float
                  ) -> dict[str, Any]:
    """First time the error reaches ``level``, interpolated log-log.

    Returns ``{"seconds": t or None, "how": "interpolated" | "at first point" |
    "not reached"}``.
    """
    prev = None
    for t, e in zip(seconds, errors):
        if e is None or not math.isfinite(e):
            continue  # no value at this budget: bracket across it
        if e <= level:
            if prev is None:
                return {"seconds": float(t), "how": "at first point"}
            t0, e0 = prev
            if e0 <= e or t0 <= 0 or e <= 0:
                return {"seconds": float(t), "how": "interpolated"}
            f = (math.log(level) - math.log(e0)) / (math.log(e) - math.log(e0))
            return {"seconds": float(math.exp(math.log(t0) + f * (math.log(t) - math.log(t0)))),
                    "how": "interpolated"}
        prev = (t, e)
    return {"seconds": None, "how": "not reached"}


# ------------------------------------------------------------------------------------------
# The sweep
# ------------------------------------------------------------------------------------------

@dataclass
class Point:
    """One budget of one estimator."""

    estimator: str
    budget_s: float
    seconds: float
    photons: int
    frames: int
    metrics: dict[str, float]
    est_rel_error: float | None
    est_noise: float | None = None
    est_blur: float | None = None

    def row(self, target: str) -> dict[str, Any]:
        return {"target": target, "estimator": self.estimator, "budget_s": self.budget_s,
                "seconds": self.seconds, "photons": self.photons, "frames": self.frames,
                **self.metrics, "est_rel_error": self.est_rel_error,
                "est_noise": self.est_noise, "est_blur": self.est_blur}


def warm_up(scene: Scene, config: RunConfig) -> float:
    """Compile and load the numba kernels a configuration uses; returns seconds.

    Runs the same configuration (same frame size: some kernels have size-dependent
    paths) for two frames (build, then incremental insertion) and a final image.
    """
    t0 = time.perf_counter()
    with Session(scene, config) as s:
        s.run(photons=2 * config.frame_photons)
    return time.perf_counter() - t0


def sweep(target: Target, spec: EstimatorSpec, budgets: Sequence[float], seed: int = 1,
          frame_photons: int = 50_000, lit_fraction: float = 0.1,
          progress: Callable[[str], None] | None = None, by_photons: bool = False
          ) -> tuple[list[Point], dict[str, Any]]:
    """Run one estimator through all budgets in one accumulating Session (``budgets`` in
    s, or photons with ``by_photons``: the same photons for every estimator and machine
    load, so the errors are reproducible to the bit)."""
    cfg = RunConfig(seed=seed, frame_photons=frame_photons, **spec.settings)
    warm = warm_up(target.scene, cfg)
    truth = target.truth
    lit = lit_mask(truth, lit_fraction, robust=target.exact_px is None)
    var = None if target.ref_se is None else target.ref_se**2
    points: list[Point] = []
    t_setup = time.perf_counter()
    with Session(target.scene, cfg) as session:
        setup = time.perf_counter() - t_setup
        charged_elsewhere = 0.0
        for b in sorted(budgets):
            est = (session.run(photons=int(b)) if by_photons
                   else session.run(seconds=b + charged_elsewhere))
            final = est.timings.get("render", 0.0) + est.timings.get("assemble", 0.0)
            seconds = est.seconds - charged_elsewhere
            charged_elsewhere += final
            if points and est.photons == points[-1].photons:
                if session.memory_stop is not None:
                    break  # stopped for memory: no later budget adds photons
                continue  # the previous frame already overshot this budget
            if session.memory_stop is not None and progress:
                progress(f"{spec.label:12s} {session.memory_stop.message()}")
            lux = luminous(est.lux)
            m = error_metrics(lux, truth, lit, var)
            e = est.error
            p = Point(spec.label, float(b), float(seconds), int(est.photons), session.frames,
                      m, est.rel_error, None if e is None else e.noise,
                      None if e is None else e.bias)
            points.append(p)
            if progress:
                err = "–" if p.est_rel_error is None else f"{p.est_rel_error:.2%}"
                progress(f"{spec.label:12s} {seconds:7.2f} s {p.photons:>11,} photons  "
                         f"error {m['rel_rmse']:.2%} (estimated {err})")
        plan = session.plan.explain()
    return points, {"setup_seconds": setup, "warmup_seconds": warm, "plan": plan,
                    "config": cfg.to_dict()}


@dataclass
class Step:
    """One row of the error-against-photons table.

    ``actual`` (fraction): relative RMSE against the exact answer (noise-corrected
    against the reference for scene files); ``estimated``: the tool's own figure with its
    ``noise`` and ``blur`` parts; ``ratio`` = estimated / actual; ``slope_photons`` and
    ``slope_seconds``: d log(actual) / d log(photons resp. seconds) since the previous
    row of the estimator (−½ for an unbiased Monte Carlo estimate).
    """

    estimator: str
    photons: int
    seconds: float
    actual: float | None
    estimated: float | None
    noise: float | None
    blur: float | None
    ratio: float | None
    slope_photons: float | None
    slope_seconds: float | None


@dataclass
class ConvergeResult:
    target: str
    mode: str
    points: list[Point]
    runs: dict[str, dict[str, Any]]
    reference: dict[str, Any]
    skipped: list[str]
    lit_pixels: int

    def times(self, metric: str = "rel_rmse") -> dict[str, dict[str, dict[str, Any]]]:
        out: dict[str, dict[str, dict[str, Any]]] = {}
        for label in dict.fromkeys(p.estimator for p in self.points):
            pts = [p for p in self.points if p.estimator == label]
            key = metric
            if self.mode == "reference" and metric == "rel_rmse":
                key = "rel_rmse_corrected"
            errs = [p.metrics.get(key) for p in pts]
            out[label] = {f"{lvl:.0%}": time_to_reach([p.seconds for p in pts], errs, lvl)
                          for lvl in THRESHOLDS}
        return out

    def honesty(self) -> dict[str, float | None]:
        """Median ratio estimated / actual relative RMSE per estimator (1 = honest)."""
        out: dict[str, float | None] = {}
        key = "rel_rmse_corrected" if self.mode == "reference" else "rel_rmse"
        for label in dict.fromkeys(p.estimator for p in self.points):
            r = [p.est_rel_error / p.metrics[key] for p in self.points
                 if p.estimator == label and p.est_rel_error is not None
                 and p.metrics.get(key)]
            out[label] = float(np.median(r)) if r else None
        return out

    def steps(self) -> list[Step]:
        """Every point with its local rate: the log-log slope of the actual error against
        photons (and seconds) from the previous point of the same estimator."""
        key = "rel_rmse_corrected" if self.mode == "reference" else "rel_rmse"
        out: list[Step] = []
        prev: dict[str, Point] = {}
        for p in self.points:
            a = p.metrics.get(key)
            q = prev.get(p.estimator)
            slope_n = slope_t = None
            if q is not None and a and q.metrics.get(key):
                la = math.log(a / q.metrics[key])
                if p.photons > q.photons:
                    slope_n = la / math.log(p.photons / q.photons)
                if p.seconds > q.seconds > 0:
                    slope_t = la / math.log(p.seconds / q.seconds)
            ratio = (p.est_rel_error / a) if (a and p.est_rel_error is not None) else None
            out.append(Step(p.estimator, p.photons, p.seconds, a, p.est_rel_error,
                            p.est_noise, p.est_blur, ratio, slope_n, slope_t))
            prev[p.estimator] = p
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"target": self.target, "mode": self.mode, "reference": self.reference,
                "lit_pixels": self.lit_pixels, "skipped": self.skipped,
                "time_to_rel_rmse": self.times("rel_rmse"),
                "time_to_rel_l1": self.times("rel_l1"),
                "honesty_estimated_over_actual": self.honesty(),
                "runs": self.runs, "points": [p.row(self.target) for p in self.points],
                "steps": [asdict(st) for st in self.steps()]}


def run_converge(target_spec: str, budgets: Sequence[float] = QUICK_BUDGETS,
                 estimators: Sequence[str] | None = None, seed: int = 1,
                 frame_photons: int = 50_000, lit_fraction: float = 0.1,
                 reference_factor: float = 20.0, resolution: tuple[int, int] | None = None,
                 progress: Callable[[str], None] | None = None,
                 target: Target | None = None, by_photons: bool = False) -> ConvergeResult:
    """The whole study for one target (see the module docstring); ``by_photons``: the
    budgets are photon counts (the reference then has ``reference_factor`` × the most)."""
    budgets = sorted(float(b) for b in budgets)
    if not budgets or budgets[0] <= 0:
        raise InputError("budgets must be positive " + ("photon counts" if by_photons
                                                         else "seconds"))
    target = target or resolve_target(target_spec, resolution)
    specs = list(SPECS) if estimators is None else [spec_by_label(e) for e in estimators]
    skipped = []
    runnable = []
    for s in specs:
        if s.needs_specular and not target.specular:
            skipped.append(f"{s.label}: no mirror or glass, SPT does not apply")
        else:
            runnable.append(s)
    mode = "exact" if target.exact_px is not None else "reference"
    if mode == "reference" and target.ref_px is None:
        if by_photons:
            reference_run(target, None, seed, frame_photons, progress,
                          photons=int(reference_factor * budgets[-1]))
        else:
            reference_run(target, reference_factor * budgets[-1], seed, frame_photons,
                          progress)
    lit = lit_mask(target.truth, lit_fraction, robust=mode == "reference")
    if not lit.any():
        raise InputError(f"{target.name}: nothing on the wall is lit")
    points: list[Point] = []
    runs: dict[str, dict[str, Any]] = {}
    for s in runnable:
        pts, info = sweep(target, s, budgets, seed, frame_photons, lit_fraction, progress,
                          by_photons)
        points.extend(pts)
        runs[s.label] = info
    return ConvergeResult(target.name, mode, points, runs, target.reference, skipped,
                          int(lit.sum()))


# ------------------------------------------------------------------------------------------
# Outputs
# ------------------------------------------------------------------------------------------

CSV_COLUMNS = ("target", "estimator", "budget_s", "seconds", "photons", "frames", "rmse_lx",
               "rel_rmse", "rel_l1", "est_rel_error", "est_noise", "est_blur",
               "rmse_corrected_lx",
               "rel_rmse_corrected", "reference_rel_noise", "mean_lit_lx")


def csv_text(result: ConvergeResult) -> str:
    lines = [",".join(CSV_COLUMNS)]
    for p in result.points:
        row = p.row(result.target)
        vals = []
        for c in CSV_COLUMNS:
            v = row.get(c)
            vals.append("" if v is None else (f"{v:.6g}" if isinstance(v, float) else str(v)))
        lines.append(",".join(vals))
    return "\n".join(lines) + "\n"


def plot(result: ConvergeResult, path: str | Path) -> None:
    """Log-log error against photons and against seconds (one line per estimator; dashed:
    the tool's own estimate; dotted: N^(−1/2)) and estimated against actual error."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    key = "rel_rmse_corrected" if result.mode == "reference" else "rel_rmse"
    fig = Figure(figsize=(15.0, 4.2))
    ax0, ax1, ax2 = fig.subplots(1, 3)
    labels = list(dict.fromkeys(p.estimator for p in result.points))
    colours = matplotlib.colormaps["tab10"]
    lo, hi = math.inf, 0.0
    for i, label in enumerate(labels):
        pts = [p for p in result.points if p.estimator == label]
        t = np.array([p.seconds for p in pts])
        n = np.array([p.photons for p in pts], dtype=float)
        e = np.array([max(p.metrics[key], 1e-6) for p in pts])
        ax0.loglog(n, e * 100, "o-", ms=3, color=colours(i), label=label)
        ax1.loglog(t, e * 100, "o-", ms=3, color=colours(i), label=label)
        est = [(p.seconds, p.photons, p.est_rel_error, p.metrics[key]) for p in pts
               if p.est_rel_error is not None]
        if est:
            te, ne, ee, aa = (np.array(x, dtype=float) for x in zip(*est))
            ax0.loglog(ne, ee * 100, "--", color=colours(i), alpha=0.7)
            ax1.loglog(te, ee * 100, "--", color=colours(i), alpha=0.7)
            ax2.loglog(np.maximum(aa, 1e-6) * 100, ee * 100, "o", ms=4, color=colours(i),
                       label=label)
            lo, hi = min(lo, aa.min(), ee.min()), max(hi, aa.max(), ee.max())
    if result.points:  # the Monte Carlo rate for reference: N^(-1/2) through the first point
        p0 = result.points[0]
        n_all = np.array([p.photons for p in result.points], dtype=float)
        span_n = np.array([n_all.min(), n_all.max()])
        ax0.loglog(span_n, 100 * p0.metrics[key] * (span_n / p0.photons) ** -0.5, ":",
                   color="black", lw=0.8, label="∝ N^(−1/2)")
    for ax in (ax0, ax1):
        for lvl in THRESHOLDS:
            ax.axhline(lvl * 100, color="grey", lw=0.6, ls=":")
        ax.set_ylabel(("relative RMSE vs reference (noise-corrected)"
                       if result.mode == "reference" else "relative RMSE vs exact")
                      + ", lit region (%)", fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    ax0.set_xlabel("photons")
    ax1.set_xlabel("run time (s)")
    ax0.set_title(f"{result.target}: solid = actual, dashed = estimated", fontsize=9)
    ax1.set_title("against run time (this machine's load)", fontsize=9)
    if labels:
        ax0.legend(fontsize=8)
    if hi > 0:
        span = np.array([max(lo, 1e-5) * 0.7, hi * 1.4]) * 100
        ax2.loglog(span, span, color="grey", lw=0.8, label="honest (estimated = actual)")
        for f in (0.8, 1.25):
            ax2.loglog(span, f * span, color="grey", lw=0.5, ls="--")
        ax2.legend(fontsize=8)
    else:
        ax2.text(0.5, 0.5, "no error estimate", ha="center", transform=ax2.transAxes)
    ax2.set_xlabel("actual relative RMSE (%)")
    ax2.set_ylabel("estimated relative error (%)")
    ax2.set_title("is the estimate honest? (dashed: 0.8 and 1.25)", fontsize=9)
    from matplotlib.ticker import NullFormatter

    ax2.xaxis.set_minor_formatter(NullFormatter())  # minor labels overlap on a short span
    ax2.yaxis.set_minor_formatter(NullFormatter())
    ax2.grid(True, which="both", alpha=0.3)
    caption = converge_caption(result)
    add_caption(fig, caption)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=100, metadata=png_metadata(caption))


def converge_caption(result: ConvergeResult) -> str:
    """The plot's caption: target, what the error is against, runs and photons."""
    photons = [p.photons for p in result.points]
    span = f"{min(photons):,}–{max(photons):,} photons" if photons else "no runs"
    against = "a reference run" if result.mode == "reference" else "the exact answer"
    return run_text(result.target, f"convergence study against {against}",
                    f"{len(result.points)} runs · {span} · error figure: relative RMSE, "
                    "lit region")


def write_outputs(result: ConvergeResult, out_dir: str | Path) -> dict[str, Path]:
    """converge.csv, converge.json and converge.png in ``out_dir`` (written atomically)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"csv": out / "converge.csv", "json": out / "converge.json",
             "png": out / "converge.png"}
    write_text(paths["csv"], csv_text(result))
    write_json(paths["json"], result.to_dict())
    plot(result, paths["png"])
    return paths
