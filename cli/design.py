"""``lightsim design``: a ring-and-sector multi-facet low beam aimed at a regulation target.

The options are :class:`~lightsim.luminaires.design.DesignSettings`' declarations (flag,
unit, range, default, help); the command builds the settings once from them, runs
:func:`~lightsim.luminaires.design.design_lowbeam` (or ``--restarts`` designs, each checked
by :func:`~lightsim.luminaires.design_check.check_lamp`), writes the GLB, optionally checks
it and prints the objective's terms.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import click
from rich.console import Console

from lightsim.errors import InputError
from lightsim.luminaires.analyses import for_options
from lightsim.luminaires.design import (
    DesignResult,
    DesignSettings,
    DesignStart,
    design_lowbeam,
    design_start,
    write_design,
)
from lightsim.luminaires.design_check import check_lamp, choose
from lightsim.luminaires.regulations.check import format_regulation
from lightsim.options import click_option, table
from lightsim.simulate import SimulateOptions, check_out_dir, run_simulation


def design_options(fn: Callable) -> Callable:
    """The click options of every command-line field of :class:`DesignSettings`, in their
    order (``--regulation`` is required: it has no default)."""
    for opt in reversed([o for o in table(DesignSettings) if o.on_cli]):
        if opt.name == "regulation":
            fn = click.option(*opt.flag, opt.name, required=True, metavar=opt.metavar,
                              help=opt.help)(fn)
        else:
            fn = click_option(opt)(fn)
    return fn


@click.command()
@click.argument("out_glb", type=click.Path(dir_okay=False))
@design_options
@click.option("--quiet", "-q", is_flag=True, help="No progress output.")
def design(out_glb: str, quiet: bool, **values: Any) -> None:
    """Design a multi-facet low-beam reflector for BULB aimed at REGULATION; write OUT_GLB
    (reflector, bulb, shield, lens) and print the objective's terms."""
    settings = DesignSettings(**values)
    if not str(out_glb).lower().endswith(".glb"):
        raise InputError(f"{out_glb}: the output must be a .glb file")
    start = design_start(settings)
    check_out_dir(str(Path(out_glb).resolve().parent))
    t0 = time.perf_counter()
    say = _Say(quiet)
    if settings.restarts == 1:
        out = design_lowbeam(settings, start, progress=say.progress, note=say)
        info = _record(settings, start, out, settings.seed)
    else:
        out, info = _restarts(settings, start, out_glb, say)
    size = write_design(out_glb, out.x, out.layout, info)
    _print_design(out, settings, out_glb, size)
    _check_runs(settings, out_glb)
    if settings.restarts > 1:
        _print_restarts(info)
    click.echo(f"total {time.perf_counter() - t0:.1f} s")


