"""Engineering outputs of a finished run that need no rule set: detector-aperture
intensities with their intervals, the iso-lux and road views, the light that leaves the
lamp (for far-field files).

The last stage of the data flow (scene → photons → photon maps → images → **reports**).
Rule sets and photometric files build on these (:mod:`lightsim.luminaires.regulations.
check`, :mod:`lightsim.luminaires.photometric.analysis`) and are handed to the run as
:class:`~lightsim.analysis.Analysis` objects: this module imports neither.

======================  =====  =========  ===============================================
parameter               unit   default    meaning
======================  =====  =========  ===============================================
``mount_height``        m      0.65       lamp height above the road (road view)
``photons``             –      10⁶        photons traced without the wall (far field)
``confidence``          –      0.95       two-sided level of the aperture intervals
``SPARSE_PHOTONS_PER``  –      1          photons per set below which an interval is the
``_SET``                                  photon-count one
======================  =====  =========  ===============================================

Detector apertures (``lightsim.engine.apertures``) count every wall photon inside a square
of the sky around a direction: I = flux / solid angle, unbiased per interleave set.

Intervals of an intensity (:class:`IntensityEvidence`)
------------------------------------------------------
An intensity here is one aperture's or a sum of apertures'. Its S per-set values and its
photon statistics — the effective count n = (Σw)²/Σw² of the photon contributions w
(cd) pooled over the sets, one photon's worth q = Σw²/Σw and the heaviest photon's
worth w_max — give one-sided bounds, each wrong with a stated probability (α/2 for the
two-sided 95 % interval):

* **well populated**, n ≥ ``SPARSE_PHOTONS_PER_SET`` · S (a photon per set or more):
  Student-t over the S per-set values, mean ± t(1 − tail, S − 1)·s/√S. The sets are
  independent and unbiased, so the interval holds whatever the photons' weights and
  correlations, once the per-set values are close enough to normal — which they are
  when each set holds photons;
* **sparse**, n below that: most sets hold no photon, the sets' spread says little (it is
  zero when no set saw one) and a t interval is too narrow and can go negative. The
  photon count decides instead: the mid-p Poisson bounds of n times q, the gamma interval
  of a weighted sum of Poisson counts (Fay & Feuer 1997, with mid-p quantiles; n and q
  are its shape and scale), :func:`~lightsim.engine.apertures.count_bounds`;
* **in both**: the upper bound is at least the estimate plus −ln(2·tail) (3.0 at 95 %)
  heaviest photons — photons as heavy as w_max that happened to miss, which light ones
  counted cannot rule out; and no lower bound is below 0 (the truth is never negative,
  so clipping a bound at 0 cannot make it wrong).

A sum of apertures pools its apertures' photons: Σw and Σw² add, w_max is the largest.
Without photon statistics (the kNN method) only the Student-t rule applies; with a single
set there is no error estimate and the bounds collapse to the value.
"""


from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import stdtrit

from lightsim import __version__
from lightsim.engine.apertures import (
    count_bounds,
    count_statistics,
    intensities,
    layout_from_config,
    midp_poisson,
    raster_tiles,
)
from lightsim.engine.guiding import heaviest_weight
from lightsim.errors import InputError
from lightsim.io.plot_worker import InProcess
from lightsim.io.plots import PlotCaption, isolux_noise_floor, road_view_data
from lightsim.render.frame import luminous
from lightsim.render.road import REACH_LEVELS
from lightsim.sampling import SelectiveSampler, digit_permutations, halton_points, photon_keys
from lightsim.scene import WALL, Scene
from lightsim.tracer import PhotonTracer

SPARSE_PHOTONS_PER_SET = 1.0
"""Below this many counted photons per set an intensity's interval is the photon-count
one instead of Student-t over the sets."""


def _frame_dict(frame: Any) -> dict[str, Any]:
    return frame.to_dict() if hasattr(frame, "to_dict") else dict(frame)


@dataclass(frozen=True)
class Bounds:
    """An estimate (cd) with its lower and upper bound and how they were found.

    Attributes
    ----------
    mean, lo, hi : ndarray
        Estimate and bounds in cd (``lo`` ≥ 0).
    counted : ndarray of bool
        True where the bounds are the photon-count ones (sparse), False where they are
        Student-t over the sets (or given by the caller).
    unseen : ndarray
        The least upper bound the photon statistics allow: the estimate plus the heaviest
        photons that may have missed (−inf without statistics).
    """

    mean: NDArray
    lo: NDArray
    hi: NDArray
    counted: NDArray
    unseen: NDArray


