"""``lightsim road RUN_DIR``: visibility reach and glare of a finished run on straight and
curved roads (:mod:`lightsim.road_evaluation`)."""

from __future__ import annotations

from pathlib import Path

import click

from lightsim.options import click_options
from lightsim.road_evaluation import (
    DEFAULT_APPROACHES,
    ROAD_FILE,
    SCORE_NOTE,
    RoadSettings,
    evaluate_road,
    load_far_field,
    parse_approaches,
    reach_lines,
    write_road,
)


@click.command()
@click.argument("run_dir", type=click.Path(file_okay=False))
@click.option("--approaches", default=",".join(DEFAULT_APPROACHES), show_default=True,
              help="Approaches, comma-separated: straight, left-R, right-R (R the curve "
              "radius in m, > 0).")
@click.option("--left-run", type=click.Path(file_okay=False),
              help="A second run for the left lamp (default: the same far field, mirrored "
              "position).")
@click.option("--no-plots", is_flag=True, help="Only road.json, no road_<approach>.png.")
@click_options(RoadSettings)
def road(run_dir: str, approaches: str, left_run: str | None, no_plots: bool,
         **kwargs) -> None:
    """Reach (5, 3, 1 lx at the road edges) and glare (oncoming driver's eye) of RUN_DIR's
    lamp pair on a straight road and 150 m / 250 m curves; writes road.json and one plot per
    approach into RUN_DIR."""
    settings = RoadSettings(approaches=parse_approaches(approaches), **kwargs)
    settings.approach_list()  # a bad radius fails before reading anything
    far = load_far_field(run_dir)
    left = load_far_field(left_run) if left_run else None
    ev = evaluate_road(far, settings, left)  # every check before the first file
    written = write_road(Path(run_dir), ev, plots=not no_plots)
    if ev.n_sets > 1:
        click.echo(f"intervals: {settings.confidence:.0%}, from {ev.n_sets} interleave sets")
    else:
        click.echo("no intervals: the run has no per-set maps (simulate with --road to "
                   "store them)")
    for line in reach_lines(ev.to_dict()):
        click.echo(line)
    if settings.sensitivity:
        click.echo("sensitivity (re-projected, 0 photons traced): see "
                   f"{ROAD_FILE} 'sensitivity'")
    click.echo(SCORE_NOTE)
    click.echo(f"evaluated in {ev.seconds:.2f} s; wrote " + ", ".join(str(p) for p in written))
