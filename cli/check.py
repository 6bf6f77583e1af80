"""``lightsim check SOURCE --regulation ID``: a run folder or a photometric file against a
rule set with its measuring conditions (re-aim, aim, test distance, beam type)."""

from __future__ import annotations

import sys

import click
from rich.console import Console

from lightsim.io.summary import write_json
from lightsim.luminaires.regulations.lamp_check import check_lamp, lamp_source, verdict_counts
from lightsim.luminaires.regulations.reaim import format_reaim_table


@click.command()
@click.argument("source", type=click.Path())
@click.option("--regulation", required=True,
              help="Rule set id or file, e.g. fmvss-lb1v-lower (see `lightsim report "
              "--list-rulesets`).")
@click.option("--beam", type=click.Choice(["lower", "upper"]),
              help="The lamp's beam [default: lower when a cut-off is found, else upper].")
@click.option("--traffic", type=click.Choice(["right", "left"]), default="right",
              show_default=True, help="Traffic side.")
@click.option("--confidence", type=float, default=0.95, show_default=True,
              help="Two-sided level of the intervals.")
@click.option("--aperture", type=float, default=0.0, show_default=True,
              help="Angular diameter of the photometer's aperture (deg); every reading is "
              "the mean over it. 0: point values.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False),
              help="Also write the verdicts as JSON.")
def check(source: str, regulation: str, beam: str | None, traffic: str, confidence: float,
          aperture: float, json_path: str | None) -> None:
    """Verdicts of SOURCE (a run folder, or an .ies/.ldt file) against a rule set; points
    that pass only after the permitted re-aim are named so."""
    res = check_lamp(lamp_source(source), regulation, beam, traffic, confidence, aperture)
    console = Console(width=None if sys.stdout.isatty() else 160)
    console.print(format_reaim_table(res.results, f"{res.ruleset.title} — {source}",
                                     res.unevaluated))
    click.echo(f"beam: {res.beam} ({res.beam_from})")
    for note in res.notes:
        click.echo(note)
    if res.n_sets < 2:
        click.echo("no error estimate: one intensity source (a file, or a run without "
                   "per-set maps)")
    c = verdict_counts(res.results)
    click.echo(f"{c['pass']} pass ({c['after_reaim']} only after re-aim), {c['fail']} fail, "
               f"{c['uncertain']} uncertain")
    if json_path:
        write_json(json_path, res.to_dict())
        click.echo(f"wrote {json_path}")
