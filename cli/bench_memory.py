"""``lightsim bench memory``: peak RSS against photons, default run and keep-all path."""

from __future__ import annotations

import click

from lightsim.errors import InputError
from lightsim.luminaires.headlight import EXAMPLES_DIR
from lightsim.validation.bench.memory import (
    FULL_PHOTONS,
    KEEP_ALL_MAX,
    QUICK_PHOTONS,
    REGULATION,
    bench_memory,
    plot_memory,
)
from lightsim.validation.bench.pipeline import load_average
from lightsim.validation.bench.table import print_table, write_json


@click.command("memory")
@click.argument("scene_file", required=False, type=click.Path(dir_okay=False, exists=True))
@click.option("--quick", is_flag=True,
              help=f"Photons {', '.join(f'{n // 10**6} M' for n in QUICK_PHOTONS)} (a check "
                   "that it works) instead of "
                   f"{', '.join(f'{n // 10**6} M' for n in FULL_PHOTONS)}.")
@click.option("--photons", "photons_text", metavar="N,N,…",
              help="Photon counts to run (overrides --quick).")
@click.option("--keep-all-max", type=int, default=KEEP_ALL_MAX, show_default=True,
              help="Largest photon count the keep-all path (--keep-photons) runs at.")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False),
              default="bench_memory.png", show_default=True,
              help="Peak RSS against photons (PNG).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(scene_file: str | None, quick: bool, photons_text: str | None,
            keep_all_max: int, plot_path: str, json_path: str | None) -> None:
    """Peak RSS of `simulate` on SCENE_FILE (default: the README's low beam at 320x128
    with both rule sets) against photons: the default run, which keeps no photon, and
    the keep-all path (--keep-photons), in one run, with a plot."""
    counts = QUICK_PHOTONS if quick else FULL_PHOTONS
    if photons_text:
        try:
            counts = tuple(int(float(t)) for t in photons_text.split(",") if t.strip())
        except ValueError:
            raise InputError(f"--photons must be counts separated by commas, got "
                             f"'{photons_text}'") from None
    if not counts or min(counts) < 1:
        raise InputError("--photons: every count must be at least 1")
    scene = scene_file or str(EXAMPLES_DIR / "lowbeam.glb")
    regulation = REGULATION if scene_file is None else None
    before = load_average()

    def show(row) -> None:
        click.echo(f"  {row['path']:>8} {row['photons']:>13,} photons: peak "
                   f"{row['peak_rss_mb']:,.0f} MB, {row['photons_per_s'] / 1e3:,.0f} k/s, "
                   f"{row['photons_per_cpu_s'] / 1e3:,.0f} k per CPU-s",
                   err=True)

    rows = bench_memory(scene, tuple(sorted(counts)), keep_all_max, progress=show,
                        regulation=regulation)
    title = (f"memory: {scene}, peak RSS against photons, load average {before} before, "
             f"{load_average()} after")
    print_table(title, rows, ["path", "photons", "peak_rss_mb", "rss_vs_first",
                              "rss_vs_default", "photons_per_s", "photons_per_cpu_s", "run_s",
                              "rel_error"])
    plot_memory(rows, plot_path, title)
    click.echo(f"wrote {plot_path}")
    if json_path:
        write_json(json_path, "memory", rows, {"scene": scene, "load_before": before})
