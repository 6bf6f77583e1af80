"""False-colour PNG plots of lux maps on the measurement wall, and plain preview PNGs.

:func:`write_lux_png` draws an illuminance map (lx) with a colour bar labelled
"illuminance E (lx)" and axes in degrees — H left→right, V bottom→top — computed from the
wall frame (``docs/reference/conventions.md``): pixel edges at ``h = h_min + c·dh`` and
``v = v_max − r·dv`` (row 0 = top) are drawn at ``atan(h / D)`` and ``atan(v / D)`` (D =
``distance_m``), so every pixel sits at its true angular position even where the angle is
not linear in h. Optional iso-lux contours and marked test points (e.g. the regulation's
50R, B50L) are drawn on top. :func:`write_preview_png` saves an image pixel for pixel.
Both use matplotlib's Agg renderer directly (no display, no pyplot state; safe in worker
threads) and write atomically.

Parameters (user documentation)
-------------------------------
=============  =======  =================  ================================================
name           unit     default            meaning
=============  =======  =================  ================================================
``lux``        lx       required           (H, W) illuminance, row 0 = top; NaN pixels are
                                           drawn grey ("not computed")
``wall_frame`` –        required           dict with ``h_range_m``, ``v_range_m`` (m),
                                           ``distance_m`` (m); ``resolution`` [W, H] if
                                           present must match ``lux``
``log``        –        False              logarithmic colour scale
``vmin``       lx       0 / vmax·1e-4 log  lower end of the colour scale (log: values below
                                           it, including 0, get the lowest colour)
``vmax``       lx       image maximum      upper end of the colour scale
``title``      –        None               figure title
``contours``   lx       None               iso-lux levels (levels outside the data range
                                           are skipped), drawn black and labelled
``points``     °        None               ``(name, h_deg, v_deg, colour)`` markers
``cmap``       –        "inferno"          matplotlib colour map
``figsize``    inch     (8, 5)             figure size; the PNG is figsize·dpi pixels
``dpi``        px/inch  100                resolution
=============  =======  =================  ================================================
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from matplotlib import colors as mcolors
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path
from lightsim.wall import WallFrame

__all__ = ["LOG_FLOOR", "wall_angles", "write_lux_png", "write_preview_png"]

#: Default lower end of a logarithmic colour scale, relative to its upper end.
LOG_FLOOR = 1e-4

Point = tuple[str, float, float, str]


def wall_angles(wall_frame: Mapping[str, Any], width: int, height: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-edge angles of a wall image in degrees.

    Parameters
    ----------
    wall_frame : mapping or WallFrame
        ``h_range_m`` and ``v_range_m`` ([min, max], m, relative to the wall centre) and
        ``distance_m`` (m, lamp to wall); see :meth:`lightsim.wall.WallFrame.from_any`.
    width, height : int
        Image size in pixels.

    Returns
    -------
    h_edges : ndarray, shape (width + 1,)
        ``atan(h_m / D)`` in degrees at the column edges (h_m from H-V), increasing
        (column 0 at left).
    v_edges : ndarray, shape (height + 1,)
        ``atan(v_m / D)`` in degrees at the row edges, decreasing (row 0 at the top).
    """
    try:
        frame = WallFrame.from_any(wall_frame, resolution=(width, height))
    except InputError as exc:
        raise ValueError(f"bad wall frame: {exc}") from None
    return frame.edges_deg()


def _figure(figsize: tuple[float, float], dpi: float) -> Figure:
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: str | os.PathLike, dpi: float) -> None:
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)


