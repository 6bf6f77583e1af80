"""``lightsim bench plan``: what each stage left out by the scene plan saves."""

from __future__ import annotations

import click

from lightsim.engine.config import RunConfig
from lightsim.luminaires.headlight import example_headlight
from lightsim.options import click_option, lookup
from lightsim.scene import load_scene
from lightsim.validation.bench.plan import bench_plan
from lightsim.validation.bench.table import print_table, write_json


@click.command("plan")
@click.argument("scene_file", required=False, type=click.Path(dir_okay=False))
@click_option(lookup(RunConfig, "frame_photons"), default=100_000)
@click.option("--frames", type=int, default=3, show_default=True)
@click.option("--repeats", type=int, default=3, show_default=True,
              help="Planned and forced runs alternate this many times; the best counts.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(scene_file: str | None, frame_photons: int, frames: int, repeats: int,
            json_path: str | None) -> None:
    """Seconds per frame with the plan's choice vs the stage forced on (same run)."""
    path = scene_file or str(example_headlight())
    rows = bench_plan(load_scene(path), frame_photons=frame_photons, frames=frames,
                      repeats=repeats)
    print_table(f"plan: {path} (saving = forced ÷ planned seconds per frame)", rows)
    if json_path:
        write_json(json_path, "plan", rows, {"scene": path})
