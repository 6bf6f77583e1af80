"""Coverage of the regulation test points' intervals on synthetic lamps with known answers.

``lightsim validate --coverage`` builds many synthetic low-beam intensity distributions
with a sharp cut-off (:func:`synthetic_lamp`), writes each to a Type A IES file (the
headlamp type) in a temporary folder, loads it as a user would (``load_scene(path)``: a
goniometric point source in front of the 25 m wall), runs the engine with detector
apertures at the rule set's test points
(:func:`lightsim.luminaires.regulations.check.aperture_config`) and
compares every point's 95 % Student-t interval with the exact answer: the aperture mean
of the file's intensity,

    I_true = ∫_aperture I(ω) dΩ / Ω,

integrated with ``quad`` × ``quad`` midpoints in (H, V) weighted by the exact
dΩ = sec²H sec²V / (1 + tan²H + tan²V)^{3/2} dH dV. The intensity is the one the source
samples: the file's bilinear interpolant :meth:`HVGrid.intensity_hv` (the goniometric
sampler draws exactly from it, see :mod:`~lightsim.emitters.polar`).

Reported: the share of (lamp, point) evaluations whose interval covers the truth (target
93–97 % for 95 % intervals), the worst single evaluation's bias in units of its interval
half-width, and the worst *point's* mean bias over the lamps (a systematic error shows
there; for an unbiased estimator it is ≈ N(0, 1/(1.96²·n_lamps))).

==============  =====  ================  ==============================================
parameter       unit   default           meaning
==============  =====  ================  ==============================================
lamps           –      40 (quick 4)      synthetic lamps
photons         –      1 000 000         photons per lamp
aperture_deg    deg    0.15              detector aperture side
ruleset         –      r112-b-passing    whose points are tested (plus H-V)
spt             –      False             Selective Photon Tracing aimed at the points
quad            –      64                midpoints per aperture side for the truth
seed            –      1                 lamp parameters and photon sequences
==============  =====  ================  ==============================================
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lightsim.engine.config import RunConfig

__all__ = ["COVERAGE_BAND", "CoverageResult", "SptGain", "aperture_truth", "coverage_study",
           "run_lamp", "spt_gain", "synthetic_lamp"]

COVERAGE_BAND = (0.93, 0.97)
"""Target share of 95 % intervals that cover the truth."""
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
    from lightsim.luminaires.photometric import HVGrid, hv_directions
    from lightsim.luminaires.photometric.candela import hv_from_directions

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
    from lightsim.engine.apertures import rect_solid_angle

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
class LampRun:
    """One lamp: per-set aperture intensities and the exact answers at its points."""

    names: tuple[str, ...]
    h_deg: NDArray
    v_deg: NDArray
    per_set_cd: NDArray  # (S, P)
    interval_cd: NDArray  # (P, 2) as the regulation table reports it
    n_eff: NDArray  # (P,) photons counted in each aperture (effective number)
    truth_cd: NDArray  # (P,)
    seconds: float


def point_apertures(ruleset: str, traffic: str, frame: Any
                    ) -> tuple[tuple[str, ...], NDArray, NDArray, NDArray]:
    """The rule set's points (plus H-V): names, H, V and their probe indices."""
    from lightsim.luminaires.regulations import load_ruleset, probe_points

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
             ruleset: str = "r112-b-passing", traffic: str = "right", spt: bool = False,
             seed: int = 1, quad: int = 64, config: RunConfig | None = None,
             confidence: float = 0.95) -> LampRun:
    """Simulate the IES file at ``path`` as a point source and measure its test points."""
    from scipy.special import stdtrit

    from lightsim.engine.server import Session
    from lightsim.luminaires.photometric import read_ies
    from lightsim.luminaires.regulations.check import aperture_config
    from lightsim.report import aperture_values
    from lightsim.scene import load_scene

    scene = load_scene(str(path), resolution=(160, 64))
    cfg = config or RunConfig(seed=seed, estimator="bin", frame_photons=250_000)
    cfg = aperture_config(cfg, ruleset, traffic, scene.wall, aperture_deg, spt=spt)
    names, h, v, idx = point_apertures(ruleset, traffic, scene.wall)
    t0 = time.perf_counter()
    session = Session(scene, cfg)
    try:
        while sum(session.emitted_per_set().values()) < photons:
            session.shoot()
        ap = aperture_values(session, 0.0, confidence)
        cd = ap["cd"][:, idx]
        S = cd.shape[0]
        mean = cd.mean(axis=0)
        half = (stdtrit(S - 1, 0.5 + confidence / 2) * cd.std(axis=0, ddof=1) / math.sqrt(S))
        interval = np.stack([mean - half, mean + half], axis=1)
        count = ap["intervals_cd"][idx]
        sparse = np.isfinite(count).all(axis=1)
        interval[sparse] = count[sparse]  # as the regulation table does
        n_eff = ap["n_eff"][idx]
    finally:
        session.close()
    seconds = time.perf_counter() - t0
    grid = read_ies(path)
    return LampRun(names, h, v, cd, interval, n_eff,
                   aperture_truth(grid, h, v, aperture_deg, quad), seconds)


@dataclass
class CoverageResult:
    """Coverage of the per-point 95 % intervals over lamps × points."""

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

    @property
    def rate(self) -> float:
        return self.covered / self.evaluations if self.evaluations else float("nan")

    def band(self, z: float = 3.0) -> tuple[float, float]:
        """Accepted coverage: the 93–97 % target widened to 0.95 ± z binomial standard
        errors when there are too few evaluations to resolve it."""
        se = math.sqrt(0.95 * 0.05 / max(self.evaluations, 1))
        return min(COVERAGE_BAND[0], 0.95 - z * se), max(COVERAGE_BAND[1], 0.95 + z * se)

    def to_dict(self) -> dict[str, Any]:
        return {"lamps": self.lamps, "photons": self.photons,
                "aperture_deg": self.aperture_deg, "spt": self.spt,
                "evaluations": self.evaluations, "covered": self.covered,
                "rate": self.rate, "worst_bias_halfwidths": self.worst_bias,
                "worst_bias_point": self.worst_bias_point,
                "worst_mean_bias_halfwidths": self.worst_mean_bias,
                "worst_mean_point": self.worst_mean_point, "seconds": self.seconds,
                "per_point": self.per_point}


def coverage_study(lamps: int = 40, photons: int = 1_000_000, *, aperture_deg: float = 0.15,
                   ruleset: str = "r112-b-passing", spt: bool = False, seed: int = 1,
                   confidence: float = 0.95, quad: int = 64,
                   progress: Callable[[int, LampRun], None] | None = None) -> CoverageResult:
    """Run ``lamps`` synthetic lamps and count interval coverage (see module docstring)."""
    from lightsim.luminaires.photometric import write_ies

    if lamps < 1 or photons < 1000:
        raise ValueError("coverage study needs ≥ 1 lamp and ≥ 1000 photons")
    rng = np.random.default_rng([seed, 0xC0FE])
    t0 = time.perf_counter()
    cover, bias, names_all = [], [], []
    with tempfile.TemporaryDirectory(prefix="lightsim-coverage-") as tmp:
        for n in range(lamps):
            grid, _ = synthetic_lamp(rng)
            path = Path(tmp) / f"lamp{n:03d}.ies"
            write_ies(path, grid)
            run = run_lamp(path, photons, aperture_deg=aperture_deg, ruleset=ruleset,
                           spt=spt, seed=seed + n, quad=quad,
                           confidence=confidence)
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
                          time.perf_counter() - t0, per_point)


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
    from lightsim.luminaires.photometric import write_ies

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
