"""``lightsim report RESULT_DIR``: regenerate plots and tables from a finished run."""

from __future__ import annotations

import sys
from pathlib import Path

import click
from rich.console import Console

from lightsim import report as rp
from lightsim.errors import InputError
from lightsim.io import plot_worker
from lightsim.io.exr import read_exr
from lightsim.io.summary import read_json, write_json
from lightsim.luminaires import regulations
from lightsim.luminaires.provenance_report import (
    SPOTS_FILE,
    draw_region_spots,
    draw_spots,
    format_breakdown,
    format_region,
    parse_box,
    region_breakdown,
    region_image_name,
    rule_breakdown,
    spots_image_name,
)
from lightsim.luminaires.regulations import check


@click.command()
@click.argument("result_dir", required=False, type=click.Path(file_okay=False))
@click.option("--regulation", help="Re-evaluate this rule set (must match probes.npz).")
@click.option("--confidence", type=float, default=0.95, show_default=True,
              help="Two-sided level of the intervals.")
@click.option("--mount-height", type=float, default=0.65, show_default=True,
              help="Lamp height above the road for the road view (m).")
@click.option("--log/--linear", "log_scale", default=True, show_default=True,
              help="Colour scale of wall_lux.png: logarithmic or linear.")
@click.option("--list-rulesets", is_flag=True, help="List the available rule sets and exit.")
@click.option("--provenance", "provenance_rule", metavar="RULE",
              help="Print where RULE's light comes from (path classes with intervals) of a "
              "run made with simulate --provenance, and draw provenance-RULE.png: the lamp "
              "seen from the screen, coloured by how much of RULE's light left each spot.")
@click.option("--part", metavar="NAME",
              help="With --provenance: only the path classes that meet part NAME.")
@click.option("--provenance-box", "provenance_box", metavar="H0,H1,V0,V1",
              help="Print where the light of a screen region (a box in H/V degrees) comes "
              "from, of a run made with simulate --provenance: its mean illuminance split "
              "by path class with intervals, and draw provenance-box-….png.")
def report(result_dir: str | None, regulation: str | None, confidence: float,
           mount_height: float, log_scale: bool, list_rulesets: bool,
           provenance_rule: str | None, part: str | None,
           provenance_box: str | None) -> None:
    """Rebuild wall_lux.png, isolux.png, road.png, error_vs_time.png and the regulation
    table of RESULT_DIR from its wall_lux.exr, summary.json and probes.npz."""
    console = Console(width=None if sys.stdout.isatty() else 160)
    if part is not None and provenance_rule is None:
        raise InputError("--part goes with --provenance RULE")
    if provenance_box is not None:
        out, summary = _run_folder(result_dir, confidence)
        if not isinstance(summary.get("provenance"), dict):
            raise InputError("this run was made without --provenance: run lightsim simulate "
                             "--provenance --regulation … to break its screen down by path")
        b = region_breakdown(out, parse_box(provenance_box), confidence)
        console.print(format_region(b))
        path = draw_region_spots(out, b, out / region_image_name(b["covered_deg"]))
        click.echo(f"wrote {path}")
        return
    if provenance_rule is not None:
        if result_dir is None:
            raise InputError("missing RESULT_DIR (a folder written by lightsim simulate)")
        out = Path(result_dir)
        summary = read_json(out / "summary.json")
        found = rule_breakdown(summary, provenance_rule, part)
        first = found[0][0] if found else ""
        tables = [t.get("ruleset") for t in check.regulation_tables(summary)]
        first = tables[0] if tables else first
        for rs, b in found:
            console.print(format_breakdown(rs, provenance_rule, b))
        wrote = [draw_spots(out / SPOTS_FILE, rs, provenance_rule,
                            out / spots_image_name(provenance_rule, rs, first), b)
                 for rs, b in found]
        click.echo("wrote " + ", ".join(str(p) for p in wrote))
        return
    if list_rulesets:
        for rs in regulations.list_rulesets():
            click.echo(f"{rs['id']:<20} {rs.get('title', '')}  [{rs.get('path', '')}]")
            if "error" in rs:
                click.echo(f"{'':<20} error: {rs['error']}")
                continue
            click.echo(f"{'':<20} version: {rs.get('version', '')}")
            click.echo(f"{'':<20} source: {rs.get('source', '')}")
        return
    out, summary = _run_folder(result_dir, confidence)
    channels, _ = read_exr(out / "wall_lux.exr")
    if "Y" not in channels:
        raise InputError(f"{out / 'wall_lux.exr'} has no Y (illuminance) channel")
    lux = channels["Y"].astype(float)
    try:
        wall = summary["wall"]
    except (KeyError, TypeError):
        raise InputError(f"{out / 'summary.json'}: no wall frame (not a lightsim result?)"
                         ) from None
    # the plot process (started with the command) draws what it takes while
    # the regulation tables are re-checked here (lightsim/io/plot_worker.py)
    plots = plot_worker.start()
    caption = rp.plot_caption(summary)
    drawn = [plots.draw("error_vs_time", out / "error_vs_time.png",
                        summary.get("error_vs_time", []),
                        caption=None if caption is None else caption.text())]
    try:
        written = _tables_and_plots(out, summary, lux, wall, regulation, confidence,
                                    mount_height, plots, console, log_scale)
        for p in drawn:
            p.result()
    except BaseException:
        plots.settle()  # no plot is cut short in the result folder
        raise
    finally:
        plots.close()
    written = [*written, out / "error_vs_time.png"]
    click.echo(summary["road"]["text"])
    click.echo("wrote " + ", ".join(str(p) for p in written))


def _tables_and_plots(out: Path, summary: dict, lux, wall, regulation: str | None,
                      confidence: float, mount_height: float, plots, console,
                      log_scale: bool = True) -> list[Path]:
    """Re-check every rule set of the run, then the iso-lux and road plots; summary.json
    rewritten with both."""
    results = None
    names: list[str | None] = ([regulation] if regulation else
                               [t.get("ruleset") for t in check.regulation_tables(summary)])
    if not names and (out / check.PROBES_FILE).exists():
        names = [None]
    for name in names:  # every rule set of the run (probes.npz, probes-ID.npz)
        reg = check.recheck_from_probes(out, summary, lux, name, confidence)
        summary[check.regulation_key(reg["ruleset"], summary)] = reg
        results = (results or []) + reg["results"]
        console.print(check.format_regulation(reg))
    if names:
        write_json(out / "summary.json", summary)
    written = rp.engineering_plots(out, lux, wall, results, mount_height, summary=summary,
                                   plots=plots, which=("wall_lux", "isolux", "road"),
                                   log=log_scale)
    write_json(out / "summary.json", summary)  # noise floor and road reach
    return written


def _run_folder(result_dir: str | None, confidence: float) -> tuple[Path, dict]:
    """The run folder and its summary.json, after checking the arguments (one line)."""
    if result_dir is None:
        raise InputError("missing RESULT_DIR (a folder written by lightsim simulate)")
    if not 0 < confidence < 1:
        raise InputError(f"--confidence must lie in (0, 1), got {confidence}")
    out = Path(result_dir)
    return out, read_json(out / "summary.json")
