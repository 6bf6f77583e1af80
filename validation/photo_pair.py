"""Photo against photo (``lightsim compare A --against B``): what changed between two shots.

"The same car with and without headlamp deflectors" is two photos of one wall. They are
aligned by the **static scene**, never by the beams (the beams are what may have changed):

1. **Markers** (:mod:`~lightsim.validation.screen_target`) found on both photos (two or
   more shared): the homography B → A from the corners of the markers they share (OpenCV
   :func:`cv2.findHomography`, RANSAC at ``ransac_px``).
2. Otherwise **features** of the static scene: ORB key points (OpenCV, up to
   ``features`` per photo) detected only *outside* both beams — the beam is every pixel
   at or above ``beam_level`` of the photo's 99.5th percentile (and 3× its 25th
   percentile, the room light) after a σ = 3 px blur,
   grown by ``beam_margin`` of the photo's diagonal — on images tone-mapped so that the
   background, not the beam, fills the 8-bit range; Lowe's ratio test (``ratio``), then
   RANSAC, then a sub-pixel refinement by OpenCV's ECC (enhanced correlation
   coefficient) on the static pixels (kept when it moves no corner by more than 3 px).
   Fewer than ``min_inliers`` agreeing matches is an error that says to light the room
   or use markers.

**Exposure**: B is scaled by the ratio of the EXIF relative exposures (``t·ISO/N²``) when
both photos have one; otherwise by the median B/A over the static scene (the room light
did not change); otherwise — stated in the report — by the median over the beam, which
hides an overall brightness change. The **relative difference** ``(k·B − A)/A`` is
computed on A's pixel grid where A is lit (≥ ``lit_level`` of its 99.5th percentile) and
neither photo is clipped; with A's screen geometry (``--points`` or markers) the **change
at each test point** of the UN R112 passing-beam rule set is read off too (means over
±``point_radius_deg``).

Parameters
----------
================  ====  =======  =============================================================
name              unit  default  meaning
================  ====  =======  =============================================================
features          –     6000     ORB key points per photo
ratio             1     0.75     Lowe's ratio test
ransac_px         px    2.0      RANSAC inlier distance (A px)
min_inliers       –     12       fewest agreeing matches
beam_level        1     0.05     beam mask level, relative to the 99.5th percentile
beam_margin       1     0.02     beam mask growth, fraction of the photo diagonal
lit_level         1     0.05     difference map: A pixels at least this bright (relative)
point_radius_deg  deg   0.1      test-point sampling half-width
================  ====  =======  =============================================================
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import binary_dilation, gaussian_filter, map_coordinates

from lightsim.errors import InputError
from lightsim.io.caption import run_text
from lightsim.io.summary import write_json
from lightsim.luminaires.regulations.ruleset import load_ruleset
from lightsim.validation.photo_io import PhotoImage, read_photo, srgb_encode
from lightsim.validation.photo_plots import plot_pair_difference
from lightsim.validation.photo_register import apply_matrix
from lightsim.validation.screen_geometry import ScreenGeometry, fit_screen, parse_points
from lightsim.validation.screen_target import detect_markers, load_layout, marker_mask

__all__ = ["PairComparison", "PairOptions", "align_pair", "compare_pair", "run_pair",
           "write_pair"]


@dataclass(frozen=True)
class PairOptions:
    """Settings of :func:`compare_pair` (module table)."""

    features: int = 6000
    ratio: float = 0.75
    ransac_px: float = 2.0
    min_inliers: int = 12
    beam_level: float = 0.05
    beam_margin: float = 0.02
    lit_level: float = 0.05
    point_radius_deg: float = 0.1
    markers: str = "auto"


@dataclass
class PairComparison:
    """Result of :func:`compare_pair`.

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        B px → A px.
    method : str
        ``"markers"``, ``"features + ECC"`` or ``"features"`` (ECC refinement failed).
    inliers : int
        Matches (or marker corners) that agree with the homography.
    residual_px : float
        RMS distance of those in A px.
    exposure_ratio : float
        k, the factor B is multiplied by.
    exposure_source : str
        ``"exif"``, ``"static scene"`` or ``"beam median"``.
    rel_diff : ndarray, shape A
        ``(k·B − A)/A`` where A is lit and nothing clipped, NaN elsewhere.
    points : list of dict
        Test points: name, H/V (deg), A and k·B (relative), change (1), clipped flags.
    geometry : ScreenGeometry or None
        A's screen geometry (for the test points).
    statement : str
        What the alignment rests on and what the numbers mean.
    """

    matrix: NDArray
    method: str
    inliers: int
    residual_px: float
    exposure_ratio: float
    exposure_source: str
    rel_diff: NDArray
    points: list[dict[str, Any]] = field(default_factory=list)
    geometry: ScreenGeometry | None = None
    statement: str = ""
    paths: tuple[str, str] = ("", "")

    def to_json(self) -> dict[str, Any]:
        """Content of ``pair.json``."""
        lit = np.isfinite(self.rel_diff)
        stats = ({"median": float(np.median(self.rel_diff[lit])),
                  "p05": float(np.percentile(self.rel_diff[lit], 5)),
                  "p95": float(np.percentile(self.rel_diff[lit], 95)),
                  "pixels": int(lit.sum())} if lit.any() else None)
        return {"a": self.paths[0], "b": self.paths[1],
                "alignment": {"method": self.method, "maps": "B pixels → A pixels",
                              "matrix": [[float(v) for v in r] for r in
                                         self.matrix / self.matrix[2, 2]],
                              "inliers": self.inliers, "residual_px": self.residual_px},
                "exposure": {"ratio": self.exposure_ratio, "source": self.exposure_source},
                "relative_difference": stats, "test_points": self.points,
                "geometry": self.geometry.to_dict() if self.geometry is not None else None,
                "statement": self.statement}


def _beam_mask(photo: PhotoImage, opts: PairOptions) -> NDArray:
    lum = gaussian_filter(photo.luminance, 3.0, mode="nearest")
    ref = float(np.percentile(lum, 99.5)) or 1.0
    room = float(np.percentile(lum, 25))            # the room light on the wall
    beam = (lum >= max(opts.beam_level * ref, 3.0 * room)) | photo.clipped
    grow = max(1, round(opts.beam_margin * math.hypot(*photo.shape)))
    return binary_dilation(beam, iterations=grow)


def _static_image(photo: PhotoImage, beam: NDArray) -> NDArray:
    """8-bit image with the background (not the beam) filling the range."""
    lum = photo.luminance
    bg = lum[~beam]
    ref = float(np.percentile(bg, 99.5)) if bg.size else float(np.percentile(lum, 99.5))
    ref = ref if ref > 0 else 1.0
    return np.round(255 * srgb_encode(np.clip(lum / ref, 0, 1))).astype(np.uint8)


def _by_markers(a: PhotoImage, b: PhotoImage, ga: ScreenGeometry | None,
                gb: ScreenGeometry | None, opts: PairOptions
                ) -> tuple[NDArray, int, float] | None:
    import cv2

    if ga is None or gb is None:
        return None
    qa, qb = ga.details.get("marker_quads_px", {}), gb.details.get("marker_quads_px", {})
    common = sorted(set(qa) & set(qb))
    if len(common) < 2:             # one marker's corners would leave nothing to check
        return None
    pa = np.vstack([np.asarray(qa[i], np.float64) for i in common])
    pb = np.vstack([np.asarray(qb[i], np.float64) for i in common])
    m, inl = cv2.findHomography(pb, pa, cv2.RANSAC if len(pa) > 4 else 0, opts.ransac_px)
    if m is None:
        return None
    inl = np.ones(len(pa), bool) if inl is None else inl.ravel().astype(bool)
    if inl.sum() >= 4:                  # least squares on the inliers
        m2, _ = cv2.findHomography(pb[inl], pa[inl], 0)
        m = m2 if m2 is not None else m
    return m / m[2, 2], int(inl.sum()), _rms(m, pb[inl], pa[inl])


def _rms(m: NDArray, src: NDArray, dst: NDArray) -> float:
    x, y = apply_matrix(m, src[:, 0], src[:, 1])
    return float(np.sqrt(np.mean((x - dst[:, 0]) ** 2 + (y - dst[:, 1]) ** 2)))


def _by_features(a: PhotoImage, b: PhotoImage, beam_a: NDArray, beam_b: NDArray,
                 opts: PairOptions) -> tuple[NDArray, int, float]:
    import cv2

    orb = cv2.ORB_create(nfeatures=opts.features)
    ka, da = orb.detectAndCompute(_static_image(a, beam_a),
                                  (~beam_a).astype(np.uint8) * 255)
    kb, db = orb.detectAndCompute(_static_image(b, beam_b),
                                  (~beam_b).astype(np.uint8) * 255)
    if da is None or db is None or len(ka) < opts.min_inliers or len(kb) < opts.min_inliers:
        raise InputError("too few features in the static scene (outside the beams) to align "
                         "the two photos: light the room a little or put screen markers up")
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(db, da, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < opts.ratio * p[1].distance]
    if len(good) < opts.min_inliers:
        raise InputError(f"only {len(good)} static-scene features match between the two "
                         "photos: are they of the same wall? (or put screen markers up)")
    pb = np.array([kb[g.queryIdx].pt for g in good], np.float64)
    pa = np.array([ka[g.trainIdx].pt for g in good], np.float64)
    m, inl = cv2.findHomography(pb, pa, cv2.RANSAC, opts.ransac_px, maxIters=5000,
                                confidence=0.999)
    if m is None or inl is None or int(inl.sum()) < opts.min_inliers:
        raise InputError("the static-scene features of the two photos do not agree on one "
                         "view of the wall (RANSAC found too few inliers)")
    inl = inl.ravel().astype(bool)
    # refine on the inliers only (least squares)
    m2, _ = cv2.findHomography(pb[inl], pa[inl], 0)
    m = m2 if m2 is not None else m
    return m / m[2, 2], int(inl.sum()), _rms(m, pb[inl], pa[inl])


def align_pair(a: PhotoImage, b: PhotoImage, ga: ScreenGeometry | None = None,
               gb: ScreenGeometry | None = None, opts: PairOptions | None = None
               ) -> tuple[NDArray, str, int, float]:
    """B px → A px by the static scene: shared markers, else background features.

    Returns
    -------
    matrix, method, inliers, residual_px
    """
    o = opts or PairOptions()
    by_m = _by_markers(a, b, ga, gb, o)
    if by_m is not None:
        return by_m[0], "markers", by_m[1], by_m[2]
    beam_a, beam_b = _beam_mask(a, o), _beam_mask(b, o)
    m, n, r = _by_features(a, b, beam_a, beam_b, o)
    refined = _refine_ecc(a, b, m, beam_a, beam_b)
    if refined is None:
        return m, "features", n, r
    return refined, "features + ECC", n, r


def _refine_ecc(a: PhotoImage, b: PhotoImage, m: NDArray, beam_a: NDArray, beam_b: NDArray,
                max_move_px: float = 3.0) -> NDArray | None:
    """Sub-pixel refinement of B → A on the static scene: OpenCV's ECC (enhanced correlation
    coefficient, invariant to brightness and contrast) for a homography, started at the
    feature fit and only on B's static pixels. None when it fails or moves any photo
    corner by more than ``max_move_px`` (it then left the feature fit's basin)."""
    import cv2

    ia = _static_image(a, beam_a).astype(np.float32)
    ib = _static_image(b, beam_b).astype(np.float32)
    warp0 = np.linalg.inv(m).astype(np.float32)            # ECC's warp maps A → B
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-7)
    try:
        _, wm = cv2.findTransformECC(ia, ib, warp0, cv2.MOTION_HOMOGRAPHY, crit,
                                     (~beam_b).astype(np.uint8) * 255, 5)
    except cv2.error:
        return None
    out = np.linalg.inv(wm.astype(np.float64))
    out /= out[2, 2]
    h, w = b.shape
    cx, cy = np.array([0, w - 1, 0, w - 1.0]), np.array([0, 0, h - 1, h - 1.0])
    x0, y0 = apply_matrix(m, cx, cy)
    x1, y1 = apply_matrix(out, cx, cy)
    moved = np.hypot(x1 - x0, y1 - y0)
    return out if np.all(np.isfinite(moved)) and moved.max() <= max_move_px else None


