"""A marker board for the measuring screen and finding its markers on a photo.

``lightsim screen-target OUT.pdf|OUT.png`` prints ArUco fiducials (OpenCV's
``cv2.aruco``, dictionary ``DICT_4X4_50``) whose places on the screen are fixed in
**degrees**, so one layout serves any distance: marker *i* is centred at (H_i, V_i) and is
``size_deg`` wide, i.e. ``2·D·tan(size/2)`` metres at distance D. Stuck on the wall at those
places (H right and V up of H-V as seen from behind the lamp), they let ``lightsim
compare`` map the photo onto the screen exactly: each marker found gives its four corners
as control points (:func:`detect_markers` →
:func:`~lightsim.validation.screen_geometry.fit_screen`).

Default layout (:data:`DEFAULT_LAYOUT`, ids ↔ centre in degrees): a row of five markers
2.5° above the horizon (ids 0–4 at H = −8, −4, 0, 4, 8°) and a row 4.5° below it (ids 5–9
at the same H), 1.5° wide — clear of the cut-off, of H-V and of the R112 test points.
Marker pixels are left out of the beam comparison.

Outputs
    * ``OUT.png``: the whole screen drawn to scale (white, markers black, thin H-H and V-V
      lines), ``px_per_m`` pixels per metre — for a large-format print or a projector.
    * ``OUT.pdf``: page 1 the layout (a drawing and a table of ids, H/V in degrees and
      in metres at D, marker edge); then one page per marker, drawn at its true size when
      it fits on A4 (else as large as the page allows, with the edge to scale it to).
    * ``OUT.layout.json``: the layout (dictionary, distance, ids, centres, size) that
      ``compare --markers`` reads for a non-default board.

Parameters
----------
===========  =====  ============  ===========================================================
name         unit   default       meaning
===========  =====  ============  ===========================================================
distance_m   m      25            lamp → screen distance the print is sized for
size_deg     deg    1.5           marker edge (angle)
markers      –      10 (above)    id ↔ (H, V) centre in degrees
dictionary   –      DICT_4X4_50   ArUco dictionary
px_per_m     px/m   100           PNG resolution
min_markers  –      1             markers needed to use the board (4 corners each)
===========  =====  ============  ===========================================================
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import binary_dilation, map_coordinates
from skimage.draw import polygon

from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path
from lightsim.io.summary import read_json, write_json
from lightsim.validation.photo_io import srgb_encode
from lightsim.validation.screen_geometry import ScreenGeometry, fit_screen
from lightsim.wall import WallFrame, deg_from_wall_m, wall_m_from_deg

__all__ = [
    "DEFAULT_LAYOUT",
    "ScreenLayout",
    "board_reflectance",
    "detect_markers",
    "load_layout",
    "marker_corners_m",
    "marker_mask",
    "write_target",
]

_H = (-8.0, -4.0, 0.0, 4.0, 8.0)


@dataclass(frozen=True)
class ScreenLayout:
    """Marker ids and their centres on the screen (degrees)."""

    markers: tuple[tuple[int, float, float], ...] = field(default_factory=lambda: tuple(
        [(i, h, 2.5) for i, h in enumerate(_H)] + [(5 + i, h, -4.5) for i, h in enumerate(_H)]))
    size_deg: float = 1.5
    dictionary: str = "DICT_4X4_50"
    distance_m: float = 25.0

    def check(self) -> None:
        """Raise :class:`InputError` for an unusable layout."""
        import cv2

        if not hasattr(cv2.aruco, self.dictionary):
            raise InputError(f"unknown ArUco dictionary {self.dictionary!r}")
        if not (0 < self.size_deg < 20 and math.isfinite(self.distance_m)
                and self.distance_m > 0):
            raise InputError("marker size must be 0–20° and the distance > 0 m")
        ids = [m[0] for m in self.markers]
        if len(set(ids)) != len(ids) or not ids:
            raise InputError("marker ids must be unique and at least one marker given")
        for i, h, v in self.markers:
            if not (math.isfinite(h) and math.isfinite(v) and abs(h) < 60 and abs(v) < 60):
                raise InputError(f"marker {i}: centre must be finite and within ±60°")

    def size_m(self) -> float:
        """Marker edge in metres at :attr:`distance_m`."""
        return 2 * self.distance_m * math.tan(math.radians(self.size_deg / 2))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready layout."""
        d = asdict(self)
        d["markers"] = [{"id": i, "h_deg": h, "v_deg": v,
                         "h_m": float(wall_m_from_deg(h, self.distance_m)),
                         "v_m": float(wall_m_from_deg(v, self.distance_m))}
                        for i, h, v in self.markers]
        d["size_m"] = self.size_m()
        d["axes"] = "H right, V up of H-V, seen from behind the lamp; centres of the markers"
        return d


