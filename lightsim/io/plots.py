"""Lighting-engineering plots (PNG, matplotlib Agg, written atomically).

* :func:`isolux_plot` — iso-lux lines of the wall pattern in H/V degrees (H to the right,
  V up, equal scale), labelled in lx and cd (I = E·D²), the regulation test points
  coloured by verdict and labelled, zone outlines, and the H-H / V-V axes. Levels below
  the map's noise floor (:func:`isolux_noise_floor`) are not drawn: there a contour
  follows the photon noise, not the beam.
* :func:`wall_lux_plot` — the wall map in false colour, logarithmic by default, with the
  H-H / V-V lines, the rule set's test points and an intensity (cd) scale beside the lux
  scale.
* :func:`road_view_plot` — bird's-eye view of the road illuminance (lx) for a lamp at a
  given height: lateral position (m) across, distance ahead (m) up, iso-lux lines
  (default 1, 3, 5, 10, 20 lx); physics in :mod:`lightsim.render.road`.

Test-point labels are placed by :func:`place_labels`: beside their point where there is
room, else further out with a leader line, so that no two labels overlap. Every plot can
carry a caption (:class:`PlotCaption`: lamp, seed, photons, error figure, rule set and
version, lightsim version) under its axes.

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
x_range_m       m      (−15, 15)                  road view lateral extent computed
z_range_m       m      (0, 100)                   road view distance ahead computed
fit_margin      –      0.15                       road view axes: lit area + this share
log_floor       –      1e-3                       wall_lux_plot: log scale from max × this
dpi             1/in   120                        output resolution
==============  =====  =========================  ===================================
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

import lightsim
from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path
from lightsim.io.caption import add_caption, png_metadata
from lightsim.io.contour_noise import smoothed_for_levels
from lightsim.io.placeholder import image_problem, placeholder_png
from lightsim.render.road import road_illuminance
from lightsim.wall import WallFrame

__all__ = ["VERDICT_COLOURS", "PlotCaption", "auto_levels", "isolux_levels",
           "isolux_noise_floor", "isolux_plot", "place_labels", "road_view_plot",
           "wall_lux_plot", "warm_up"]

VERDICT_COLOURS = {"pass": "#1a9850", "fail": "#d73027", "uncertain": "#f39c12"}
"""Marker colours of the three verdicts (green, red, amber)."""


LOG_FLOOR = 1e-3
FIT_MARGIN = 0.15
RINGS = 16  # rings of candidate label places around a point, 9 pt apart


@dataclass(frozen=True)
class PlotCaption:
    """What a plot handed to a colleague must say about the run it shows.

    Attributes
    ----------
    lamp : str
        The scene file's name.
    seed, photons : int
        The run's seed and photons emitted.
    error : str or None
        The run's error figure as text (``summary.json["error_text"]``).
    rulesets : tuple of (id, version)
        The rule set(s) the plot shows; empty when none.
    version : str
        lightsim's version.
    """

    lamp: str
    seed: int
    photons: int
    error: str | None = None
    rulesets: tuple[tuple[str, str], ...] = ()
    version: str = lightsim.__version__

    def for_ruleset(self, index: int) -> PlotCaption:
        """The caption of a plot that shows only rule set ``index``."""
        return replace(self, rulesets=self.rulesets[index:index + 1])

    def text(self) -> str:
        """The caption as two lines of text."""
        rules = "; ".join(f"{rid} ({ver})" for rid, ver in self.rulesets) or "no rule set"
        err = self.error or "no error figure"
        return (f"{self.lamp} · seed {self.seed} · {self.photons:,} photons · error {err}\n"
                f"rule set: {rules} · lightsim {self.version}")

    @classmethod
    def from_any(cls, value: Any) -> PlotCaption | None:
        """A caption from a :class:`PlotCaption`, its dict (the plot process's pickles
        carry either) or None."""
        if value is None or isinstance(value, PlotCaption):
            return value
        d = dict(value)
        d["rulesets"] = tuple(tuple(x) for x in d.get("rulesets", ()))
        return cls(**d)


def _caption_text(caption: Any) -> str | None:
    cap = PlotCaption.from_any(caption)
    return None if cap is None else cap.text()


def _caption(fig: Any, caption: Any) -> None:
    """Write ``caption`` under the figure's axes (constrained layout makes room)."""
    add_caption(fig, _caption_text(caption))


