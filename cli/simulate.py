"""``lightsim simulate``: parse options, run :func:`lightsim.simulate.run_simulation`, print."""

from __future__ import annotations

import math
import signal
import sys
import time
from typing import Any

import click
from click.core import ParameterSource
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from lightsim.analysis import StopsRun
from lightsim.engine.config import RunConfig
from lightsim.errors import InputError
from lightsim.io import plot_worker
from lightsim.luminaires.analyses import for_options
from lightsim.luminaires.provenance_report import failing_breakdowns
from lightsim.luminaires.regulations.check import format_regulation, regulation_tables
from lightsim.options import click_options
from lightsim.road_evaluation import reach_lines
from lightsim.simulate import SimulateOptions, read_checkpoint, run_simulation


class _Progress:
    """Progress line: photons, photons/s, frames/s, estimated error, ETA."""

    def __init__(self, quiet: bool, photons: int | None, seconds: float | None,
                 target: float | None, status: Any = None) -> None:
        self.quiet = quiet
        self.status = status  # () → str: the stopping rule's line (--until decided)
        self.photons, self.seconds, self.target = photons, seconds, target
        self.progress = None
        self.task = None
        self.t0 = time.perf_counter()
        self.frames = 0

    def __enter__(self) -> _Progress:
        if not self.quiet:
            self.progress = Progress(TextColumn("[bold]simulate"), BarColumn(),
                                     TextColumn("{task.fields[info]}"), TimeElapsedColumn(),
                                     transient=False)
            self.progress.__enter__()
            self.task = self.progress.add_task("sim", total=1.0, info="planning…")
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.progress is not None:
            self.progress.__exit__(*exc)

    def __call__(self, est: Any) -> None:
        self.frames += 1
        if self.progress is None:
            return
        dt = max(time.perf_counter() - self.t0, 1e-9)
        rate = est.photons / max(est.seconds, 1e-9)
        err = "–" if est.rel_error is None else f"{est.rel_error:.2%}"
        fractions = []
        if self.photons:
            fractions.append(est.photons / self.photons)
        if self.seconds:
            fractions.append(est.seconds / self.seconds)
        if self.target and est.rel_error:
            # noise falls as 1/√N: the photons needed scale with (error / target)²
            need = est.photons * (est.rel_error / self.target) ** 2
            fractions.append(est.photons / max(need, 1.0))
        frac = min(1.0, max(fractions)) if fractions else 0.0
        eta = (1 - frac) / frac * est.seconds if frac > 0 else math.inf
        eta_s = f"{eta:.0f} s" if math.isfinite(eta) else "?"
        info = (f"{est.photons:,} photons  {rate / 1e3:,.0f} k/s  "
                f"{self.frames / dt:.2f} frames/s  error {err}  ETA {eta_s}")
        if self.status is not None:
            info += f"  {self.status()}"
        self.progress.update(self.task, completed=frac, info=info)


def until_text(until: dict[str, Any]) -> str:
    """``--until decided`` / ``verdict``: what stopped the run and what is still open."""
    looks = until.get("looks") or []
    head = (f"until {until.get('rule', 'decided')}: {len(looks)} looks of "
            f"{until.get('looks_planned')} planned "
            f"(each at {until.get('look_level', 0):.2%}, so that every verdict holds at "
            f"{until.get('confidence', 0.95):.0%} over all looks)")
    if until.get("decided"):
        return f"{head}; every verdict decided at {until.get('photons', 0):,} photons"
    opened = [f"{o['ruleset']} {o['name']}" for o in until.get("undecided", [])]
    if until.get("stopped_by") == "verdict" and until.get("lamp_verdict") == "fail":
        return (f"{head}; the lamp fails, decided at {until.get('photons', 0):,} photons "
                f"(a rule decided fail); {len(opened)} rules left undecided: "
                f"{', '.join(opened) or '-'}")
    cap = {"photons": "the photon cap", "time": "the time cap",
           "memory": "the memory"}.get(str(until.get("stopped_by")), "a cap")
    notes = "; ".join(f"{k}: {v}" for k, v in (until.get("notes") or {}).items())
    return (f"{head}; stopped by {cap} at {until.get('photons', 0):,} photons with "
            f"{len(opened)} rules undecided: {', '.join(opened) or '-'}"
            + (f" ({notes})" if notes else ""))


@click.command()
@click.argument("scene_file", required=False, type=click.Path(dir_okay=False))
@click_options(SimulateOptions, RunConfig)  # every run option, from their declarations
@click.option("--resume", "resume_dir", type=click.Path(file_okay=False),
              help="Continue an interrupted run from its output folder (budgets and "
              "workers may be given anew; other options must match the checkpoint).")
