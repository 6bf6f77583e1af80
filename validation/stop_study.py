"""Where ``--target-error`` stops: the true error at the stop against the target, over seeds.

A run with a target error stops when its error figure is within the target at the stop's
confidence (:class:`~lightsim.engine.server.MapErrorRule`). This study runs that stop on
scenes with exact answers, many seeds each, and scores the map the run returns against
the exact pixel means over the region the figure reports (``lit``: exact E ≥
``lit_fraction`` × its maximum; ``interior``: the lit pixels ``INSET`` × R_eq inside the
edge, :func:`lightsim.render.region.interior`). It shows two things:

* **waste**: the true error at the stop over the target (``ratio``); 0.7–1.0 is the aim
  (:data:`BAND`), lower means photons spent beyond what the target needs;
* **honesty**: how many runs stop with the true error above the target, against the
  rate the stop's confidence allows (:data:`~lightsim.engine.server.STOP_ALPHA`; the
  count ``allowed`` is the 95 % quantile of Binomial(runs, α): more than that says the
  stop is wrong more often than it claims).

Cases (:data:`CASES`): the analytic targets of ``lightsim converge`` over their lit pixels
and ``paraboloid-fine`` (a point source at the focus of a paraboloid mirror, 0.94 mm
pixels) over the beam's interior.

==================  =====  ===========  ===============================================
parameter           unit   default      meaning
==================  =====  ===========  ===============================================
``targets``         –      0.02         target errors (fractions) every case stops at
``seeds``           –      20           runs per case and target (seeds 1 … N)
``lit_fraction``    –      0.1          lit threshold (the figure's own)
``BAND``            –      0.7 … 1.0    true error / target the stop aims into
``ALLOWED_LEVEL``   –      0.95         quantile of Binomial(runs, α) a count above
                                        the target may reach
==================  =====  ===========  ===============================================
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import binom

from lightsim.engine.config import RunConfig
from lightsim.engine.server import STOP_ALPHA, MapErrorRule, Session
from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path, write_text
from lightsim.io.caption import add_caption, png_metadata, run_text
from lightsim.io.summary import write_json
from lightsim.render.frame import luminous
from lightsim.render.region import REGIONS, interior
from lightsim.validation.converge import analytic_target, error_metrics

#: true error / target the stop aims into
BAND = (0.7, 1.0)
#: a count of stops above the target is within the stop's confidence up to this quantile
#: of Binomial(runs, STOP_ALPHA)
ALLOWED_LEVEL = 0.95
#: case → the region its figure (and the stop) covers
CASES: dict[str, str] = {
    "isotropic": "lit", "paraboloid": "lit", "slab": "lit", "slab-absorbing": "lit",
    "lambertian": "lit", "shield": "lit", "paraboloid-fine": "interior",
}


@dataclass(frozen=True)
class StopRun:
    """One run stopped by its target error.

    Attributes
    ----------
    case, region : str
        The analytic case and the region its figure covers.
    target : float
        The target error (fraction).
    seed : int
    photons : int
        Photons at the stop.
    frames : int
        Frames shot.
    seconds : float
        The run's own clock (s).
    figure : float or None
        The run's error figure at the stop (fraction).
    true : float
        Relative rms error against the exact answer over the region (fraction).
    looks : int
        Tests the stop spent its error budget on (:class:`MapErrorRule`).
    """

    case: str
    region: str
    target: float
    seed: int
    photons: int
    frames: int
    seconds: float
    figure: float | None
    true: float
    looks: int = 0

    @property
    def ratio(self) -> float:
        """True error over the target."""
        return self.true / self.target


@dataclass(frozen=True)
class StopSummary:
    """The runs of one case and target, summarised (ratios: true error / target)."""

    case: str
    region: str
    target: float
    runs: int
    median_ratio: float
    min_ratio: float
    max_ratio: float
    in_band: int
    above: int
    nominal_above: float
    median_photons: float
    median_seconds: float
    allowed: int = 0
    min_photons: float = 0.0
    max_photons: float = 0.0

    @property
    def honest(self) -> bool:
        """Whether the runs above the target are within what the confidence allows."""
        return self.above <= self.allowed

    def row(self) -> list[str]:
        return [self.case, self.region, f"{self.target:.2%}", str(self.runs),
                f"{self.median_photons:,.0f}",
                f"{self.min_photons:,.0f}–{self.max_photons:,.0f}",
                f"{self.median_ratio:.2f}", f"{self.min_ratio:.2f}–{self.max_ratio:.2f}",
                f"{self.in_band}/{self.runs}", f"{self.above}/{self.runs}",
                f"≤ {self.allowed}", f"{self.median_seconds:.2f}"]


HEADER = ("case", "region", "target", "seeds", "photons at stop", "range",
          "true/target", "range", f"in {BAND[0]}–{BAND[1]}", "above target", "allowed",
          "s")


def allowed_above(runs: int, alpha: float = STOP_ALPHA, level: float = ALLOWED_LEVEL
                  ) -> int:
    """The most stops above the target ``runs`` stops at confidence 1 − ``alpha`` may
    show: the ``level`` quantile of Binomial(runs, α)."""
    return int(binom.ppf(level, runs, alpha)) if runs > 0 else 0


def region_mask(exact: np.ndarray, region: str, pixel_size_m: tuple[float, float],
                lit_fraction: float = 0.1) -> np.ndarray:
    """(H, W) bool: the pixels a figure over ``region`` covers, from the exact map."""
    if region not in REGIONS:
        raise InputError(f"unknown error region '{region}' (choose from {', '.join(REGIONS)})")
    H, W = exact.shape
    lit = exact >= lit_fraction * float(exact.max())
    if region == "lit":
        return lit
    dh, dv = pixel_size_m
    return interior(lit.ravel(), (H, W), (dv, dh)).reshape(H, W)


def run_case(case: str, target: float, seeds: Sequence[int], lit_fraction: float = 0.1,
             progress: Callable[[str], None] | None = None,
             **settings: Any) -> list[StopRun]:
    """``case`` stopped at ``target`` once per seed (``settings``: more
    :class:`RunConfig` fields)."""
    if case not in CASES:
        raise InputError(f"no stop study for '{case}' (choose from {', '.join(CASES)})")
    region = CASES[case]
    tgt = analytic_target(case)
    exact = tgt.truth
    mask = region_mask(exact, region, tgt.scene.wall.pixel_size_m, lit_fraction)
    runs = []
    for seed in seeds:
        cfg = RunConfig(seed=int(seed), error_region=region, **settings)
        rule = MapErrorRule(target)
        with Session(tgt.scene, cfg) as s:
            t0 = time.perf_counter()
            est = s.run(target_error=target, probes=False, rule=rule)
            dt = time.perf_counter() - t0
            frames = s.frames
        true = error_metrics(luminous(est.lux), exact, mask)["rel_rmse"]
        run = StopRun(case, region, float(target), int(seed), int(est.photons), frames,
                      dt, None if est.error is None else est.error.total, true, rule.looks)
        runs.append(run)
        if progress:
            fig = "–" if run.figure is None else f"{run.figure:.2%}"
            progress(f"{case:15s} target {target:.2%} seed {seed:3d}: stopped at "
                     f"{run.photons:>10,} photons, figure {fig}, true {true:.2%} "
                     f"({run.ratio:.2f} × target)")
    return runs


def summarise(runs: Sequence[StopRun]) -> list[StopSummary]:
    """One :class:`StopSummary` per case and target, in the runs' order."""
    out = []
    keys = list(dict.fromkeys((r.case, r.target) for r in runs))
    for case, target in keys:
        rs = [r for r in runs if r.case == case and r.target == target]
        ratios = np.array([r.ratio for r in rs])
        out.append(StopSummary(
            case, rs[0].region, target, len(rs), float(np.median(ratios)),
            float(ratios.min()), float(ratios.max()),
            int(np.sum((ratios >= BAND[0]) & (ratios <= BAND[1]))), int(np.sum(ratios > 1.0)),
            STOP_ALPHA, float(np.median([r.photons for r in rs])),
            float(np.median([r.seconds for r in rs])), allowed_above(len(rs)),
            float(min(r.photons for r in rs)), float(max(r.photons for r in rs))))
    return out


