"""The analytic validation suite (``lightsim validate``): the engine against exact answers.

Each case (:mod:`lightsim.validation.scenes.analytic`) is run through the public
:class:`~lightsim.engine.server.Session` API, exactly as ``lightsim simulate`` runs a scene,
and every checked quantity becomes a :class:`Check` row: expected, measured, error, the
allowed deviation ("uncertainty") and pass/fail.

How the allowed deviation is set
--------------------------------
``uncertainty = q · σ + bias``, nothing else:

* **σ, photon statistics.** Lux values are checked as means over profile regions (rings
  of θ or r on the wall). Every one of the S = M² interleave sets is an independent
  estimate with its own photons, so their spread (from probe points at the region's
  pixel centres, :class:`~lightsim.render.frame.ProbeStats`) gives the standard error
  without assuming how the photons are distributed (quasi-random sampling makes Poisson
  formulas pessimistic). For ``bin`` the image pools all sets at every pixel: σ = s/√S
  of the S per-set region means. The interleaved kNN/radius image shows each set only
  on its own pixel lattice and box-filters it, which keeps pixel-scale noise that a
  set's mean over the whole region averages away: σ is computed for exactly that
  combination (:func:`interleaved_sigma`). Fluxes from the
  energy ledger use the per-photon variance of independent photons (conservative).
* **q** is the two-sided Student-t quantile with S − 1 degrees of freedom at the coverage
  of ±4σ of a normal law (1 − 6.3·10⁻⁵): 5.48 for S = 16 instead of 4, because σ is
  itself estimated from S values. A fixed seed makes every run reproducible.
* **bias** is zero for the ``bin`` estimator: a bin measures the pixel mean, and the
  expected value is the exact pixel mean (4 × 4 Gauss–Legendre points per pixel; pixels
  that straddle a discontinuity are left out of the regions). Density estimators
  (``knn``, ``radius``) blur: a box-kernel estimate measures the mean of E over its disk
  of radius r, and the image then goes through the M × M box filter. The allowance is
  computed, not guessed: the exact answer (zero off the detector) is averaged over the
  disk, box-filtered like the image, and the difference of its region mean from the
  exact region mean is the bias allowance. The radius is the expected one: r_k holds k
  photons of one set on average (the exact photon density integrated over the disk, so
  that beside a beam edge the neighbours come from the bright side), clipped to the
  Session's [min_radius, max_radius]; the fixed min_radius for ``radius``. The kNN
  estimate counts the k-th neighbour (on the disk's boundary) half, which keeps it within
  1/(2(k − 1)) of the disk mean whether the photons are independent (the upper end:
  (k − ½)/(k − 1)) or evenly stratified ((k − ½)/k); that fraction of the measured value
  is added to the allowance (0.79 % for k = 64; the full runs' σ is smaller than that).
  The fixed-radius counts at min_radius or max_radius are unbiased for the disk mean.
* **positions** (the ring caustic's cusp): the local shape of the nephroid: a pixel row
  of height h holds both folds of the cusp up to u = (3R/4)(h/2R)^{2/3} beyond it, so
  the row's maximum lies between R/2 and R/2 + u, ± half a pixel (plus the kernel radius
  for density estimators); that it is not inside R/2 is checked on its own.
* **bookkeeping** closes to 1e-6 relative (it is exact to rounding).

========================  =====  ==========  ==============================================
parameter                 unit   default     meaning
========================  =====  ==========  ==============================================
``photons``               –      400 000     photons per image case (``--full``: 4 000 000)
``estimators``            –      bin, knn    density estimators run on the image cases (kNN
                                             on isotropic, paraboloid, ring; ``--full``:
                                             bin, knn and radius on every case)
``interleave``            –      4           M (S = M² sets give σ)
``k``                     –      64          photons per kNN estimate
``seed``                  –      1           photon sequence
``box_photons``           –      100 000     photons in the closed-box balance (full: 2 M)
========================  =====  ==========  ==============================================
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.ndimage import binary_dilation
from scipy.stats import t as student_t

from lightsim.engine.config import RunConfig
from lightsim.engine.estimator import effective_radii, set_k
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.render.boxfilter import box_filter
from lightsim.render.frame import luminous
from lightsim.render.interleave import InterleavePattern
from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.tracer import LEDGER, PhotonTracer
from lightsim.validation.scenes import analytic as an

GAUSS_4SIGMA_TAIL = 6.334248366623973e-05  # two-sided P(|Z| > 4) of a normal law
BUDGET_RTOL = 1e-6


def student_q(n_sets: int, tail: float = GAUSS_4SIGMA_TAIL) -> float:
    """Quantile q with P(|t_{S−1}| > q) = ``tail``: the "4σ" multiplier for S sets."""
    if n_sets < 2:
        return math.inf
    return float(student_t.ppf(1.0 - tail / 2.0, n_sets - 1))


# ------------------------------------------------------------------------------------------
# Result rows
# ------------------------------------------------------------------------------------------

@dataclass
class Check:
    """One checked quantity.

    Attributes
    ----------
    case : str
        Case name (with the estimator, e.g. ``paraboloid/bin``).
    quantity : str
        What is compared (e.g. ``E θ 10–15°``).
    expected, measured : float or str
        Exact and measured values (in ``unit``), or words for qualitative checks.
    unit : str
    sigma : float or None
        Standard error from photon statistics (``unit``).
    q : float
        Multiplier of ``sigma`` (≈ 4σ coverage).
    bias : float
        Allowance for a known systematic deviation of the estimator (``unit``).
    tolerance : float or None
        Explicit allowed |error| (replaces q σ + bias), e.g. rounding or pixel size.
    ok : bool or None
        Verdict of a qualitative check (expected/measured are words).
    note : str
        How the allowance was set, or what went wrong.
    """

    case: str
    quantity: str
    expected: float | str
    measured: float | str
    unit: str = ""
    sigma: float | None = None
    q: float = 0.0
    bias: float = 0.0
    tolerance: float | None = None
    ok: bool | None = None
    note: str = ""
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def numeric(self) -> bool:
        return isinstance(self.expected, int | float) and isinstance(self.measured, int | float)

    @property
    def uncertainty(self) -> float | None:
        """Allowed |measured − expected| (``unit``)."""
        if self.tolerance is not None:
            return float(self.tolerance)
        if self.sigma is None:
            return None
        return self.q * self.sigma + self.bias

    @property
    def error(self) -> float | None:
        if not self.numeric:
            return None
        return float(self.measured) - float(self.expected)

    @property
    def passed(self) -> bool:
        if self.ok is not None:
            return bool(self.ok)
        err, unc = self.error, self.uncertainty
        if err is None or unc is None or not math.isfinite(err) or not math.isfinite(unc):
            return False
        return abs(err) <= unc

    def to_dict(self) -> dict[str, Any]:
        return {"case": self.case, "quantity": self.quantity, "unit": self.unit,
                "expected": self.expected, "measured": self.measured, "error": self.error,
                "uncertainty": self.uncertainty, "sigma": self.sigma, "q": self.q,
                "bias_allowance": self.bias, "pass": self.passed, "note": self.note,
                **({"details": self.details} if self.details else {})}


def _fmt(x: Any) -> str:
    if x is None:
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int | float):
        x = float(x)
        if not math.isfinite(x):
            return str(x)
        if x == 0:
            return "0"
        if 1e-3 <= abs(x) < 1e6:
            return f"{x:.5g}"
        return f"{x:.3e}"
    return str(x)


def table_rows(checks: Iterable[Check]) -> list[list[str]]:
    """Rows of the printed table: case, quantity, expected, measured, error, uncertainty,
    pass."""
    out = []
    for c in checks:
        unit = f" {c.unit}" if c.unit else ""
        err = c.error
        rel = ""
        if err is not None and isinstance(c.expected, int | float) and c.expected:
            rel = f" ({err / abs(float(c.expected)):+.2%})"
        out.append([c.case, c.quantity + (f" [{c.unit}]" if unit else ""), _fmt(c.expected),
                    _fmt(c.measured), (_fmt(err) + rel) if err is not None else "–",
                    _fmt(c.uncertainty) if c.uncertainty is not None else "–",
                    "PASS" if c.passed else "FAIL"])
    return out


TABLE_COLUMNS = ("case", "quantity", "expected", "measured", "error", "uncertainty", "pass")


# ------------------------------------------------------------------------------------------
# Settings
# ------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SuiteSettings:
    """Photon budgets and estimator settings of one validation run (see module table)."""

    photons: int = 400_000
    estimators: tuple[str, ...] = ("bin", "knn")
    interleave: int = 4
    k: int = 64
    seed: int = 1
    box_photons: int = 100_000
    full: bool = False

    @classmethod
    def fast(cls, **kw: Any) -> SuiteSettings:
        return cls(**kw)

    @classmethod
    def full_run(cls, **kw: Any) -> SuiteSettings:
        base = {"photons": 4_000_000, "box_photons": 2_000_000, "full": True,
                "estimators": ("bin", "knn", "radius")}
        base.update(kw)
        return cls(**base)


# ------------------------------------------------------------------------------------------
# Expected images of density estimators
# ------------------------------------------------------------------------------------------

def _disk_nodes(rings: int = 6, spokes: int = 16, kernel: str = "box"
                ) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature nodes (n, 2) on the unit disk and weights (sum 1) for a kernel."""
    r = np.sqrt((np.arange(rings) + 0.5) / rings)  # equal-area rings
    pts, w = [], []
    for i, ri in enumerate(r):
        ang = 2 * np.pi * (np.arange(spokes) + 0.5 * (i % 2)) / spokes
        pts.append(np.stack([ri * np.cos(ang), ri * np.sin(ang)], axis=1))
        weight = {"box": 1.0, "cone": 1.0 - ri, "epanechnikov": 1.0 - ri * ri}[kernel]
        w.append(np.full(spokes, weight))
    p, ww = np.concatenate(pts), np.concatenate(w)
    return p, ww / ww.sum()


