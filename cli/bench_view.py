"""``lightsim bench view``: latency, frames/s and convergence of ``lightsim view`` in a
real browser (headless Chromium), with a model for 16 and 64 Ray workers."""

from __future__ import annotations

from pathlib import Path

import click

from lightsim.cli.bench_tracer import example_headlight
from lightsim.errors import InputError
from lightsim.options import click_option, lookup
from lightsim.validation.bench.table import print_table, write_json
from lightsim.validation.bench.view import bench_view, error_law
from lightsim.view.settings import ViewSettings


@click.command("view")
@click.argument("scene_file", required=False, type=click.Path(dir_okay=False))
@click_option(lookup(ViewSettings, "resolution"))
@click_option(lookup(ViewSettings, "frame_photons"))
@click.option("--changes", type=int, default=5, show_default=True, help="Latency samples.")
@click.option("--drag-seconds", type=float, default=6.0, show_default=True)
@click.option("--converge-timeout", type=float, default=40.0, show_default=True)
@click.option("--chromium", default="/usr/bin/chromium", show_default=True,
              type=click.Path(dir_okay=False), help="Chromium executable.")
@click.option("--screenshots", type=click.Path(file_okay=False),
              help="Save the page (interaction, converged) as PNG here.")
@click.option("--law", "law_marks", metavar="N1,N2,…",
              help="Instead: the written map's error (noise, blur) at these photon counts "
              "(millions, e.g. 1,2,4,8,16), no browser.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(scene_file: str | None, resolution: tuple[int, int], frame_photons: int, changes: int,
            drag_seconds: float, converge_timeout: float, chromium: str,
            screenshots: str | None, law_marks: str | None, json_path: str | None) -> None:
    """Time from a control change to the drawn image, interaction frames/s, convergence."""
    w, h = resolution
    path = scene_file or str(example_headlight())
    if law_marks is not None:
        try:
            marks = tuple(float(x) * 1e6 for x in law_marks.split(","))
        except ValueError:
            raise InputError(f"--law: expected millions of photons like 1,2,4, got "
                             f"'{law_marks}'") from None
        if not marks or not all(0 < m < 1e10 for m in marks):
            raise InputError(f"--law: photon counts must be positive, got '{law_marks}'")
        rows = error_law(path, (w, h), marks)
        print_table(f"written map's error against photons: {Path(path).name} at {w}x{h}", rows)
        if json_path:
            write_json(json_path, "view-law", rows, {})
        return
    try:
        import playwright  # noqa: F401
    except ImportError:
        raise InputError("bench view needs Playwright for Python: pip install playwright") \
            from None
    if changes < 1 or drag_seconds <= 0 or converge_timeout <= 0:
        raise InputError("--changes, --drag-seconds and --converge-timeout must be positive")
    res = bench_view(path, (w, h), frame_photons, changes, drag_seconds, converge_timeout,
                     chromium, Path(screenshots) if screenshots else None)
    print_table(f"bench view: {Path(path).name} at {w}x{h}, {frame_photons:,} photons/frame "
                f"(load average {res['load_average_start']:.1f} → "
                f"{res['load_average_end']:.1f} on {res['costs']['cores']} cores)", res["rows"])
    parts = res.get("latency_parts") or {}
    if parts:
        print_table("change → image drawn: where the time went (ms, median)",
                    [{"part": k, "ms": v} for k, v in parts.items()])
    print_table("model for Ray workers from the measured costs "
                "(docs/explanation/benchmarks.md)", res["model"])
    if json_path:
        write_json(json_path, "view", res["rows"] + res["model"],
                   {k: v for k, v in res.items() if k not in ("rows", "model")})
