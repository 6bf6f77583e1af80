"""``lightsim bench adb [RUN_DIR]``: a 1,000-frame ADB sequence composed and judged from
per-source maps, against re-tracing one frame in the same run; optionally the memory of
``--per-source`` against a plain run."""

from __future__ import annotations

import click

from lightsim.validation.bench.adb import MEMORY_RATIO, TARGET_S, bench_adb
from lightsim.validation.bench.table import print_table, write_json


@click.command("adb")
@click.argument("run_dir", required=False, type=click.Path(file_okay=False, exists=True))
@click.option("--frames", type=click.IntRange(1, 100_000), default=1000, show_default=True,
              help="Frames of the traffic sequence.")
@click.option("--memory-photons", type=click.IntRange(0), default=0, show_default=True,
              help="> 0: also compare the peak memory of --per-source and plain runs of the "
              "matrix lamp at this many photons (two child processes).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(run_dir: str | None, frames: int, memory_photons: int,
            json_path: str | None) -> None:
    """Compose and judge a traffic sequence (oncoming car 400 m → 30 m, a car ahead) from
    RUN_DIR's per-source maps (default: the shipped matrix lamp, one frame at 640×256, run
    here); ratios against re-tracing one frame."""
    rows = bench_adb(run_dir, frames, memory_photons)
    print_table(f"ADB sequence of {frames} frames (target ≤ {TARGET_S:g} s; memory ≤ "
                f"{MEMORY_RATIO:g}× plain)", rows)
    if json_path:
        write_json(json_path, "adb", rows, {"run_dir": run_dir, "frames": frames,
                                            "memory_photons": memory_photons})
