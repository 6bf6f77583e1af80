"""``lightsim bench filter``: frames/s of the O(1) box filter against in-run baselines.

Options (user documentation)
----------------------------
================  ======  ==========  ===================================================
option            unit    default     meaning
================  ======  ==========  ===================================================
``--width``       pixels  640         image width
``--height``      pixels  480         image height
``--sizes``       pixels  3,4,5,6     comma-separated window sides n
``--repeats``     –       50          timed calls per (method, n); medians are reported
``--channels``    –       1           image channels
``--json FILE``   –       none        also write the rows (and a summary) as JSON
================  ======  ==========  ===================================================
"""

from __future__ import annotations

import click

from lightsim.errors import InputError
from lightsim.validation.bench.filter import METHODS, run
from lightsim.validation.bench.table import print_table, write_json


def _sizes(text: str) -> list[int]:
    try:
        sizes = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise InputError(f"--sizes must be comma-separated integers, got {text!r}") from None
    if not sizes or any(not 1 <= n <= 64 for n in sizes):
        raise InputError(f"--sizes must be window sides 1…64, got {text!r}")
    return sizes


@click.command("filter")
@click.option("--width", type=click.IntRange(1), default=640, show_default=True,
              help="Image width (pixels).")
@click.option("--height", type=click.IntRange(1), default=480, show_default=True,
              help="Image height (pixels).")
@click.option("--sizes", default="3,4,5,6", show_default=True,
              help="Comma-separated window sides n (pixels).")
@click.option("--repeats", type=click.IntRange(1), default=50, show_default=True,
              help="Timed calls per method and size (the median is reported).")
@click.option("--channels", type=click.IntRange(1, 16), default=1, show_default=True,
              help="Image channels.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Also write the rows as JSON to FILE.")
def command(width: int, height: int, sizes: str, repeats: int, channels: int,
            json_path: str | None) -> None:
    """Box-filter frames/s (paper 4.1): O(1) filter vs naive O(n²) and scipy."""
    rows, summary = run(width=width, height=height, sizes=_sizes(sizes), repeats=repeats,
                        channels=channels)
    print_table(f"Box filter, {width}×{height}×{channels} float32 "
                f"(par: {summary['threads']} bands)", rows,
                ["method", "n", "ms_median", "ms_best", "fps", "vs_scipy", "vs_naive"])
    load = summary.get("load_average_1min")
    if load is not None:
        click.echo(f"load average at start: {load:.2f} on {summary['threads']} CPUs")
    for name in METHODS[:3]:
        s = summary[name]
        click.echo(f"{name}: slowest/fastest n = {s['size_spread']:.2f} median, "
                   f"{s['size_spread_best']:.2f} best (target ≤ 1.20); worst "
                   f"{s['worst_fps']:.0f} frames/s median, {s['worst_fps_best']:.0f} best")
    if json_path:
        write_json(json_path, "filter", rows, meta=summary)
        click.echo(f"wrote {json_path}")
