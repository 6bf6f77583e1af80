"""Photometric normalisation of a registered photo and the photo-vs-simulation metrics.

After registration the photo is resampled onto the simulation's wall grid. Its exposure
and tone curve are unknown, so :func:`fit_photometric` fits ``P = gain·E^gamma`` (gamma = 1
unless asked) between the photo's linear luminance P and the simulated illuminance E (lx)
by robust least squares on ``ln P − ln gain − gamma·ln E`` (:func:`scipy.optimize.least_squares`,
soft-L1 loss) over overlapping, unclipped pixels brighter than ``fit_level`` × the
simulation's peak; :func:`to_lux` inverts it, so the photo is expressed in lx. A clipped
pixel's true value is only known to be at least ``clip_lx`` (the lux that reaches full
scale).

Metrics (:func:`compute_metrics`), on the overlap without clipped photo pixels unless said
------------------------------------------------------------------------------------------
==============================  =====  ======  ===========================================
name                            unit   better  definition
==============================  =====  ======  ===========================================
``zncc``                        1      higher  zero-normalised cross-correlation of the
                                               lux maps
``ssim``                        1      higher  SSIM (Gaussian window σ = 1.5 px, data
                                               range = simulation peak), mean over the
                                               overlap shrunk by the window radius
``psnr_db``                     dB     higher  10·log10(peak² / MSE), peak = simulation
                                               maximum
``nmi``                         1      higher  normalised mutual information
                                               (H(A)+H(B))/H(A,B), 1–2, of log10 lux
                                               floored at 10⁻³ peak, 64 bins
``rel_rmse``                    1      lower   RMSE / RMS of the simulation
``iou_10``, ``iou_30``,         1      higher  intersection over union of the regions at
``iou_60``                                     or above 10/30/60 % of the simulation peak;
                                               clipped pixels count as inside when the
                                               clip level is above the threshold and are
                                               left out when it is below
``hotspot_offset_deg``          deg    lower   distance between the hot spots: centroids
                                               of the regions ≥ 90 % of the smaller of
                                               the two maxima (after σ = 1 px smoothing)
``hotspot_dh_deg``,             deg    –       photo − simulation hot spot, H and V
``hotspot_dv_deg``
``cutoff_v_photo_deg``,         deg    –       cut-off position (R112 annex 9 scans,
``cutoff_v_sim_deg``                           :func:`lightsim.render.cutoff.find_cutoff`);
                                               None where there is none or the photo does
                                               not cover the scans
``cutoff_v_sim_blurred_deg``    deg    –       the simulation's cut-off after blurring it
                                               as much as the registration found the photo
                                               blurrier (blur moves the inflection of
                                               log E upwards)
``cutoff_shape_gap_deg``       deg    lower   abs(photo − blurred simulation) cut-off
                                               position after registration: a shape
                                               check, **not the aim** (a beam-registered
                                               photo is moved onto the beam; the aim is
                                               ``cutoff_dv_deg`` of the aim section)
==============================  =====  ======  ===========================================

Parameters
----------
==============  ====  =======  =============================================================
name            unit  default  meaning
==============  ====  =======  =============================================================
fit_gamma       –     False    also fit the exponent of ``P = gain·E^gamma``
fit_level       1     0.02     pixels fitted: E ≥ this × the simulation's peak
levels          1     .1 .3 .6 isolux levels relative to the simulation's peak
traffic         –     "right"  which side the cut-off scans are on (R112)
==============  ====  =======  =============================================================
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import binary_erosion, gaussian_filter
from scipy.optimize import least_squares
from skimage.metrics import (
    normalized_mutual_information,
    peak_signal_noise_ratio,
    structural_similarity,
)

from lightsim.errors import InputError
from lightsim.render.cutoff import find_cutoff
from lightsim.wall import WallFrame, wall_m_from_deg

__all__ = [
    "HIGHER_IS_BETTER",
    "LEVELS",
    "LOWER_IS_BETTER",
    "METRICS",
    "Photometric",
    "compute_metrics",
    "fit_photometric",
    "to_lux",
]

#: Isolux contour levels relative to the simulation's peak.
LEVELS = (0.1, 0.3, 0.6)
#: Metrics where a larger value means a closer match.
HIGHER_IS_BETTER = ("zncc", "ssim", "psnr_db", "nmi", "iou_10", "iou_30", "iou_60")
#: Metrics where a smaller value means a closer match.
LOWER_IS_BETTER = ("rel_rmse", "hotspot_offset_deg", "cutoff_shape_gap_deg", "cutoff_dv_abs_deg")
#: Every metric name in ``comparison.json["metrics"]``.
METRICS = (*HIGHER_IS_BETTER, *LOWER_IS_BETTER, "hotspot_dh_deg", "hotspot_dv_deg",
           "cutoff_v_photo_deg", "cutoff_v_sim_deg", "cutoff_v_sim_blurred_deg",
           "cutoff_dv_deg", "cutoff_dv_interval_deg", "geometry_residual_deg")


@dataclass(frozen=True)
class Photometric:
    """Fitted ``P = gain·E^gamma`` between photo (relative) and simulation (lx).

    Attributes
    ----------
    gain : float
        Photo value of 1 lx (relative full-scale units per lx^gamma).
    gamma : float
        Exponent (1 unless fitted).
    clip_lx : float
        Illuminance (lx) that reaches full scale; clipped pixels are at least this bright.
    pixels : int
        Pixels used in the fit.
    fitted_gamma : bool
        Whether gamma was fitted.
    """

    gain: float
    gamma: float
    clip_lx: float
    pixels: int
    fitted_gamma: bool

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return asdict(self)


def fit_photometric(photo: NDArray, sim: NDArray, usable: NDArray, fit_gamma: bool = False,
                    fit_level: float = 0.02, full_scale: float = 1.0) -> Photometric:
    """Fit ``photo ≈ gain·sim^gamma`` robustly in log space.

    Parameters
    ----------
    photo : ndarray
        Registered photo, linear relative luminance (1 = full scale), NaN outside.
    sim : ndarray
        Simulated illuminance in lx, same shape.
    usable : ndarray of bool
        Overlapping, unclipped pixels.
    fit_gamma : bool, default False
        Fit the exponent as well (else gamma = 1).
    fit_level : float, default 0.02
        Only pixels with ``sim ≥ fit_level × max(sim)`` are fitted.
    full_scale : float, default 1
        Photo value at which pixels clip.

    Returns
    -------
    Photometric

    Raises
    ------
    InputError
        Too few lit, unclipped pixels in the overlap.
    """
    peak = float(np.nanmax(np.where(usable, sim, np.nan))) if usable.any() else 0.0
    sel = usable & np.isfinite(photo) & (sim >= fit_level * peak) & (photo > 0) & (sim > 0)
    n = int(sel.sum())
    if n < 20 or not peak > 0:
        raise InputError("too few lit, unclipped photo pixels overlap the simulation to "
                         "fit the exposure")
    lp, ls = np.log(photo[sel]), np.log(sim[sel])
    scale = float(np.median(np.abs(lp - np.median(lp)))) or 0.1

    def resid(p: NDArray) -> NDArray:
        gamma = p[1] if fit_gamma else 1.0
        return lp - p[0] - gamma * ls

    x0 = np.array([float(np.median(lp - ls)), 1.0])
    res = least_squares(resid, x0 if fit_gamma else x0[:1], loss="soft_l1", f_scale=scale)
    log_gain = float(res.x[0])
    gamma = float(res.x[1]) if fit_gamma else 1.0
    if not (math.isfinite(log_gain) and gamma > 0.05):
        raise InputError("the photo's brightness does not follow the simulation (exposure "
                         "fit failed)")
    gain = math.exp(log_gain)
    clip_lx = (full_scale / gain) ** (1.0 / gamma)
    return Photometric(gain, gamma, clip_lx, n, fit_gamma)


def to_lux(photo: NDArray, phot: Photometric) -> NDArray:
    """Photo (relative linear) → illuminance in lx by inverting ``gain·E^gamma``."""
    return (np.maximum(photo, 0.0) / phot.gain) ** (1.0 / phot.gamma)


# ---------------------------------------------------------------------------------------
# metrics
# ---------------------------------------------------------------------------------------

def _zncc(a: NDArray, b: NDArray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(np.dot(a, a)) * float(np.dot(b, b)))
    return float(np.dot(a, b) / den) if den > 0 else math.nan


def _ssim(photo: NDArray, sim: NDArray, mask: NDArray, peak: float) -> float:
    filled = np.where(mask, photo, sim) / peak
    _, full = structural_similarity(sim / peak, filled, data_range=1.0, gaussian_weights=True,
                                    sigma=1.5, use_sample_covariance=False, full=True)
    inner = binary_erosion(mask, iterations=5)
    region = inner if inner.sum() >= 25 else mask
    return float(full[region].mean())


def _nmi(photo: NDArray, sim: NDArray, peak: float) -> float:
    floor = 1e-3 * peak
    return float(normalized_mutual_information(np.log10(np.maximum(sim, floor)),
                                               np.log10(np.maximum(photo, floor)), bins=64))


def _iou(photo: NDArray, sim: NDArray, overlap: NDArray, clipped: NDArray, threshold: float,
         clip_lx: float) -> float:
    domain = overlap & ~(clipped & (clip_lx < threshold))
    a = domain & (sim >= threshold)
    b = domain & ((photo >= threshold) | (clipped & (clip_lx >= threshold)))
    union = int((a | b).sum())
    return float((a & b).sum() / union) if union else math.nan


def _angles(wall: WallFrame, row: float, col: float) -> tuple[float, float]:
    h = float(np.interp(col, np.arange(wall.width), wall.h_deg()))
    v = float(np.interp(row, np.arange(wall.height), wall.v_deg()))
    return h, v


def _hotspots(photo: NDArray, sim: NDArray, overlap: NDArray, wall: WallFrame
              ) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """Hot spots (h_deg, v_deg) of photo and simulation at a common level."""
    ps = gaussian_filter(np.where(overlap, photo, 0.0), 1.0)
    ss = gaussian_filter(np.where(overlap, sim, 0.0), 1.0)
    level = 0.9 * min(float(ps[overlap].max()), float(ss[overlap].max()))
    if not level > 0:
        return None
    out = []
    for img in (ps, ss):
        rr, cc = np.nonzero(overlap & (img >= level))
        out.append(_angles(wall, float(rr.mean()), float(cc.mean())))
    return out[0], out[1]


def _scan_covered(overlap: NDArray, wall: WallFrame, traffic: str) -> bool:
    """Whether the photo covers the R112 cut-off scans (1.5–3.5° from V-V, −3…1.5° V)."""
    sign = -1.0 if traffic == "right" else 1.0
    h_deg = np.sort(sign * np.array([1.45, 3.55]))
    v_deg = np.array([min(1.5, float(wall.v_deg().max())), max(-3.0, float(wall.v_deg().min()))])
    rows, cols = wall.pixel_of(wall_m_from_deg(h_deg, wall.distance_m),
                               wall_m_from_deg(v_deg, wall.distance_m))
    r0, r1 = max(int(np.floor(rows[0])), 0), min(int(np.ceil(rows[1])), wall.height - 1)
    c0, c1 = max(int(np.floor(cols[0])), 0), min(int(np.ceil(cols[1])), wall.width - 1)
    return r1 >= r0 and c1 >= c0 and bool(overlap[r0:r1 + 1, c0:c1 + 1].all())


def _cutoffs(photo: NDArray, sim: NDArray, overlap: NDArray, wall: WallFrame, frame: dict,
             traffic: str, sim_blur_px: float) -> dict[str, Any]:
    def position(img: NDArray) -> tuple[float | None, str]:
        res = find_cutoff(img, frame, traffic=traffic)
        return (res.v_cutoff_deg if res.found else None), res.message

    out: dict[str, Any] = {}
    out["cutoff_v_sim_deg"], out["sim_message"] = position(sim)
    seen = gaussian_filter(sim, sim_blur_px, mode="nearest") if sim_blur_px > 0 else sim
    out["cutoff_v_sim_blurred_deg"], _ = position(seen)
    if not _scan_covered(overlap, wall, traffic):
        out["cutoff_v_photo_deg"] = None
        out["photo_message"] = "the photo does not cover the cut-off scans"
    else:
        out["cutoff_v_photo_deg"], out["photo_message"] = position(np.where(overlap, photo, 0.0))
    a, b = out["cutoff_v_photo_deg"], out["cutoff_v_sim_blurred_deg"]
    out["cutoff_shape_gap_deg"] = abs(a - b) if a is not None and b is not None else None
    return out


def compute_metrics(photo_lux: NDArray, sim: NDArray, overlap: NDArray, clipped: NDArray,
                    frame: dict[str, Any], clip_lx: float = math.inf,
                    traffic: str = "right", sim_blur_px: float = 0.0
                    ) -> tuple[dict[str, Any], dict[str, Any]]:
    """All metrics of a registered, photometrically normalised photo against the simulation.

    Parameters
    ----------
    photo_lux : ndarray, shape (H, W)
        Photo on the simulation grid in lx (NaN outside the photo).
    sim : ndarray, shape (H, W)
        Simulated illuminance in lx.
    overlap : ndarray of bool
        Pixels where both images have data.
    clipped : ndarray of bool
        Overlap pixels that are clipped in the photo.
    frame : dict
        Wall frame (``docs/reference/conventions.md``).
    clip_lx : float, default inf
        Illuminance (lx) at which the photo clips.
    traffic : {"right", "left"}
        Side of the cut-off scans.
    sim_blur_px : float, default 0
        How much blurrier (Gaussian σ, simulation px) the photo is than the simulation, as
        found by the registration; the cut-off offset compares the photo with the
        simulation blurred by this much (blur moves a cut-off's inflection upwards).

    Returns
    -------
    metrics : dict
        Name → float or None (see the module's table).
    details : dict
        Positions (deg) of hot spots, cut-off messages, pixel counts.

    Raises
    ------
    InputError
        No overlap, or no unclipped pixels in it.
    """
    wall = WallFrame.from_any(frame)
    clipped = clipped & overlap
    usable = overlap & ~clipped & np.isfinite(photo_lux) & np.isfinite(sim)
    if usable.sum() < 25:
        raise InputError("no overlap between the photo and the simulation after registration")
    p, s = photo_lux[usable], sim[usable]
    peak = float(np.nanmax(np.where(overlap, sim, np.nan)))
    metrics: dict[str, Any] = {
        "zncc": _zncc(p, s),
        "ssim": _ssim(np.nan_to_num(photo_lux), np.nan_to_num(sim), usable, peak),
        "psnr_db": float(peak_signal_noise_ratio(s, p, data_range=peak)),
        "nmi": _nmi(p, s, peak),
        "rel_rmse": float(np.sqrt(np.mean((p - s) ** 2)) / np.sqrt(np.mean(s**2))),
    }
    photo_f = np.nan_to_num(photo_lux)
    for level in LEVELS:
        metrics[f"iou_{round(level * 100)}"] = _iou(photo_f, sim, overlap, clipped,
                                                     level * peak, clip_lx)
    details: dict[str, Any] = {"pixels_overlap": int(overlap.sum()),
                               "pixels_compared": int(usable.sum()),
                               "pixels_clipped": int(clipped.sum()), "peak_lx": peak}
    spots = _hotspots(photo_f, np.nan_to_num(sim), overlap, wall)
    if spots is None:
        metrics.update(hotspot_offset_deg=None, hotspot_dh_deg=None, hotspot_dv_deg=None)
    else:
        (hp, vp), (hs, vs) = spots
        metrics.update(hotspot_offset_deg=math.hypot(hp - hs, vp - vs),
                       hotspot_dh_deg=hp - hs, hotspot_dv_deg=vp - vs)
        details.update(hotspot_photo_deg=[hp, vp], hotspot_sim_deg=[hs, vs])
    cut = _cutoffs(photo_f, np.nan_to_num(sim), overlap, wall, frame, traffic, sim_blur_px)
    for key in ("cutoff_v_photo_deg", "cutoff_v_sim_deg", "cutoff_v_sim_blurred_deg",
                "cutoff_shape_gap_deg"):
        metrics[key] = cut[key]
    details.update(cutoff_photo=cut["photo_message"], cutoff_sim=cut["sim_message"],
                   sim_blur_px=sim_blur_px)
    for key, value in metrics.items():
        if value is not None and not math.isfinite(value):
            metrics[key] = None
    return metrics, details