def write_lux_png(path: str | os.PathLike, lux: np.ndarray, wall_frame: Mapping[str, Any], *,
                  log: bool = False, title: str | None = None, vmin: float | None = None,
                  vmax: float | None = None, contours: Sequence[float] | None = None,
                  points: Sequence[Point] | None = None, cmap: str = "inferno",
                  figsize: tuple[float, float] = (8.0, 5.0), dpi: float = 100.0) -> None:
    """Write a false-colour illuminance map with degree axes and a lux colour bar.

    Parameters
    ----------
    path : path-like
        Destination PNG (written atomically).
    lux : ndarray, shape (H, W)
        Illuminance in lx; row 0 is the top of the wall, column 0 its left (smallest H).
    wall_frame : mapping
        Wall frame (``h_range_m``, ``v_range_m``, ``distance_m``; see
        :func:`wall_angles`).
    log : bool, default False
        Logarithmic colour scale from ``vmin`` (default ``vmax · LOG_FLOOR``) to ``vmax``;
        zeros and values below ``vmin`` get the lowest colour.
    title : str, optional
        Figure title.
    vmin, vmax : float, optional
        Colour scale limits in lx (defaults: 0 or the log floor, and the image maximum;
        an all-zero image gets [0, 1] lx).
    contours : sequence of float, optional
        Iso-lux levels in lx.
    points : sequence of (name, h_deg, v_deg, colour), optional
        Points to mark (degrees, H right, V up) with a labelled marker.
    cmap : str, default "inferno"
        Colour map.
    figsize : (float, float), default (8, 5)
        Figure size in inches.
    dpi : float, default 100
        Pixels per inch; the PNG has ``figsize · dpi`` pixels.
    """
    E = np.asarray(lux, dtype=np.float64)
    if E.ndim != 2 or E.size == 0:
        raise ValueError(f"lux must be a non-empty (H, W) array, got shape {E.shape}")
    H, W = E.shape
    res = wall_frame.get("resolution")
    if res is not None and [int(x) for x in res] != [W, H]:
        raise ValueError(f"wall_frame resolution {list(res)} does not match lux {[W, H]}")
    h_edges, v_edges = wall_angles(wall_frame, W, H)

    finite = np.isfinite(E)
    data = np.ma.masked_invalid(E)
    top = float(np.max(E[finite])) if finite.any() else 0.0
    vmax_ = float(vmax) if vmax is not None else top
    if log:
        if not vmax_ > 0:
            vmax_ = 1.0
        vmin_ = float(vmin) if vmin is not None and vmin > 0 else vmax_ * LOG_FLOOR
        if vmin_ >= vmax_:
            vmin_ = vmax_ * LOG_FLOOR
        norm: mcolors.Normalize = mcolors.LogNorm(vmin=vmin_, vmax=vmax_, clip=True)
        data = np.ma.masked_invalid(np.where(finite, np.maximum(E, vmin_), np.nan))
    else:
        vmin_ = float(vmin) if vmin is not None else min(0.0, float(np.min(E[finite]))
                                                          if finite.any() else 0.0)
        if not vmax_ > vmin_:
            vmax_ = vmin_ + 1.0
        norm = mcolors.Normalize(vmin=vmin_, vmax=vmax_, clip=True)

    cm = _cmap(cmap)
    fig = _figure(figsize, dpi)
    ax = fig.add_subplot()
    mesh = ax.pcolormesh(h_edges, v_edges, data, norm=norm, cmap=cm, shading="flat",
                         rasterized=True)
    cbar = fig.colorbar(mesh, ax=ax)
    cbar.set_label("illuminance E (lx)")

    if contours:
        lo_, hi_ = (float(np.min(E[finite])), top) if finite.any() else (0.0, 0.0)
        levels = sorted({float(c) for c in contours if lo_ < float(c) < hi_})
        if levels:
            hc = 0.5 * (h_edges[1:] + h_edges[:-1])
            vc = 0.5 * (v_edges[1:] + v_edges[:-1])
            cs = ax.contour(hc, vc, np.ma.masked_invalid(E), levels=levels, colors="black",
                            linewidths=0.8)
            ax.clabel(cs, fmt=lambda x: f"{x:g} lx", fontsize=7)

    for pt in points or ():
        name, hd, vd, colour = pt
        ax.plot([hd], [vd], marker="+", markersize=9, markeredgewidth=1.5, color=colour,
                linestyle="none")
        ax.annotate(str(name), (hd, vd), xytext=(4, 4), textcoords="offset points",
                    color=colour, fontsize=8)

    ax.set_xlim(h_edges[0], h_edges[-1])
    ax.set_ylim(v_edges[-1], v_edges[0])
    ax.set_xlabel("H (°), right +")
    ax.set_ylabel("V (°), up +")
    ax.set_aspect("equal")
    if title:
        ax.set_title(title)
    _save(fig, path, dpi)


def _cmap(name: str) -> mcolors.Colormap:
    import matplotlib

    return matplotlib.colormaps[name].with_extremes(bad="0.6")  # NaN: not computed


def write_preview_png(path: str | os.PathLike, image: np.ndarray, *, vmin: float | None = None,
                      vmax: float | None = None, cmap: str = "gray", log: bool = False) -> None:
    """Save an image as a PNG with one PNG pixel per image pixel (no axes).

    Parameters
    ----------
    path : path-like
        Destination PNG (written atomically).
    image : ndarray
        (H, W) scalar image, mapped through ``cmap`` between ``vmin`` and ``vmax``
        (defaults: its finite minimum and maximum; NaN → black); or (H, W, 3|4) RGB(A),
        uint8 or floats in [0, 1] (clipped).
    vmin, vmax : float, optional
        Scale limits of a scalar image (image unit).
    cmap : str, default "gray"
        Colour map of a scalar image.
    log : bool, default False
        Logarithmic scale of a scalar image (floor ``vmax · LOG_FLOOR``).
    """
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] in (3, 4):
        if a.dtype == np.uint8:
            rgba = a
        else:
            rgba = np.nan_to_num(np.clip(a.astype(np.float64), 0.0, 1.0), nan=0.0)
            rgba = np.round(rgba * 255.0).astype(np.uint8)
    elif a.ndim == 2 and a.size > 0:
        E = a.astype(np.float64)
        finite = np.isfinite(E)
        lo = float(np.min(E[finite])) if finite.any() else 0.0
        hi = float(np.max(E[finite])) if finite.any() else 1.0
        vmax_ = float(vmax) if vmax is not None else hi
        if log:
            vmax_ = vmax_ if vmax_ > 0 else 1.0
            vmin_ = float(vmin) if vmin is not None and vmin > 0 else vmax_ * LOG_FLOOR
            t = (np.log10(np.maximum(np.where(finite, E, vmin_), vmin_)) - math.log10(vmin_)) \
                / max(math.log10(vmax_) - math.log10(vmin_), 1e-300)
        else:
            vmin_ = float(vmin) if vmin is not None else lo
            span = vmax_ - vmin_ if vmax_ > vmin_ else 1.0
            t = (np.where(finite, E, vmin_) - vmin_) / span
        t = np.clip(t, 0.0, 1.0)
        import matplotlib

        rgba = matplotlib.colormaps[cmap](t, bytes=True)
        rgba[~finite] = (0, 0, 0, 255)
    else:
        raise ValueError(f"image must be (H, W) or (H, W, 3|4), got shape {a.shape}")
    from matplotlib.image import imsave

    with atomic_path(path, suffix=".png") as tmp:
        imsave(tmp, np.ascontiguousarray(rgba), format="png")