@dataclass(frozen=True)
class IntensityEvidence:
    """What a run knows about P intensities: per-set values and photon statistics.

    The bounds of one intensity or of a sum of them follow the rule of the module
    docstring (Student-t where the sets are well populated, the weighted photon count
    where they are sparse, never below 0, room for unseen heavy photons).

    Attributes
    ----------
    per_set : ndarray, shape (S, P)
        Per-set intensities (cd).
    count : ndarray, shape (4, P), optional
        Photon statistics of each intensity as
        :func:`~lightsim.engine.apertures.count_statistics` gives them: effective count
        n, one photon's worth q (cd), the heaviest photon's worth w_max (cd), mean (cd).
        None where the intensities were not counted (kNN estimates).
    fixed : ndarray, shape (P, 2), optional
        Intervals (cd) given by the caller; where both bounds are finite they are used
        as they are, at every level.
    """

    per_set: NDArray
    count: NDArray | None = None
    fixed: NDArray | None = None

    def __post_init__(self) -> None:
        # bounds of every intensity, by (tail_lo, tail_hi): computed over all P at once
        # (a column's mean is then the same number whichever rule asks for it)
        object.__setattr__(self, "_every", {})
        per = np.asarray(self.per_set, dtype=np.float64)
        object.__setattr__(self, "per_set", per[None, :] if per.ndim == 1 else per)
        P = self.per_set.shape[1]
        if self.count is not None:
            count = np.asarray(self.count, dtype=np.float64)
            if count.shape != (4, P):
                raise InputError(f"photon statistics must have shape (4, {P}), "
                                 f"got {count.shape}")
            object.__setattr__(self, "count",
                               count if np.isfinite(count).all() else None)
        if self.fixed is not None:
            fixed = np.asarray(self.fixed, dtype=np.float64)
            if fixed.shape != (P, 2):
                raise InputError(f"intervals_cd must have shape ({P}, 2), got {fixed.shape}")
            object.__setattr__(self, "fixed", fixed)

    @property
    def n_sets(self) -> int:
        """Independent sets S."""
        return int(self.per_set.shape[0])

    def each(self, cols: ArrayLike, tail_lo: float, tail_hi: float) -> Bounds:
        """Bounds of every intensity in ``cols``: P(truth < lo) ≤ ``tail_lo`` and
        P(truth > hi) ≤ ``tail_hi`` for each one (shapes (len(cols),))."""
        cols = np.asarray(cols, dtype=np.int64).reshape(-1)
        key = (float(tail_lo), float(tail_hi))
        every = self._every.get(key)
        if every is None:
            every = _bounds(self.per_set, self.count, tail_lo, tail_hi)
            if self.fixed is not None:
                use = np.isfinite(self.fixed).all(axis=1)
                every = Bounds(every.mean, np.where(use, self.fixed[:, 0], every.lo),
                               np.where(use, self.fixed[:, 1], every.hi),
                               every.counted & ~use, every.unseen)
            self._every[key] = every
        return Bounds(every.mean[cols], every.lo[cols], every.hi[cols], every.counted[cols],
                      every.unseen[cols])

    def total(self, cols: ArrayLike, tail_lo: float, tail_hi: float) -> Bounds:
        """Bounds of the sum of the intensities in ``cols`` (shapes (1,)): the per-set
        sums, and the pooled photons of all of them (Σw and Σw² add, the heaviest photon
        is the heaviest of any)."""
        cols = np.asarray(cols, dtype=np.int64).reshape(-1)
        per = self.per_set[:, cols].sum(axis=1, keepdims=True)
        stats = None
        if self.count is not None:
            n, q, w_max, mean = self.count[:, cols]
            y = float(mean.sum())
            v = float(np.sum(np.where(n > 0, mean * q, 0.0)))
            top = float(w_max.max())
            n_sum = y * y / v if v > 0 else 0.0
            q_sum = v / y if y > 0 and v > 0 else top
            stats = np.array([[n_sum], [q_sum], [top], [y]])
        return _bounds(per, stats, tail_lo, tail_hi)