def _warp_b(b: NDArray, matrix: NDArray, shape: tuple[int, int], order: int = 1) -> NDArray:
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    x, y = apply_matrix(np.linalg.inv(matrix), xx, yy)
    hb, wb = b.shape
    inside = np.isfinite(x) & np.isfinite(y) & (x >= 0) & (x <= wb - 1) & (y >= 0) & (
        y <= hb - 1)
    out = map_coordinates(np.asarray(b, np.float64), [np.where(inside, y, 0), np.where(
        inside, x, 0)], order=order, mode="nearest")
    return np.where(inside, out, np.nan)


def compare_pair(a: PhotoImage, b: PhotoImage, geometry: ScreenGeometry | None = None,
                 opts: PairOptions | None = None, traffic: str = "right") -> PairComparison:
    """Align B onto A by the static scene, normalise the exposure, difference and points.

    Parameters
    ----------
    a, b : PhotoImage
        The reference photo and the changed one.
    geometry : ScreenGeometry, optional
        A's screen geometry (else found from markers on A when ``opts.markers`` allows).
    opts : PairOptions, optional
        Settings (module table).
    traffic : {"right", "left"}
        Side of the test points.

    Raises
    ------
    InputError
        The photos cannot be aligned, or they share no lit pixels.
    """
    o = opts or PairOptions()
    layout = None if o.markers in ("auto", "off") else load_layout(o.markers)
    use_markers = o.markers != "off"
    ga = detect_markers(a.luminance, layout, min_markers=2) if use_markers else None
    gb = detect_markers(b.luminance, layout, min_markers=2) if use_markers else None
    geometry = geometry or ga
    matrix, method, inliers, resid = align_pair(a, b, ga, gb, o)
    bw = _warp_b(b.luminance, matrix, a.shape)
    bclip = _warp_b(b.clipped.astype(np.float64), matrix, a.shape) > 0.01
    bad = a.clipped | bclip | ~np.isfinite(bw)
    if ga is not None:
        bad |= marker_mask(ga, a.shape)
    ref_a = float(np.percentile(a.luminance, 99.5)) or 1.0
    lit = ~bad & (a.luminance >= o.lit_level * ref_a) & (bw > 0)
    if lit.sum() < 25:
        raise InputError("the two photos share no lit, unclipped pixels after alignment")
    ea, eb = a.info.get("exif"), b.info.get("exif")
    beam_b = _warp_b(_beam_mask(b, o).astype(np.float64), matrix, a.shape) > 0.01
    static = ~bad & ~_beam_mask(a, o) & ~beam_b & (a.luminance > 0) & (bw > 0)
    if ea and eb and ea.get("relative_exposure") and eb.get("relative_exposure"):
        k, source = ea["relative_exposure"] / eb["relative_exposure"], "exif"
    elif static.sum() >= 500 and np.median(a.luminance[static]) > 4e-3 * ref_a:
        k, source = float(np.median(a.luminance[static] / bw[static])), "static scene"
    else:
        k, source = float(np.median(a.luminance[lit] / bw[lit])), "beam median"
    rel = np.where(lit, (k * np.nan_to_num(bw) - a.luminance) / np.where(lit, a.luminance, 1),
                   np.nan)
    points = _point_changes(a.luminance, k * np.nan_to_num(bw, nan=0.0), bad, geometry,
                            traffic, o.point_radius_deg) if geometry is not None else []
    statement = (f"aligned by the static scene ({method}, {inliers} agreeing "
                 f"{'corners' if method == 'markers' else 'matches'}, {resid:.2f} px RMS"
                 f"{' before ECC' if 'ECC' in method else ''}), "
                 f"not by the beams; exposure from the {source}")
    if source == "beam median":
        statement += " (so an overall brightness change does not show)"
    if geometry is None:
        statement += ("; no screen geometry for A (--points or markers): test points not "
                      "located")
    return PairComparison(matrix, method, inliers, resid, k, source, rel, points, geometry,
                          statement, (a.path, b.path))


