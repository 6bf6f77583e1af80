"""Figures of a photo comparison: overlay, signed difference and isolux contours.

All three are drawn on the wall's angular axes (H right, V up, in degrees; pixel edges at
``atan(h/D)``, ``atan(v/D)`` via :func:`lightsim.io.png.wall_angles`), with matplotlib's
Agg renderer (no display, no pyplot state) and written atomically.

=================  ==========================================================================
file               content
=================  ==========================================================================
``overlay.png``    registered photo and simulation side by side (both in lx after the
                   exposure fit, shown with the sRGB curve relative to the simulation's
                   peak), and below a blend: simulation in green, photo in magenta
                   (grey/white where they agree); the dashed line bounds the photo
``difference.png`` (photo − simulation) / simulation peak in %, diverging colour map
                   with a colour bar; grey outside the photo and on clipped photo pixels
                   (whose true value is unknown), which are also outlined in black
``contours.png``   isolux contours at 10, 30, 60 % of the simulation's peak: simulation
                   solid, photo dashed, over the simulation in grey
=================  ==========================================================================

Parameters
----------
=========  ====  ========  =================================================================
name       unit  default   meaning
=========  ====  ========  =================================================================
photo_lux  lx    required  registered photo on the simulation grid (NaN outside the photo)
sim        lx    required  simulated illuminance
frame      –     required  wall frame (``docs/reference/conventions.md``)
credit     –     None      attribution line printed under every figure (e.g. a photo's
                           licence)
caption    –     None      the run's caption (lamp, seed, photons, error figure, rule sets,
                           lightsim version) and the photo, under every figure and in its
                           PNG metadata (:func:`comparison_caption`)
dpi        px/in 110       resolution
=========  ====  ========  =================================================================
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from numpy.typing import NDArray

import lightsim
from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path
from lightsim.io.caption import add_caption, png_metadata, run_text
from lightsim.io.exr import read_exr
from lightsim.io.plots import PlotCaption
from lightsim.io.png import wall_angles
from lightsim.io.summary import read_json
from lightsim.report import plot_caption
from lightsim.validation.photo_io import srgb_encode
from lightsim.validation.photo_metrics import LEVELS
from lightsim.wall import WallFrame

__all__ = ["comparison_caption", "plot_contours", "plot_difference", "plot_overlay",
           "plot_pair_difference", "simulation_caption"]


def _figure(size: tuple[float, float]) -> Figure:
    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: str | os.PathLike, dpi: int, credit: str | None,
          caption: str | None = None) -> Path:
    """Save atomically with the caption under the axes and in the PNG's metadata (the
    credit joins the caption, or stands alone in the corner without one)."""
    if caption:
        caption = f"{caption}\n{credit}" if credit else caption
        add_caption(fig, caption)
    elif credit:
        fig.text(0.995, 0.002, credit, ha="right", va="bottom", fontsize=7, color="0.35")
    p = Path(path)
    with atomic_path(p, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=dpi, metadata=png_metadata(caption))
    return p


def simulation_caption(source: str | os.PathLike) -> PlotCaption | None:
    """The caption of the run a comparison is against: from its ``summary.json`` (lamp,
    seed, photons, error figure, rule sets, lightsim version) or, without one, from the
    ``wall_lux.exr`` metadata (lamp, seed, photons, version); None when neither says."""
    src = Path(source)
    exr = src if src.suffix.lower() == ".exr" else src / "wall_lux.exr"
    with contextlib.suppress(InputError, OSError, ValueError, TypeError, AttributeError):
        summary = read_json(exr.parent / "summary.json")
        if isinstance(summary, dict):
            return plot_caption(summary)
    with contextlib.suppress(InputError, OSError, ValueError, TypeError, KeyError):
        meta = read_exr(exr)[1]
        return PlotCaption(lamp=Path(str(meta["source"])).name, seed=int(meta["seed"]),
                           photons=int(meta["photons"]),
                           version=str(meta.get("lightsim_version", lightsim.__version__)))
    return None


def comparison_caption(photo: str | os.PathLike, source: str | os.PathLike) -> str:
    """Caption of a photo comparison's figures: the run's caption and the photo."""
    cap = simulation_caption(source)
    photo_line = f"photo: {Path(photo).name}"
    if cap is None:
        return run_text(f"simulation {Path(source).name}", "no run metadata", photo_line)
    return f"{cap.text()}\n{photo_line}"


def _axes(frame: dict[str, Any], sim: NDArray) -> tuple[NDArray, NDArray, float, float]:
    """Pixel edges H, V (°) of the wall image, the simulation's peak (lx) and the
    image's aspect (H extent / V extent)."""
    he, ve = wall_angles(frame, sim.shape[1], sim.shape[0])
    return he, ve, float(np.nanmax(sim)), (he[-1] - he[0]) / (ve[0] - ve[-1])