DEFAULT_LAYOUT = ScreenLayout()


def load_layout(path: str | os.PathLike) -> ScreenLayout:
    """Read a ``.layout.json`` written by :func:`write_target`.

    Raises
    ------
    InputError
        Missing file or malformed layout.
    """
    doc = read_json(path)
    try:
        markers = tuple((int(m["id"]), float(m["h_deg"]), float(m["v_deg"]))
                        for m in doc["markers"])
        layout = ScreenLayout(markers, float(doc["size_deg"]), str(doc["dictionary"]),
                              float(doc.get("distance_m", 25.0)))
    except (KeyError, TypeError, ValueError):
        raise InputError(f"marker layout {path}: needs markers (id, h_deg, v_deg), size_deg "
                         "and dictionary") from None
    layout.check()
    return layout


def marker_corners_m(layout: ScreenLayout, distance_m: float | None = None
                     ) -> dict[int, NDArray]:
    """Wall corners (m, relative to H-V) of each marker in ArUco's order.

    ArUco lists corners clockwise from the marker's top-left as it is printed: top-left,
    top-right, bottom-right, bottom-left — on the wall (H right, V up) that is
    (h − s/2, v + s/2), (h + s/2, v + s/2), (h + s/2, v − s/2), (h − s/2, v − s/2).
    """
    d = distance_m or layout.distance_m
    s = 2 * d * math.tan(math.radians(layout.size_deg / 2))
    out = {}
    for i, h, v in layout.markers:
        hc, vc = float(wall_m_from_deg(h, d)), float(wall_m_from_deg(v, d))
        out[i] = np.array([[hc - s / 2, vc + s / 2], [hc + s / 2, vc + s / 2],
                           [hc + s / 2, vc - s / 2], [hc - s / 2, vc - s / 2]])
    return out


def _marker_image(layout: ScreenLayout, marker_id: int, px: int) -> NDArray:
    """Marker ``marker_id`` as a (px, px) uint8 image (0 black, 255 white)."""
    import cv2

    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, layout.dictionary))
    return cv2.aruco.generateImageMarker(d, int(marker_id), int(px), borderBits=1)


