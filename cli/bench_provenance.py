"""``lightsim bench provenance``: time and memory of a run with and without path
signatures, in one run."""

from __future__ import annotations

import click

from lightsim.validation.bench.provenance import MEMORY_X, TIME_X, bench_provenance
from lightsim.validation.bench.table import print_table, write_json


@click.command("provenance")
@click.option("--photons", type=click.IntRange(1000, 10**9), default=1_000_000,
              show_default=True, help="Photons per run.")
@click.option("--regulation", "ruleset", default="r112-b-passing", show_default=True,
              help="Rule set whose points are split.")
@click.option("--repeats", type=click.IntRange(1, 20), default=1, show_default=True,
              help="Timed runs per variant (median reported).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(photons: int, ruleset: str, repeats: int, json_path: str | None) -> None:
    """The shipped low beam simulated without and with --provenance: seconds and peak
    traced memory, as ratios to the run without."""
    rows = bench_provenance(photons, ruleset, repeats=repeats)
    print_table(f"--provenance cost, lowbeam.glb, {ruleset} (targets ≤ {TIME_X:g}× time, "
                f"≤ {MEMORY_X:g}× memory)", rows)
    if json_path:
        write_json(json_path, "provenance", rows, {"photons": photons, "ruleset": ruleset,
                                                   "repeats": repeats})