def _model_functions(case: an.AnalyticScene) -> tuple[an.LuxFn, an.LuxFn]:
    """E (lx) and photon density (1/m² per emitted photon) as the estimator sees them:
    zero off the detector, and tabulated along r when the answer is radially symmetric
    (fast enough for the hundreds of evaluations per pixel below)."""
    frame = case.frame
    h0, h1 = frame.h_range_m
    v0, v1 = frame.v_range_m
    exact = case.exact
    assert exact is not None

    def on_wall(h: np.ndarray, v: np.ndarray) -> np.ndarray:
        return ((h >= h0) & (h <= h1) & (v >= v0) & (v <= v1)).astype(np.float64)

    if not case.radial:
        return (lambda h, v: exact(h, v) * on_wall(h, v),
                lambda h, v: case.photon_density(h, v) * on_wall(h, v))
    rmax = math.hypot(max(abs(h0), abs(h1)), max(abs(v0), abs(v1))) * 1.001
    rho = np.linspace(0.0, rmax, 40_001)
    e_tab = exact(rho, np.zeros_like(rho))
    n_tab = case.photon_density(rho, np.zeros_like(rho))
    return (lambda h, v: np.interp(np.hypot(h, v), rho, e_tab, right=0.0) * on_wall(h, v),
            lambda h, v: np.interp(np.hypot(h, v), rho, n_tab, right=0.0) * on_wall(h, v))


