"""Aim read off a photo with known screen geometry: cut-off offset, hot spot, test points.

With the screen geometry fixed by control points or markers
(:mod:`~lightsim.validation.screen_geometry`), every photo pixel has a known screen angle,
so the lamp's aim can be measured **without moving the photo onto the simulated beam**:

Cut-off offset (:func:`cutoff_offset`)
    Along the R112 scans (1.5°, 2.5°, 3.5° from V-V on the flat side, bands 0.1° wide,
    resampled every ``step_deg``) the photo's log luminance is matched by the simulation's
    log illuminance moved up by ``dv`` and blurred (Gaussian σ in V, the camera's and the
    photo's own blur) and passed through a tone curve ``a + b·log E``:
    ``min over dv, σ, a, b of Σ (log P(v) − a − b·log E_σ(v − dv))²`` over ±``window_deg``
    around the moved cut-off. ``dv`` is searched on a grid of ``step_deg`` over
    ±``max_offset_deg`` and refined by a parabola; σ on a grid up to ``max_blur_deg`` — a
    fit that ends at that cap is reported (``blur_at_cap``), as the offset then depends on
    the cap. Photo samples that are clipped or outside the photo take no part. The offset is
    the mean over the scans found; its **interval** (≈95 %) is ``±1.96·√(σ_scan² +
    σ_geometry² + σ_resolution²)`` with ``σ_scan`` the standard error of the scans' mean
    (at least half a resampling step), ``σ_geometry`` the screen geometry's uncertainty in
    V **at the cut-off** (the homography's covariance carried there, so a cut-off far from
    the markers — an extrapolation — gets a wider interval) and ``σ_resolution`` a
    quarter of the simulation's pixel in V (``RESOLUTION_SHARE``): the profile match
    compares the photo with a resampled map and resolves no finer (the re-aim study,
    :mod:`lightsim.validation.photo_aim_study`, finds errors of ~0.15 px without it).

Test points (:func:`test_points`)
    75R, 50V and B50L (UN R112, mirrored for left-hand traffic) read off the photo as
    means over ±``point_radius_deg``, **relative to the normalisation point** (default
    50R): ``photo(p)/photo(n)`` beside ``sim(p)/sim(n)`` — an unknown exposure cancels.
    A clipped photo sample is flagged (its value is only a lower bound).

Parameters
----------
================  ====  =======  ==============================================================
name              unit  default  meaning
================  ====  =======  ==============================================================
traffic           –     right    side of the cut-off scans and of the test points
step_deg          deg   0.01     resampling step along V
window_deg        deg   1.0      fit window half-height around the moved cut-off
max_offset_deg    deg   2.0      offsets searched (±)
max_blur_deg      deg   1.0      largest blur fitted (Gaussian σ along V)
point_radius_deg  deg   0.1      test-point sampling half-width
normalise_at      –     50R      test point (or "H,V" in degrees) the relative values are
                                 normalised at
================  ====  =======  ==============================================================
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter, gaussian_filter1d, map_coordinates

from lightsim.errors import InputError
from lightsim.luminaires.regulations.ruleset import load_ruleset
from lightsim.render.cutoff import find_cutoff
from lightsim.validation.photo_register import apply_matrix
from lightsim.wall import WallFrame, wall_m_from_deg

__all__ = [
    "AIM_POINTS",
    "AimResult",
    "AngleSampler",
    "CutoffOffset",
    "PointReading",
    "cutoff_offset",
    "parse_normalise_at",
    "test_points",
]

#: Test points read off the photo (names of the R112 passing-beam rule set).
AIM_POINTS = ("75R", "50V", "B50L")
#: R112 scan distances from V-V (deg), on the side away from the step.
SCANS_DEG = (1.5, 2.5, 3.5)
DEFAULT_NORMALISE_AT = "50R"


class AngleSampler:
    """Sample the photo and the simulation at screen angles (deg).

    Parameters
    ----------
    photo : ndarray, shape (Hp, Wp)
        Linear relative photo luminance.
    clipped : ndarray of bool, shape (Hp, Wp)
        Clipped photo pixels.
    matrix : ndarray, shape (3, 3)
        Photo px → simulation px.
    sim : ndarray, shape (Hs, Ws)
        Simulated illuminance (lx).
    frame : dict or WallFrame
        The simulation's wall frame.
    """

    def __init__(self, photo: NDArray, clipped: NDArray, matrix: NDArray, sim: NDArray,
                 frame: Any):
        self.wall = WallFrame.from_any(frame)
        self.photo = gaussian_filter(np.asarray(photo, np.float64), 0.7, mode="nearest")
        self.clipped = np.asarray(clipped, np.float64)
        self.sim = np.nan_to_num(np.asarray(sim, np.float64))
        self.inv = np.linalg.inv(np.asarray(matrix, np.float64))
        self.cut_v: dict[float, float] = {}      # photo cut-off per scan (deg), for σ

    def _sim_px(self, h_deg: NDArray, v_deg: NDArray) -> tuple[NDArray, NDArray]:
        d = self.wall.distance_m
        row, col = self.wall.pixel_of(wall_m_from_deg(h_deg, d), wall_m_from_deg(v_deg, d))
        return row, col

    def photo_at(self, h_deg: NDArray, v_deg: NDArray) -> tuple[NDArray, NDArray]:
        """Photo luminance (NaN outside the photo) and clipped flags at angles."""
        row, col = self._sim_px(h_deg, v_deg)
        x, y = apply_matrix(self.inv, col, row)
        hp, wp = self.photo.shape
        inside = np.isfinite(x) & np.isfinite(y) & (x >= 0) & (x <= wp - 1) & (y >= 0) & (
            y <= hp - 1)
        xs, ys = np.where(inside, x, 0.0), np.where(inside, y, 0.0)
        val = map_coordinates(self.photo, [ys, xs], order=1, mode="nearest")
        clip = map_coordinates(self.clipped, [ys, xs], order=1, mode="nearest") > 0.01
        return np.where(inside, val, np.nan), clip & inside

    def sim_at(self, h_deg: NDArray, v_deg: NDArray) -> NDArray:
        """Simulated lux at angles (NaN outside the simulated wall)."""
        row, col = self._sim_px(h_deg, v_deg)
        hs, ws = self.sim.shape
        inside = (row >= 0) & (row <= hs - 1) & (col >= 0) & (col <= ws - 1)
        val = map_coordinates(self.sim, [np.where(inside, row, 0.0), np.where(inside, col, 0.0)],
                              order=1, mode="nearest")
        return np.where(inside, val, np.nan)


@dataclass
class CutoffOffset:
    """Cut-off of the photo relative to the simulation (deg, up positive)."""

    offset_deg: float | None
    interval_deg: float | None
    scans_deg: list[float | None]
    blur_deg: float | None
    blur_at_cap: bool
    sigma_scan_deg: float | None
    sigma_geometry_deg: float | None
    message: str
    sigma_resolution_deg: float | None = None


@dataclass
class PointReading:
    """A test point read off the photo, relative to the normalisation point."""

    name: str
    h_deg: float
    v_deg: float
    photo_rel: float | None
    sim_rel: float | None
    ratio: float | None
    clipped: bool


@dataclass
class AimResult:
    """The aim section of a comparison."""

    judgeable: bool
    statement: str
    geometry: str
    cutoff: CutoffOffset
    hotspot_dh_deg: float | None
    hotspot_dv_deg: float | None
    hotspot_interval_deg: float | None
    normalised_at: dict[str, Any]
    points: list[PointReading] = field(default_factory=list)
    markers: dict[str, Any] | None = None
    refused: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return asdict(self)


RESOLUTION_SHARE = 0.25
"""σ of the cut-off match, in simulation pixels (V)."""
MIN_AIM_MARKERS = 4
"""Markers (or control points) the aim is read through at the least."""
COLLINEAR_DEG = 0.5
"""Markers whose centres all lie within this of one line (deg) do not fix the screen
across that line: the aim is not read through them."""
FAR_FROM_CUTOFF_DEG = 6.0
"""When every marker is farther than this from the cut-off (deg), the cut-off is read by
extrapolating the screen geometry: the aim is not read through them."""


def marker_search(found: list[int], layout_ids: list[int]) -> dict[str, Any]:
    """What a marker search on a photo found: ``found``/``missing`` ids of the layout's
    ``of`` markers, and one line saying so."""
    found = sorted(int(i) for i in found)
    missing = sorted(int(i) for i in layout_ids if int(i) not in found)
    n = len(layout_ids)
    text = (f"markers: {len(found)} of {n} found"
            + (f" (ids {', '.join(map(str, found))})" if found else "")
            + (f"; missing {', '.join(map(str, missing))}" if missing else ""))
    return {"of": n, "found": found, "missing": missing, "text": text}


def aim_geometry_problem(geometry: Any, cutoff_v_deg: float | None) -> str | None:
    """Why a screen geometry does not constrain the aim, or None when it does.

    The aim is not read through fewer than :data:`MIN_AIM_MARKERS` markers (control
    points), through markers that lie nearly on one line (:data:`COLLINEAR_DEG`), or
    through markers all farther than :data:`FAR_FROM_CUTOFF_DEG` from the cut-off at
    ``cutoff_v_deg`` (deg; None: not checked).
    """
    pts = np.asarray(geometry.screen_deg, np.float64).reshape(-1, 2)
    if geometry.source == "markers":
        ids = list(geometry.details.get("marker_ids", []))
        centres = pts.reshape(-1, 4, 2).mean(axis=1) if len(pts) % 4 == 0 else pts
        what = f"{len(centres)} marker(s) (ids {', '.join(map(str, ids))})"
    else:
        centres = pts
        what = f"{len(centres)} control point(s)"
    if len(centres) < MIN_AIM_MARKERS:
        return f"only {what}; at least {MIN_AIM_MARKERS} are needed to read the aim"
    d = centres - centres.mean(axis=0)
    _, sv, vt = np.linalg.svd(d, full_matrices=False)
    off_line = np.abs(d @ vt[-1]) if len(sv) > 1 else np.zeros(len(d))
    if off_line.max() < COLLINEAR_DEG:
        return (f"the {what} lie nearly on one line (within {off_line.max():.2f}° of it): "
                "they do not fix the screen across it")
    if cutoff_v_deg is not None and np.isfinite(cutoff_v_deg):
        near = float(np.min(np.abs(centres[:, 1] - cutoff_v_deg)))
        if near > FAR_FROM_CUTOFF_DEG:
            return (f"the {what} are all more than {FAR_FROM_CUTOFF_DEG:g}° from the cut-off "
                    f"(nearest {near:.1f}°): reading it would extrapolate the screen")
    return None


def _band(sampler: AngleSampler, h: float, v: NDArray, band_deg: float = 0.1,
          sim_dh: float = 0.0) -> tuple[NDArray, NDArray, NDArray]:
    hs = h + band_deg * np.linspace(-0.5, 0.5, 5)
    hh, vv = np.meshgrid(hs, v, indexing="ij")
    p, c = sampler.photo_at(hh, vv)
    s = sampler.sim_at(hh - sim_dh, vv)
    return np.mean(p, axis=0), np.any(c, axis=0), np.mean(s, axis=0)


def _scan_offset(sampler: AngleSampler, h: float, step: float, window: float,
                 max_offset: float, max_blur: float, dh: float = 0.0
                 ) -> tuple[float, float, bool] | None:
    """(dv, blur σ, blur at cap) of one scan, or None when the scan shows no cut-off."""
    n_pad = round((max_offset + window + 3 * max_blur) / step) + 2
    v = np.arange(-3.0, 1.5 + step / 2, step)
    v_wide = -3.0 + step * np.arange(-n_pad, len(v) + n_pad)
    p, clip, _ = _band(sampler, h, v)
    _, _, s_wide = _band(sampler, h, v_wide, sim_dh=dh)
    usable = np.isfinite(p) & ~clip
    if usable.sum() < 20 or not np.any(np.isfinite(s_wide)):
        return None
    s_wide = np.nan_to_num(s_wide)
    if not s_wide.max() > 0 or not np.nanmax(np.where(usable, p, np.nan)) > 0:
        return None
    lp = np.log(np.maximum(np.where(usable, p, 0.0), 1e-3 * np.nanmax(p[usable])))
    # the fit window sits on the photo's own steepest fall (fixed for every shift tried, so
    # the costs compare); it must be a real cut-off on the simulation too
    fall = -np.gradient(gaussian_filter1d(lp, 0.05 / step, mode="nearest"))
    fall[~usable] = -np.inf
    v_photo = float(v[int(np.argmax(fall))])
    cut = find_cutoff(sampler.sim, sampler.wall, scan_h_deg=(abs(h),),
                      traffic="right" if h < 0 else "left")
    if not cut.found:
        return None
    sampler.cut_v[h] = v_photo
    shifts = np.arange(-round(max_offset / step), round(max_offset / step) + 1)
    idx = np.arange(len(v)) + n_pad
    blurs = np.arange(0.0, max_blur + 1e-9, 0.05)      # refined continuously below
    best = (math.inf, 0.0, 0.0)
    costs_best = None
    for sigma in blurs:
        sb = gaussian_filter1d(s_wide, sigma / step, mode="nearest") if sigma > 0 else s_wide
        ls = np.log(np.maximum(sb, 1e-3 * sb.max()))
        x = ls[idx[None, :] - shifts[:, None]]                  # E(v − dv) for each dv
        w = np.broadcast_to((usable & (np.abs(v - v_photo) <= window)).astype(np.float64),
                            x.shape)
        nw = w.sum(axis=1)
        ok = nw >= 10
        nw = np.maximum(nw, 1)
        mx, my = (w * x).sum(1) / nw, (w * lp[None, :]).sum(1) / nw
        sxx = (w * (x - mx[:, None]) ** 2).sum(1)
        sxy = (w * (x - mx[:, None]) * (lp[None, :] - my[:, None])).sum(1)
        syy = (w * (lp[None, :] - my[:, None]) ** 2).sum(1)
        b = np.where(sxx > 0, sxy / np.maximum(sxx, 1e-300), 0.0)
        cost = np.where(ok & (b > 0), (syy - b * sxy) / nw, np.inf)
        k = int(np.argmin(cost))
        if cost[k] < best[0]:
            best, costs_best = (float(cost[k]), float(sigma), float(k)), cost
    if not math.isfinite(best[0]) or costs_best is None:
        return None
    k = int(best[2])
    if k in (0, len(shifts) - 1):
        return None                     # the best shift is at the edge of the search
    return _refine_scan(v, p, usable & (np.abs(v - v_photo) <= window), v_wide, s_wide,
                        float(shifts[k] * step), best[1], max_offset, max_blur, step)


def _refine_scan(v: NDArray, p: NDArray, sel: NDArray, v_wide: NDArray, s_wide: NDArray,
                 dv0: float, sigma0: float, max_offset: float, max_blur: float, step: float
                 ) -> tuple[float, float, bool]:
    """Continuous fit of ``ln P = ln(α·E_σ(v − dv)^b + c)`` from the grid's best start.

    The additive ``c`` is the room light and the camera's black offset, which lift the dark
    side of the cut-off and would otherwise bias the log-space shift.
    """
    from scipy.optimize import least_squares

    vs, ps = v[sel], np.maximum(p[sel], 1e-12 * float(np.max(p[sel])))
    lp = np.log(ps)
    e = s_wide / s_wide.max()
    floor = 1e-6

    def model(theta: NDArray) -> NDArray:
        dv, sig, la, b, lc = theta
        eb = gaussian_filter1d(e, max(sig, 0.0) / step, mode="nearest") if sig > 0 else e
        ev = np.maximum(np.interp(vs - dv, v_wide, eb), floor)
        return np.log(np.exp(la) * ev**b + np.exp(lc))

    pmax = float(ps.max())
    lo_c = float(np.percentile(ps, 2))
    x0 = np.array([dv0, min(max(sigma0, 0.01), max_blur * 0.99), math.log(pmax), 1.0,
                   math.log(max(0.5 * lo_c, 1e-9 * pmax))])
    lo = [dv0 - 0.2, 0.0, x0[2] - 10, 0.2, math.log(1e-9 * pmax)]
    hi = [dv0 + 0.2, max_blur, x0[2] + 10, 5.0, math.log(pmax)]
    x0 = np.clip(x0, np.array(lo) + 1e-9, np.array(hi) - 1e-9)
    try:
        res = least_squares(lambda t: model(t) - lp, x0, bounds=(lo, hi), loss="soft_l1",
                            f_scale=0.1, diff_step=[1e-3, 1e-2, 1e-4, 1e-4, 1e-3],
                            max_nfev=400)
        dv, sig = float(res.x[0]), float(res.x[1])
    except (ValueError, np.linalg.LinAlgError):
        dv, sig = dv0, sigma0
    if not (math.isfinite(dv) and abs(dv) < max_offset):
        return None  # type: ignore[return-value]
    return dv, sig, sig >= 0.98 * max_blur


def cutoff_offset(sampler: AngleSampler, traffic: str = "right",
                  sigma_geometry_deg: float | None = None, geometry: Any = None,
                  step_deg: float = 0.01,
                  window_deg: float = 1.0, max_offset_deg: float = 2.0,
                  max_blur_deg: float = 1.0, dh_deg: float = 0.0) -> CutoffOffset:
    """Vertical offset of the photo's cut-off from the simulation's (module docstring).

    Returns
    -------
    CutoffOffset
        ``offset_deg`` > 0 when the photo's cut-off is higher; None with a message when no
        scan shows a cut-off on both.
    """
    sign = -1.0 if traffic == "right" else 1.0
    found = [_scan_offset(sampler, sign * h, step_deg, window_deg, max_offset_deg,
                          max_blur_deg, dh_deg) for h in SCANS_DEG]
    scans = [f[0] if f else None for f in found]
    good = [f for f in found if f]
    if not good:
        return CutoffOffset(None, None, scans, None, False, None, sigma_geometry_deg,
                            "no cut-off found on both the photo and the simulation along "
                            "the R112 scans")
    dvs = np.array([g[0] for g in good])
    if geometry is not None and geometry.param_cov is not None:
        # the geometry's V uncertainty where the cut-off is measured (extrapolation counts)
        hs = np.array([sign * h for h, f in zip(SCANS_DEG, found) if f])
        vs = np.array([float(v) for v in (sampler.cut_v.get(h) for h in hs)])
        x, y = geometry.deg_to_photo(hs, vs)
        sig = geometry.sigma_at(x, y)
        if sig is not None and np.all(np.isfinite(sig[1])):
            sigma_geometry_deg = float(np.sqrt(np.mean(sig[1] ** 2)))
    blur = float(np.mean([g[1] for g in good]))
    at_cap = any(g[2] for g in good)
    s_scan = float(np.std(dvs, ddof=1) / math.sqrt(len(dvs))) if len(dvs) > 1 else 0.0
    s_scan = max(s_scan, 0.5 * step_deg)
    s_geo = sigma_geometry_deg or 0.0
    v = sampler.wall.v_deg()
    s_res = RESOLUTION_SHARE * (float(np.mean(np.abs(np.diff(v)))) if len(v) > 1 else 0.0)
    interval = 1.96 * math.sqrt(s_scan ** 2 + s_geo ** 2 + s_res ** 2)
    msg = f"{len(good)} of {len(SCANS_DEG)} scans"
    if at_cap:
        msg += f"; fitted blur reached its cap of {max_blur_deg:g}° (offset depends on it)"
    if sigma_geometry_deg is None:
        msg += "; screen geometry residual unknown (exactly 4 points), not in the interval"
    return CutoffOffset(float(dvs.mean()), interval, scans, blur, at_cap, s_scan,
                        sigma_geometry_deg, msg, s_res)


def parse_normalise_at(text: str | None, traffic: str = "right") -> tuple[str, float, float]:
    """A test-point name of the R112 passing-beam rule set or ``"H,V"`` (deg)."""
    text = (text or DEFAULT_NORMALISE_AT).strip()
    if "," in text:
        try:
            h, v = (float(t) for t in text.split(","))
        except ValueError:
            raise InputError(f"--normalise-at must be a test point or H,V, got {text!r}"
                             ) from None
        if not (math.isfinite(h) and math.isfinite(v)):
            raise InputError(f"--normalise-at must be finite, got {text!r}")
        return f"{h:g},{v:g}", h, v
    rules = load_ruleset("r112-b-passing").for_traffic(traffic)
    try:
        g = rules.geometry(text)
    except KeyError:
        names = [g.name for g in rules.geometries if g.kind == "point"]
        raise InputError(f"--normalise-at: unknown test point {text!r} (one of "
                         f"{', '.join(names)} or H,V)") from None
    return g.name, g.h, g.v


def _disc(sampler: AngleSampler, h: float, v: float, r: float
          ) -> tuple[float | None, bool, float | None]:
    off = r * np.linspace(-1, 1, 5)
    hh, vv = np.meshgrid(h + off, v + off)
    p, c = sampler.photo_at(hh, vv)
    s = sampler.sim_at(hh, vv)
    pv = float(np.mean(p)) if np.all(np.isfinite(p)) else None
    sv = float(np.mean(s)) if np.all(np.isfinite(s)) else None
    return pv, bool(c.any()), sv


def test_points(sampler: AngleSampler, traffic: str = "right",
                normalise_at: str | None = None, radius_deg: float = 0.1
                ) -> tuple[dict[str, Any], list[PointReading]]:
    """75R, 50V, B50L relative to the normalisation point, photo beside simulation."""
    rules = load_ruleset("r112-b-passing").for_traffic(traffic)
    name, hn, vn = parse_normalise_at(normalise_at, traffic)
    pn, cn, sn = _disc(sampler, hn, vn, radius_deg)
    norm = {"point": name, "h_deg": hn, "v_deg": vn, "clipped": cn,
            "photo": pn, "sim_lx": sn}
    out = []
    for pname in AIM_POINTS:
        g = rules.geometry(pname)
        p, c, s = _disc(sampler, g.h, g.v, radius_deg)
        pr = p / pn if p is not None and pn else None
        sr = s / sn if s is not None and sn else None
        ratio = pr / sr if pr is not None and sr else None
        out.append(PointReading(pname, g.h, g.v, pr, sr, ratio, c))
    return norm, out