def _point_changes(a: NDArray, b: NDArray, bad: NDArray, geometry: ScreenGeometry,
                   traffic: str, radius: float) -> list[dict[str, Any]]:
    rules = load_ruleset("r112-b-passing").for_traffic(traffic)
    out = []
    h, w = a.shape
    off = radius * np.linspace(-1, 1, 5)
    for g in rules.geometries:
        if g.kind != "point":
            continue
        hh, vv = np.meshgrid(g.h + off, g.v + off)
        x, y = geometry.deg_to_photo(hh, vv)
        if not (np.all(np.isfinite(x)) and x.min() >= 0 and x.max() <= w - 1
                and y.min() >= 0 and y.max() <= h - 1):
            continue
        va = map_coordinates(a, [y.ravel(), x.ravel()], order=1)
        vb = map_coordinates(b, [y.ravel(), x.ravel()], order=1)
        clip = bool(map_coordinates(bad.astype(float), [y.ravel(), x.ravel()], order=1).max()
                    > 0.01)
        ma, mb = float(va.mean()), float(vb.mean())
        out.append({"name": g.name, "h_deg": g.h, "v_deg": g.v, "a": ma, "b": mb,
                    "change": (mb / ma - 1.0) if ma > 0 else None, "unusable": clip})
    return out