def board_reflectance(layout: ScreenLayout, frame: Any, white: float = 0.9,
                      black: float = 0.04) -> NDArray:
    """Reflectance of the screen with its markers on a wall pixel grid.

    Parameters
    ----------
    layout : ScreenLayout
        Marker board.
    frame : WallFrame or dict
        The grid (its distance sizes the markers).
    white, black : float
        Reflectance of the paper and of the ink (1).

    Returns
    -------
    ndarray, shape (H, W)
        Reflectance per pixel (area-weighted: each pixel averages 4×4 sub-samples).
    """
    wf = WallFrame.from_any(frame)
    out = np.full((wf.height, wf.width), white, np.float64)
    corners = marker_corners_m(layout, wf.distance_m)
    sub = (np.arange(4) + 0.5) / 4 - 0.5
    n_mod = 1000                                    # marker drawn fine, then sampled
    for i, quad in corners.items():
        img = _marker_image(layout, i, n_mod).astype(np.float64) / 255.0
        (h0, v1), (h1, _), _, (_, v0) = quad
        r0, c0 = wf.pixel_of(h0, v1)
        r1, c1 = wf.pixel_of(h1, v0)
        rows = np.arange(max(math.floor(min(r0, r1)) - 1, 0),
                         min(math.ceil(max(r0, r1)) + 2, wf.height))
        cols = np.arange(max(math.floor(min(c0, c1)) - 1, 0),
                         min(math.ceil(max(c0, c1)) + 2, wf.width))
        if rows.size == 0 or cols.size == 0:
            continue
        rr = (rows[:, None, None, None] + sub[None, None, :, None])
        cc = (cols[None, :, None, None] + sub[None, None, None, :])
        u = (cc - c0) / (c1 - c0) * n_mod - 0.5        # marker image column
        w = (rr - r0) / (r1 - r0) * n_mod - 0.5        # marker image row
        uu, ww = np.broadcast_arrays(u, w)
        inside = (uu >= -0.5) & (uu <= n_mod - 0.5) & (ww >= -0.5) & (ww <= n_mod - 0.5)
        val = map_coordinates(img, [ww.ravel(), uu.ravel()], order=0, mode="nearest"
                              ).reshape(uu.shape)
        refl = np.where(inside, black + (white - black) * val, white).mean(axis=(2, 3))
        cover = inside.mean(axis=(2, 3))
        block = out[np.ix_(rows, cols)]
        out[np.ix_(rows, cols)] = np.where(cover > 0, refl, block)
    return out


def detect_markers(photo: NDArray, layout: ScreenLayout | None = None,
                   distance_m: float | None = None, min_markers: int = 1
                   ) -> ScreenGeometry | None:
    """Find the layout's markers on a photo and fit the screen geometry to their corners.

    Parameters
    ----------
    photo : ndarray, shape (H, W)
        Linear relative luminance (1 = full scale).
    layout : ScreenLayout, optional
        Board (default :data:`DEFAULT_LAYOUT`).
    distance_m : float, optional
        Lamp → screen distance (m); default the layout's.
    min_markers : int, default 1
        Fewest layout markers needed.

    Returns
    -------
    ScreenGeometry or None
        None when fewer than ``min_markers`` of the layout's markers are found. The
        details list the ids found, the ids ignored (not in the layout) and the marker
        quadrilaterals in the photo (px).
    """
    import cv2

    lay = layout or DEFAULT_LAYOUT
    d = distance_m or lay.distance_m
    img = np.asarray(photo, np.float64)
    ref = float(np.percentile(img, 99.5)) or float(img.max()) or 1.0
    # sRGB-like encoding of the exposure-normalised photo: markers in dim light keep contrast
    grey = np.round(srgb_encode(np.clip(img / ref, 0, 1)) * 255).astype(np.uint8)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, lay.dictionary)), params)
    corners, ids, _ = det.detectMarkers(grey)
    if ids is None:
        return None
    corners = [_refine_linear(img, np.asarray(q, np.float64).reshape(4, 2)) for q in corners]
    wall = marker_corners_m(lay, d)
    xy, hv, found, other, quads = [], [], [], [], {}
    for quad, mid in zip(corners, ids.ravel()):
        mid = int(mid)
        if mid not in wall or mid in found:
            other.append(mid)
            continue
        found.append(mid)
        q = np.asarray(quad, np.float64).reshape(4, 2)
        quads[mid] = q.tolist()
        xy.append(q)
        hv.append(deg_from_wall_m(wall[mid], d))
    if len(found) < max(1, min_markers):
        return None
    return fit_screen(np.vstack(xy), np.vstack(hv), d, source="markers",
                      details={"marker_ids": sorted(found), "ignored_ids": sorted(other),
                               "marker_quads_px": quads, "dictionary": lay.dictionary,
                               "size_deg": lay.size_deg})


