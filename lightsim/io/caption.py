"""Plot captions: the lines under a plot and the same text in the PNG's metadata.

A plot handed to a colleague says what it shows: the lamp, the run's seed, photons and
error figure, the rule set and its version, lightsim's version
(:class:`lightsim.io.plots.PlotCaption` builds that text for a run). This module puts a
caption text on a figure and into the PNG file as its ``Description`` text chunk (PNG
``tEXt``, read back by :func:`read_caption`), so that a script or a test can read what a
plot is of without looking at it.

=================  =====  ========  ===================================================
parameter          unit   default   meaning
=================  =====  ========  ===================================================
``text``           –      –         caption, one or more lines
``chars_per_in``   1/in   17        characters of 7 pt per inch of figure width
``fontsize``       pt     7         caption size
=================  =====  ========  ===================================================
"""

from __future__ import annotations

import os
import textwrap
from typing import Any

from PIL import Image

import lightsim

CAPTION_KEY = "Description"
CHARS_PER_IN = 17.0
FONTSIZE = 7.0
LINE_IN = 0.14  # height of a caption line (in) at FONTSIZE


def caption_lines(text: str, width_in: float) -> list[str]:
    """``text`` wrapped to a figure ``width_in`` inches wide (continuations indented)."""
    width = max(int(width_in * CHARS_PER_IN), 40)
    return [w for line in text.splitlines()
            for w in (textwrap.wrap(line, width, subsequent_indent="  ") or [""])]


def caption_height_in(text: str, width_in: float) -> float:
    """Height (in) the caption takes under a figure ``width_in`` inches wide."""
    return 0.06 + LINE_IN * len(caption_lines(text, width_in))


def add_caption(fig: Any, text: str | None) -> None:
    """Write ``text`` at the bottom of ``fig`` and keep the axes clear of it.

    A constrained-layout figure gets the room from its layout engine; any other figure
    is laid out again (``tight_layout``) above the caption. Call it when the axes are
    final. Nothing happens for an empty ``text``.
    """
    if not text:
        return
    lines = caption_lines(text, fig.get_figwidth())
    frac = caption_height_in(text, fig.get_figwidth()) / fig.get_figheight()
    engine = fig.get_layout_engine()
    if engine is not None and type(engine).__name__ == "ConstrainedLayoutEngine":
        engine.set(rect=(0.0, frac, 1.0, 1.0 - 2.0 * frac))
    else:
        fig.tight_layout(rect=(0.0, frac, 1.0, 1.0))
    fig.text(0.01, 0.008, "\n".join(lines), fontsize=FONTSIZE, color="0.3", ha="left",
             va="bottom")


def png_metadata(text: str | None) -> dict[str, str]:
    """``savefig(metadata=…)`` of a captioned PNG: the caption as ``Description``."""
    meta = {"Software": f"lightsim {lightsim.__version__}"}
    if text:
        meta[CAPTION_KEY] = text
    return meta


def read_caption(path: str | os.PathLike) -> str | None:
    """The caption stored in a PNG written with :func:`png_metadata` (None without)."""
    with Image.open(path) as img:
        return getattr(img, "text", {}).get(CAPTION_KEY)


def run_text(lamp: str, what: str, extra: str = "") -> str:
    """A caption for a plot that is not of a single run (a study, a photo pair):
    ``lamp`` (or the inputs), ``what`` the plot is of, ``extra`` (seeds, photons), and
    lightsim's version."""
    first = " · ".join(x for x in (lamp, what) if x)
    second = " · ".join(x for x in (extra, f"lightsim {lightsim.__version__}") if x)
    return f"{first}\n{second}"
