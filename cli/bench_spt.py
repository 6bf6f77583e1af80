"""``lightsim bench spt``: caustic yield, plain vs Selective Photon Tracing (Table 4)."""

from __future__ import annotations

import click

from lightsim.validation.bench.spt import bench_spt
from lightsim.validation.bench.table import print_table, write_json
from lightsim.validation.scenes import paper


@click.command("spt")
@click.option("--scenes", default="ring,egg,glass", show_default=True)
@click.option("--photons", type=int, default=400_000, show_default=True)
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(scenes: str, photons: int, json_path: str | None) -> None:
    """Percentage of photon paths that contribute to a caustic, plain vs SPT."""
    names = [s.strip() for s in scenes.split(",") if s.strip()]
    rows = bench_spt({n: paper.build(n, (128, 128)) for n in names}, photons=photons)
    print_table("Table 4: caustic yield (plain sampling is the in-run baseline)", rows)
    if json_path:
        write_json(json_path, "spt", rows)