def _refine_linear(img: NDArray, quad: NDArray) -> NDArray:
    """Corners refined on the *linear* photo, normalised to the marker's own range.

    The detector works on an sRGB-like encoding (to see markers in dim light), where a
    blurred edge's midpoint lies towards the dark side: the square looks about one blur σ
    too small. In linear light the steepest gradient sits on the true edge, so
    :func:`cv2.cornerSubPix` on the linear image removes that bias.
    """
    import cv2

    edge = float(np.mean(np.hypot(*(np.roll(quad, -1, axis=0) - quad).T)))
    pad = max(4, round(0.4 * edge))
    x0, y0 = np.floor(quad.min(axis=0)).astype(int) - pad
    x1, y1 = np.ceil(quad.max(axis=0)).astype(int) + pad
    h, w = img.shape
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w - 1), min(y1, h - 1)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return quad
    win = img[y0:y1 + 1, x0:x1 + 1]
    lo, hi = np.percentile(win, [2, 98])
    if not hi > lo:
        return quad
    local = np.clip((win - lo) / (hi - lo), 0, 1).astype(np.float32) * 255
    half = int(np.clip(round(edge / 12), 2, 10))    # about half a module
    pts = (quad - [x0, y0]).astype(np.float32).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    out = cv2.cornerSubPix(local, pts, (half, half), (-1, -1), crit).reshape(4, 2)
    moved = np.hypot(*(out - (quad - [x0, y0])).T)
    return np.where((moved < half)[:, None], out + [x0, y0], quad)


def marker_mask(geometry: ScreenGeometry, shape: tuple[int, int], grow: float = 0.15
                ) -> NDArray:
    """Photo pixels covered by the markers found (each quad grown by ``grow`` of its size)."""
    mask = np.zeros(shape, bool)
    for q in geometry.details.get("marker_quads_px", {}).values():
        q = np.asarray(q, np.float64)
        c = q.mean(axis=0)
        g = c + (q - c) * (1 + 2 * grow)
        rr, cc = polygon(g[:, 1], g[:, 0], shape)
        mask[rr, cc] = True
    return mask


# ---------------------------------------------------------------------------------------
# printing
# ---------------------------------------------------------------------------------------

def _screen_frame(layout: ScreenLayout, px_per_m: float) -> dict[str, Any]:
    hs = [h for _, h, _ in layout.markers]
    vs = [v for _, _, v in layout.markers]
    pad = layout.size_deg
    d = layout.distance_m
    h0, h1 = wall_m_from_deg(min(hs) - pad, d), wall_m_from_deg(max(hs) + pad, d)
    v0, v1 = wall_m_from_deg(min(vs) - pad, d), wall_m_from_deg(max(vs) + pad, d)
    w = max(16, round((h1 - h0) * px_per_m))
    h = max(16, round((v1 - v0) * px_per_m))
    return {"distance_m": d, "h_range_m": [float(h0), float(h0 + w / px_per_m)],
            "v_range_m": [float(v0), float(v0 + h / px_per_m)], "resolution": [w, h]}


def write_target(path: str | os.PathLike, layout: ScreenLayout | None = None,
                 px_per_m: float = 100.0) -> list[Path]:
    """Write the board as PNG or PDF plus ``<name>.layout.json`` (atomically).

    Returns
    -------
    list of Path
        Files written.

    Raises
    ------
    InputError
        Unknown suffix, bad layout or resolution.
    """
    lay = layout or DEFAULT_LAYOUT
    lay.check()
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in (".png", ".pdf"):
        raise InputError(f"screen target must end in .png or .pdf, got {p.name}")
    if not (math.isfinite(px_per_m) and 5 <= px_per_m <= 2000):
        raise InputError(f"--px-per-m must be 5–2000, got {px_per_m!r}")
    if not p.parent.exists():
        raise InputError(f"output folder {p.parent} does not exist")
    frame = _screen_frame(lay, px_per_m)
    if suffix == ".png":
        refl = board_reflectance(lay, frame, white=1.0, black=0.0)
        wf = WallFrame.from_any(frame)
        row, col = wf.pixel_of(0.0, 0.0)
        img = np.round(refl * 255).astype(np.uint8)
        # H-H and V-V as thin grey lines, kept off the markers (and their quiet zone)
        clear = ~binary_dilation(refl < 1.0, iterations=max(2, round(0.2 * lay.size_m()
                                                                     * px_per_m)))
        r, c = round(float(row)), round(float(col))
        img[r, clear[r]] = 128
        img[clear[:, c], c] = 128
        with atomic_path(p) as tmp:
            iio.imwrite(tmp, img, extension=".png")
    else:
        with atomic_path(p) as tmp:
            _write_pdf(tmp, lay, frame)
    side = p.with_name(p.stem + ".layout.json")
    write_json(side, lay.to_dict())
    return [p, side]


