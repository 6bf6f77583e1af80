"""``lightsim bench verdicts``: time and photons to all-decided, uniform against guided."""

from __future__ import annotations

import click

from lightsim.options import parse_pair
from lightsim.validation.bench.table import print_table, write_json
from lightsim.validation.bench.verdicts import COLUMNS, LAMPS, TARGET_S, bench_verdicts


@click.command("verdicts")
@click.option("--lamp", "lamps", multiple=True, type=click.Choice(list(LAMPS)),
              help="Lamps to run (repeatable; default every one).")
@click.option("--photons", "-n", type=click.IntRange(1), default=48_000_000,
              show_default=True, help="Each run's photon cap.")
@click.option("--seed", type=int, default=7, show_default=True,
              help="Photon seed (the same for the uniform and the guided run).")
@click.option("--resolution", default="320x128", show_default=True, help="Wall pixels WxH.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(lamps: tuple[str, ...], photons: int, seed: int, resolution: str,
            json_path: str | None) -> None:
    """Simulate each lamp with --until decided, uniform and with --guide points: the
    seconds and photons until every verdict is decided; ratios against the uniform run."""
    res = parse_pair(resolution, "--resolution", int)
    rows = bench_verdicts(lamps, cap_photons=photons, seed=seed, resolution=res,
                          note=lambda s: click.echo(f"  {s}", err=True))
    print_table(f"verdicts decided: uniform vs guided emission (README lamp target ≤ "
                f"{TARGET_S:g} s)", rows, COLUMNS)
    if json_path:
        write_json(json_path, "verdicts", rows, {"photons": photons, "seed": seed,
                                                 "resolution": list(res)})
