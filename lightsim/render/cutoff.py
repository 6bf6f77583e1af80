"""Cut-off line of a passing beam on the wall: position, sharpness, linearity and aim.

Method (UN R112 annex 9): vertical scans through the flat part of the cut-off at 1.5°,
2.5° and 3.5° from V-V on the side away from the step (left of V-V for right-hand
traffic, right for left-hand traffic).
Along each scan the cut-off is the **inflection point**, where log10 E falls fastest going
up: the maximum of ``g(v) = −d(log10 E)/dV``. The **sharpness** is
``G = log10 E(β) − log10 E(β + 0.1°)`` with the 0.1° window centred on the inflection
(β = v_inflection − 0.05°); R112 asks for 0.13 ≤ G ≤ 0.40 (reported as ``sharpness_ok``).
The cut-off is **linear** when the three inflections lie within 0.2° of each other. The aim
correction moves the 2.5° scan's inflection (or the mean of the scans found) to 0.57° D
(``target_v_deg = −0.57``, 1 % below the horizontal).

Robustness
    * each scan averages the image over a vertical band ``band_deg`` wide (bilinear samples
      at five H positions across it), resampled every ``step_deg`` in V;
    * zeros and near-zeros are floored at ``floor_rel`` × the scan's maximum before the
      logarithm, so black regions and clipped (saturated) plateaus give zero gradient
      instead of infinities;
    * a cut-off must separate light from dark: the median log10 E over 0.2–1.0° below the
      inflection must exceed the median over 0.2–1.0° above by ``min_contrast`` decades;
    * the log profile is smoothed by a Gaussian of σ = max(``smooth_deg``, one pixel) for
      locating the inflection (symmetric smoothing does not move a symmetric step), and by
      σ = max(``g_smooth_deg``, half a pixel) for G; the peak is refined by a parabola
      through its three samples;
    * a scan reports "no cut-off" (never raises) when it has no light, when the steepest
      fall is at the edge of the window, when the contrast is too low or when its sharpness
      is below ``min_sharpness``.

Re-aiming (:func:`apply_shift`) rotates the lamp: the wall lux image is converted to
intensity (``I = E·r³/D``), every new pixel looks up the direction it had before the
rotation (pitch by dv about the H axis, then yaw by dh about the V axis) with **bilinear
interpolation** between pixel centres, and the result is converted back to lux. Directions
that come from outside the original image get ``fill`` lux (default 0).

Parameters
----------
==============  =====  ===============  ==============================================
name            unit   default          meaning
==============  =====  ===============  ==============================================
lux             lx     –                wall illuminance image (H, W), row 0 on top
frame           –      –                wall frame (``WallFrame`` or its dict)
traffic         –      "right"          scans left of V-V for right-hand traffic
scan_h_deg      deg    (1.5, 2.5, 3.5)  distances of the scans from V-V
v_window_deg    deg    (−3.0, 1.5)      V range searched for the cut-off
band_deg        deg    0.1              width of each vertical scan band
step_deg        deg    0.01             resampling step along V
smooth_deg      deg    0.05             Gaussian σ for the inflection search
g_smooth_deg    deg    0.02             Gaussian σ for the sharpness G
floor_rel       1      1e-4             floor of E relative to the scan maximum
min_sharpness   1      0.05             below this G a scan has no cut-off
min_contrast    dec    0.5              log10 E step needed across the cut-off
target_v_deg    deg    −0.57            where the aim puts the cut-off (0.57° D)
dh_deg, dv_deg  deg    –                re-aim: right / up positive
fill            lx     0.0              lux for directions not on the original image
==============  =====  ===============  ==============================================
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import stdtrit

from lightsim.errors import InputError
from lightsim.render.filters import gaussian_filter1d, map_coordinates
from lightsim.wall import (
    WallFrame,
    candela_from_lux,
    lux_from_candela,
    wall_m_from_deg,
)

__all__ = [
    "G_RANGE",
    "LINEARITY_DEG",
    "TARGET_V_DEG",
    "CutoffInterval",
    "CutoffResult",
    "ScanResult",
    "aim_shift",
    "apply_shift",
    "cutoff_interval",
    "find_cutoff",
    "scan_sample_points",
]

TARGET_V_DEG = -0.57
"""Aim of the cut-off inflection: 0.57° below the horizontal (1 %)."""
G_RANGE = (0.13, 0.40)
"""R112 annex 9 sharpness range."""
LINEARITY_DEG = 0.2
"""Largest allowed spread of the three scans' inflections."""


