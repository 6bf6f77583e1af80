"""``lightsim screen-target OUT.pdf|OUT.png``: print the marker board for the screen.

The board, its layout and the detection are in :mod:`lightsim.validation.screen_target`.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click

from lightsim.validation.screen_target import DEFAULT_LAYOUT, write_target


@click.command("screen-target")
@click.argument("out", metavar="OUT.(pdf|png)", type=click.Path(path_type=Path, dir_okay=False))
@click.option("--distance", type=float, default=25.0, show_default=True, metavar="M",
              help="Lamp → screen distance the markers are sized and placed for (m).")
@click.option("--px-per-m", type=float, default=100.0, show_default=True,
              help="PNG resolution (pixels per metre of screen).")
def screen_target(out: Path, distance: float, px_per_m: float) -> None:
    """Write a marker board (ArUco DICT_4X4_50) and OUT's .layout.json for `compare`."""
    layout = replace(DEFAULT_LAYOUT, distance_m=distance)
    paths = write_target(out, layout, px_per_m)
    click.echo(f"wrote {paths[0]} and {paths[1]}: {len(layout.markers)} markers, edge "
               f"{layout.size_deg:g}° = {100 * layout.size_m():.1f} cm at {distance:g} m")
    for i, h, v in layout.markers:
        click.echo(f"  marker {i}: H {h:+.2f}°, V {v:+.2f}°")