@dataclass
class StopStudy:
    """Every run of the study and its summary."""

    runs: list[StopRun]

    @property
    def summary(self) -> list[StopSummary]:
        return summarise(self.runs)

    def above(self) -> tuple[int, int]:
        """(runs above the target, runs) over every case."""
        return sum(r.ratio > 1.0 for r in self.runs), len(self.runs)

    def to_dict(self) -> dict[str, Any]:
        return {"band": list(BAND), "nominal_above": STOP_ALPHA,
                "allowed_level": ALLOWED_LEVEL,
                "summary": [{**asdict(s), "honest": s.honest} for s in self.summary],
                "runs": [{**asdict(r), "ratio": r.ratio} for r in self.runs]}


def run_study(cases: Sequence[str] | None = None, targets: Sequence[float] = (0.02,),
              seeds: int = 20, first_seed: int = 1,
              progress: Callable[[str], None] | None = None) -> StopStudy:
    """Every case at every target, ``seeds`` runs each (seeds ``first_seed`` …)."""
    if seeds < 1:
        raise InputError(f"--seeds must be at least 1, got {seeds}")
    for t in targets:
        if not (0 < t < 1 and math.isfinite(t)):
            raise InputError(f"target errors must lie in (0, 1), got {t}")
    names = list(cases) if cases else list(CASES)
    for c in names:
        if c not in CASES:
            raise InputError(f"no stop study for '{c}' (choose from {', '.join(CASES)})")
    runs: list[StopRun] = []
    for c in names:
        for t in targets:
            runs.extend(run_case(c, t, range(first_seed, first_seed + seeds),
                                 progress=progress))
    return StopStudy(runs)


