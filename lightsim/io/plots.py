"""Lighting-engineering plots (PNG, matplotlib Agg, written atomically).

* :func:`isolux_plot` — iso-lux lines of the wall pattern in H/V degrees (H to the right,
  V up, equal scale), labelled in lx and cd (I = E·D²), the regulation test points
  coloured by verdict and labelled, zone outlines, and the H-H / V-V axes. Levels below
  the map's noise floor (:func:`isolux_noise_floor`) are not drawn: there a contour
  follows the photon noise, not the beam.
* :func:`road_view_plot` — bird's-eye view of the road illuminance (lx) for a lamp at a
  given height: lateral position (m) across, distance ahead (m) up, iso-lux lines
  (default 1, 3, 5, 10, 20 lx); physics in :mod:`lightsim.render.road`.

Degenerate data (nothing finite, nothing above zero, a constant image, fewer than 2 × 2
pixels) gives an image that says so (:mod:`lightsim.io.placeholder`) instead of raising.

Figures are drawn on a private :class:`matplotlib.figure.Figure` with the Agg canvas (no
pyplot state, safe in threads) and saved through :func:`lightsim.io.atomic.atomic_path`.

Parameters
----------
==============  =====  =========================  ===================================
name            unit   default                    meaning
==============  =====  =========================  ===================================
lux             lx     –                          wall illuminance (H, W), row 0 top
frame           –      –                          wall frame (``WallFrame`` or dict)
results         –      None                       ``regulations.evaluate`` output
levels          lx     auto (1-2-5 steps)         iso-lux levels of the wall plot
noise_floor_lx  lx     None                       levels below it are left out
max_rel_noise   –      0.25                       noise-floor criterion (1/√photons)
road_levels     lx     (1, 3, 5, 10, 20)          iso-lux levels of the road view
mount_height_m  m      0.65                       lamp height above the road
x_range_m       m      (−15, 15)                  road view lateral extent
z_range_m       m      (0, 100)                   road view distance ahead
dpi             1/in   120                        output resolution
==============  =====  =========================  ===================================
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path
from lightsim.io.contour_noise import smoothed_for_levels
from lightsim.io.placeholder import image_problem, placeholder_png
from lightsim.render.road import road_illuminance
from lightsim.wall import WallFrame

__all__ = ["VERDICT_COLOURS", "auto_levels", "isolux_levels", "isolux_noise_floor",
           "isolux_plot", "road_view_plot", "warm_up"]

VERDICT_COLOURS = {"pass": "#1a9850", "fail": "#d73027", "uncertain": "#f39c12"}
"""Marker colours of the three verdicts (green, red, amber)."""


def auto_levels(max_value: float, decades: float = 3.0) -> list[float]:
    """1-2-5 levels from ``max_value / 10**decades`` up to ``max_value`` (empty if ≤ 0)."""
    if not (np.isfinite(max_value) and max_value > 0):
        return []
    lo = max_value / 10**decades
    out = []
    for k in range(int(np.floor(np.log10(lo))), int(np.ceil(np.log10(max_value))) + 1):
        for m in (1.0, 2.0, 5.0):
            v = m * 10.0**k
            if lo <= v < max_value:
                out.append(float(f"{v:.6g}"))
    return out


def isolux_noise_floor(photons: int, flux_lm: float, area_m2: float,
                       max_rel_noise: float = 0.25) -> float | None:
    """Illuminance (lx) below which a map estimate rests on fewer than 1/max_rel_noise²
    photons.

    A density estimate over an area A (the largest kNN disk π r_max², a fixed-radius disk
    or a pixel) from N photons of a lamp of flux Φ counts n = E·A·N/Φ photons at
    illuminance E when each carries Φ/N (photons reaching the wall carry at most that),
    so its relative noise is 1/√n. Where n < 1/max_rel_noise² an iso-lux line traces
    the noise as speckle islands.

    Parameters
    ----------
    photons : int
        Photons emitted (all sets).
    flux_lm : float
        Luminous flux of the lamp Φ (lm).
    area_m2 : float
        Largest area an estimate averages over (m²).
    max_rel_noise : float, default 0.25
        Relative noise allowed at a drawn level (0.25 → 16 photons).

    Returns
    -------
    float or None
        The floor in lx, or None when it cannot be stated (no photons, unbounded area).
    """
    vals = (float(photons), float(flux_lm), float(area_m2), float(max_rel_noise))
    if not all(np.isfinite(x) and x > 0 for x in vals):
        return None
    n_min = 1.0 / max_rel_noise**2
    return n_min * vals[1] / (vals[0] * vals[2])


def isolux_levels(vmax: float, levels: Sequence[float] | None = None,
                  noise_floor_lx: float | None = None) -> list[float]:
    """The iso-lux levels (lx) drawn for a map with maximum ``vmax`` (lx): ``levels`` or
    1-2-5 steps (three decades, or from the noise floor up), without those at or above
    the maximum and those below ``noise_floor_lx``."""
    if levels is not None:
        lv = _levels_checked(levels)
    elif noise_floor_lx is not None and vmax > noise_floor_lx:
        lv = auto_levels(vmax, decades=float(np.log10(vmax / noise_floor_lx)))
    else:
        lv = auto_levels(vmax)
    if noise_floor_lx is not None:
        lv = [x for x in lv if x >= noise_floor_lx]
    return [x for x in lv if x < vmax] if vmax > 0 else []


def _new_figure(size: tuple[float, float]) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def warm_up() -> None:
    """Draw a small contour plot with text into memory: matplotlib's fonts, text layout
    and contouring are loaded before the first real plot (the plot process runs it
    while the run goes on; a fuller warm-up, every plot once, cost more than an idle core
    gives)."""
    fig = _new_figure((3.0, 2.0))
    ax = fig.add_subplot(1, 1, 1)
    z = np.outer(np.hanning(16), np.hanning(16))
    cs = ax.contour(z, levels=[0.25, 0.5])
    ax.clabel(cs, fmt="%g lx", fontsize=7)
    ax.set_title("warm-up")
    fig.colorbar(ax.contourf(z, levels=[0.1, 0.5, 1.0]), ax=ax, location="bottom")
    fig.savefig(io.BytesIO(), format="png", dpi=50)


def _save(fig: Any, path: str | os.PathLike, dpi: int) -> Path:
    p = Path(path)
    fmt = p.suffix.lstrip(".").lower() or "png"
    with atomic_path(p) as tmp:
        fig.savefig(tmp, format=fmt, dpi=dpi)
    return p


def _levels_checked(levels: Sequence[float]) -> list[float]:
    lv = sorted({float(x) for x in levels})
    if any(not np.isfinite(x) or x <= 0 for x in lv):
        raise InputError(f"iso-lux levels must be positive numbers, got {list(levels)!r}")
    return lv


def isolux_plot(path: str | os.PathLike, lux: ArrayLike, frame: Any,
                results: Sequence[Mapping[str, Any]] | None = None,
                levels: Sequence[float] | None = None, *, title: str | None = None,
                dpi: int = 120, figsize: tuple[float, float] | None = None,
                noise_floor_lx: float | None = None,
                estimate_area_px: float | None = None) -> Path:
    """Iso-lux plot of a wall lux image with regulation test points and zones.

    Parameters
    ----------
    path : path-like
        Output image (PNG unless the suffix says otherwise), written atomically.
    lux : array_like, shape (H, W)
        Wall illuminance in lx.
    frame : WallFrame or mapping
        The wall frame (pixel positions in H/V degrees).
    results : sequence of dict, optional
        From ``lightsim.luminaires.regulations.evaluate``: points (and relation
        left-hand points) are marked and labelled in their verdict colour, zones outlined
        (``polygon_deg``/``line_deg``); sums are listed in a text box.
    levels : sequence of float, optional
        Iso-lux levels in lx (default: 1-2-5 steps over three decades below the maximum).
    title : str, optional
        Plot title.
    dpi : int, default 120
        Resolution.
    figsize : (width, height) in inches, optional
        Default scales with the wall's angular aspect.
    noise_floor_lx : float, optional
        Levels below this illuminance (lx, see :func:`isolux_noise_floor`) are left out;
        the automatic levels then span from the floor to the maximum.
    estimate_area_px : float, optional
        Area (pixels) an estimate at the noise floor averages over. With the floor it makes
        each level be drawn on the map smoothed just enough for a clean line
        (:mod:`lightsim.io.contour_noise`); without it levels are drawn on the raw map.

    Returns
    -------
    Path
        The written file.
    """
    from matplotlib import patheffects
    from matplotlib.colors import LogNorm
    from matplotlib.lines import Line2D

    if levels is not None:
        _levels_checked(levels)  # a bad option is an error even when nothing is lit
    problem = image_problem(lux, contours=True)
    if problem is not None:  # a plot that cannot show anything says so
        WallFrame.from_any(frame).check_image(lux)
        return placeholder_png(path, problem, title=title or "iso-lux on the wall", dpi=dpi)
    wf = WallFrame.from_any(frame)
    img = np.nan_to_num(wf.check_image(lux), nan=0.0)
    h = wf.h_deg()
    v = wf.v_deg()
    H, V = np.meshgrid(h, v)
    vmax = float(img.max()) if img.size else 0.0
    floor = (float(noise_floor_lx) if noise_floor_lx is not None
             and np.isfinite(noise_floor_lx) and noise_floor_lx > 0 else None)
    lv = isolux_levels(vmax, levels, floor)
    d2 = wf.distance_m ** 2  # I = E·D² (cd) on the screen axis, as the rule sets count
    span_h, span_v = float(h.max() - h.min()), float(v.max() - v.min())
    if figsize is None:
        figsize = (10.0, float(np.clip(10.0 * span_v / max(span_h, 1e-9) + 1.6, 3.5, 9.0)))
    fig = _new_figure(figsize)
    ax = fig.add_subplot(1, 1, 1)
    if lv:
        fill_lv = [*lv, vmax * 1.0001]
        fill_img, line_imgs, sigmas = np.maximum(img, lv[0] * 1e-3), [img] * len(lv), []
        if floor is not None and estimate_area_px is not None:
            line_imgs, band, sigmas = smoothed_for_levels(img, lv, floor, estimate_area_px)
            # the fill shows the same bands as the lines: a value inside each band
            mids = [*(np.sqrt(a * b) for a, b in zip(lv, fill_lv[1:], strict=True))]
            fill_img = np.where(band < 0, lv[0] * 1e-3,
                                np.asarray(mids)[np.clip(band, 0, None).astype(int)])
        cf = ax.contourf(H, V, fill_img, levels=fill_lv,
                         norm=LogNorm(vmin=lv[0], vmax=fill_lv[-1]), cmap="YlOrRd",
                         alpha=0.55, extend="neither")
        for x, limg in zip(lv, line_imgs, strict=True):
            cs = ax.contour(H, V, limg, levels=[x], colors="0.15", linewidths=0.7)
            ax.clabel(cs, fmt=lambda x: f"{x:g} lx · {x * d2:,.0f} cd", fontsize=7,
                      inline=True)
        cb = fig.colorbar(cf, ax=ax, label="illuminance on the wall (lx)",
                          location="bottom", shrink=0.6, aspect=40)
        cb.set_ticks(lv)
        cb.set_ticklabels([f"{x:g}" for x in lv])
        top = cb.ax.secondary_xaxis("top", functions=(lambda e: e * d2, lambda i: i / d2))
        top.set_xticks([x * d2 for x in lv])
        top.set_xticklabels([f"{x * d2:,.0f}" for x in lv], fontsize=7)
        top.set_xlabel(f"intensity I = E·D² (cd, D = {wf.distance_m:g} m)", fontsize=8)
        if floor is not None:
            smooth = max(sigmas, default=0.0)
            px_deg = float(np.ptp(h)) / max(len(h) - 1, 1)
            extra = (f"; lines near it drawn on the map smoothed by σ ≤ {smooth * px_deg:.2g}°"
                     if smooth > 0 else "")
            ax.text(0.99, 0.02, f"levels below the noise floor {floor:.2g} lx "
                    f"not drawn{extra}", transform=ax.transAxes, fontsize=7, ha="right",
                    va="bottom", color="0.3")
    else:
        ax.text(0.5, 0.5, "no light on the wall", transform=ax.transAxes, ha="center",
                va="center", color="0.4")
    ax.axhline(0.0, color="0.5", lw=0.6, ls="-")
    ax.axvline(0.0, color="0.5", lw=0.6, ls="-")
    halo = [patheffects.withStroke(linewidth=2.2, foreground="white")]
    notes = []
    used = set()
    for r in results or ():
        verdict = str(r.get("verdict", ""))
        col = VERDICT_COLOURS.get(verdict, "0.3")
        used.add(verdict)
        poly = r.get("polygon_deg")
        line = r.get("line_deg")
        if poly:
            pts = np.asarray([*poly, poly[0]], dtype=float)
            ax.plot(pts[:, 0], pts[:, 1], color=col, lw=1.2, ls="--")
            verts = np.asarray(poly, float)
            top = verts[np.isclose(verts[:, 1], verts[:, 1].max())]
            anchor = (float(np.clip(top[:, 0].mean(), h.min(), h.max())),
                      float(np.clip(verts[:, 1].max(), v.min(), v.max())))
            ax.annotate(f"zone {r['name']}", anchor,
                        xytext=(0, -3), textcoords="offset points", color=col, fontsize=8,
                        ha="center", va="top", fontweight="bold", path_effects=halo)
        elif line:
            pts = np.asarray(line, dtype=float)
            ax.plot(pts[:, 0], pts[:, 1], color=col, lw=1.5, ls="--")
        if r.get("kind") == "sum" or r.get("h_deg") is None:
            notes.append(f"{r['name']}: {r.get('value_cd', 0):,.0f} cd — {verdict}")
            continue
        if r.get("kind") == "zone":
            marker = "x"
            label = f"{r['name']} max" if r.get("stat") == "max" else f"{r['name']} min"
        else:
            marker = "o"
            label = str(r.get("lhs", r["name"])) if r.get("kind") == "relation" else str(
                r["name"])
        ax.plot([r["h_deg"]], [r["v_deg"]], marker=marker, ms=6, mfc=col, mec="black",
                mew=0.6, color=col, ls="none", zorder=5)
        ax.annotate(label, (r["h_deg"], r["v_deg"]), xytext=(4, 4),
                    textcoords="offset points", fontsize=7, color=col, zorder=6,
                    path_effects=halo)
    if notes:
        ax.text(0.01, 0.02, "\n".join(notes), transform=ax.transAxes, fontsize=7,
                va="bottom", ha="left", bbox={"facecolor": "white", "alpha": 0.8,
                                               "edgecolor": "0.7"})
    handles = [Line2D([], [], marker="o", ls="none", mfc=VERDICT_COLOURS[k], mec="black",
                      label=k) for k in ("pass", "fail", "uncertain") if k in used]
    if handles:
        ax.legend(handles=handles, loc="upper right", fontsize=7, title="verdict",
                  title_fontsize=7)
    ax.set_xlim(float(h.min()), float(h.max()))
    ax.set_ylim(float(v.min()), float(v.max()))
    ax.set_aspect("equal")
    ax.set_xlabel("H (deg, right +)")
    ax.set_ylabel("V (deg, up +)")
    ax.set_title(title or f"Iso-lux on the wall at {wf.distance_m:g} m")
    return _save(fig, path, dpi)


def road_view_data(lux: ArrayLike | None, frame: Any, *, mount_height_m: float = 0.65,
                   x_range_m: tuple[float, float] = (-15.0, 15.0),
                   z_range_m: tuple[float, float] = (0.0, 100.0), resolution_m: float = 0.25
                   ) -> Any:
    """The road illuminance :func:`road_view_plot` draws (same defaults), without drawing:
    None where the wall map cannot be shown (the plot would say why instead)."""
    if lux is None or frame is None:
        raise InputError("road_view_plot needs a wall lux map and its frame, or road=")
    if image_problem(lux, contours=True) is not None:
        return None
    return road_illuminance(lux, frame, mount_height_m, x_range_m, z_range_m, resolution_m)


def road_view_plot(path: str | os.PathLike, lux: ArrayLike | None = None, frame: Any = None,
                   *, road: Any = None, mount_height_m: float = 0.65,
                   levels: Sequence[float] = (1.0, 3.0, 5.0, 10.0, 20.0),
                   x_range_m: tuple[float, float] = (-15.0, 15.0),
                   z_range_m: tuple[float, float] = (0.0, 100.0), resolution_m: float = 0.25,
                   title: str | None = None, dpi: int = 120,
                   figsize: tuple[float, float] = (6.0, 9.0)) -> Any:
    """Bird's-eye road view: iso-lux lines of the road illuminance (lx).

    Parameters
    ----------
    path : path-like
        Output image, written atomically.
    lux, frame : array_like and WallFrame/mapping
        Wall lux map and its frame (ignored when ``road`` is given).
    road : RoadIlluminance, optional
        Precomputed road illuminance (e.g. from ``road_illuminance_from`` for an IES file).
    mount_height_m, levels, x_range_m, z_range_m, resolution_m
        See the module's parameter table (levels in lx).
    title : str, optional
        Plot title.
    dpi : int, default 120
        Resolution.
    figsize : (width, height) in inches, default (6, 9)

    Returns
    -------
    RoadIlluminance
        The road illuminance that was drawn (its ``summary()`` gives the reach per level).
    """
    _levels_checked(levels)
    problem = image_problem(road.lux if road is not None else lux, contours=True)
    if problem is not None and (road is not None or lux is not None):
        placeholder_png(path, problem, title=title or "road illuminance", figsize=figsize,
                        dpi=dpi)
        return road
    if road is None:
        road = road_view_data(lux, frame, mount_height_m=mount_height_m,
                              x_range_m=x_range_m, z_range_m=z_range_m,
                              resolution_m=resolution_m)
    lv = _levels_checked(levels)
    X, Z = np.meshgrid(road.x_m, road.z_m)
    data = np.ma.masked_invalid(road.lux)
    fig = _new_figure(figsize)
    ax = fig.add_subplot(1, 1, 1)
    ax.set_facecolor("0.85")  # grey = outside the measured wall (unknown)
    finite = np.isfinite(road.lux)
    emax = float(np.nanmax(road.lux)) if finite.any() else 0.0
    bands = [x for x in lv if x < emax]
    if bands:
        from matplotlib import colormaps

        edges = [0.0, *bands, max(emax, bands[-1]) * 1.0001]
        blues = colormaps["Blues"]
        colours = ["white"] + [blues(x) for x in np.linspace(0.3, 0.95, len(bands))]
        cf = ax.contourf(X, Z, data, levels=edges, colors=colours, extend="neither")
        cs = ax.contour(X, Z, data, levels=bands, colors="0.1", linewidths=0.8)
        ax.clabel(cs, fmt=lambda x: f"{x:g} lx", fontsize=7, inline=True)
        cb = fig.colorbar(cf, ax=ax, label="illuminance on the road (lx)", shrink=0.6,
                          spacing="uniform")
        cb.set_ticks(edges[:-1])
        cb.set_ticklabels([f"{x:g}" for x in edges[:-1]])
    else:
        ax.text(0.5, 0.5, f"below {lv[0]:g} lx everywhere", transform=ax.transAxes,
                ha="center", va="center", color="0.3")
    ax.plot([0.0], [0.0], marker="^", ms=9, color="black", ls="none", clip_on=False)
    ax.annotate(f"lamp, {road.mount_height_m:g} m high", (0.0, 0.0), xytext=(6, 4),
                textcoords="offset points", fontsize=8)
    ax.axvline(0.0, color="0.5", lw=0.5, ls=":")
    ax.set_xlim(float(road.x_m[0]), float(road.x_m[-1]))
    ax.set_ylim(0.0, float(road.z_m[-1]))
    ax.set_aspect("equal")
    ax.set_xlabel("lateral position (m, right +)")
    ax.set_ylabel("distance ahead (m)")
    sub = road.reach_text()
    ax.set_title(title or f"Road illuminance, lamp at {road.mount_height_m:g} m\n{sub}",
                 fontsize=10)
    _save(fig, path, dpi)
    return road