def estimator_radius(case: an.AnalyticScene, config: RunConfig, photons_per_set: float,
                     radii: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Expected kernel radius r (m) and kNN radius r_k (m) at every pixel centre, (H, W).

    kNN: r_k is the radius whose disk is expected to hold k photons of one set,
    π r² · (mean photon density over the disk) = k — solved on a geometric ladder of radii
    with the density averaged over each disk, so that near an edge of the beam the k
    nearest photons come from the bright side, as they do in the estimator. Then
    r = r_k clipped to ``radii`` = (min_radius, max_radius) (the Session's
    :attr:`~lightsim.engine.server.Session.radii_m`). ``radius`` estimator: min_radius.
    """
    min_radius, max_radius = radii
    frame = case.frame
    h, v = frame.pixel_centres()
    hh, vv = np.meshgrid(h, v)
    if config.estimator == "radius":
        return np.full(hh.shape, min_radius), np.full(hh.shape, min_radius)
    _, dens = _model_functions(case)
    nodes, w = _disk_nodes(4, 12)  # the photon count is a smooth function of r
    base = max(min_radius, 0.25 * min(frame.pixel_size_m))
    diag = math.hypot(np.ptp(frame.h_range_m), np.ptp(frame.v_range_m))
    ladder = base * 2.0 ** (np.arange(-8, 64) / 2.0)
    ladder = ladder[ladder <= 2 * diag]

    k = float(set_k(config))
    rows = []
    for r in ladder:
        acc = np.zeros(hh.shape)
        for (dx, dy), wi in zip(nodes, w):
            acc += wi * dens(hh + r * dx, vv + r * dy)
        rows.append(math.pi * r * r * acc * photons_per_set)
        if np.all(rows[-1] >= k):
            break  # every pixel holds k photons: larger radii are not needed
    radii = ladder[:len(rows)]
    counts = np.stack(rows)
    reached = counts >= k
    first = np.where(reached.any(axis=0), reached.argmax(axis=0), len(radii) - 1)
    lo = np.maximum(first - 1, 0)
    c_lo = np.take_along_axis(counts, lo[None], 0)[0]
    c_hi = np.take_along_axis(counts, first[None], 0)[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.clip(np.log(k / c_lo) / np.log(c_hi / c_lo), 0.0, 1.0)
    f = np.where(np.isfinite(f) & (first > 0), f, 1.0)
    rk = radii[lo] * (radii[first] / radii[lo]) ** f
    rk = np.where(reached.any(axis=0), rk, radii[-1])
    return np.clip(rk, min_radius, max_radius), rk


def expected_image(case: an.AnalyticScene, config: RunConfig, photons_per_set: float,
                   radii: tuple[float, float]) -> np.ndarray:
    """What a density estimator measures on average, (H, W) lx.

    E is averaged over the kernel's disk at the expected radius (288-point rule), then
    box-filtered like the image. For ``bin`` it is the exact pixel mean. ``radii`` are
    the Session's (min_radius, max_radius) in m.
    """
    frame = case.frame
    assert case.exact is not None
    if config.estimator == "bin":
        return an.pixel_average(case.exact, frame)
    r, _ = estimator_radius(case, config, photons_per_set, radii)
    efn, _ = _model_functions(case)
    h, v = frame.pixel_centres()
    hh, vv = np.meshgrid(h, v)
    nodes, w = _disk_nodes(12, 24, kernel=config.kernel)
    # offsets in the wall plane are isotropic, so (h, v) serve as plane coordinates
    acc = np.zeros(hh.shape)
    for (dx, dy), wi in zip(nodes, w):
        acc += wi * efn(hh + r * dx, vv + r * dy)
    if config.final == "interleaved" and config.interleave > 1 and config.filter_n > 1:
        acc = np.asarray(box_filter(acc, config.filter_n), dtype=np.float64)
    return acc


# ------------------------------------------------------------------------------------------
# Running one image case
# ------------------------------------------------------------------------------------------

@dataclass
class ImageRun:
    """What one Session run of an image case produced (for the checks and for reports)."""

    case: an.AnalyticScene
    config: RunConfig
    lux: np.ndarray              # (H, W) luminous, lx
    exact_px: np.ndarray | None  # (H, W) exact pixel means, lx
    per_set: np.ndarray          # (S, P) per-set probe values at the region pixels, lx
    probe_index: np.ndarray      # (H, W) int: probe column of a pixel, −1 if none
    energy: dict[str, float]
    photons: int
    seconds: float
    rel_error: float | None
    min_radius: float
    max_radius: float = math.inf

    @property
    def n_sets(self) -> int:
        return int(self.per_set.shape[0])


@dataclass
class SessionRun:
    """Outputs of one Session run (all luminous, lx / lm)."""

    lux: np.ndarray             # (H, W) filtered image
    raw: np.ndarray | None      # (H, W) before filtering
    per_set: np.ndarray         # (S, P) per-set estimates at the extra probes
    grid_means: np.ndarray      # (P_grid,) mean over sets at the error-estimate grid
    energy: dict[str, float]
    photons: int
    seconds: float
    rel_error: float | None
    min_radius: float
    warnings: list[str]
    max_radius: float = math.inf


def run_session(scene: Any, config: RunConfig, photons: int,
                probes_hv: np.ndarray | None = None) -> SessionRun:
    """Shoot ``photons`` in one frame through a :class:`Session` and collect its outputs."""
    probes = np.zeros((0, 2)) if probes_hv is None else np.asarray(probes_hv, float)
    cfg = config.with_(frame_photons=max(int(photons), config.n_sets))
    t0 = time.perf_counter()
    with Session(scene, cfg, extra_probes=probes) as session:
        est = session.run(photons=photons)
        energy = session.energy()
        min_r, max_r = session.radii_m
        grid = session.grid_count
    if est.probes is not None:
        per_set = luminous(est.probes.values[:, grid:, :])
        grid_means = luminous(est.probes.mean[:grid])
    else:
        per_set, grid_means = np.zeros((1, len(probes))), np.zeros(0)
    raw = None if est.raw is None else luminous(est.raw)
    return SessionRun(luminous(est.lux), raw, per_set, grid_means, energy, int(est.photons),
                      time.perf_counter() - t0, est.rel_error, min_r, list(scene.warnings),
                      max_r)


def run_image_case(case: an.AnalyticScene, config: RunConfig, photons: int,
                   masks: Sequence[np.ndarray] | None = None) -> ImageRun:
    """Run ``case`` through a Session with probes at every pixel centre of its regions."""
    frame = case.frame
    h, v = frame.pixel_centres()
    hh, vv = np.meshgrid(h, v)
    if masks is None:
        masks = [pred(hh, vv) for _, pred in case.regions]
    union = np.zeros(hh.shape, bool)
    for m in masks:
        union |= m
    if config.estimator != "bin" and config.final == "interleaved" and config.interleave > 1:
        # the image's box filter reaches filter_n pixels around a region: probe those too
        n = config.filter_n
        union = binary_dilation(union, np.ones((2 * n + 1, 2 * n + 1), bool))
    probe_index = np.full(hh.shape, -1, np.int64)
    probe_index[union] = np.arange(int(union.sum()))
    probes = np.stack([hh[union], vv[union]], axis=1)
    sr = run_session(case.scene, config, photons, probes)
    exact_px = an.pixel_average(case.exact, frame) if case.exact is not None else None
    return ImageRun(case, config.with_(frame_photons=max(int(photons), config.n_sets)),
                    sr.lux, exact_px, sr.per_set, probe_index, sr.energy, sr.photons,
                    sr.seconds, sr.rel_error, sr.min_radius, sr.max_radius)


def interleaved_sigma(run: ImageRun, mask: np.ndarray) -> float:
    """Standard error (lx) of the region mean of an interleaved, box-filtered image.

    The image shows set s only on its own pixel lattice L_s (every M-th pixel) and then
    box-filters. Averaging a set over *all* pixels of a region (what the probes do) would
    understate the noise: quasi-random photons are well stratified over a large region
    but not at the scale of one pixel's kernel. So, with ê_s(p) the deviation of set s
    from the mean of all sets at probe pixel p, Y_{s,t} = region mean of the box-filtered
    field ê_s restricted to lattice L_t; for each lattice t the S sets give independent
    copies of the noise the image gets from that lattice, and
    σ² = Σ_t Σ_s Y_{s,t}² / (S − 1) (the Y_{s,t} sum to zero over s).
    """
    cfg = run.config
    H, W = run.lux.shape
    pattern = InterleavePattern(cfg.interleave, W, H)
    have = run.probe_index >= 0
    dev = run.per_set - run.per_set.mean(axis=0, keepdims=True)  # (S, P)
    S = dev.shape[0]
    n = cfg.filter_n
    var = 0.0
    for t in range(pattern.n_sets):
        rows, cols = pattern.set_pixels(t)
        lattice = np.zeros((H, W), bool)
        lattice[np.ix_(rows, cols)] = True
        sel = lattice & have
        ys, xs = np.nonzero(sel)
        ys_all = []
        for s in range(S):
            f = np.zeros((H, W))
            f[ys, xs] = dev[s, run.probe_index[ys, xs]]
            if n > 1:
                f = np.asarray(box_filter(f, n), dtype=np.float64)
            ys_all.append(float(f[mask].mean()))
        y = np.asarray(ys_all)
        var += float((y * y).sum() / (S - 1))
    return math.sqrt(var)


def budget_check(name: str, energy: dict[str, float]) -> Check:
    """Σ ledger parts = emitted within 1e-6 relative."""
    parts = sum(energy[k] for k in LEDGER)
    emitted = energy["emitted"]
    return Check(name, "energy budget Σ parts", emitted, parts, "lm",
                 tolerance=BUDGET_RTOL * abs(emitted),
                 note="wall + absorbed + escaped + roulette + max depth = emitted (exact "
                      "bookkeeping; 1e-6 relative allows rounding)",
                 details={k: energy[k] for k in ("emitted", *LEDGER)})


def region_checks(run: ImageRun, name: str, regions: Sequence[tuple[str, np.ndarray]],
                  expected_img: np.ndarray | None = None) -> list[Check]:
    """One check per region: exact region mean vs the image's region mean.

    """
    assert run.exact_px is not None
    S = run.n_sets
    q = student_q(S)
    # the pooled image is the mean of every set at every pixel: the plain spread of the sets'
    # region means is its σ; the interleaved image needs the lattice-aware σ
    interleaved = (run.config.estimator != "bin" and run.config.final == "interleaved"
                   and S > 1)
    out = []
    for label, mask in regions:
        if not mask.any():
            continue
        if interleaved:
            se = interleaved_sigma(run, mask)
        else:
            idx = run.probe_index[mask]
            per_set_mean = run.per_set[:, idx].mean(axis=1)
            se = float(per_set_mean.std(ddof=1) / math.sqrt(S)) if S > 1 else math.inf
        exact = float(run.exact_px[mask].mean())
        measured = float(run.lux[mask].mean())
        bias = 0.0
        note = (f"σ from {S} interleave sets"
                + (" as the interleaved image uses them" if interleaved else "")
                + f" × q={q:.2f}")
        details: dict[str, Any] = {"pixels": int(mask.sum())}
        if expected_img is not None:
            details["expected_through_estimator"] = float(expected_img[mask].mean())
            blur = abs(float(expected_img[mask].mean()) - exact)
            bias += blur
            note += f"; blur allowance {blur:.3g} lx"
        if run.config.estimator == "knn" and run.config.k > 1:
            # the k-th photon counted half: E[(k − ½)/(π r_k²)] = (k − ½)/(k − 1) × the disk
            # mean for independent photons, (k − ½)/k for evenly stratified ones
            kth = abs(float(run.lux[mask].mean())) / (2.0 * (run.config.k - 1))
            bias += kth
            note += f"; k-th photon allowance {kth:.3g} lx"
        out.append(Check(name, label, exact, measured, "lx", se, q, bias, note=note,
                         details=details))
    return out


def _regions(case: an.AnalyticScene, config: RunConfig, photons: int,
             radii: tuple[float, float]) -> list[tuple[str, np.ndarray]]:
    """Region masks; for density estimators, pixels within 2 kernel radii of the wall's
    edge are dropped (the kernel disk would reach past the detector)."""
    frame = case.frame
    h, v = frame.pixel_centres()
    hh, vv = np.meshgrid(h, v)
    masks = [(label, pred(hh, vv)) for label, pred in case.regions]
    if config.estimator == "bin":
        return masks
    r, _ = estimator_radius(case, config, photons / config.n_sets, radii)
    window = config.filter_n if config.final == "interleaved" else 1
    margin = 2 * r + window * max(frame.pixel_size_m)
    inside = ((hh - margin > frame.h_range_m[0]) & (hh + margin < frame.h_range_m[1])
              & (vv - margin > frame.v_range_m[0]) & (vv + margin < frame.v_range_m[1]))
    return [(label, m & inside) for label, m in masks]


def session_radii(case: an.AnalyticScene, config: RunConfig) -> tuple[float, float]:
    """(min_radius, max_radius) in m a Session on ``case`` will use (its defaults)."""
    return effective_radii(config, case.frame)


def _extra_regions(case: an.AnalyticScene) -> list[tuple[str, np.ndarray]]:
    """Case-specific regions probed besides the profile (the Lambertian axis)."""
    if case.name != "lambertian":
        return []
    h, v = case.frame.pixel_centres()
    hh, vv = np.meshgrid(h, v)
    return [("axis", np.hypot(hh, vv) < 0.5 * case.params["disk_radius_m"])]


def check_image_case(case: an.AnalyticScene, config: RunConfig, photons: int
                     ) -> tuple[list[Check], ImageRun]:
    """Run an image case and return its checks (regions, wall flux, energy budget)."""
    name = f"{case.name}/{config.estimator}"
    regions = _regions(case, config, photons, session_radii(case, config))
    extra = _extra_regions(case)
    run = run_image_case(case, config, photons, [m for _, m in regions + extra])
    exp_img = None
    if config.estimator != "bin":
        exp_img = expected_image(case, config, run.photons / run.n_sets,
                                 (run.min_radius, run.max_radius))
    checks = region_checks(run, name, regions, exp_img)
    if case.name == "lambertian" and extra[0][1].any():
        # luminance from the illuminance on the axis: E_axis = π L a² / (a² + d²)
        rc = region_checks(run, name, extra, exp_img)[0]
        a, d = case.params["disk_radius_m"], case.params["distance_m"]
        L = case.extra["luminance"]
        scale = L / float(rc.expected)
        checks.append(Check(name, "luminance L = Φ/(πA)", L, float(rc.measured) * scale,
                            "cd/m²", None if rc.sigma is None else rc.sigma * scale, rc.q,
                            rc.bias * scale,
                            note=f"from E within r < {0.5 * a * 1e3:.1f} mm of the axis: "
                                 f"L = E (a²+d²)/(π a²), a = {a} m, d = {d} m"))
    if case.wall_flux is not None and case.wall_flux_sigma is not None:
        checks.append(Check(name, "flux on the wall", case.wall_flux, run.energy["wall"], "lm",
                            case.wall_flux_sigma / math.sqrt(run.photons), 4.0,
                            note="exact solid-angle flux; σ of independent photons (quasi-"
                                 "random sampling does better)"))
    checks.append(budget_check(name, run.energy))
    return checks, run


# ------------------------------------------------------------------------------------------
# Ring caustic
# ------------------------------------------------------------------------------------------

def check_ring(case: an.AnalyticScene, config: RunConfig, photons: int
               ) -> tuple[list[Check], ImageRun]:
    """Find the nephroid's cusp on the floor: the maximum of E along the symmetry axis."""
    name = f"{case.name}/{config.estimator}"
    frame = case.frame
    h, v = frame.pixel_centres()
    _hh, vv = np.meshgrid(h, v)
    R = case.params["radius_m"]
    dv = frame.pixel_size_m[1]
    axis_rows = np.abs(vv) < 0.5 * dv + 1e-12
    run = run_image_case(case, config, photons, [axis_rows])
    row = np.flatnonzero(axis_rows.any(axis=1))[0]
    profile = run.lux[row]
    # search between the centre and the wall, away from both
    window = (h < -0.15 * R) & (h > -0.9 * R)
    i = int(np.argmax(np.where(window, profile, -np.inf)))
    cusp_h = float(h[i])
    px = frame.pixel_size_m[0]
    # Near the cusp the nephroid x = (R/4)(3 cos t − cos 3t), z = (R/4)(3 sin t − sin 3t)
    # has the two folds z = ±R (4u / 3R)^{3/2} at u = x − R/2 ≥ 0 (towards the wall). A
    # pixel row of height h holds both fold lines (line singularities of E) up to
    # u_row = (3R/4)(h / 2R)^{2/3} beyond the cusp, so the row's maximum lies between
    # R/2 and R/2 + u_row, give or take half a pixel for the pixel centre.
    u_row = 0.75 * R * (dv / (2 * R)) ** (2.0 / 3.0)
    blur = 0.0 if config.estimator == "bin" else run.min_radius
    tol = u_row + 0.5 * px + blur
    note = (f"row maximum lies within u = (3R/4)(h/2R)^(2/3) = {u_row * 1e3:.2f} mm beyond "
            f"the cusp (row height h = {dv * 1e3:.2f} mm) ± half a pixel")
    if blur:
        note += f" + kernel radius {blur * 1e3:.2f} mm"
    expected = case.extra["cusp_hv"][0]
    inner_limit = abs(expected) - 0.5 * px - blur
    checks = [Check(name, "cusp distance from the axis", abs(expected), abs(cusp_h), "m",
                    tolerance=tol, note=note,
                    details={"profile_h_m": h[window].tolist(),
                             "profile_lux": profile[window].tolist(), "u_row_m": u_row}),
              Check(name, "maximum not inside the cusp", f"≥ {inner_limit:.4g}", abs(cusp_h),
                    "m", ok=bool(abs(cusp_h) >= inner_limit),
                    note="inside R/2 no ray crosses the axis (R/(2 cos φ) ≥ R/2)")]
    # the cusp must stand out: peak well above the direct light and its surroundings
    e_dir = case.extra["direct_lux"]
    checks.append(Check(name, "cusp peak / direct light", "> 5", float(profile[i] / e_dir),
                        ok=bool(profile[i] > 5 * e_dir),
                        note="a caustic, not noise: the fold concentrates the reflected light"))
    checks.append(budget_check(name, run.energy))
    return checks, run


# ------------------------------------------------------------------------------------------
# Closed box
# ------------------------------------------------------------------------------------------

def check_box(photons: int, albedo: float = 0.7, seed: int = 1, max_depth: int = 64,
              groups: int = 64) -> list[Check]:
    """Point source in a closed diffuse box: nothing escapes, bookkeeping closes, and the
    flux arriving at the walls over all bounces is Φ (1 − ρᴰ)/(1 − ρ)."""
    flux = 10.0
    scene = an.closed_box(flux, albedo)
    tracer = PhotonTracer(scene, max_depth=max_depth, record="all")
    idx = np.arange(photons, dtype=np.int64)
    pts = halton_points(idx, digit_permutations(seed, 0, None))
    group = idx % groups
    res = tracer.trace_points(pts, photon_keys(seed, 0, 0, idx), group=group, n_groups=groups)
    tracer.caster.close()
    name = f"box ρ={albedo:g}"
    led = res.ledger[:, :, 0]  # (groups, K)
    emitted = float(res.emitted.sum()) / photons
    total = {k: float(led[:, i].sum()) / photons for i, k in enumerate(LEDGER)}
    checks = [Check(name, "escaped flux", 0.0, total["escaped"], "lm", tolerance=0.0,
                    note="a closed box: not one photon may leave"),
              budget_check(name, {"emitted": emitted, **total})]
    # absorbed = Φ minus what roulette (zero mean) and the depth limit keep
    n_g = np.bincount(group, minlength=groups).astype(float)
    absorbed_g = led[:, LEDGER.index("absorbed_diffuse")] / n_g
    exp_abs = flux * (1.0 - albedo**max_depth)
    checks.append(Check(name, "absorbed flux", exp_abs, total["absorbed_diffuse"], "lm",
                        float(absorbed_g.std(ddof=1) / math.sqrt(groups)), student_q(groups),
                        note=f"Φ (1 − ρᴰ), D = {max_depth}; σ from {groups} photon groups "
                             "(roulette noise)"))
    # arrivals: Σ recorded incident flux / Φ = mean number of diffuse hits per lumen
    rec = res.records
    per_photon = np.bincount(rec.source, weights=rec.power[:, 0].astype(np.float64),
                             minlength=photons) / flux
    expected_hits = an.box_incident_flux(1.0, albedo, max_depth)
    checks.append(Check(name, "arrivals per emitted lumen", expected_hits,
                        float(per_photon.mean()), "", float(per_photon.std(ddof=1)
                                                            / math.sqrt(photons)), 4.0,
                        note="(1 − ρᴰ)/(1 − ρ) = mean number of bounces; σ per photon"))
    return checks


# ------------------------------------------------------------------------------------------
# The suite
# ------------------------------------------------------------------------------------------

@dataclass
class SuiteResult:
    checks: list[Check]
    seconds: float
    settings: SuiteSettings
    skipped: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    def to_dict(self) -> dict[str, Any]:
        return {"passed": self.passed, "seconds": self.seconds,
                "settings": self.settings.__dict__, "skipped": self.skipped,
                "checks": [c.to_dict() for c in self.checks]}


def case_builders(full: bool) -> dict[str, Callable[[], an.AnalyticScene]]:
    """Image cases of the fast (or full) suite, by name."""
    if not full:
        return {"isotropic": an.isotropic_case, "paraboloid": an.paraboloid_case,
                "slab": an.slab_case, "ring": an.ring_case, "lambertian": an.lambertian_case}
    return {
        "isotropic": lambda: an.isotropic_case(resolution=(128, 128)),
        "paraboloid": lambda: an.paraboloid_case(resolution=(128, 128), radial=128,
                                                 azimuthal=512),
        "slab": lambda: an.slab_case(resolution=(128, 128)),
        "slab-absorbing": lambda: an.slab_case(sigma=10.0, resolution=(128, 128)),
        "ring": lambda: an.ring_case(resolution=(257, 257), segments=512),
        "lambertian": lambda: an.lambertian_case(resolution=(128, 128)),
    }


CASE_NAMES = ("isotropic", "paraboloid", "slab", "slab-absorbing", "ring", "lambertian", "box")


def run_suite(settings: SuiteSettings | None = None, cases: Sequence[str] | None = None,
              progress: Callable[[str], None] | None = None) -> SuiteResult:
    """Run the analytic suite (fast by default) and return every check.

    Parameters
    ----------
    settings : SuiteSettings
        Budgets and estimators (``SuiteSettings.full_run()`` for the long study).
    cases : sequence of str, optional
        Only these cases (names in :data:`CASE_NAMES`).
    progress : callable, optional
        Called with a short line before each case.
    """
    settings = settings or SuiteSettings.fast()
    t0 = time.perf_counter()
    builders = case_builders(settings.full)
    wanted = list(cases) if cases else [*builders, "box"]
    unknown = [c for c in wanted if c not in CASE_NAMES]
    if unknown:
        raise InputError(f"unknown validation case(s): {', '.join(unknown)} "
                         f"(known: {', '.join(CASE_NAMES)})")
    estimators = list(settings.estimators)
    checks: list[Check] = []
    for name in wanted:
        if name == "box":
            if progress:
                progress("box")
            checks.extend(check_box(settings.box_photons, seed=settings.seed))
            continue
        build = builders.get(name) or case_builders(True)[name]
        for est in estimators:
            if est == "knn" and not settings.full and name not in ("isotropic", "paraboloid",
                                                                   "ring"):
                continue  # the fast subset checks kNN on the cases where it matters most
            if progress:
                progress(f"{name}/{est}")
            case = build()
            # bandwidth="knn": the checks compare with the kNN model (r_k disk blur); the
            # default ICI map's accuracy is measured by `lightsim converge`
            cfg = RunConfig(seed=settings.seed, interleave=settings.interleave, estimator=est,
                            k=settings.k, spt=False, bandwidth="knn")
            if name == "ring":
                checks.extend(check_ring(case, cfg, settings.photons)[0])
            else:
                checks.extend(check_image_case(case, cfg, settings.photons)[0])
    return SuiteResult(checks, time.perf_counter() - t0, settings)
