"""One plot per road approach: the sensors on the road plan, and illuminance against
distance (``road_<approach>.png`` of ``lightsim road``).

Left panel: the road plan (metres; the vehicle at the origin heading up the page), lane
lines, the lamps, and every sensor coloured by its illuminance (log scale), with the 5, 3
and 1 lx reach of each edge marked and the stretches where the glare sensor exceeds the
limit drawn in red. Right panel: illuminance (lx, log scale) of the right edge, left edge
and glare sensor against distance along the approach, with their interval bands where the
run stored its interleave sets, the reach levels and the glare limit.

==================  =====  =========================================================
name                unit   meaning
==================  =====  =========================================================
``curves``          lx     the approach's three :class:`SensorCurve` (right edge, left
                           edge, glare)
``lane_width``      m      lane width (for the lane lines)
``glare_limit``     lx     the glare limit drawn
``DPI``             –      110
==================  =====  =========================================================
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lightsim.io.atomic import atomic_path
from lightsim.io.caption import add_caption, png_metadata
from lightsim.render.road_course import (
    EDGE_LEVELS_LUX,
    LampPair,
    SensorCurve,
    approach_by_name,
    crossing_distance,
)

__all__ = ["plot_approach"]

DPI = 110
COLOURS = {"right_edge": "tab:blue", "left_edge": "tab:green", "glare": "tab:red"}
LABELS = {"right_edge": "right edge (0.25 m)", "left_edge": "left edge (0.25 m)",
          "glare": "glare (1.1 m, oncoming lane)"}


def plot_approach(path: Path, curves: Sequence[SensorCurve], lamps: LampPair,
                  lane_width: float, glare_limit: float, confidence: float = 0.95,
                  caption: str | None = None) -> Path:
    """Draw one approach (see the module docstring) to ``path`` atomically, with the
    run's ``caption`` (:class:`lightsim.io.plots.PlotCaption` text) under it and in the
    PNG's metadata."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    name = curves[0].approach
    ap = approach_by_name(name, lane_width)
    fig, (ax_plan, ax_e) = plt.subplots(1, 2, figsize=(12, 6.5),
                                        gridspec_kw={"width_ratios": [1, 1.4]})
    s = curves[0].s_m
    # lane lines: right edge, centre line, left edge (right-hand traffic offsets)
    sign = 1.0 if lamps.traffic == "right" else -1.0
    for off, style in ((0.5, "-"), (-0.5, "--"), (-1.5, "-")):
        x, z, _, _ = ap.point(s, sign * off * lane_width)
        ax_plan.plot(x, z, color="0.4", lw=0.8, ls=style)
    vals = np.concatenate([np.nan_to_num(c.lux, nan=0.0) for c in curves])
    top = max(float(vals.max()), 1e-3) if vals.size else 1.0
    norm = LogNorm(vmin=max(top * 1e-4, 1e-3), vmax=top)
    sc = None
    for c in curves:
        e = np.nan_to_num(c.lux, nan=0.0)
        sc = ax_plan.scatter(c.x_m, c.z_m, c=np.clip(e, norm.vmin, None), s=4, cmap="inferno",
                             norm=norm, marker="s" if c.sensor == "glare" else "o")
        if c.sensor == "glare":
            over = e > glare_limit
            ax_plan.scatter(c.x_m[over], c.z_m[over], s=10, facecolors="none",
                            edgecolors="red", linewidths=0.6)
            continue
        for lv, mk in zip(EDGE_LEVELS_LUX, ("o", "s", "^"), strict=True):
            d = crossing_distance(c.s_m, c.lux, lv)["distance_m"]
            if d is not None:
                i = int(np.argmin(np.abs(c.s_m - d)))
                ax_plan.plot(c.x_m[i], c.z_m[i], marker=mk, color=COLOURS[c.sensor], ms=7,
                             mfc="none")
                ax_plan.annotate(f"{lv:g} lx {d:.0f} m", (c.x_m[i], c.z_m[i]), fontsize=7,
                                 xytext=(4, 2), textcoords="offset points")
    for x in lamps.lamp_x().values():
        ax_plan.plot(x, 0.0, "k^", ms=6)
    if sc is not None:
        fig.colorbar(sc, ax=ax_plan, label="illuminance (lx)", shrink=0.8)
    ax_plan.set_xlabel("lateral position x (m, right +)")
    ax_plan.set_ylabel("ahead z (m)")
    if ap.kind == "straight":  # a thin strip at equal scale: widen the lateral axis
        ax_plan.set_xlim(-4.0 * lane_width, 4.0 * lane_width)
    else:
        ax_plan.set_aspect("equal", adjustable="datalim")
    ax_plan.set_title(f"{name}: road plan, lamps {lamps.mount_height_m:g} m high")
    for c in curves:
        e = c.lux
        ax_e.semilogy(c.s_m, np.where(e > 0, e, np.nan), color=COLOURS[c.sensor],
                      label=LABELS[c.sensor], lw=1.2)
        if c.lux_lo is not None:
            ax_e.fill_between(c.s_m, np.maximum(c.lux_lo, 1e-6), c.lux_hi,
                              color=COLOURS[c.sensor], alpha=0.2, lw=0)
    for lv in EDGE_LEVELS_LUX:
        ax_e.axhline(lv, color="0.5", lw=0.6, ls=":")
        ax_e.text(s[-1], lv, f" {lv:g} lx", fontsize=7, va="center")
    ax_e.axhline(glare_limit, color="red", lw=0.8, ls="--", label=f"glare limit "
                 f"{glare_limit:g} lx")
    band = f"; bands: {confidence:.0%} intervals" if curves[0].lux_lo is not None else ""
    ax_e.set_title(f"illuminance along the approach{band}")
    ax_e.set_xlabel("distance along the road (m)")
    ax_e.set_ylabel("illuminance (lx)")
    ax_e.set_ylim(max(top * 1e-4, 1e-3), top * 2)
    ax_e.grid(True, which="both", alpha=0.3)
    ax_e.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    add_caption(fig, caption)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=DPI, metadata=png_metadata(caption))
    plt.close(fig)
    return path
