"""``lightsim bench road RUN_DIR``: the road evaluation's time against the run's load time."""

from __future__ import annotations

import click

from lightsim.validation.bench.road import TARGET_S, bench_road
from lightsim.validation.bench.table import print_table, write_json


@click.command("road")
@click.argument("run_dir", type=click.Path(file_okay=False, exists=True))
@click.option("--repeats", type=click.IntRange(1, 50), default=3, show_default=True,
              help="Timed repetitions (median reported).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(run_dir: str, repeats: int, json_path: str | None) -> None:
    """Load, evaluate (5 approaches + sensitivity, re-projected) and plot RUN_DIR's road
    evaluation; ratios against the run's own load time."""
    rows = bench_road(run_dir, repeats)
    print_table(f"road evaluation of {run_dir} (target ≤ {TARGET_S:g} s)", rows)
    if json_path:
        write_json(json_path, "road", rows, {"run_dir": run_dir, "repeats": repeats})
