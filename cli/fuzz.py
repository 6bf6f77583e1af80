"""``lightsim fuzz N``: run the input-fuzzing study (:mod:`lightsim.validation.fuzz`).

Prints one line per failing case and a table of verdicts by input kind (cases, ran =
clean exit 0, rejected = clean exit 2, then each broken-promise class); exits with code 1
if any case broke the input-error promise (2 for bad options, as every command).
"""

from __future__ import annotations

import click

from lightsim.cli.main import main
from lightsim.io.summary import write_json
from lightsim.validation.fuzz import KINDS, run_fuzz


@click.command()
@click.argument("n", type=click.IntRange(min=1))
@click.option("--seed", type=int, default=1, show_default=True, help="Corpus seed.")
@click.option("--kind", "kinds", multiple=True, type=click.Choice(list(KINDS)),
              help="Input kinds (repeatable; default all, taken in turn).")
@click.option("--photons", type=click.IntRange(min=1), default=20_000, show_default=True,
              help="Photons per simulated case.")
@click.option("--resolution", default="64x32", show_default=True, help="Wall pixels WxH.")
@click.option("--timeout", "timeout_s", type=click.FloatRange(min=1), default=180.0,
              show_default=True, help="Time limit per case (s).")
@click.option("--headlight", is_flag=True, help="Also mutate the shipped headlight (slow).")
@click.option("--keep", "keep_dir", type=click.Path(file_okay=False),
              help="Keep every case's input and output in this folder.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False),
              help="Write every case with its verdict and stderr as JSON.")
@click.option("--verbose", "-v", is_flag=True, help="A line for every case, not only failures.")
def fuzz(n: int, seed: int, kinds: tuple[str, ...], photons: int, resolution: str,
         timeout_s: float, headlight: bool, keep_dir: str | None, json_path: str | None,
         verbose: bool) -> None:
    """Run N mutated inputs of every kind lightsim reads through the command line.

    Kinds: GLB/glTF, IES, LDT, photos, STEP, IGES, material maps (TOML), TM-25 and Zemax
    ray files, --points strings, the view's state.json and its WebSocket messages.
    """

    def show(r) -> None:
        if verbose or not r.ok:
            click.echo(r.describe())

    report = run_fuzz(n, seed, kinds or KINDS, command=main, photons=photons,
                      resolution=resolution, timeout_s=timeout_s, headlight=headlight,
                      workdir=keep_dir, progress=show)
    for line in report.table():
        click.echo(line)
    if json_path:
        write_json(json_path, report.to_json())
    if report.failures:
        raise SystemExit(1)