@dataclass(frozen=True)
class ScanResult:
    """One vertical scan: where (deg) and how sharp the cut-off is, or why there is none."""

    h_deg: float
    found: bool
    v_inflection_deg: float | None = None
    sharpness_g: float | None = None
    max_gradient_per_deg: float | None = None
    message: str = ""


@dataclass(frozen=True)
class CutoffResult:
    """Cut-off of a wall image (see the module docstring); ``to_dict`` is JSON-ready."""

    found: bool
    message: str
    traffic: str
    scans: tuple[ScanResult, ...] = ()
    v_cutoff_deg: float | None = None
    sharpness_g: float | None = None
    sharpness_ok: bool | None = None
    linear: bool | None = None
    spread_deg: float | None = None
    aim_dh_deg: float = 0.0
    aim_dv_deg: float | None = None
    target_v_deg: float = TARGET_V_DEG
    settings: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable dict."""
        d = asdict(self)
        d["scans"] = [asdict(s) for s in self.scans]
        return d


def _profile(lux: NDArray, wf: WallFrame, h_deg: float, v_grid: NDArray, band_deg: float
             ) -> NDArray:
    """Band-averaged illuminance (lx) along V at ``h_deg``, bilinear between pixels."""
    offsets = np.linspace(-band_deg / 2, band_deg / 2, 5) if band_deg > 0 else np.zeros(1)
    hm = wall_m_from_deg(h_deg + offsets, wf.distance_m)
    vm = wall_m_from_deg(v_grid, wf.distance_m)
    H, V = np.meshgrid(hm, vm)
    row, col = wf.pixel_of(H, V)
    samples = map_coordinates(lux, [row.ravel(), col.ravel()], order=1, mode="nearest")
    return samples.reshape(H.shape).mean(axis=1)


def _parabola_peak(y: NDArray, k: int) -> float:
    if 0 < k < len(y) - 1:
        a, b, c = y[k - 1], y[k], y[k + 1]
        den = a - 2 * b + c
        if den < 0:
            return float(k + 0.5 * (a - c) / den)
    return float(k)


def _scan(lux: NDArray, wf: WallFrame, h_deg: float, v_lo: float, v_hi: float,
          band_deg: float, step_deg: float, smooth_deg: float, g_smooth_deg: float,
          floor_rel: float, min_sharpness: float, min_contrast: float) -> ScanResult:
    if v_hi - v_lo < 10 * step_deg:
        return ScanResult(h_deg, False, message="scan window outside the wall image")
    v = np.arange(v_lo, v_hi + 0.5 * step_deg, step_deg)
    e = _profile(lux, wf, h_deg, v, band_deg)
    pix_deg = wf.pixel_pitch_deg[1]
    return _scan_profile(v, e, h_deg, pix_deg, step_deg, smooth_deg, g_smooth_deg,
                         floor_rel, min_sharpness, min_contrast)


def _scan_profile(v: NDArray, e: NDArray, h_deg: float, pix_deg: float, step_deg: float,
                  smooth_deg: float, g_smooth_deg: float, floor_rel: float,
                  min_sharpness: float, min_contrast: float) -> ScanResult:
    """The inflection search on one band-averaged profile ``e`` (lx) along ``v`` (deg)."""
    v_lo = float(v[0])
    peak = float(np.max(e)) if e.size else 0.0
    if not np.isfinite(peak) or peak <= 0:
        return ScanResult(h_deg, False, message="no light on this scan")
    log_e = np.log10(np.maximum(e, peak * floor_rel))
    sig = max(smooth_deg, pix_deg) / step_deg
    sig_g = max(g_smooth_deg, 0.5 * pix_deg) / step_deg
    smooth = gaussian_filter1d(log_e, sig, mode="nearest")
    grad = -np.gradient(smooth, step_deg)
    margin = int(np.ceil(2 * sig))
    k = int(np.argmax(grad))
    if not grad[k] > 0:
        return ScanResult(h_deg, False, message="no cut-off found (light does not fall "
                          "off upwards)")
    if k < margin or k > len(v) - 1 - margin:
        return ScanResult(h_deg, False, max_gradient_per_deg=float(grad[k]),
                          message="no cut-off found (steepest fall at the edge of the "
                                  "scan window)")
    v_inf = float(v_lo + _parabola_peak(grad, k) * step_deg)
    below = log_e[(v >= v_inf - 1.0) & (v <= v_inf - 0.2)]
    above = log_e[(v >= v_inf + 0.2) & (v <= v_inf + 1.0)]
    if below.size < 5 or above.size < 5:
        return ScanResult(h_deg, False, v_inf, None, float(grad[k]),
                          message="no cut-off found (too close to the scan window's edge)")
    contrast = float(np.median(below) - np.median(above))
    if contrast < min_contrast:
        return ScanResult(h_deg, False, v_inf, None, float(grad[k]),
                          message=f"no cut-off found (contrast {contrast:.2f} decades < "
                                  f"{min_contrast:g})")
    fine = gaussian_filter1d(log_e, sig_g, mode="nearest")
    g = float(np.interp(v_inf - 0.05, v, fine) - np.interp(v_inf + 0.05, v, fine))
    if g < min_sharpness:
        return ScanResult(h_deg, False, v_inf, g, float(grad[k]),
                          message=f"no cut-off found (sharpness G = {g:.3f} < "
                                  f"{min_sharpness:g})")
    return ScanResult(h_deg, True, v_inf, g, float(grad[k]), "ok")


def find_cutoff(lux: ArrayLike, frame: Any, traffic: str = "right",
                scan_h_deg: Sequence[float] = (1.5, 2.5, 3.5),
                v_window_deg: tuple[float, float] = (-3.0, 1.5), band_deg: float = 0.1,
                step_deg: float = 0.01, smooth_deg: float = 0.05, g_smooth_deg: float = 0.02,
                floor_rel: float = 1e-4, min_sharpness: float = 0.05,
                min_contrast: float = 0.5, target_v_deg: float = TARGET_V_DEG
                ) -> CutoffResult:
    """Locate the cut-off on a wall lux image (R112 annex 9 scans; see module docstring).

    Parameters
    ----------
    lux : array_like, shape (H, W)
        Wall illuminance in lx (row 0 on top). NaNs count as 0.
    frame : WallFrame or mapping
        The wall frame.
    traffic : {"right", "left"}, default "right"
        Right-hand traffic scans left of V-V (h = −1.5, −2.5, −3.5°), left-hand traffic right.
    scan_h_deg, v_window_deg, band_deg, step_deg, smooth_deg, g_smooth_deg, floor_rel,
    min_sharpness, min_contrast, target_v_deg
        See the module's parameter table.

    Returns
    -------
    CutoffResult
        ``found`` False with a one-line ``message`` when no scan shows a cut-off;
        otherwise the cut-off position (deg, at the 2.5° scan when found there), G,
        linearity and the vertical aim correction ``aim_dv_deg`` (deg, up positive).
    """
    wf = WallFrame.from_any(frame)
    img = np.nan_to_num(wf.check_image(lux), nan=0.0, posinf=0.0, neginf=0.0)
    img = np.maximum(img, 0.0)
    t = str(traffic).lower()
    if t not in ("right", "left"):
        raise InputError(f"traffic must be 'right' or 'left', got {traffic!r}")
    if step_deg <= 0 or band_deg < 0 or smooth_deg < 0 or not (0 < floor_rel < 1):
        raise InputError("find_cutoff: step_deg > 0, band_deg ≥ 0, smooth_deg ≥ 0 and "
                         "0 < floor_rel < 1 are required")
    sign = -1.0 if t == "right" else 1.0
    h_lo, h_hi, v_min, v_max = (float(x) for x in (wf.h_deg().min(), wf.h_deg().max(),
                                                   wf.v_deg().min(), wf.v_deg().max()))
    v_lo = max(v_window_deg[0], v_min)
    v_hi = min(v_window_deg[1], v_max)
    scans = []
    for off in scan_h_deg:
        h = sign * abs(float(off))
        if not (h_lo <= h <= h_hi):
            scans.append(ScanResult(h, False, message="scan outside the wall image"))
            continue
        scans.append(_scan(img, wf, h, v_lo, v_hi, band_deg, step_deg, smooth_deg,
                           g_smooth_deg, floor_rel, min_sharpness, min_contrast))
    settings = {"scan_h_deg": [float(s.h_deg) for s in scans],
                "v_window_deg": [float(v_lo), float(v_hi)], "band_deg": band_deg,
                "step_deg": step_deg, "smooth_deg": smooth_deg, "g_smooth_deg": g_smooth_deg,
                "floor_rel": floor_rel, "min_sharpness": min_sharpness,
                "min_contrast": min_contrast}
    found = [s for s in scans if s.found]
    if not found:
        reasons = "; ".join(f"{abs(s.h_deg):g}°: {s.message}" for s in scans)
        return CutoffResult(False, f"no cut-off found ({reasons})", t, tuple(scans),
                            target_v_deg=target_v_deg, settings=settings)
    main = next((s for s in found if abs(abs(s.h_deg) - 2.5) < 1e-9), None)
    if main is not None:
        v_cut, g = main.v_inflection_deg, main.sharpness_g
    else:
        v_cut = float(np.mean([s.v_inflection_deg for s in found]))
        g = float(np.mean([s.sharpness_g for s in found]))
    spread = None
    linear = None
    if len(found) == len(scans) and len(scans) > 1:
        vals = [s.v_inflection_deg for s in found]
        spread = float(max(vals) - min(vals))
        linear = spread <= LINEARITY_DEG + 1e-12
    msg = "ok" if len(found) == len(scans) else (
        f"cut-off found on {len(found)} of {len(scans)} scans")
    return CutoffResult(True, msg, t, tuple(scans), v_cutoff_deg=float(v_cut),
                        sharpness_g=float(g),
                        sharpness_ok=bool(G_RANGE[0] <= g <= G_RANGE[1]), linear=linear,
                        spread_deg=spread, aim_dh_deg=0.0,
                        aim_dv_deg=float(target_v_deg - v_cut), target_v_deg=target_v_deg,
                        settings=settings)


def aim_shift(lux: ArrayLike, frame: Any, traffic: str = "right",
              target_v_deg: float = TARGET_V_DEG, **kwargs: Any) -> tuple[float, float]:
    """Re-aim (dh_deg, dv_deg) that puts the cut-off inflection at ``target_v_deg``.

    Only the vertical aim is derived from the cut-off (dh is 0: the horizontal position of
    the step's elbow is not measured here).

    Raises
    ------
    InputError
        If no cut-off is found (the message says why).
    """
    res = find_cutoff(lux, frame, traffic=traffic, target_v_deg=target_v_deg, **kwargs)
    if not res.found:
        raise InputError(f"cannot aim: {res.message}")
    return 0.0, float(res.aim_dv_deg)  # type: ignore[arg-type]


def _rot(dh_deg: float, dv_deg: float) -> NDArray:
    a, b = np.radians(dh_deg), np.radians(dv_deg)
    yaw = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    pitch = np.array([[1, 0, 0], [0, np.cos(b), np.sin(b)], [0, -np.sin(b), np.cos(b)]])
    return yaw @ pitch  # in (H, V, forward) coordinates: pitch first, then yaw


def apply_shift(lux: ArrayLike, frame: Any, dh_deg: float, dv_deg: float,
                fill: float = 0.0) -> NDArray:
    """The wall lux image after re-aiming the lamp by (dh_deg right, dv_deg up).

    Parameters
    ----------
    lux : array_like, shape (H, W)
        Wall illuminance in lx.
    frame : WallFrame or mapping
        The wall frame.
    dh_deg, dv_deg : float
        Yaw to the right and pitch up, in degrees.
    fill : float, default 0.0
        Illuminance (lx) for pixels whose original direction is not on the image.

    Returns
    -------
    ndarray, shape (H, W)
        Re-aimed illuminance in lx (bilinear resampling of the intensity; see module
        docstring).
    """
    wf = WallFrame.from_any(frame)
    img = wf.check_image(lux)
    D = wf.distance_m
    hm, vm = np.meshgrid(wf.h_m(), wf.v_m())
    intensity = candela_from_lux(img, hm, vm, D)
    d_new = np.stack([hm, vm, np.full_like(hm, D)], axis=-1)
    d_old = d_new @ _rot(dh_deg, dv_deg)  # row vectors: R^T applied
    z = d_old[..., 2]
    ok = z > 1e-12
    zs = np.where(ok, z, 1.0)
    h_old = D * d_old[..., 0] / zs
    v_old = D * d_old[..., 1] / zs
    row, col = wf.pixel_of(h_old, v_old)
    inside = ok & (row >= -0.5) & (row <= wf.height - 0.5) & (col >= -0.5) & (
        col <= wf.width - 0.5)
    i_new = map_coordinates(intensity, [row.ravel(), col.ravel()], order=1, mode="nearest")
    e_new = lux_from_candela(i_new.reshape(hm.shape), hm, vm, D)
    return np.where(inside, e_new, fill)


# ---- an interval for the cut-off position from the independent sets -------------------
@dataclass(frozen=True)
class CutoffInterval:
    """Uncertainty of the cut-off position from the interleave sets (jackknife).

    The pooled image is the mean of the S sets' estimates. Leaving set s out gives S
    images of S − 1 sets; each is scanned exactly as :func:`find_cutoff` scans (same R112
    scans and settings; the 2.5° scan's inflection or the mean of the scans found), and
    the jackknife standard error ``se = √((n−1)/n · Σ (v₋ₛ − v̄)²)`` gives the Student-t
    interval ``centre ± t(n−1)·se`` around the pooled image's position ``centre``.
    ``per_set_deg`` holds the leave-one-out positions; those without a cut-off are
    counted (``found_sets``), not used.
    """

    found_sets: int
    sets: int
    centre_deg: float | None
    interval_deg: tuple[float, float] | None
    per_set_deg: tuple[float, ...]
    confidence: float

    def to_dict(self) -> dict[str, Any]:
        return {"found_sets": self.found_sets, "sets": self.sets,
                "centre_deg": self.centre_deg,
                "interval_deg": None if self.interval_deg is None else list(self.interval_deg),
                "per_set_deg": list(self.per_set_deg), "confidence": self.confidence}


def scan_sample_points(frame: Any, traffic: str = "right",
                       scan_h_deg: Sequence[float] = (1.5, 2.5, 3.5),
                       v_window_deg: tuple[float, float] = (-3.0, 1.5),
                       band_deg: float = 0.1, step_deg: float = 0.01
                       ) -> tuple[NDArray, NDArray, NDArray]:
    """Wall points (m) at which the sets must be estimated for :func:`cutoff_interval`.

    Returns
    -------
    hv_m : (n_scans · n_v · 5, 2) wall metres, scan-major, then V, then the band's 5 H
    h_deg : (n_scans,) scan positions; v_deg : (n_v,) the V grid
    """
    wf = WallFrame.from_any(frame)
    sign = -1.0 if str(traffic).lower() == "right" else 1.0
    v_lo = max(v_window_deg[0], float(wf.v_deg().min()))
    v_hi = min(v_window_deg[1], float(wf.v_deg().max()))
    v = np.arange(v_lo, v_hi + 0.5 * step_deg, step_deg) if v_hi > v_lo else np.zeros(0)
    hs = np.array([sign * abs(float(o)) for o in scan_h_deg])
    offsets = np.linspace(-band_deg / 2, band_deg / 2, 5) if band_deg > 0 else np.zeros(1)
    H = (hs[:, None, None] + offsets[None, None, :]) * np.ones((1, len(v), 1))
    V = np.broadcast_to(v[None, :, None], H.shape)
    hv = np.stack([wall_m_from_deg(H, wf.distance_m).ravel(),
                   wall_m_from_deg(V, wf.distance_m).ravel()], axis=1)
    return hv, hs, v


def cutoff_interval(values: ArrayLike, frame: Any, centre_deg: float | None,
                    traffic: str = "right", scan_h_deg: Sequence[float] = (1.5, 2.5, 3.5),
                    v_window_deg: tuple[float, float] = (-3.0, 1.5), band_deg: float = 0.1,
                    step_deg: float = 0.01, smooth_deg: float = 0.05,
                    g_smooth_deg: float = 0.02, floor_rel: float = 1e-4,
                    min_sharpness: float = 0.05, min_contrast: float = 0.5,
                    confidence: float = 0.95) -> CutoffInterval:
    """Cut-off interval from per-set estimates (S, n) at :func:`scan_sample_points`.

    ``centre_deg``: the pooled image's cut-off (from :func:`find_cutoff`); None = scan
    the mean of the sets' profiles.
    """
    wf = WallFrame.from_any(frame)
    _, hs, v = scan_sample_points(wf, traffic, scan_h_deg, v_window_deg, band_deg, step_deg)
    vals = np.nan_to_num(np.asarray(values, dtype=float), nan=0.0)
    S = vals.shape[0]
    if len(v) < 10 or vals.shape[1] != len(hs) * len(v) * (5 if band_deg > 0 else 1):
        return CutoffInterval(0, S, centre_deg, None, (), confidence)
    prof = vals.reshape(S, len(hs), len(v), -1).mean(axis=-1)
    pix_deg = wf.pixel_pitch_deg[1]
    # jackknife: the pooled image is the mean of the sets' estimates, so leaving one set
    # out gives a nearly as good image; the spread of those positions is the variance of
    # a nonlinear statistic of a mean (a single set's own scan is far noisier)
    total = prof.sum(axis=0)

    def position(p: NDArray) -> float | None:
        res = [_scan_profile(v, np.maximum(p[i], 0.0), float(hs[i]), pix_deg, step_deg,
                             smooth_deg, g_smooth_deg, floor_rel, min_sharpness,
                             min_contrast) for i in range(len(hs))]
        found = [r for r in res if r.found]
        main = next((r for r in found if abs(abs(r.h_deg) - 2.5) < 1e-9), None)
        if main is not None:
            return float(main.v_inflection_deg)
        return float(np.mean([r.v_inflection_deg for r in found])) if found else None

    if centre_deg is None:  # the pooled estimate's own position
        centre_deg = position(total / S)
    per_set = [x for s in range(S)
               if (x := position((total - prof[s]) / max(S - 1, 1))) is not None]
    n = len(per_set)
    interval = None
    if centre_deg is not None and n >= 2:
        se = float(np.sqrt((n - 1) / n * np.sum((np.asarray(per_set) - np.mean(per_set)) ** 2)))
        half = float(stdtrit(n - 1, 0.5 + confidence / 2)) * se
        interval = (float(centre_deg) - half, float(centre_deg) + half)
    return CutoffInterval(n, S, centre_deg, interval, tuple(per_set), confidence)