def write_pair(result: PairComparison, out_dir: str | os.PathLike, credit: str | None = None
               ) -> dict[str, Path]:
    """Write ``pair.json`` and ``relative_difference.png`` into ``out_dir``."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create output folder {out}: {exc.strerror or exc}") from None
    a, b = Path(result.paths[0]).name, Path(result.paths[1]).name
    caption = run_text(f"photo B {b} against photo A {a}", "relative difference (B − A) / A")
    png = plot_pair_difference(out / "relative_difference.png", result.rel_diff,
                               result.points, result.geometry, f"{b} vs {a}", credit,
                               caption=caption)
    write_json(out / "pair.json", result.to_json())
    return {"pair.json": out / "pair.json", "relative_difference.png": png}


def run_pair(a_path: str | os.PathLike, b_path: str | os.PathLike, out_dir: str | os.PathLike,
             points: str | None = None, opts: PairOptions | None = None,
             screen_distance_m: float | None = None, traffic: str = "right",
             credit: str | None = None) -> tuple[PairComparison, list[str]]:
    """Read photos A and B, compare them (:func:`compare_pair`) and write the outputs
    (:func:`write_pair`).

    Parameters
    ----------
    a_path, b_path : path-like
        The reference photo and the changed one.
    out_dir : path-like
        Output folder.
    points : str, optional
        Control points of A, ``"x,y=H,V; …"`` (photo px = screen degrees): A's screen
        geometry (else markers on A, as ``opts.markers`` allows).
    opts : PairOptions, optional
        Settings (module table).
    screen_distance_m : float, optional
        Lamp → screen distance of the photos in m (default 25).
    traffic : {"right", "left"}
        Side of the test points.
    credit : str, optional
        Attribution printed on the figure.

    Returns
    -------
    result : PairComparison
    warnings : list of str
        What reading A, then B, warned about (one line each).
    """
    a, b = read_photo(a_path), read_photo(b_path)
    geometry = None
    if points:
        xy, hv = parse_points(points)
        geometry = fit_screen(xy, hv, screen_distance_m or 25.0, source="points")
    result = compare_pair(a, b, geometry, opts, traffic)
    write_pair(result, out_dir, credit)
    return result, a.info.get("warnings", []) + b.info.get("warnings", [])