def _bounds(per_set: NDArray, count: NDArray | None, tail_lo: float, tail_hi: float
            ) -> Bounds:
    """The rule of the module docstring on (S, K) per-set values and (4, K) statistics."""
    S = per_set.shape[0]
    mean = per_set.mean(axis=0)
    if S >= 2:
        sd = per_set.std(axis=0, ddof=1)
        lo = mean - float(stdtrit(S - 1, 1.0 - tail_lo)) * sd / np.sqrt(S)
        hi = mean + float(stdtrit(S - 1, 1.0 - tail_hi)) * sd / np.sqrt(S)
    else:  # one set: no error estimate
        lo, hi = mean.copy(), mean.copy()
    counted = np.zeros(mean.shape, dtype=bool)
    unseen = np.full(mean.shape, -np.inf)
    if count is not None:
        n_eff, q, w_max, c_mean = count
        c_lo, c_hi = count_bounds(n_eff, q, w_max, c_mean, tail_lo, tail_hi)
        counted = n_eff < SPARSE_PHOTONS_PER_SET * S
        lo = np.where(counted, c_lo, lo)
        # room for unseen heavy photons above the t bound too (count_bounds keeps it)
        unseen = c_mean + float(midp_poisson(np.zeros(1), 1.0 - tail_hi)[0]) * w_max
        hi = np.where(counted, c_hi, np.maximum(hi, unseen) if S >= 2 else hi)
    return Bounds(mean, np.maximum(lo, 0.0), hi, counted, unseen)


