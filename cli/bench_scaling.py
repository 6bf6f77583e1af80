"""``lightsim bench scaling``: frames/s for 1 and 2 Ray workers (paper Table 6)."""

from __future__ import annotations

import click

from lightsim.engine.config import RunConfig
from lightsim.luminaires.headlight import example_headlight
from lightsim.options import click_option, lookup
from lightsim.scene import SceneSettings, load_scene
from lightsim.simulate import SimulateOptions
from lightsim.validation.bench.scaling import bench_scaling
from lightsim.validation.bench.table import print_table, write_json


@click.command("scaling")
@click.argument("scene_file", required=False, type=click.Path(dir_okay=False))
@click.option("--workers", default="0,1,2", show_default=True,
              help="Comma-separated worker counts (0 = in-process baseline).")
@click_option(lookup(RunConfig, "frame_photons"), default=50_000)
@click.option("--accumulate", type=int, default=400_000, show_default=True)
@click.option("--frames", type=int, default=5, show_default=True)
@click_option(lookup(SimulateOptions, "resolution"))
@click.option("--address", help="Ray cluster address (default: a local Ray runtime).")
@click.option("--threads-per-worker", type=int, default=1, show_default=True,
              help="Threads of each worker (0 = all cores shared among the workers).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(scene_file: str | None, workers: str, frame_photons: int, accumulate: int,
            frames: int, resolution: tuple[int, int], address: str | None, threads_per_worker: int,
            json_path: str | None) -> None:
    """Interaction and walkthrough frames/s per worker count, with bytes per frame."""
    w, h = resolution
    path = scene_file or str(example_headlight())
    scene = load_scene(path, SceneSettings(resolution=(w, h)))
    counts = tuple(int(x) for x in workers.split(","))
    rows = bench_scaling(scene, counts, frame_photons=frame_photons, accumulate=accumulate,
                         frames=frames, address=address, threads=threads_per_worker or None)
    print_table(f"scaling: {path} at {w}x{h}", rows)
    if json_path:
        write_json(json_path, "scaling", rows, {"scene": path, "resolution": [w, h]})
