"""Plot of the estimated error against run time and photons (``error_vs_time.png``).

The left panel shows the relative error estimated from the interleave sets against
seconds, the right one against photons with a 1/√N reference through the last point —
noise-limited estimates follow it — each with its two parts, noise and blur, where the
log has them. A log with no positive, finite error (nothing lit, or an error of exactly
zero) gives an image that says so instead of a plot.
"""

from __future__ import annotations

import numbers
import os
import textwrap
from collections.abc import Sequence
from typing import Any

import numpy as np

from lightsim.io.atomic import atomic_path
from lightsim.io.caption import png_metadata


def _loggable(*values: object) -> bool:
    """All values are finite numbers > 0 (what a log-log axis can show)."""
    return all(isinstance(v, numbers.Real) and not isinstance(v, bool) and np.isfinite(v)
               and v > 0 for v in values)


def error_vs_time_plot(path: str | os.PathLike, log: Sequence[dict[str, Any]],
                       title: str | None = None, caption: str | None = None) -> None:
    """Write the error-vs-time plot from ``summary.json["error_vs_time"]`` entries;
    ``caption`` (the run's, :class:`lightsim.io.plots.PlotCaption` text) goes under it."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    pts = [(e["seconds"], e["photons"], e["rel_error"]) for e in log
           if _loggable(e.get("rel_error"), e.get("photons"), e.get("seconds"))]
    fig = Figure(figsize=(9.0, 3.6))
    ax1, ax2 = fig.subplots(1, 2)
    if pts:
        t, n, err = (np.asarray(x, dtype=np.float64) for x in zip(*pts, strict=True))
        ax1.loglog(t, err * 100, "o-", ms=3, label="estimated error")
        ax2.loglog(n, err * 100, "o-", ms=3, label="estimated error")
        # its two parts, where the log has them (noise from the sets, blur from the windows)
        for key, style, label in (("rel_noise", ":", "noise"), ("rel_bias", "-.", "blur")):
            part = [(e["seconds"], e["photons"], e[key]) for e in log
                    if _loggable(e.get(key), e.get("photons"), e.get("seconds"))
                    and _loggable(e.get("rel_error"))]
            if part:
                tp, n_p, vp = (np.asarray(x, dtype=np.float64) for x in zip(*part, strict=True))
                ax1.loglog(tp, vp * 100, style, lw=1, label=label)
                ax2.loglog(n_p, vp * 100, style, lw=1, label=label)
        ref = err[-1] * np.sqrt(n[-1] / n)
        ax2.loglog(n, ref * 100, "--", color="grey", label="∝ 1/√N")
        ax1.legend(loc="upper right", fontsize=8)
        ax2.legend(loc="upper right", fontsize=8)
    else:
        for ax in (ax1, ax2):
            ax.text(0.5, 0.5, "no error estimate to plot\n(nothing lit, or no error above 0)",
                    ha="center", va="center", transform=ax.transAxes)
            ax.set_xscale("log")
            ax.set_yscale("log")
    ax1.set_xlabel("run time (s)")
    ax2.set_xlabel("photons emitted")
    from matplotlib.ticker import EngFormatter, FuncFormatter, LogLocator, NullFormatter

    plain = FuncFormatter(lambda x, _: f"{x:g}")
    for ax in (ax1, ax2):
        ax.set_ylabel("relative error, lit region (%)")
        ax.grid(True, which="both", alpha=0.3)
        for axis in (ax.xaxis, ax.yaxis):  # 1-2-5 labels: short runs span less than a decade
            axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(NullFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax1.xaxis.set_major_formatter(plain)
    ax2.xaxis.set_major_formatter(EngFormatter())
    if title:
        fig.suptitle(title)
    # fixed margins for this fixed size and these labels: tight_layout would draw the
    # figure once more only to measure them
    bottom = 0.14
    if caption:  # wrapped to the figure's width, with room made below the axes
        lines = [w for line in caption.splitlines()
                 for w in textwrap.wrap(line, int(fig.get_figwidth() * 17),
                                        subsequent_indent="  ")]
        extra = 0.06 + 0.14 * len(lines)
        height = fig.get_figheight()
        fig.set_figheight(height + extra)
        fig.text(0.01, 0.01, "\n".join(lines), fontsize=7, color="0.3", ha="left",
                 va="bottom")
        bottom = (0.14 * height + extra) / (height + extra)
    fig.subplots_adjust(left=0.062, right=0.988, bottom=bottom,
                        top=0.86 if title else 0.955, wspace=0.19)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=100, metadata=png_metadata(caption))