def heaviest_photon(config: Any, spt: bool) -> float:
    """The heaviest photon a run emits, in average emitted photons (1 without Selective
    Photon Tracing).

    SPT gives a cell's photons the weight n_pass / (L n_c) (:class:`~lightsim.sampling.
    SelectiveSampler`): a cell that keeps the fewest photons per pass (one in caustic SPT,
    the base share when aiming at test points) weighs the most.
    """
    guided = heaviest_weight(config)  # a guided photon weighs up to 1/(1 − share) more
    if not (spt or config.aperture_targets):
        return guided
    share = None if spt else float(config.aperture_spt_share)
    sampler = SelectiveSampler(int(config.seed), 0, refine_share=share,
                               pass_photons=config.photons_per_set)
    cells, per_pass = sampler.n_cells, sampler.pass_photons
    fewest = 1 if share is None else max(1, int((1.0 - share) * per_pass) // cells)
    plain = max(1, per_pass // cells)  # passes before anything is refined
    return guided * max(per_pass / (cells * fewest), per_pass / (cells * plain))


def aperture_values(session, shift_deg: float = 0.0, confidence: float = 0.95
                    ) -> dict[str, Any]:
    """Per-set aperture intensities (cd) of a finished session's test points and Imax.

    Returns
    -------
    dict with ``cd`` (S, P) test points (last column H-V), ``tiles`` (S, nc, nv) Imax
    raster, ``tile_h_deg``, ``tile_v_deg``, ``layout``, ``shift_deg`` (applied, rounded),
    ``n_eff`` (P,) photons counted (effective number, pooled over sets),
    ``count_stats`` (4, P) the photon statistics (:class:`IntensityEvidence`) and
    ``intervals_cd`` (P, 2) every aperture's interval at ``confidence`` by the rule of
    the module docstring.
    """
    stats = session.backend.stats()
    sets = sorted(stats)
    per_set = session.backend.apertures()
    counts = np.stack([per_set[s] for s in sets])
    emitted = np.array([stats[s]["emitted"] for s in sets], dtype=np.float64)
    layout = layout_from_config(session.config, session.scene.wall.distance_m)
    try:
        _k, applied = layout.quantize_shift(shift_deg)
    except ValueError as exc:
        raise InputError(f"--aim: {exc}") from None
    cd = luminous(intensities(counts, emitted, layout, applied))
    power = np.stack([stats[s]["emitted_power"] for s in sets])
    heaviest = heaviest_photon(session.config, bool(session.plan.spt))
    count = np.stack(count_statistics(counts, emitted, power, layout, applied,
                                      heaviest))  # (4, P)
    tail = (1.0 - confidence) / 2.0
    b = IntensityEvidence(cd, count).each(np.arange(cd.shape[1]), tail, tail)
    tiles = raster_tiles(counts, emitted, layout)
    return {"cd": cd, "tiles": luminous(tiles.values), "tile_h_deg": tiles.h_deg,
            "tile_v_deg": tiles.v_deg, "layout": layout, "shift_deg": applied,
            "n_eff": count[0], "intervals_cd": np.stack([b.lo, b.hi], axis=1),
            "count_stats": count}


def plot_caption(summary: dict[str, Any] | None) -> PlotCaption | None:
    """The caption every plot of a run carries, from its ``summary.json`` (None without
    one): lamp, seed, photons, error figure, the rule sets with their versions, lightsim's
    version."""
    if summary is None:
        return None
    tables = ruleset_tables(summary)
    return PlotCaption(
        lamp=Path(str(summary.get("scene", {}).get("source", "") or "?")).name,
        seed=int(summary.get("seed", 0) or 0), photons=int(summary.get("photons", 0) or 0),
        error=summary.get("error_text"),
        rulesets=tuple((str(t.get("ruleset", "?")), str(t.get("version", "?")))
                       for t in tables),
        version=str(summary.get("lightsim_version", __version__)))


def ruleset_tables(summary: dict[str, Any]) -> list[dict[str, Any]]:
    """The regulation tables of a run's summary (``regulation``, ``regulation:ID``), in
    the order the rule sets were asked for."""
    return [v for k, v in summary.items()
            if (k == "regulation" or k.startswith("regulation:")) and isinstance(v, dict)]


def isolux_file(index: int, ruleset: str) -> str:
    """The iso-lux plot of the ``index``-th rule set: ``isolux.png`` for the first (and
    for a run without one), ``isolux-<ID>.png`` for every further one."""
    return "isolux.png" if index == 0 else f"isolux-{ruleset}.png"


def engineering_plots(out: Path, lux: np.ndarray, frame: Any,
                      results: list[dict[str, Any]] | None = None,
                      mount_height_m: float = 0.65,
                      summary: dict[str, Any] | None = None, *,
                      which: tuple[str, ...] = ("isolux", "road"),
                      plots: Any = None, log: bool = True) -> list[Path]:
    """Write ``wall_lux.png`` (when ``which`` names ``wall_lux``; ``log``: its scale),
    the iso-lux plots (``isolux``) and ``road.png`` (``road``), drawn by ``plots``
    (:mod:`lightsim.io.plot_worker`: a plot process, or here by default).

    Each rule set of the run's ``summary`` gets its own iso-lux plot
    (:func:`isolux_file`) with only its test points; without rule sets in the summary
    ``results`` are marked on ``isolux.png``. ``wall_lux.png`` marks the first rule
    set's points. Every plot carries the run's caption (:func:`plot_caption`).

    With the run's ``summary`` the iso-lux levels start at the map's noise floor, and
    ``summary["isolux"]`` (floor, levels, files) and ``summary["road"]`` (reach per
    level) are filled in — whether or not the plots are drawn.
    """
    plots = plots if plots is not None else InProcess()
    fd = _frame_dict(frame)
    floor = noise_floor_from_summary(summary, fd) if summary is not None else None
    area_px = estimate_area_px_from_summary(summary, fd) if summary is not None else None
    caption = plot_caption(summary)
    tables = ruleset_tables(summary) if summary is not None else []
    sets = ([(str(t.get("ruleset", "?")), str(t.get("title", "")), t.get("results"))
             for t in tables] or [("", "", results)])
    pending: list[tuple[Path, Any]] = []
    caps = [None if caption is None else asdict(caption.for_ruleset(i))
            for i in range(len(sets))]
    if "wall_lux" in which:
        pending.append((Path(out) / "wall_lux.png", plots.draw(
            "wall_lux", Path(out) / "wall_lux.png", lux, fd, results=sets[0][2], log=log,
            caption=caps[0])))
    iso_files = [isolux_file(i, rid) for i, (rid, _, _) in enumerate(sets)]
    if "isolux" in which:
        for i, (rid, title, marks) in enumerate(sets):
            name = iso_files[i]
            pending.append((Path(out) / name, plots.draw(
                "isolux", Path(out) / name, lux, fd, results=marks,
                title=f"iso-lux on the screen — {rid}: {title}" if rid else
                "iso-lux on the screen", noise_floor_lx=floor,
                estimate_area_px=area_px, caption=caps[i])))
    rd = None
    if "road" in which:
        rd = plots.draw("road", Path(out) / "road.png", lux, fd,
                        mount_height_m=mount_height_m, caption=caps[0])
    paths = []
    for path, p in pending:
        p.result()
        paths.append(path)  # as given (the plot process's is absolute)
    if rd is not None:
        road = rd.result()
        paths.append(Path(out) / "road.png")
    else:
        road = road_view_data(lux, fd, mount_height_m=mount_height_m)
    if summary is not None:
        summary["isolux"] = {"noise_floor_lx": floor,
                             "noise_floor_rule": "levels where an estimate holds < 16 "
                                                 "photons (relative noise > 25 %) are "
                                                 "not drawn",
                             # the file of each rule set's plot (drawn or not)
                             "files": {rid or "none": name for (rid, _, _), name
                                       in zip(sets, iso_files, strict=True)}}
        if road is None:  # nothing to show (the plot says why): no reach either
            summary["road"] = {"mount_height_m": mount_height_m, "reach_m": None,
                               "text": "no road illuminance to show (see road.png)"}
        else:
            summary["road"] = {**road.summary(REACH_LEVELS), "text": road.reach_text()}
    return paths


def estimate_area_px_from_summary(summary: dict[str, Any], frame: dict[str, Any]
                                  ) -> float | None:
    """Area (wall pixels) the largest estimate of a run averages over: the kNN/radius
    disk π r_max², or one pixel when binning; None when the summary does not say."""
    try:
        w, h = frame["resolution"]
        px = ((frame["h_range_m"][1] - frame["h_range_m"][0]) / w
              * (frame["v_range_m"][1] - frame["v_range_m"][0]) / h)
        est = summary.get("estimator", {})
        if est.get("name") == "bin":
            return 1.0
        r = est.get("max_radius_m")
        area = math.pi * float(r) ** 2 / px if r is not None else math.inf
        return area if math.isfinite(area) and area > 0 else None
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return None


def noise_floor_from_summary(summary: dict[str, Any], frame: dict[str, Any]) -> float | None:
    """The iso-lux noise floor (lx) of a run from its summary: photons, lamp flux and the
    largest area an estimate averages over (kNN or radius disk, or a pixel for binning)."""
    try:
        est = summary.get("estimator", {})
        if est.get("name") == "bin":
            w, h = frame["resolution"]
            area = ((frame["h_range_m"][1] - frame["h_range_m"][0]) / w
                    * (frame["v_range_m"][1] - frame["v_range_m"][0]) / h)
        else:
            r = est.get("max_radius_m")
            area = math.pi * float(r) ** 2 if r is not None else math.inf
        return isolux_noise_floor(int(summary["photons"]),
                                  float(summary["scene"]["flux_lm"]), area)
    except (KeyError, TypeError, ValueError):
        return None  # an older or partial summary: draw all levels


@dataclass(frozen=True)
class EscapedLight:
    """Photons that left the lamp with the wall taken away: the far field's raw data.

    Attributes
    ----------
    directions : ndarray, shape (n, 3)
        Unit directions of the escaping photons (world axes).
    power_lm : ndarray, shape (n,)
        Luminous flux of each (lm), normalised by ``photons`` (sums to the escaping flux).
    photons : int
        Photons emitted.
    lamp_lumens : float
        The scene's emitted flux (lm).
    luminaire : str
        Name of the scene file.
    """

    directions: np.ndarray
    power_lm: np.ndarray
    photons: int
    lamp_lumens: float
    luminaire: str


def escaped_light(scene, photons: int = 1_000_000, seed: int = 1,
                  threads: int | None = None) -> EscapedLight:
    """Trace ``photons`` through the luminaire alone (no wall) and keep those escaping to
    infinity, as the far field sees them (binned by :func:`lightsim.luminaires.
    photometric.farfield_from_photons`).
    """
    if photons < 1000:
        raise InputError(f"far field needs at least 1000 photons, got {photons}")
    lamp = Scene([p for p in scene.parts if p.role != WALL], None, scene.source,
                 list(scene.warnings), 1)
    tracer = PhotonTracer(lamp, threads=threads)
    farfield_set = (1 << 21) + 1  # a key space no interleave set uses
    dirs, power = [], []
    batch = 250_000
    for lo in range(0, photons, batch):
        idx = np.arange(lo, min(photons, lo + batch), dtype=np.int64)
        pts = halton_points(idx, digit_permutations(seed, farfield_set, None))
        res = tracer.trace_points(pts, photon_keys(seed, farfield_set, 0, idx),
                                  record_escaped=True)
        dirs.append(res.escaped_dir)
        power.append(res.escaped_power[:, 0] / photons)  # lm per photon
    tracer.caster.close()
    return EscapedLight(np.concatenate(dirs), np.concatenate(power), int(photons),
                        float(scene.total_flux), Path(scene.source).name or "lightsim")

