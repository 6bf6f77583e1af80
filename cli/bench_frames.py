"""``lightsim bench frames``: frames/s vs resolution, interaction and walkthrough (Table 7)."""

from __future__ import annotations

import click

from lightsim.engine.config import RunConfig
from lightsim.options import click_option, lookup
from lightsim.validation.bench.frames import RESOLUTIONS, bench_frames
from lightsim.validation.bench.table import print_table, write_json
from lightsim.validation.scenes import paper


@click.command("frames")
@click.option("--scenes", default="ring,headlight", show_default=True,
              help="Comma-separated: ring, egg, glass, headlight.")
@click_option(lookup(RunConfig, "frame_photons"), default=50_000)  # interaction frames
@click.option("--accumulate", type=int, default=500_000, show_default=True,
              help="Photons accumulated before walkthrough frames.")
@click.option("--frames", type=int, default=3, show_default=True, help="Frames timed per row.")
@click.option("--max-resolution", default="1280x960", show_default=True)
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(scenes: str, frame_photons: int, accumulate: int, frames: int,
            max_resolution: str, json_path: str | None) -> None:
    """Frames per second at 640×480 … 1280×960 in one process (paper Table 7)."""
    wmax = int(max_resolution.lower().split("x")[0])
    res = [r for r in RESOLUTIONS if r[0] <= wmax]
    rows = []
    for name in [s.strip() for s in scenes.split(",") if s.strip()]:
        rows += bench_frames(lambda r, n=name: paper.build(n, r), name, res,
                             frame_photons=frame_photons, accumulate=accumulate, frames=frames)
    print_table("frames/s vs resolution (one process; slowdown vs 640×480 of the same scene)",
                rows)
    if json_path:
        write_json(json_path, "frames", rows)