def place_labels(ax: Any, items: Sequence[tuple[str, float, float, Any]], *,
                 fontsize: float = 7.0, avoid: Sequence[Any] = (),
                 halo: Any = None) -> list[Any]:
    """Label points so that no two labels (nor a label and a point) overlap.

    Each label goes to the first free spot of a ring of places around its point, ring
    after ring further out; from the second ring on it is joined to its point by a
    leader line. Points are labelled from the most crowded outwards.

    Parameters
    ----------
    ax : matplotlib Axes
        Axes with final limits (data → display must not change afterwards).
    items : sequence of (text, x, y, colour)
        Labels and their points, in data coordinates.
    fontsize : float, default 7
        Label size in pt.
    avoid : sequence of matplotlib Bbox
        Display-space boxes no label may cover (legend, text boxes).
    halo : list of path effects, optional
        Drawn around each label's text.

    Returns
    -------
    list of matplotlib Text
        The labels, in the order of ``items``.
    """
    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    pts = np.array([ax.transData.transform((x, y)) for _, x, y, _ in items]).reshape(-1, 2)
    dot = 4.0 * fig.dpi / 72.0  # a marker's half size (px)
    taken = [_box(x - dot, y - dot, x + dot, y + dot) for x, y in pts] + list(avoid)
    order = np.argsort([-np.sum(np.hypot(*(pts - p).T) < 40 * fig.dpi / 72) for p in pts],
                       kind="stable")
    axbox = ax.get_window_extent(renderer)
    out: list[Any] = [None] * len(items)
    for i in order:
        label, x, y, col = items[i]
        t = ax.annotate(label, (x, y), xytext=(4, 4), textcoords="offset points",
                        fontsize=fontsize, color=col, zorder=6, path_effects=halo,
                        annotation_clip=False)
        bb = t.get_window_extent(renderer)
        w, h = bb.width, bb.height
        best = None
        for ring in range(RINGS):
            r = (5.0 + 9.0 * ring) * fig.dpi / 72.0
            for ang in np.deg2rad(np.arange(0.0, 360.0, 30.0 if ring < 2 else 15.0) + 45.0):
                cx, cy = pts[i][0] + r * np.cos(ang), pts[i][1] + r * np.sin(ang)
                # anchor the box on its side nearest the point
                x0 = cx if np.cos(ang) > 0.3 else cx - w if np.cos(ang) < -0.3 else cx - w / 2
                y0 = cy if np.sin(ang) > 0.3 else cy - h if np.sin(ang) < -0.3 else cy - h / 2
                box = _box(x0, y0, x0 + w, y0 + h)
                # inside the axes while the nearer rings last, then anywhere
                inside = ring >= RINGS // 2 or (
                    box.x0 >= axbox.x0 and box.x1 <= axbox.x1 and box.y0 >= axbox.y0
                    and box.y1 <= axbox.y1)
                if inside and not any(box.overlaps(o) for o in taken):
                    best = (ring, box)
                    break
            if best is not None:
                break
        if best is None:  # nowhere free (very crowded): the first place, drawn anyway
            best = (0, _box(pts[i][0] + 4, pts[i][1] + 4, pts[i][0] + 4 + w, pts[i][1] + 4 + h))
        ring, box = best
        off = ((box.x0 - pts[i][0]) * 72.0 / fig.dpi, (box.y0 - pts[i][1]) * 72.0 / fig.dpi)
        t.remove()
        t = ax.annotate(label, (x, y), xytext=off, textcoords="offset points",
                        fontsize=fontsize, color=col, zorder=6, path_effects=halo,
                        ha="left", va="bottom", annotation_clip=False,
                        arrowprops=None if ring < 2 else {
                            "arrowstyle": "-", "color": col, "lw": 0.6,
                            "shrinkA": 0.0, "shrinkB": 3.0})
        taken.append(box)
        out[i] = t
    return out


def _box(x0: float, y0: float, x1: float, y1: float) -> Any:
    from matplotlib.transforms import Bbox

    return Bbox([[x0, y0], [x1, y1]])


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