class _Say:
    """Progress on stderr (nothing with ``--quiet``): a line per note, per evaluation."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet

    def __call__(self, text: str) -> None:
        if not self.quiet:
            click.echo(text, err=True)

    def progress(self, i: int, e: dict[str, Any]) -> None:
        if self.quiet:
            return
        if "model_evaluation" in e:
            click.echo(f"model round {e['round']} eval {e['model_evaluation']:5d}  "
                       f"J={e['objective']:.4f}  {e['seconds']:.0f} s  short: "
                       f"{', '.join(e['failing']) or '-'}", err=True)
        else:
            x = ", ".join(f"{v:+.2f}" for v in e["x"])
            click.echo(f"round {e['round']} eval {i:3d}  J={e['objective']:.4f}  "
                       f"{e['seconds']:.1f} s  x=({x})  short: "
                       f"{', '.join(e['failing']) or '-'}", err=True)


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None


def _record(settings: DesignSettings, start: DesignStart, out: DesignResult,
            seed: int) -> dict[str, Any]:
    """The design record written into the GLB's extras (a continued lamp's model rounds
    first)."""
    return {"command": "lightsim design", "regulation": settings.regulation, "seed": seed,
            "photons": settings.photons, "resolution": list(settings.resolution),
            "evaluations": len(out.history), "objective": _finite(out.objective),
            "optimiser": settings.optimiser, "model": list(start.previous) + out.model,
            "validation_objective": _finite(out.validation_objective)}


def _restarts(settings: DesignSettings, start: DesignStart, out_glb: str, say: _Say
              ) -> tuple[DesignResult, dict[str, Any]]:
    """Design ``restarts`` lamps at seeds ``seed`` … ``seed + restarts − 1``, check each
    (:func:`~lightsim.luminaires.design_check.check_lamp`) and return the chosen design and
    its record (with every restart's check)."""
    n = settings.restarts
    res, seeds = settings.restart_resolution, settings.restart_seeds
    work = Path(tempfile.mkdtemp(prefix=".lightsim-restarts-",
                                 dir=str(Path(out_glb).resolve().parent)))
    outs, checks, seeds_k = [], [], []
    try:
        for k in range(n):
            s = settings.seed + k
            say(f"restart {k + 1}/{n}: design seed {s}")
            out = design_lowbeam(replace(settings, seed=s), start, progress=say.progress,
                                 note=say)
            glb = work / f"restart{k}.glb"
            write_design(glb, out.x, out.layout, _record(settings, start, out, s))
            say(f"restart {k + 1}/{n}: checking ({settings.restart_photons:,} photons, "
                f"{res[0]}x{res[1]}, seeds {', '.join(map(str, seeds))})")
            chk = check_lamp(glb, settings.regulation, photons=settings.restart_photons,
                             resolution=res, seeds=seeds, traffic=settings.traffic,
                             aim=settings.aim_photons == 0, note=say,
                             until=settings.until)
            say(f"restart {k + 1}/{n}: {len(chk.not_passing)} of {chk.rows} rows not "
                f"passing, smallest margin {chk.min_margin:+.3f}")
            outs.append(out)
            checks.append(chk)
            seeds_k.append(s)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    best = choose(checks, [o.objective for o in outs])
    info = _record(settings, start, outs[best], seeds_k[best])
    info["restarts"] = [{"seed": s, "objective": _finite(o.objective), "check": c.to_dict()}
                        for s, o, c in zip(seeds_k, outs, checks)]
    info["chosen"] = best
    return outs[best], info


def _deg(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}°"


def _print_design(out: DesignResult, settings: DesignSettings, out_glb: str,
                  size: int) -> None:
    """The design's summary, its terms (the validation's when there is one) and every
    model round, aim step and linearity step."""
    what = ("model improvements" if out.model else "evaluations")
    click.echo(f"design: {len(out.history)} {what} in {out.seconds:.1f} s; "
               f"J = {out.objective:.4f} (validation, fresh seed ×{settings.validate_factor} "
               f"photons: {out.validation_objective:.4f}); wrote {out_glb} ({size:,} bytes)")
    click.echo("x = (" + ", ".join(f"{v:+.4f}" for v in out.x) + "); ring offsets = ("
               + ", ".join(f"{d:+.3f}" for d in out.layout.ring_offsets_deg)
               + ")° from " + str(len(out.calibration_deg)) + " calibration steps")
    click.echo(f"{'term':14s} {'value':>10s}  {'log-margin':>10s}  target")
    for t in out.validation or out.terms:
        v = "-" if t.value is None else f"{t.value:,.4g}"
        click.echo(f"{t.name:14s} {v:>10s}  {t.margin:+10.3f}  {t.target}"
                   + ("   SHORT" if t.margin < 0 else ""))
    for m in out.model:
        if m["round"] == "aim":
            click.echo(f"final aim step: every facet {m['aim_step_deg']:+.3f}°")
        elif m["round"] == "linearity":
            moved = ", ".join(f"facet {k} {d:+.2f}°"
                              for k, d in zip(m["candidates"], m["shifts_deg"]))
            click.echo(f"linearity step: annex-9 scans' spread {_deg(m['spread_before_deg'])}"
                       f" → {_deg(m['spread_after_deg'])} ({moved or 'nothing moved'}; "
                       f"{m['evaluations']} simulated tries in {m['seconds']:.0f} s)")
        else:
            again = "; ".join(f"× {t['step']:g} re-measured J {t['objective']:.4f}"
                              for t in m.get("remeasured", []))
            click.echo(f"model round {m['round']}: {m['facets']} facets' footprints measured "
                       f"in {m['footprint_seconds']:.0f} s; J {m['start_objective']:.4f} → "
                       f"{m['objective']:.4f} in {m['evaluations']} model evaluations"
                       + (f"; {again}; kept × {m['accepted_step']:g}" if again else ""))


def _check_runs(settings: DesignSettings, out_glb: str) -> None:
    """``--check-photons``: simulate the written lamp once per rule set with the
    regulation's detector apertures and print each table."""
    if not settings.check_photons:
        return
    for rs in settings.regulation.split(","):
        opts = SimulateOptions(out_glb, out_dir=str(Path(settings.check_dir) / rs.strip()),
                               photons=settings.check_photons, regulation=rs.strip(),
                               traffic=settings.traffic, aim=settings.aim_photons == 0,
                               config={"seed": settings.seed + 2000}, until=settings.until)
        sim = run_simulation(opts, analyses=for_options(opts))
        Console(width=120).print(format_regulation(sim.summary["regulation"]))


def _print_restarts(info: dict[str, Any]) -> None:
    """One row per restart: seed, J, rows not passing, smallest margin, the chosen one."""
    click.echo(f"{'restart':>7s} {'seed':>5s} {'J':>8s} {'not passing':>11s} "
               f"{'min margin':>10s}")
    for k, r in enumerate(info["restarts"]):
        m = float(r["check"]["min_margin"])
        j = math.nan if r["objective"] is None else r["objective"]
        click.echo(f"{k:7d} {r['seed']:5d} {j:8.4f} "
                   f"{len(r['check']['not_passing']):11d} {m:+10.3f}"
                   + ("   chosen" if k == info["chosen"] else ""))
