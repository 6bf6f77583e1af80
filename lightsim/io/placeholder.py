"""A plot that cannot show anything says so: the placeholder image and the test for it.

Plots of degenerate data (no finite value, nothing above zero, a constant image, too few
points for contours or a log axis) are replaced by an image of the same kind that states
the reason in words, so a run never fails in its last step and the folder still holds
every file it promises. Written through :func:`lightsim.io.atomic.atomic_path`.

=============  =====  =========  ====================================================
parameter      unit   default    meaning
=============  =====  =========  ====================================================
``message``    –      –          the reason, shown in the middle of the image
``title``      –      None       figure title (the plot's usual one)
``figsize``    inch   (8, 5)     figure size
``dpi``        1/in   100        resolution
=============  =====  =========  ====================================================
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from lightsim.io.atomic import atomic_path
from lightsim.io.caption import add_caption, png_metadata

__all__ = ["image_problem", "placeholder_png"]


def image_problem(image: ArrayLike, *, what: str = "illuminance", contours: bool = False
                  ) -> str | None:
    """Why ``image`` cannot be plotted, or None if it can.

    Parameters
    ----------
    image : array_like
        A 2-D map (any unit).
    what : str
        The quantity's name, for the message.
    contours : bool
        The plot draws contours: it also needs at least 2 × 2 pixels and a value range.
    """
    a = np.asarray(image)
    if a.ndim != 2 or a.size == 0:
        return f"no {what} map (shape {a.shape})"
    if not np.issubdtype(a.dtype, np.number):
        return f"{what} map is not numeric"
    finite = np.isfinite(a)
    if not finite.any():
        return f"no finite {what} value"
    vals = a[finite]
    if not np.any(vals > 0):
        return f"no light: {what} is zero everywhere"
    if contours and (min(a.shape) < 2):
        return f"{a.shape[1]} × {a.shape[0]} pixels: too few for contours"
    if contours and float(vals.max()) == float(vals.min()):
        return f"constant {what} ({float(vals.max()):g}): no contours to draw"
    return None


def placeholder_png(path: str | os.PathLike, message: str, *, title: str | None = None,
                    figsize: tuple[float, float] = (8.0, 5.0), dpi: float = 100.0,
                    caption: str | None = None) -> Path:
    """Write an image that says ``message`` instead of a plot (atomically), with the
    run's ``caption`` (:mod:`lightsim.io.caption`) when given."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.set_axis_off()
    ax.text(0.5, 0.5, f"nothing to plot:\n{message}", ha="center", va="center",
            transform=ax.transAxes, fontsize=12, color="0.3", wrap=True)
    if title:
        ax.set_title(title)
    add_caption(fig, caption)
    p = Path(path)
    fmt = p.suffix.lstrip(".").lower() or "png"
    with atomic_path(p, suffix=p.suffix or ".png") as tmp:
        fig.savefig(tmp, format=fmt, dpi=dpi,
                    metadata=png_metadata(caption) if fmt == "png" else None)
    return p