def _save(fig: Any, path: str | os.PathLike, dpi: int, caption: Any = None) -> Path:
    """Save atomically; a PNG carries the caption in its metadata too."""
    p = Path(path)
    fmt = p.suffix.lstrip(".").lower() or "png"
    meta = png_metadata(_caption_text(caption)) if fmt == "png" else None
    with atomic_path(p) as tmp:
        fig.savefig(tmp, format=fmt, dpi=dpi, metadata=meta)
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
                estimate_area_px: float | None = None, caption: Any = None) -> Path:
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
    caption : PlotCaption or dict, optional
        The run's caption, written under the plot.

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
        return placeholder_png(path, problem, title=title or "iso-lux on the wall", dpi=dpi,
                               caption=_caption_text(caption))
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
    line_labels: list[Any] = []  # the iso-lux lines' own labels: test points avoid them
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
            line_labels += ax.clabel(cs, fmt=lambda x: f"{x:g} lx · {x * d2:,.0f} cd",
                                     fontsize=7, inline=True)
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
    labels: list[tuple[str, float, float, Any]] = []
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
            labels.append((f"zone {r['name']}", *anchor, col))
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
        labels.append((label, float(r["h_deg"]), float(r["v_deg"]), col))
    boxes = []
    if notes:
        boxes.append(ax.text(0.01, 0.02, "\n".join(notes), transform=ax.transAxes,
                             fontsize=7, va="bottom", ha="left",
                             bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"}))
    handles = [Line2D([], [], marker="o", ls="none", mfc=VERDICT_COLOURS[k], mec="black",
                      label=k) for k in ("pass", "fail", "uncertain") if k in used]
    if handles:
        boxes.append(ax.legend(handles=handles, loc="upper right", fontsize=7,
                               title="verdict", title_fontsize=7))
    ax.set_xlim(float(h.min()), float(h.max()))
    ax.set_ylim(float(v.min()), float(v.max()))
    ax.set_aspect("equal")
    ax.set_xlabel("H (deg, right +)")
    ax.set_ylabel("V (deg, up +)")
    ax.set_title(title or f"Iso-lux on the wall at {wf.distance_m:g} m")
    _caption(fig, caption)
    _freeze_layout(fig)  # the labels are placed in display space: the layout is final
    renderer = fig.canvas.get_renderer()
    place_labels(ax, labels, avoid=[b.get_window_extent(renderer)
                                    for b in [*boxes, *line_labels]], halo=halo)
    return _save(fig, path, dpi, caption)


def _freeze_layout(fig: Any) -> None:
    """Lay the figure out once (constrained layout) and keep that layout from now on."""
    fig.draw_without_rendering()
    fig.set_layout_engine("none")


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
                   figsize: tuple[float, float] | None = None, caption: Any = None,
                   fit: bool = True) -> Any:
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
    figsize : (width, height) in inches, optional
        Default: 6 wide, the height following the shown area's aspect.
    caption : PlotCaption or dict, optional
        The run's caption, written under the plot.
    fit : bool, default True
        Fit the axes to the area lit to the lowest level (plus a margin,
        :meth:`~lightsim.render.road.RoadIlluminance.lit_box_m`) instead of the whole
        computed grid.

    Returns
    -------
    RoadIlluminance
        The road illuminance that was drawn (its ``summary()`` gives the reach per level).
    """
    _levels_checked(levels)
    problem = image_problem(road.lux if road is not None else lux, contours=True)
    if problem is not None and (road is not None or lux is not None):
        placeholder_png(path, problem, title=title or "road illuminance",
                        figsize=figsize or (6.0, 9.0), dpi=dpi, caption=_caption_text(caption))
        return road
    if road is None:
        road = road_view_data(lux, frame, mount_height_m=mount_height_m,
                              x_range_m=x_range_m, z_range_m=z_range_m,
                              resolution_m=resolution_m)
    lv = _levels_checked(levels)
    X, Z = np.meshgrid(road.x_m, road.z_m)
    data = np.ma.masked_invalid(road.lux)
    box = road.lit_box_m(lv[0], FIT_MARGIN) if fit else None
    x_lo, x_hi, far = box or (float(road.x_m[0]), float(road.x_m[-1]), float(road.z_m[-1]))
    if figsize is None:
        figsize = (6.0, float(np.clip(4.6 * far / max(x_hi - x_lo, 1e-9) + 2.4, 5.0, 10.0)))
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
    if not finite.all():  # the wedges: directions the wall map does not cover
        from matplotlib.patches import Patch

        wf = WallFrame.from_any(frame) if frame is not None else None
        where = ("" if wf is None else
                 f" (H {wf.h_deg().min():.0f}…{wf.h_deg().max():.0f}°, "
                 f"V {wf.v_deg().min():.1f}…{wf.v_deg().max():.1f}°)")
        ax.legend(handles=[Patch(facecolor="0.85", edgecolor="0.6",
                                 label=f"grey: road not seen by the wall map\n{where.strip()}"
                                       ":\ntoo steep near the lamp or too far\naside — "
                                       "unknown, not dark")],
                  loc="upper left", fontsize=7, framealpha=0.9)
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(0.0, far)
    ax.set_aspect("equal")
    ax.set_xlabel("lateral position (m, right +)")
    ax.set_ylabel("distance ahead (m)")
    sub = road.reach_text()
    ax.set_title(title or f"Road illuminance, lamp at {road.mount_height_m:g} m\n{sub}",
                 fontsize=10)
    _caption(fig, caption)
    _save(fig, path, dpi, caption)
    return road


def wall_lux_plot(path: str | os.PathLike, lux: ArrayLike, frame: Any,
                  results: Sequence[Mapping[str, Any]] | None = None, *, log: bool = True,
                  title: str | None = None, caption: Any = None, dpi: int = 100,
                  figsize: tuple[float, float] | None = None) -> Path:
    """The wall map in false colour, for a reader who has not seen the run.

    Parameters
    ----------
    path : path-like
        Output image, written atomically.
    lux : array_like, shape (H, W)
        Wall illuminance in lx.
    frame : WallFrame or mapping
        The wall frame (pixel positions in H/V degrees, distance D in m).
    results : sequence of dict, optional
        A rule set's rows (``regulations.evaluate``): its test points are marked in their
        verdict colour and labelled.
    log : bool, default True
        Logarithmic colour scale over three decades below the maximum (the cut-off and the
        spill show); False: linear from 0.
    title : str, optional
        Plot title.
    caption : PlotCaption or dict, optional
        The run's caption, written under the plot.
    dpi : int, default 100
        Resolution.
    figsize : (width, height) in inches, optional
        Default scales with the wall's angular aspect.

    Returns
    -------
    Path
        The written file.
    """
    from matplotlib import patheffects
    from matplotlib.colors import LogNorm, Normalize

    problem = image_problem(lux, contours=False)
    if problem is not None:
        WallFrame.from_any(frame).check_image(lux)
        return placeholder_png(path, problem, title=title or "illuminance on the wall",
                               dpi=dpi, caption=_caption_text(caption))
    wf = WallFrame.from_any(frame)
    img = wf.check_image(lux).astype(np.float64)
    h, v = wf.h_deg(), wf.v_deg()
    finite = np.isfinite(img)
    vmax = float(img[finite].max())
    d2 = wf.distance_m ** 2
    if log and vmax > 0:
        vmin = vmax * LOG_FLOOR
        norm: Any = LogNorm(vmin=vmin, vmax=vmax, clip=True)
        data = np.ma.masked_invalid(np.where(finite, np.maximum(img, vmin), np.nan))
    else:
        vmin = min(0.0, float(img[finite].min()))
        norm = Normalize(vmin=vmin, vmax=vmax if vmax > vmin else vmin + 1.0)
        data = np.ma.masked_invalid(img)
    span_h, span_v = float(np.ptp(h)), float(np.ptp(v))
    if figsize is None:
        figsize = (10.0, float(np.clip(10.0 * span_v / max(span_h, 1e-9) + 2.2, 3.8, 9.0)))
    fig = _new_figure(figsize)
    ax = fig.add_subplot(1, 1, 1)
    mesh = ax.pcolormesh(h, v, data, norm=norm, cmap="inferno", shading="nearest",
                         rasterized=True)
    ax.axhline(0.0, color="0.75", lw=0.7)
    ax.axvline(0.0, color="0.75", lw=0.7)
    ax.annotate("H-H", (float(h.max()), 0.0), xytext=(-3, 2), textcoords="offset points",
                ha="right", va="bottom", fontsize=7, color="0.85")
    ax.annotate("V-V", (0.0, float(v.max())), xytext=(3, -3), textcoords="offset points",
                ha="left", va="top", fontsize=7, color="0.85")
    halo = [patheffects.withStroke(linewidth=2.0, foreground="black")]
    labels = []
    used = set()
    for r in results or ():
        if r.get("h_deg") is None or r.get("kind") == "sum":
            continue
        verdict = str(r.get("verdict", ""))
        col = VERDICT_COLOURS.get(verdict, "0.8")
        used.add(verdict)
        ax.plot([r["h_deg"]], [r["v_deg"]], marker="x" if r.get("kind") == "zone" else "o",
                ms=5, mfc=col, mec="white", mew=0.6, color=col, ls="none", zorder=5)
        name = str(r.get("lhs", r["name"])) if r.get("kind") == "relation" else str(r["name"])
        labels.append((name, float(r["h_deg"]), float(r["v_deg"]), col))
    cb = fig.colorbar(mesh, ax=ax, location="bottom", shrink=0.6, aspect=40,
                      label="illuminance on the wall (lx)" + (", log scale" if log else ""))
    top = cb.ax.secondary_xaxis("top", functions=(lambda e: e * d2, lambda i: i / d2))
    top.set_xlabel(f"intensity I = E·D² (cd, D = {wf.distance_m:g} m)", fontsize=8)
    top.tick_params(labelsize=7)
    ax.set_xlim(float(h.min()), float(h.max()))
    ax.set_ylim(float(v.min()), float(v.max()))
    ax.set_aspect("equal")
    ax.set_xlabel("H (deg, right +)")
    ax.set_ylabel("V (deg, up +)")
    names = {"pass": "green pass", "fail": "red fail", "uncertain": "amber uncertain"}
    verdicts = ", ".join(names[k] for k in names if k in used)
    ax.set_title(title or "illuminance on the wall"
                 + (f" — test points: {verdicts}" if verdicts else ""), fontsize=10)
    _caption(fig, caption)
    _freeze_layout(fig)
    place_labels(ax, labels, halo=halo)
    return _save(fig, path, dpi, caption)