def _write_pdf(path: Path, lay: ScreenLayout, frame: dict[str, Any]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.backends.backend_pdf import PdfPages

    a4 = (8.27, 11.69)                      # inches
    s_m = lay.size_m()
    with PdfPages(path) as pdf:
        fig = plt.figure(figsize=a4)
        ax = fig.add_axes((0.1, 0.55, 0.8, 0.35))
        refl = board_reflectance(lay, frame, white=1.0, black=0.0)
        wf = WallFrame.from_any(frame)
        ext = wf.extent_deg()
        ax.imshow(refl, cmap="gray", vmin=0, vmax=1, extent=ext, aspect="equal")
        ax.axhline(0, color="0.5", lw=0.5)
        ax.axvline(0, color="0.5", lw=0.5)
        for i, h, v in lay.markers:
            ax.annotate(str(i), (h, v + 0.75 * lay.size_deg), ha="center", fontsize=8,
                        color="tab:red")
        ax.set_xlabel("H (deg, right +)")
        ax.set_ylabel("V (deg, up +)")
        ax.set_title(f"lightsim screen target: {lay.dictionary}, {len(lay.markers)} markers, "
                     f"edge {lay.size_deg:g}° = {100 * s_m:.1f} cm at {lay.distance_m:g} m",
                     fontsize=9)
        d = lay.distance_m
        rows = [f"{i:>3}  H {h:+6.2f}°  V {v:+6.2f}°   h {wall_m_from_deg(h, d):+7.3f} m"
                f"  v {wall_m_from_deg(v, d):+7.3f} m" for i, h, v in lay.markers]
        text = ("Stick each marker with its centre at (h, v) metres from H-V, "
                "H right and V up as seen from behind the lamp; keep them upright "
                "(id at the top of the page).\n\n id   centre (deg)            centre (m)\n"
                + "\n".join(rows))
        fig.text(0.1, 0.48, text, family="monospace", fontsize=8, va="top")
        pdf.savefig(fig)
        plt.close(fig)
        max_edge_in = 7.0
        edge_in = s_m / 0.0254
        true_size = edge_in <= max_edge_in
        draw_in = edge_in if true_size else max_edge_in
        for i, h, v in lay.markers:
            fig = plt.figure(figsize=a4)
            w, hgt = draw_in / a4[0], draw_in / a4[1]
            ax = fig.add_axes(((1 - w) / 2, (1 - hgt) / 2, w, hgt))
            ax.imshow(_marker_image(lay, i, 600), cmap="gray", vmin=0, vmax=255,
                      interpolation="nearest")
            ax.set_axis_off()
            note = ("printed at its true size" if true_size else
                    f"scale this print so the black square is {100 * s_m:.1f} cm wide")
            fig.text(0.5, 0.93, f"marker {i}: centre H {h:+.2f}°, V {v:+.2f}° "
                     f"({wall_m_from_deg(h, lay.distance_m):+.3f} m, "
                     f"{wall_m_from_deg(v, lay.distance_m):+.3f} m at {lay.distance_m:g} m)",
                     ha="center", fontsize=10)
            fig.text(0.5, 0.9, f"edge {100 * s_m:.1f} cm — {note}; this side up",
                     ha="center", fontsize=9)
            pdf.savefig(fig)
            plt.close(fig)