@click.option("--explain", is_flag=True, help="Print which stages run and why.")
@click.option("--quiet", "-q", is_flag=True, help="No progress output.")
def simulate(scene_file: str | None, resume_dir: str | None, explain: bool, quiet: bool,
             **values: Any) -> None:
    """Simulate SCENE_FILE (GLB/glTF/OBJ/STL/PLY, STEP/IGES, a .tm25ray ray file) and write
    the wall illuminance in lux."""
    resume = None
    if resume_dir is not None:
        if scene_file is not None:
            raise InputError("--resume continues a run with its own scene: give no SCENE_FILE")
        stored, resume = read_checkpoint(resume_dir)
        ctx = click.get_current_context()
        given = {n: v for n, v in values.items() if ctx.get_parameter_source(n) in
                 (ParameterSource.COMMANDLINE, ParameterSource.ENVIRONMENT)}
        opts = stored.resumed(given, resume_dir)
    elif scene_file is None:
        raise InputError("missing SCENE_FILE (or --resume DIR)")
    else:
        opts = SimulateOptions.from_command_line(scene_file, values)
        opts.run_config()  # validate the settings before any work
    analyses = for_options(opts)  # regulation table, far-field files (checked here)

    stop = {"signal": None}

    def on_signal(signum, _frame) -> None:
        if stop["signal"] is not None:  # a second Ctrl-C: give up at once
            raise KeyboardInterrupt
        stop["signal"] = signum
        click.echo(f"\nlightsim: {signal.Signals(signum).name}: finishing the current frame, "
                   "then writing a checkpoint…", err=True)

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}

    def on_plan(session) -> None:
        for w in session.scene.warnings:
            click.echo(f"lightsim: warning: {w}", err=True)
        if explain:
            click.echo("plan:")
            for line in session.plan.explain():
                click.echo(f"  {line}")
            if session.memory_estimate is not None:
                click.echo("memory:")
                for line in session.memory_estimate.explain():
                    click.echo(f"  {line}")

    # the plot process starts now: matplotlib is imported and warmed up while the scene
    # loads and the run goes on (lightsim/io/plot_worker.py)
    plots = plot_worker.start(any(n in opts.outputs for n in plot_worker.PLOT_OUTPUTS))
    try:
        status = next((a.stop_progress for a in analyses if isinstance(a, StopsRun)), None)
        with _Progress(quiet, opts.photons, opts.seconds, opts.target_error,
                       status if opts.until else None) as prog:
            result = run_simulation(opts, progress=prog, should_stop=lambda: stop["signal"]
                                    is not None, on_plan=on_plan, resume=resume,
                                    analyses=analyses, plots=plots)
    finally:
        plots.close()
        for s, h in old.items():
            signal.signal(s, h)
    if result.interrupted:
        click.echo(f"lightsim: interrupted; checkpoint written to {result.out_dir}/"
                   f"checkpoint.json — continue with: lightsim simulate --resume "
                   f"{result.out_dir}", err=True)
        raise SystemExit(130)
    mem_note = (result.summary.get("memory_stop") or {}).get("message")
    if mem_note:  # a time or error budget stopped short of the memory
        click.echo(f"lightsim: warning: {mem_note}", err=True)
    ff_note = result.summary.get("farfield", {}).get("warning")
    if ff_note:  # flux a written Type A file leaves out
        click.echo(f"lightsim: warning: {ff_note}", err=True)
    if not quiet:
        s = result.summary
        e = s["energy_lm"]
        err = s.get("error_text") or "–"
        if s.get("rel_error_upper") is not None:
            err += f", upper bound {s['rel_error_upper']:.2%}"
        click.echo(f"{s['photons']:,} photons in {s['seconds']:.1f} s, {s['frames']} frames; "
                   f"estimated error {err}; max {s['lux']['max_lx']:.4g} lx")
        absorbed = e["absorbed_diffuse"] + e["absorbed_mirror"] + e["absorbed_volume"]
        click.echo(f"energy (lm): emitted {e['emitted']:.6g} = wall {e['wall']:.6g} + "
                   f"absorbed {absorbed:.6g} + escaped {e['escaped']:.6g} + "
                   f"roulette {e['roulette']:.3g} + max depth {e['max_depth']:.3g}")
        if "cluster" in s:  # where a Ray run's actors ran
            c = s["cluster"]
            click.echo(f"Ray ({c['address']}): {c['actors']} actors on {c['nodes']} node(s), "
                       f"{c['cpus']} CPUs; {c['restarts']} replaced after a lost process "
                       "or node")
        if "road" in s:
            click.echo(f"road view (lamp {s['road']['mount_height_m']:g} m high): "
                       f"{s['road']['text']}")
        if "road_evaluation" in s:
            click.echo("road evaluation (m; [95 % interval]):")
            for line in reach_lines(s["road_evaluation"]):
                click.echo("  " + line)
        if any(k == "regulation" or k.startswith("regulation:") for k in s):
            console = Console(width=None if sys.stdout.isatty() else 160)
            for table in regulation_tables(s):
                console.print(format_regulation(table))
            for table in failing_breakdowns(s):  # --provenance: where the light comes from
                console.print(table)
        if "until" in s:
            click.echo(until_text(s["until"]))
        order = ("wall_lux.exr", "wall_lux.png", "isolux.png", "road.png",
                 "error_vs_time.png", "summary.json", "probes.npz")
        wrote = sorted(s.get("outputs", []), key=lambda n: (order.index(n) if n in order
                                                            else len(order), n))
        click.echo(f"wrote {result.out_dir}/{', '.join(wrote)}")
        for f in s.get("farfield", {}).get("files", []):
            click.echo(f"wrote {f} ({s['farfield']['total_flux_lm']:.1f} lm leave the lamp)")

