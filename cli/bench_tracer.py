"""``lightsim bench tracer``: photons/s and rays/s against raw embree in the same scene."""

from __future__ import annotations

import click

from lightsim.luminaires.headlight import example_headlight
from lightsim.scene import load_scene
from lightsim.validation.bench.table import print_table, write_json
from lightsim.validation.bench.tracer import bench_tracer, stage_rows
from lightsim.validation.bench.tracer_aim import bench_aim
from lightsim.validation.scenes import analytic as cases


@click.command("tracer")
@click.argument("scene_file", required=False, type=click.Path(dir_okay=False))
@click.option("--photons", type=int, default=500_000, show_default=True)
@click.option("--repeats", type=int, default=3, show_default=True)
@click.option("--threads", type=int, help="Ray-casting threads (default: all cores).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
@click.option("--analytic", type=click.Choice(["paraboloid", "slab", "shield"]),
              help="Bench an analytic validation scene instead of SCENE_FILE (the "
                   "paraboloid: point source at the focus of a mirror).")
@click.option("--aim", is_flag=True,
              help="Time aiming the lamp in a session instead: embree rebuilt vs the wall "
                   "moved (Session.update(wall_transform=…)).")
@click.option("--stages", is_flag=True,
              help="Time the tracer's stages instead (emission, embree casts, bounce "
                   "kernel, the rest) for --threads (default here: 1).")
def command(scene_file: str | None, photons: int, repeats: int, threads: int | None,
            json_path: str | None, analytic: str | None, aim: bool, stages: bool) -> None:
    """Photon tracing vs raw embree on SCENE_FILE (default: the shipped headlight)."""
    if analytic is not None:
        if scene_file is not None:
            raise click.UsageError("give either SCENE_FILE or --analytic, not both")
        path = f"analytic {analytic}"
        scene = getattr(cases, f"{analytic}_case")().scene
    else:
        path = scene_file or str(example_headlight())
        scene = load_scene(path)
    if aim:
        rows = bench_aim(scene, repeats=repeats)
        print_table(f"aim: {path} ({scene.n_triangles} triangles)", rows)
        if json_path:
            write_json(json_path, "tracer-aim", rows, {"scene": path,
                                                       "triangles": scene.n_triangles})
        return
    if stages:
        rows = stage_rows(scene, photons=photons, threads=threads or 1, repeats=repeats)
        print_table(f"tracer stages: {path} ({scene.n_triangles} triangles)", rows)
        if json_path:
            write_json(json_path, "tracer-stages", rows, {"scene": path,
                                                          "triangles": scene.n_triangles})
        return
    rows = bench_tracer(scene, photons=photons, repeats=repeats, threads=threads)
    print_table(f"tracer: {path} ({scene.n_triangles} triangles)", rows)
    if json_path:
        write_json(json_path, "tracer", rows, {"scene": path, "triangles": scene.n_triangles})
