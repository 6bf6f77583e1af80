"""``lightsim adb RUN_DIR --traffic scene.toml``: glare-free masks of a matrix lamp for a
traffic scene, composed from a ``simulate --per-source`` run (:mod:`lightsim.luminaires.adb`)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import click

from lightsim.luminaires.adb import AdbComposer, AdbSettings, read_traffic, run_adb
from lightsim.luminaires.adb_outputs import write_adb
from lightsim.luminaires.regulations.ruleset import load_ruleset
from lightsim.options import click_options
from lightsim.persource import read_per_source
from lightsim.report import plot_caption


@click.command()
@click.argument("run_dir", type=click.Path(file_okay=False))
@click.option("--traffic", "traffic_file", required=True, type=click.Path(dir_okay=False),
              help="Traffic scene (TOML): road users with distances and lanes, or an "
              "approach from far to near over frames.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False),
              help="Output folder (default: RUN_DIR/adb).")
@click.option("--frame", "shown", type=int, default=None,
              help="Frame whose composed map and plots are written (default: the last; "
              "negative counts from the end).")
@click.option("--no-plots", is_flag=True, help="Only adb.json and adb_composed.exr.")
@click_options(AdbSettings)
def adb(run_dir: str, traffic_file: str, out_dir: str | None, shown: int | None,
        no_plots: bool, **kwargs) -> None:
    """Per frame, dim each segment (0-1) so that every road user's glare positions stay
    within the R149 ADB limits for its distance with as much light as possible elsewhere;
    writes the composed map, isolux and road views with the vehicles, the verdicts with
    intervals and the residual light in the masked zone (adb.json)."""
    settings = AdbSettings(**kwargs)
    maps = read_per_source(run_dir)  # every check before the first file
    traffic = read_traffic(traffic_file)
    result = run_adb(maps, traffic, settings, shown)
    out = Path(out_dir) if out_dir else Path(run_dir) / "adb"
    written = write_adb(out, result, AdbComposer(maps, traffic, settings), plots=not no_plots,
                        caption=_caption(Path(run_dir), result.limits.ruleset))
    s = result.summary()
    c = s["verdict_counts"]
    click.echo(f"{s['frames']} frame(s) of {len(maps.names)} segments composed and judged in "
               f"{s['seconds']:.3f} s (no re-tracing): {c['pass']} pass, {c['fail']} fail, "
               f"{c['undecided']} undecided, {c['off screen']} off screen "
               f"({settings.confidence:.0%} intervals)")
    if s["frames_with_limits_unmet"]:
        click.echo(f"{s['frames_with_limits_unmet']} frame(s) cannot meet the limits even with "
                   "every free segment off (fixed levels or stray light)")
    f = result.frames[result.shown]
    click.echo(f"frame {result.shown}: levels " + " ".join(
        f"{n}={w:.2f}" for n, w in zip(maps.names, f.levels, strict=True)))
    for p in f.positions:
        lo, hi = p["interval_cd"]
        click.echo(f"  {p['user']}, {p['position']} at {p['distance_m']:.0f} m "
                   f"({p['h_deg']:+.2f}°, {p['v_deg']:+.2f}°): {p['cd']:.0f} cd "
                   f"[{lo:.0f}, {hi:.0f}] ≤ {p['max_cd']:.0f} ({p['line']}): {p['verdict']}")
    for r in f.residual:
        lo, hi = r["interval_cd"]
        frac = r["fraction_of_all_on"]
        click.echo(f"  residual in {r['user']}'s outline: {r['mean_cd']:.0f} cd [{lo:.0f}, "
                   f"{hi:.0f}]" + ("" if frac is None else f", {frac:.1%} of all-on"))
    click.echo("wrote " + ", ".join(str(p) for p in written))


def _caption(run_dir: Path, ruleset: str) -> str | None:
    """The plots' caption: the run's lamp, seed, photons and error figure, the ADB rule set
    with its version, lightsim's version (None when the run has no readable summary)."""
    try:
        summary = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    cap = plot_caption(summary)
    if cap is None:
        return None
    return replace(cap, rulesets=((ruleset, load_ruleset(ruleset).version),)).text()
