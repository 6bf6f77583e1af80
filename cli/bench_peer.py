"""``lightsim bench peer``: time to a true 2 % error, Mitsuba 3 ``ptracer`` vs lightsim."""

from __future__ import annotations

import statistics

import click

from lightsim.errors import InputError
from lightsim.validation.bench import peer
from lightsim.validation.bench.table import print_table, write_json


@click.command("peer")
@click.option("--case", "cases", multiple=True, type=click.Choice(["paraboloid", "covered"]),
              help="Scene(s) (default: both).")
@click.option("--target", type=float, default=0.02, show_default=True,
              help="Relative rms error to reach (inner 80 % of the beam).")
@click.option("--resolution", type=int, default=64, show_default=True,
              help="Wall pixels per side (64: 0.94 mm pixels).")
@click.option("--spp0", type=int, default=4, show_default=True,
              help="Mitsuba's first samples per pixel (doubling, or jumping by 1/√spp).")
@click.option("--max-seconds", type=float, default=300.0, show_default=True,
              help="Cap of one run of either tool.")
@click.option("--repeats", type=int, default=1, show_default=True,
              help="Repeat the whole comparison; the summary gives median ratios.")
@click.option("--lightsim-arg", "lightsim_args", multiple=True,
              help="Extra argument for `lightsim simulate` (repeatable), e.g. "
                   "--lightsim-arg=--estimator --lightsim-arg=bin.")
@click.option("--ladder/--no-ladder", default=True, show_default=True,
              help="Also run lightsim at fixed --photons budgets until its TRUE error is "
                   "below the target (the time an honest stop would take).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(cases: tuple[str, ...], target: float, resolution: int, spp0: int,
            max_seconds: float, repeats: int, lightsim_args: tuple[str, ...],
            ladder: bool, json_path: str | None) -> None:
    """Mitsuba 3 (ptracer) and `lightsim simulate --target-error` on the same analytic
    scenes: whole-process seconds to a TRUE error below the target, and their ratio, on
    the inner 80 % of the beam (the headline) and on the lit pixels (rim included)."""
    if not 0 < target < 1:
        raise InputError(f"--target must be in (0, 1), got {target}")
    if resolution < 4 or spp0 < 1 or repeats < 1 or not max_seconds > 0:
        raise InputError("--resolution ≥ 4, --spp0 ≥ 1, --repeats ≥ 1, --max-seconds > 0")
    why = peer.mitsuba_unavailable()
    if why:
        click.echo(f"lightsim bench peer: Mitsuba side skipped: {why}", err=True)
    runs, results, phases = [], [], []
    for rep in range(repeats):
        for name in cases or tuple(peer.CASES):
            res = peer.run_case(name, target=target, resolution=resolution, spp0=spp0,
                                max_seconds=max_seconds, lightsim_args=lightsim_args,
                                mitsuba=why is None, ladder=ladder,
                                progress=lambda s: click.echo(f"  {s}", err=True))
            results.append(res)
            runs += [{"repeat": rep + 1, **r.row()} for r in res.runs]
            phases += [{"repeat": rep + 1, **b} for r in res.runs
                       if r.tool == "lightsim" and (b := r.breakdown()) is not None]
    print_table(f"peer runs (whole process, wall clock; target {target:g})", runs,
                ["repeat", *peer.PEER_COLUMNS])
    if phases:
        print_table("lightsim: where each process's time went (s)", phases)
    summary = peer.summary_rows(results, target)
    for i, row in enumerate(summary):
        row["repeat"] = i // max(len(cases or peer.CASES), 1) + 1
    print_table("peer: time to target (inner = the headline score; _lit = lit pixels)",
                summary)
    print_table("peer: both ratios (Mitsuba / lightsim; inner is the headline, goal ≥ 3)",
                [{k: row.get(k) for k in ("case", "mitsuba_s", "lightsim_s", "ratio",
                                          "mitsuba_s_lit", "lightsim_s_lit", "ratio_lit",
                                          "ls_own_err", "ls_stop_within_10pct",
                                          "ls_own_err_lit", "ls_lit_within_10pct")}
                 for row in summary])
    medians = []
    for name in dict.fromkeys(r.case for r in results):
        mine = [r for r in results if r.case == name]
        row: dict = {"case": name, "repeats": len(mine)}
        for key, attr in (("median_ratio_mitsuba_over_lightsim", "ratio"),
                          ("median_ratio_vs_lightsim_fixed", "ratio_fixed"),
                          ("median_ratio_lit", "ratio_lit"),
                          ("median_ratio_vs_lightsim_fixed_lit", "ratio_fixed_lit")):
            vals = [getattr(r, attr) for r in mine if getattr(r, attr) is not None]
            row[key] = statistics.median(vals) if vals else None
        medians.append({**row, "target_ratio": 3.0})
    if repeats > 1:
        print_table("peer: median ratio over repeats", medians)
    if json_path:
        write_json(json_path, "peer", runs + summary + medians + phases,
                   meta={"target": target, "resolution": resolution, "spp0": spp0,
                         "lightsim_args": list(lightsim_args), "mitsuba_skipped": why})