CSV_COLUMNS = ("case", "region", "target", "seed", "photons", "frames", "seconds",
               "figure", "true", "ratio", "looks")


def csv_text(study: StopStudy) -> str:
    lines = [",".join(CSV_COLUMNS)]
    for r in study.runs:
        row = {**asdict(r), "ratio": r.ratio}
        lines.append(",".join("" if row[c] is None else (
            f"{row[c]:.6g}" if isinstance(row[c], float) else str(row[c]))
            for c in CSV_COLUMNS))
    return "\n".join(lines) + "\n"


def plot(study: StopStudy, path: str | Path) -> None:
    """True error / target at every stop, one column per case and target (the band
    shaded, the target dashed), and the photons at the stop."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    summary = study.summary
    fig = Figure(figsize=(max(6.0, 1.1 * len(summary) + 2.0), 4.2))
    ax = fig.subplots()
    ax.axhspan(*BAND, color="tab:green", alpha=0.15, label=f"aim {BAND[0]}–{BAND[1]}")
    ax.axhline(1.0, color="black", ls="--", lw=0.8, label="target")
    rng = np.random.default_rng(0)  # jitter only spreads the dots sideways
    for i, s in enumerate(summary):
        rs = [r.ratio for r in study.runs if r.case == s.case and r.target == s.target]
        x = i + rng.uniform(-0.15, 0.15, len(rs))
        ax.plot(x, rs, "o", ms=4, color="tab:blue", alpha=0.7)
        ax.plot([i - 0.3, i + 0.3], [s.median_ratio] * 2, color="tab:red", lw=1.5)
    ax.set_xticks(range(len(summary)))
    ax.set_xticklabels([f"{s.case}\n{s.region}, {s.target:.1%}" for s in summary],
                       fontsize=7)
    ax.set_ylabel("true error at the stop / target")
    above, n = study.above()
    ax.set_title(f"where --target-error stops ({n} runs; {above} above the target, "
                 f"allowed ≤ {allowed_above(n)} at α = {STOP_ALPHA:g}); red: median",
                 fontsize=9)
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(True, axis="y", alpha=0.3)
    seeds = sorted({r.seed for r in study.runs})
    photons = [r.photons for r in study.runs]
    caption = run_text(", ".join(sorted({r.case for r in study.runs})) or "no case",
                       "--target-error stopping study",
                       (f"seeds {seeds[0]}–{seeds[-1]} · {min(photons):,}–{max(photons):,} "
                        "photons at the stops" if seeds else ""))
    add_caption(fig, caption)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=100, metadata=png_metadata(caption))


def write_outputs(study: StopStudy, out_dir: str | Path) -> dict[str, Path]:
    """stop-study.csv, .json and .png in ``out_dir`` (written atomically)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"csv": out / "stop-study.csv", "json": out / "stop-study.json",
             "png": out / "stop-study.png"}
    write_text(paths["csv"], csv_text(study))
    write_json(paths["json"], study.to_dict())
    plot(study, paths["png"])
    return paths
