"""Compare a photograph of a beam pattern with a simulation (``lightsim compare``).

The paper (section 6.3, figure 5) puts the simulated headlight pattern beside a photo of
the real lamp's pattern; this module makes that comparison quantitative:

1. **Read** the photo as linear luminance (:func:`~lightsim.validation.photo_io.read_photo`:
   sRGB decoding for 8/16-bit files, Rec. 709 luminance, clipped pixels) and the
   simulation's ``wall_lux.exr`` with its wall frame.
2. **Register** the photo to the simulated view
   (:func:`~lightsim.validation.photo_register.register`: coarse rotation × scale search
   with masked FFT cross-correlation of log-luminance images, then coarse-to-fine
   ZNCC maximisation for a similarity or a homography) — or use a known transform.
3. **Resample** the photo onto the simulation's pixel grid (anti-aliased, bilinear,
   :func:`skimage.transform.warp`) and carry the clipped mask along.
4. **Normalise** the exposure: fit ``P = gain·E^gamma`` (gamma only with ``fit_gamma``)
   and express the photo in lx (:mod:`~lightsim.validation.photo_metrics`).
5. **Score** on the overlap: ZNCC, SSIM, PSNR, NMI, relative RMSE, isolux IoU at 10/30/60 %
   of the peak, hot-spot offset and cut-off positions in degrees.
6. **Write** ``comparison.json``, ``overlay.png``, ``difference.png``, ``contours.png``
   (:mod:`~lightsim.validation.photo_plots`).

The transform reported maps **photo pixels to simulation pixels** (x = column, y = row,
pixel centres at integers). Registration aligns the whole pattern, so the hot-spot offset
and the cut-off positions measure differences in the pattern's *shape* relative to the
rest of it, not the lamp's aim — unless ``transform`` fixes the camera geometry (e.g. from
markers on the wall) instead of registering.

Parameters
----------
=============  ====  ==========  ==============================================================
name           unit  default     meaning
=============  ====  ==========  ==============================================================
photo          –     required    PNG, JPEG, TIFF (8/16 bit sRGB) or EXR (linear) file
sim            –     required    result folder with ``wall_lux.exr`` (lx), or the EXR itself
out_dir        –     required    folder for the four outputs (created)
model          –     similarity  ``"similarity"`` or ``"homography"`` (photo taken at an angle)
fit_gamma      –     False       also fit the tone curve's exponent
traffic        –     "right"     side of the R112 cut-off scans
transform      –     None        3×3 photo → simulation px matrix to use instead of registering
max_rotation   deg   15          rotations searched (±)
scale_range    1     (0.5, 2)    scales searched, relative to "photo width = simulation width"
credit         –     None        attribution printed on the figures and stored in the JSON
=============  ====  ==========  ==============================================================
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter
from skimage.transform import ProjectiveTransform, warp

from lightsim import __version__
from lightsim.errors import InputError
from lightsim.io.summary import read_json, write_json
from lightsim.render.cutoff import find_cutoff
from lightsim.validation.photo_aim import (
    AimResult,
    AngleSampler,
    aim_geometry_problem,
    cutoff_offset,
    marker_search,
    test_points,
)
from lightsim.validation.photo_io import PhotoImage, Simulation, load_simulation, read_photo
from lightsim.validation.photo_lamps import find_lamps, keep_lamp
from lightsim.validation.photo_metrics import (
    HIGHER_IS_BETTER,
    LOWER_IS_BETTER,
    METRICS,
    Photometric,
    compute_metrics,
    fit_photometric,
    to_lux,
)
from lightsim.validation.photo_plots import (
    comparison_caption,
    plot_contours,
    plot_difference,
    plot_overlay,
)
from lightsim.validation.photo_register import (
    Registration,
    RegistrationOptions,
    decompose,
    downsample,
    level_matrix,
    register,
    registration_dict,
)
from lightsim.validation.screen_geometry import ScreenGeometry, fit_screen, parse_points, sim_matrix
from lightsim.validation.screen_target import (
    DEFAULT_LAYOUT,
    detect_markers,
    load_layout,
    marker_mask,
)

__all__ = [
    "OUTPUTS",
    "CompareOptions",
    "Comparison",
    "compare_images",
    "failed_thresholds",
    "load_transform",
    "parse_threshold",
    "run_compare",
    "warp_to_sim",
    "write_outputs",
]

#: Markers whose corners disagree by more than this (RMS, photo px) are not used.
MAX_MARKER_RESIDUAL_PX = 3.0

#: Files written by :func:`write_outputs`.
OUTPUTS = ("comparison.json", "overlay.png", "difference.png", "contours.png")


@dataclass(frozen=True)
class CompareOptions:
    """Settings of a comparison (see the module's parameter table)."""

    model: str = "similarity"
    fit_gamma: bool = False
    traffic: str = "right"
    transform: NDArray | None = None
    registration: RegistrationOptions = field(default_factory=RegistrationOptions)
    credit: str | None = None
    points: str | None = None
    markers: str = "auto"
    screen_distance_m: float | None = None
    normalise_at: str | None = None
    lamp: str | None = None

    def registration_options(self) -> RegistrationOptions:
        """Registration settings with this comparison's model."""
        return replace(self.registration, model=self.model)


@dataclass
class Comparison:
    """Everything a comparison produced.

    Attributes
    ----------
    photo : PhotoImage
        The photo as read.
    sim : Simulation
        The simulation.
    matrix : ndarray, shape (3, 3)
        Photo px → simulation px.
    registration : Registration or None
        Registration details (None for a given transform).
    photometric : Photometric
        Fitted exposure (and gamma).
    photo_lux : ndarray
        Photo on the simulation grid in lx, NaN outside the photo.
    clipped : ndarray of bool
        Simulation pixels that see clipped photo pixels.
    overlap : ndarray of bool
        Simulation pixels covered by the photo.
    metrics : dict
        Metric name → value (``photo_metrics`` table); None where undefined.
    details : dict
        Hot-spot positions, cut-off messages, pixel counts.
    seconds : float
        Wall-clock time of registration and scoring (s).
    """

    photo: PhotoImage
    sim: Simulation
    matrix: NDArray
    registration: Registration | None
    photometric: Photometric
    photo_lux: NDArray
    clipped: NDArray
    overlap: NDArray
    metrics: dict[str, Any]
    details: dict[str, Any]
    seconds: float
    options: CompareOptions = field(default_factory=CompareOptions)
    geometry: ScreenGeometry | None = None
    aim: AimResult | None = None

    def transform_dict(self) -> dict[str, Any]:
        """Decomposition and matrix of the transform (JSON-ready)."""
        if self.registration is not None:
            out = registration_dict(self.registration, self.photo.shape)
        else:
            out = decompose(self.matrix, self.photo.shape)
            out.update(matrix=[[float(v) for v in row] for row in self.matrix / self.matrix[2, 2]],
                       model=("screen " + self.geometry.source) if self.geometry is not None
                       else "given")
        out["maps"] = "photo pixels (x = column, y = row) → simulation pixels"
        out["overlap_fraction"] = float(self.overlap.mean())
        return out

    def _exif_gain(self) -> dict[str, Any]:
        """With EXIF: the gain per unit relative exposure (t·ISO/N²), a camera constant
        that carries the exposure fit to other photos of the same camera."""
        exif = self.photo.info.get("exif") or {}
        rel = exif.get("relative_exposure")
        if not rel:
            return {}
        return {"gain_per_relative_exposure": self.photometric.gain / rel,
                "relative_exposure": rel,
                "relative_exposure_unit": exif.get("relative_exposure_unit")}

    def to_json(self) -> dict[str, Any]:
        """The content of ``comparison.json``."""
        return {
            "lightsim_version": __version__,
            "photo": {"path": self.photo.path, **self.photo.info},
            "simulation": {"path": self.sim.source,
                           "resolution": [int(self.sim.lux.shape[1]), int(self.sim.lux.shape[0])],
                           "peak_lx": float(np.nanmax(self.sim.lux)), "wall": self.sim.frame},
            "transform": self.transform_dict(),
            "photometric": {**self.photometric.to_dict(), **self._exif_gain()},
            "metrics": self.metrics,
            "metric_info": {"higher_is_better": list(HIGHER_IS_BETTER),
                            "lower_is_better": list(LOWER_IS_BETTER),
                            "units": {"psnr_db": "dB", "hotspot_offset_deg": "deg",
                                      "hotspot_dh_deg": "deg", "hotspot_dv_deg": "deg",
                                      "cutoff_v_photo_deg": "deg", "cutoff_v_sim_deg": "deg",
                                      "cutoff_shape_gap_deg": "deg"}},
            "geometry": (self.geometry.to_dict() if self.geometry is not None else
                         {"source": "given transform" if self.registration is None
                          else "beam registration"}),
            "aim": self.aim.to_dict() if self.aim is not None else None,
            "details": self.details,
            "settings": {"model": self.options.model, "fit_gamma": self.options.fit_gamma,
                         "traffic": self.options.traffic,
                         "given_transform": self.options.transform is not None},
            "credit": self.options.credit,
            "seconds": self.seconds,
        }


# ---------------------------------------------------------------------------------------
# steps
# ---------------------------------------------------------------------------------------

def warp_to_sim(photo: NDArray, clipped: NDArray, matrix: NDArray, sim_shape: tuple[int, int]
                ) -> tuple[NDArray, NDArray]:
    """Resample the photo onto the simulation grid.

    The photo is first averaged down (anti-aliasing) when its pixels are finer than the
    simulation's by more than 1.5×, then sampled bilinearly with
    :func:`skimage.transform.warp`.

    Parameters
    ----------
    photo : ndarray, shape (Hp, Wp)
        Linear photo luminance (relative).
    clipped : ndarray of bool, shape (Hp, Wp)
        Clipped photo pixels.
    matrix : ndarray, shape (3, 3)
        Photo px → simulation px.
    sim_shape : tuple of int
        (H, W) of the simulation.

    Returns
    -------
    values : ndarray, shape sim_shape
        Photo luminance per simulation pixel, NaN outside the photo.
    clipped : ndarray of bool, shape sim_shape
        Simulation pixels touched by a clipped photo pixel.
    """
    scale = decompose(matrix, photo.shape)["scale"]          # sim px per photo px
    factor = 1.0
    if scale < 1 / 1.5:
        factor = float(2 ** math.floor(math.log2(1 / scale)))
    img = downsample(photo, factor)
    clip = downsample(clipped.astype(np.float64), factor)
    sim_to_photo = level_matrix(factor) @ np.linalg.inv(matrix)
    tform = ProjectiveTransform(matrix=sim_to_photo / sim_to_photo[2, 2])
    kw = {"output_shape": sim_shape, "order": 1, "mode": "constant", "clip": False,
          "preserve_range": True}
    values = warp(img, tform, cval=np.nan, **kw)
    clip_w = warp(clip, tform, cval=0.0, **kw) > 0.01
    return values, clip_w & np.isfinite(values)


def compare_images(photo: PhotoImage, sim: Simulation, options: CompareOptions | None = None
                   ) -> Comparison:
    """Register, normalise and score a photo against a simulation (no files written).

    Parameters
    ----------
    photo : PhotoImage
        Photo as linear luminance with its clipped mask.
    sim : Simulation
        Simulated lux map and frame.
    options : CompareOptions, optional
        Model, gamma fit, traffic side, fixed transform, registration settings.

    Returns
    -------
    Comparison

    Raises
    ------
    InputError
        Registration finds no overlap, or the overlap has no usable pixels.
    """
    opts = options or CompareOptions()
    if opts.traffic not in ("right", "left"):
        raise InputError(f"traffic must be 'right' or 'left', got {opts.traffic!r}")
    t0 = time.perf_counter()
    reg = None
    photo, lamps = _one_lamp(photo, opts.lamp)
    geometry = screen_geometry(photo, sim, opts)
    if geometry is not None and geometry.source == "markers":
        # marker pixels are paper and ink, not beam: they take no part in the comparison
        photo = replace(photo, clipped=photo.clipped | marker_mask(geometry, photo.shape))
    if geometry is not None:
        matrix = sim_matrix(geometry, sim.frame)
    elif opts.transform is not None:
        matrix = np.asarray(opts.transform, np.float64)
    else:
        reg = register(photo.luminance, ~photo.clipped, sim.lux, opts.registration_options())
        matrix = reg.matrix
    values, clip_w = warp_to_sim(photo.luminance, photo.clipped, matrix, sim.lux.shape)
    overlap = np.isfinite(values) & np.isfinite(sim.lux)
    if overlap.sum() < max(25, 0.005 * overlap.size):
        raise InputError("no overlap between the photo and the simulation after registration"
                         if reg is not None else "the photo does not show the simulated part "
                         "of the screen (no overlap through the screen geometry)")
    full_scale = 1.0 if photo.encoding.startswith("srgb") else math.inf
    phot = fit_photometric(values, sim.lux, overlap & ~clip_w, opts.fit_gamma,
                           full_scale=full_scale)
    photo_lux = np.where(overlap, to_lux(np.nan_to_num(values), phot), np.nan)
    metrics, details = compute_metrics(photo_lux, sim.lux, overlap, clip_w, sim.frame,
                                       phot.clip_lx, opts.traffic,
                                       reg.blur_px if reg is not None else 0.0)
    aim = measure_aim(photo, sim, matrix, geometry, reg, opts)
    if aim.hotspot_dh_deg is not None:      # one hot-spot measure in the whole report
        metrics.update(hotspot_dh_deg=aim.hotspot_dh_deg, hotspot_dv_deg=aim.hotspot_dv_deg,
                       hotspot_offset_deg=math.hypot(aim.hotspot_dh_deg, aim.hotspot_dv_deg))
    metrics["cutoff_dv_deg"] = aim.cutoff.offset_deg
    metrics["cutoff_dv_abs_deg"] = (abs(aim.cutoff.offset_deg)
                                    if aim.cutoff.offset_deg is not None else None)
    metrics["cutoff_dv_interval_deg"] = aim.cutoff.interval_deg
    metrics["geometry_residual_deg"] = (geometry.residual_deg[0] if geometry is not None
                                        else None)
    details["lamps"] = {"count": lamps.count, "hotspot_columns_px": list(lamps.peaks_px),
                        "split_column_px": lamps.split_px, "kept": opts.lamp}
    return Comparison(photo, sim, matrix, reg, phot, photo_lux, clip_w, overlap, metrics,
                      details, time.perf_counter() - t0, opts, geometry, aim)


def _one_lamp(photo: PhotoImage, lamp: str | None) -> tuple[PhotoImage, Any]:
    """Find the lamps on the photo; keep one (``--lamp``) or warn that there are several."""
    lamps = find_lamps(photo)
    if lamp is not None:
        return keep_lamp(photo, lamp, lamps), lamps
    if lamps.count >= 2:
        cols = ", ".join(f"{c:.0f}" for c in lamps.peaks_px)
        photo.info.setdefault("warnings", []).append(
            f"photo {Path(photo.path).name}: {lamps.count} lamps found (hot spots at x = "
            f"{cols} px) but the simulation is one lamp; pick one with --lamp left|right")
    return photo, lamps


def screen_geometry(photo: PhotoImage, sim: Simulation, opts: CompareOptions
                    ) -> ScreenGeometry | None:
    """The photo's screen geometry: ``--points``, else markers found on it, else None.

    Raises
    ------
    InputError
        Malformed or degenerate control points, or an unreadable marker layout.
    """
    distance = opts.screen_distance_m or sim.wall.distance_m
    if opts.points:
        xy, hv = parse_points(opts.points)
        hp, wp = photo.shape
        if np.any((xy < -0.5) | (xy > np.array([wp - 0.5, hp - 0.5]))):
            raise InputError(f"--points: a photo pixel lies outside the {wp}×{hp} photo")
        return fit_screen(xy, hv, distance, source="points")
    if opts.markers == "off" or opts.transform is not None:
        return None

    layout = None if opts.markers == "auto" else load_layout(opts.markers)
    geo = detect_markers(photo.luminance, layout, distance)
    name = Path(photo.path).name
    photo.info["markers"] = marker_search(
        [] if geo is None else geo.details["marker_ids"],
        [m[0] for m in (layout or DEFAULT_LAYOUT).markers])
    if geo is None:
        return None
    warnings = photo.info.setdefault("warnings", [])
    if len(geo.details["marker_ids"]) < 2:
        # four corners fix a homography exactly, with nothing left to check it (a false
        # detection in wall texture would pass): a second marker is required
        warnings.append(f"photo {name}: only marker {geo.details['marker_ids'][0]} found; "
                        "two or more are needed to check the screen geometry, so it is "
                        "not used")
        return None
    if geo.residual_px[0] > MAX_MARKER_RESIDUAL_PX:
        warnings.append(f"photo {name}: the markers found disagree (residual "
                        f"{geo.residual_px[0]:.1f} px RMS > {MAX_MARKER_RESIDUAL_PX:g}): "
                        "moved or misplaced markers, or a false detection; not used")
        return None
    return geo


_NOT_JUDGEABLE = ("aim cannot be judged from this photo: without control points (--points) "
                  "or screen markers the photo was registered by the beam itself, which moves "
                  "it onto the simulated pattern and hides any aim error; the offsets below "
                  "compare the pattern's shape only")


def measure_aim(photo: PhotoImage, sim: Simulation, matrix: NDArray,
                geometry: ScreenGeometry | None, reg: Registration | None,
                opts: CompareOptions) -> AimResult:
    """Cut-off offset, hot-spot offset and test points read off the photo (no fitting
    of the photo onto the beam when the geometry comes from the screen)."""
    sampler = AngleSampler(photo.luminance, photo.clipped, matrix, sim.lux, sim.frame)
    sigma = geometry.sigma_deg if geometry is not None else None
    spots, spot_deg = _hotspot_offset(photo, sim, matrix)
    cut = cutoff_offset(sampler, opts.traffic, sigma, geometry, dh_deg=spots[0] or 0.0)
    norm, points = test_points(sampler, opts.traffic, opts.normalise_at)
    if geometry is not None and spot_deg is not None:
        x, y = geometry.deg_to_photo(np.array([spot_deg[0]]), np.array([spot_deg[1]]))
        sig = geometry.sigma_at(x, y)
        if sig is not None:
            sigma = float(math.hypot(sig[0][0], sig[1][0]))
    markers = photo.info.get("markers")
    refused = (aim_geometry_problem(geometry, sim_cutoff_v(sim, opts.traffic))
               if geometry is not None else None)
    if refused is not None:
        judge, statement = False, f"aim not read: {refused}"
    elif geometry is not None:
        judge = True
        statement = (f"aim measured through the screen geometry from {len(geometry.photo_xy)} "
                     f"{'control points' if geometry.source == 'points' else 'marker corners'}"
                     f" (residual {geometry.residual_px[0]:.2f} px, "
                     f"{geometry.residual_deg[0]:.3f}° RMS); the photo was not moved onto "
                     "the beam")
    elif reg is None:
        judge = True
        statement = ("aim measured through the given transform; lightsim cannot check it: "
                     "it is only as good as the transform's source")
    else:
        judge, statement = False, _NOT_JUDGEABLE
        if markers is not None:  # searched, but too few to use
            statement = f"{markers['text']}; {statement}"
    # the core match resolves about a quarter of a simulation pixel; the geometry adds σ
    step = float(np.mean(np.abs(np.diff(sim.wall.v_deg())))) if sim.wall.height > 1 else 0.0
    h_int = 1.96 * math.hypot(sigma or 0.0, 0.25 * step) if judge else None
    return AimResult(judge, statement, geometry.source if geometry is not None else
                     ("given transform" if reg is None else "beam registration"), cut,
                     spots[0], spots[1], h_int, norm, points, markers, refused)


def sim_cutoff_v(sim: Simulation, traffic: str) -> float | None:
    """The simulation's cut-off position V (deg), None where it has none."""
    res = find_cutoff(np.nan_to_num(sim.lux), sim.frame, traffic)
    return res.v_cutoff_deg if res.found else None


def _hotspot_offset(photo: PhotoImage, sim: Simulation, matrix: NDArray,
                    core_level: float = 0.3, max_shift_deg: float = 2.5
                    ) -> tuple[tuple[float | None, float | None],
                               tuple[float, float] | None]:
    """Photo − simulation hot spot (deg): the shift of the photo's bright core that best
    matches the simulation's.

    The core is where the (σ = 1 px smoothed) simulation reaches ``core_level`` of its
    maximum; every integer shift within ±``max_shift_deg`` is scored by the ZNCC of the
    photo (on the simulation grid, clipped and masked pixels left out, at least half the
    core covered) against the simulation over the core, and the best is refined by a
    parabola along H and V. A shape measure robust to a noisy or clipped maximum (a
    centroid of the top 10 % is not). Returns the offset and the photo's hot spot (the
    simulation's core centroid moved by it).
    """
    values, clip_w = warp_to_sim(photo.luminance, photo.clipped, matrix, sim.lux.shape)
    good = np.isfinite(values) & ~clip_w
    s = gaussian_filter(np.nan_to_num(sim.lux), 1.0)
    core = s >= core_level * float(s.max())
    wall = sim.wall
    step_h = abs(float(np.mean(np.diff(wall.h_deg())))) if wall.width > 1 else 1.0
    step_v = abs(float(np.mean(np.diff(wall.v_deg())))) if wall.height > 1 else 1.0
    mx, my = (max(1, round(max_shift_deg / st)) for st in (step_h, step_v))
    rr, cc = np.nonzero(core)
    if rr.size < 9 or not good.any():
        return (None, None), None
    ref = s[rr, cc]
    pv = np.where(good, values, np.nan)
    hs, ws = pv.shape
    scores = np.full((2 * my + 1, 2 * mx + 1), -np.inf)
    for iy, dy in enumerate(range(-my, my + 1)):
        y = rr + dy
        for ix, dx in enumerate(range(-mx, mx + 1)):
            x = cc + dx
            ok = (y >= 0) & (y < hs) & (x >= 0) & (x < ws)
            v = np.full(rr.size, np.nan)
            v[ok] = pv[y[ok], x[ok]]
            use = np.isfinite(v)
            if use.sum() < 0.5 * rr.size:
                continue
            a, b = v[use] - v[use].mean(), ref[use] - ref[use].mean()
            den = math.sqrt(float(a @ a) * float(b @ b))
            if den > 0:
                scores[iy, ix] = float(a @ b) / den
    if not np.isfinite(scores).any():
        return (None, None), None
    iy, ix = np.unravel_index(int(np.argmax(scores)), scores.shape)

    def refine(c0: float, c1: float, c2: float) -> float:
        den = c0 - 2 * c1 + c2
        ok = all(math.isfinite(c) for c in (c0, c1, c2)) and den < 0
        return 0.5 * (c0 - c2) / den if ok else 0.0

    fx = refine(*scores[iy, ix - 1:ix + 2]) if 0 < ix < 2 * mx else 0.0
    fy = refine(*scores[iy - 1:iy + 2, ix]) if 0 < iy < 2 * my else 0.0
    dx, dy = ix - mx + fx, iy - my + fy
    dh, dv = dx * step_h, -dy * step_v                  # rows grow downwards
    w = ref / ref.sum()
    hs_deg = float(np.interp(float(w @ cc), np.arange(wall.width), wall.h_deg()))
    vs_deg = float(np.interp(float(w @ rr), np.arange(wall.height), wall.v_deg()))
    return (dh, dv), (hs_deg + dh, vs_deg + dv)


def write_outputs(result: Comparison, out_dir: str | os.PathLike) -> dict[str, Path]:
    """Write ``comparison.json`` and the three figures into ``out_dir`` (created).

    Returns
    -------
    dict
        File name → path written.
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create output folder {out}: {exc.strerror or exc}") from None
    m = result.metrics
    fmt = {k: ("–" if m.get(k) is None else f"{m[k]:.3f}") for k in ("zncc", "ssim", "iou_30")}
    title = (f"{Path(result.photo.path).name} vs {Path(result.sim.source).parent.name or 'sim'}:"
             f" ZNCC {fmt['zncc']}, SSIM {fmt['ssim']}, IoU30 {fmt['iou_30']}")
    credit = result.options.credit
    sim, frame = result.sim.lux, result.sim.frame
    caption = comparison_caption(result.photo.path, result.sim.source)
    paths = {
        "overlay.png": plot_overlay(out / "overlay.png", result.photo_lux, sim, frame, title,
                                    credit, caption=caption),
        "difference.png": plot_difference(out / "difference.png", result.photo_lux, sim,
                                          frame, result.clipped, credit, caption=caption),
        "contours.png": plot_contours(out / "contours.png", result.photo_lux, sim, frame,
                                      credit=credit, caption=caption),
    }
    write_json(out / "comparison.json", result.to_json())
    paths["comparison.json"] = out / "comparison.json"
    return paths


def run_compare(photo_path: str | os.PathLike, sim_path: str | os.PathLike,
                out_dir: str | os.PathLike, options: CompareOptions | None = None
                ) -> Comparison:
    """Read the photo and the simulation, compare them and write the outputs.

    Parameters
    ----------
    photo_path : path-like
        The photo.
    sim_path : path-like
        Result folder or ``wall_lux.exr``.
    out_dir : path-like
        Output folder.
    options : CompareOptions, optional
        Comparison settings.

    Returns
    -------
    Comparison
    """
    sim = load_simulation(sim_path)
    photo = read_photo(photo_path)
    result = compare_images(photo, sim, options)
    write_outputs(result, out_dir)
    return result


# ---------------------------------------------------------------------------------------
# functions for scripts
# ---------------------------------------------------------------------------------------

def load_transform(path: str | os.PathLike) -> NDArray:
    """Read a 3×3 photo → simulation matrix from JSON.

    Accepts a ``comparison.json`` (``transform.matrix``), a synthetic photo's
    ``.truth.json`` or any JSON object with ``matrix``.

    Raises
    ------
    InputError
        Missing file, no matrix, or not an invertible 3×3 matrix.
    """
    doc = read_json(path)
    if isinstance(doc, dict) and isinstance(doc.get("transform"), dict):
        doc = doc["transform"]
    raw = doc.get("matrix") if isinstance(doc, dict) else None
    try:
        m = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        m = np.zeros(0)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)) or abs(np.linalg.det(m)) < 1e-12:
        raise InputError(f"{path}: no invertible 3×3 'matrix' (photo → simulation pixels)")
    return m / m[2, 2]


def parse_threshold(text: str) -> tuple[str, float]:
    """``"zncc=0.9"`` → ``("zncc", 0.9)``; the name must be a known metric.

    Raises
    ------
    InputError
        Malformed text or unknown metric.
    """
    name, sep, value = str(text).partition("=")
    name = name.strip()
    if not sep or name not in METRICS:
        raise InputError(f"expected METRIC=VALUE with METRIC one of {', '.join(METRICS)}; "
                         f"got {text!r}")
    try:
        number = float(value)
    except ValueError:
        raise InputError(f"threshold for {name} is not a number: {value!r}") from None
    if not math.isfinite(number):
        raise InputError(f"threshold for {name} must be finite, got {value!r}")
    return name, number


def failed_thresholds(metrics: dict[str, Any], below: list[tuple[str, float]],
                      above: list[tuple[str, float]] | None = None) -> list[str]:
    """Messages for metrics below their ``below`` or above their ``above`` limits.

    An undefined metric (None) fails its threshold.
    """
    fails = []
    for name, limit in below:
        v = metrics.get(name)
        if v is None:
            fails.append(f"{name} is undefined (required ≥ {limit:g})")
        elif v < limit:
            fails.append(f"{name} = {v:.4g} is below {limit:g}")
    for name, limit in above or []:
        v = metrics.get(name)
        if v is None:
            fails.append(f"{name} is undefined (required ≤ {limit:g})")
        elif v > limit:
            fails.append(f"{name} = {v:.4g} is above {limit:g}")
    return fails
