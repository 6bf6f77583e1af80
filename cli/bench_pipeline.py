"""``lightsim bench pipeline``: simulate's photons/s against bench tracer's, same run."""

from __future__ import annotations

import click

from lightsim.errors import InputError
from lightsim.luminaires.headlight import example_headlight
from lightsim.simulate import SimulateOptions, load
from lightsim.validation.bench.pipeline import bench_pipeline, load_average
from lightsim.validation.bench.table import print_table, write_json
from lightsim.validation.scenes.analytic import paraboloid_case


@click.command("pipeline")
@click.argument("scene_file", required=False, type=click.Path(dir_okay=False))
@click.option("--paraboloid", is_flag=True,
              help="The analytic paraboloid (point source at the focus) instead of a file.")
@click.option("--photons", type=int, default=1_000_000, show_default=True)
@click.option("--repeats", type=int, default=3, show_default=True)
@click.option("--threads", type=int, help="Ray-casting and numba threads (default: all cores).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(scene_file: str | None, paraboloid: bool, photons: int, repeats: int,
            threads: int | None, json_path: str | None) -> None:
    """Whole `simulate` runs vs the bare tracer on SCENE_FILE (default: the shipped
    headlight), alternated REPEATS times; the ratio is the pipeline's efficiency (the share
    of a run spent tracing)."""
    if photons < 1 or repeats < 1:
        raise InputError(f"--photons and --repeats must be at least 1, got {photons}, "
                         f"{repeats}")
    if paraboloid:
        name, scene = "analytic paraboloid", paraboloid_case().scene
        config = SimulateOptions(scene_path=name).run_config()
    else:
        opts = SimulateOptions(scene_path=scene_file or str(example_headlight()))
        name, scene, config = opts.scene_path, load(opts), opts.run_config()
    before = load_average()
    rows = bench_pipeline(scene, config, photons=photons, repeats=repeats, threads=threads)
    title = (f"pipeline: {name} ({scene.n_triangles} triangles), load average "
             f"{before} before, {load_average()} after")
    print_table(title, rows)
    if json_path:
        write_json(json_path, "pipeline", rows, {"scene": name, "load_before": before,
                                                 "triangles": scene.n_triangles})