def _single_panel(aspect: float) -> tuple[Figure, Any]:
    """A 9-inch-wide figure with one axes for an image of ``aspect``."""
    fig = _figure((9.0, 9.0 / aspect + 1.4))
    return fig, fig.add_subplot()


def _label(ax: Any, title: str) -> None:
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("H (°), right +")
    ax.set_ylabel("V (°), up +")
    ax.set_aspect("equal")


def _display(lux: NDArray, peak: float) -> NDArray:
    """Display values 0–1: sRGB curve of lux relative to ``peak`` (NaN → 0)."""
    return srgb_encode(np.nan_to_num(lux, nan=0.0) / peak)


def _outline(ax: Any, frame: dict[str, Any], mask: NDArray, **style: Any) -> None:
    if mask.any() and not mask.all():
        wf = WallFrame.from_any(frame)
        ax.contour(wf.h_deg(), wf.v_deg(), mask.astype(float), levels=[0.5], **style)


def plot_overlay(path: str | os.PathLike, photo_lux: NDArray, sim: NDArray,
                 frame: dict[str, Any], title: str = "", credit: str | None = None,
                 dpi: int = 110, caption: str | None = None) -> Path:
    """Write ``overlay.png``: photo, simulation and their colour blend (see module);
    ``caption`` (:func:`comparison_caption`) goes under it and into its metadata.

    Returns
    -------
    Path
        The file written.
    """
    he, ve, peak, aspect = _axes(frame, sim)
    inside = np.isfinite(photo_lux)
    p, s = _display(photo_lux, peak), _display(sim, peak)
    blend = np.stack([p, s, p], axis=-1)
    fig = _figure((11.0, 1.5 * 11.0 / aspect + 1.6))
    grid = fig.add_gridspec(2, 2, height_ratios=[1, 2])
    axes = [fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1]),
            fig.add_subplot(grid[1, :])]
    for ax, img, name in ((axes[0], p, "photo (registered, lx)"),
                          (axes[1], s, "simulation (lx)")):
        ax.pcolormesh(he, ve, img, cmap="gray", vmin=0, vmax=1)
        _label(ax, name)
    axes[2].pcolormesh(he, ve, np.clip(blend, 0, 1))
    _outline(axes[2], frame, inside, colors="white", linestyles="dashed", linewidths=0.8)
    _label(axes[2], "blend: simulation green, photo magenta (dashed: edge of the photo)")
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path, dpi, credit, caption)


def plot_difference(path: str | os.PathLike, photo_lux: NDArray, sim: NDArray,
                    frame: dict[str, Any], clipped: NDArray, credit: str | None = None,
                    dpi: int = 110, caption: str | None = None) -> Path:
    """Write ``difference.png``: signed (photo − simulation) in % of the peak, with
    ``caption``.

    Returns
    -------
    Path
        The file written.
    """
    he, ve, peak, aspect = _axes(frame, sim)
    diff = np.where(clipped, np.nan, 100.0 * (photo_lux - sim) / peak)
    finite = diff[np.isfinite(diff)]
    lim = float(np.percentile(np.abs(finite), 99.5)) if finite.size else 1.0
    lim = max(lim, 1e-3)
    fig, ax = _single_panel(aspect)
    ax.set_facecolor("0.75")
    mesh = ax.pcolormesh(he, ve, np.ma.masked_invalid(diff), cmap="RdBu_r", vmin=-lim,
                         vmax=lim)
    _outline(ax, frame, clipped, colors="black", linewidths=0.6)
    cbar = fig.colorbar(mesh, ax=ax, shrink=0.9)
    cbar.set_label("photo − simulation (% of simulation peak)")
    _label(ax, f"signed difference (peak {peak:.3g} lx; grey: no photo or clipped, "
               "outlined: clipped)")
    return _save(fig, path, dpi, credit, caption)


def plot_contours(path: str | os.PathLike, photo_lux: NDArray, sim: NDArray,
                  frame: dict[str, Any], levels: Sequence[float] = LEVELS,
                  credit: str | None = None, dpi: int = 110,
                  caption: str | None = None) -> Path:
    """Write ``contours.png``: isolux contours of photo (dashed) and simulation (solid),
    with ``caption``.

    Returns
    -------
    Path
        The file written.
    """
    he, ve, peak, aspect = _axes(frame, sim)
    wf = WallFrame.from_any(frame)
    fig, ax = _single_panel(aspect)
    ax.pcolormesh(he, ve, _display(sim, peak), cmap="gray", vmin=0, vmax=1.6)
    lux_levels = [lv * peak for lv in levels]
    colours = ["tab:blue", "tab:orange", "tab:red"][: len(levels)]
    handles = []
    for img, style in ((sim, "solid"), (np.ma.masked_invalid(photo_lux), "dashed")):
        if np.nanmax(np.asarray(img, dtype=float)) >= min(lux_levels):
            ax.contour(wf.h_deg(), wf.v_deg(), img, levels=lux_levels, colors=colours,
                       linestyles=style, linewidths=1.2)
    for lv, c in zip(levels, colours):
        handles.append(Line2D([], [], color=c, label=f"{100 * lv:g} % ({lv * peak:.3g} lx)"))
    handles += [Line2D([], [], color="k", ls="solid", label="simulation"),
                Line2D([], [], color="k", ls="dashed", label="photo")]
    ax.legend(handles=handles, fontsize=8, loc="upper right")
    _label(ax, "isolux contours (levels relative to the simulation's peak)")
    return _save(fig, path, dpi, credit, caption)


def plot_pair_difference(path: str | os.PathLike, rel_diff: NDArray,
                         points: Sequence[dict[str, Any]] = (), geometry: Any = None,
                         title: str = "", credit: str | None = None, dpi: int = 110,
                         caption: str | None = None) -> Path:
    """Write ``relative_difference.png`` of photo B against photo A (``--against``),
    with ``caption`` (the two photos, :func:`lightsim.io.caption.run_text`).

    The map is ``(k·B − A)/A`` in % on A's pixel grid (x right, y down, photo px),
    diverging colour map clipped at ±50 %, grey where A is dark or either photo clipped;
    test points (with A's screen geometry) are marked and labelled with their change.
    """
    h, w = rel_diff.shape
    fig = _figure((9.0, 9.0 * h / w + 1.4))
    ax = fig.add_subplot()
    ax.set_facecolor("0.6")
    im = ax.imshow(100 * rel_diff, cmap="RdBu_r", vmin=-50, vmax=50, interpolation="nearest")
    fig.colorbar(im, ax=ax, shrink=0.8, label="(B − A) / A  (%)")
    if geometry is not None:
        for p in points:
            x, y = geometry.deg_to_photo(np.array(p["h_deg"]), np.array(p["v_deg"]))
            change = p.get("change")
            text = p["name"] + ("" if change is None else f" {100 * change:+.0f}%")
            ax.plot(float(x), float(y), "k+", ms=6)
            ax.annotate(text, (float(x), float(y)), xytext=(3, 3), textcoords="offset points",
                        fontsize=7)
    ax.set_title(title or "relative difference", fontsize=10)
    ax.set_xlabel("x (photo A px)")
    ax.set_ylabel("y (photo A px)")
    return _save(fig, path, dpi, credit, caption)
