"""``lightsim design``: a ring-and-sector multi-facet low beam aimed at a regulation target
(parse, call :func:`lightsim.luminaires.design.design_lowbeam`, write the GLB, check it,
print)."""

from __future__ import annotations

import math
import time
from dataclasses import replace
from pathlib import Path

import click

from lightsim.engine.config import RunConfig
from lightsim.errors import InputError
from lightsim.options import click_option, lookup
from lightsim.simulate import SimulateOptions


def _resolution(text: str, flag: str = "--resolution") -> tuple[int, int]:
    try:
        w, h = (int(t) for t in text.lower().split("x"))
    except ValueError:
        raise InputError(f"{flag} must be WxH, got {text!r}") from None
    if not (8 <= w <= 4096 and 8 <= h <= 4096):
        raise InputError(f"{flag} must be 8–4096 pixels a side, got {text!r}")
    return w, h


@click.command()
@click.argument("out_glb", type=click.Path(dir_okay=False))
@click.option("--bulb", default="H4", show_default=True,
              help="Bulb: H4 (its passing filament and shield cup) or a preset name.")
@click.option("--regulation", required=True, help="Rule set target, e.g. r112-b-passing.")
@click.option("--rings", type=int, default=3, show_default=True,
              help="Facet rings (radial).")
@click.option("--sectors", type=int, default=8, show_default=True,
              help="Facet sectors (azimuthal): rings × sectors facets.")
@click.option("--focal-length", type=float, default=25.0, show_default=True, help="mm")
@click.option("--opening", type=float, default=160.0, show_default=True,
              help="Lamp opening (reflector rim diameter), mm.")
@click.option("--evaluations", type=int, default=30, show_default=True,
              help="Powell function evaluations per round (each one simulation).")
@click.option("--rounds", type=int, default=2, show_default=True,
              help="Optimisation rounds; each round re-draws the photon noise (seed + round).")
@click.option("--photons", "-n", type=int, default=300_000, show_default=True,
              help="Photons per evaluation.")
@click.option("--resolution", default="80x256", show_default=True,
              help="Wall pixels WxH of every evaluation.")
@click.option("--validate-factor", type=int, default=4, show_default=True,
              help="The best lamp is re-simulated with a fresh seed and this many times "
                   "the photons (0: not).")
@click.option("--check-photons", type=int, default=0, show_default=True,
              help="Photons of a final full-resolution check run of the written lamp with "
                   "the regulation's detector apertures (0: none).")
@click_option(lookup(RunConfig, "seed"))
@click.option("--safety", type=float, default=0.10, show_default=True,
              help="Relative margin asked beyond every limit.")
@click.option("--reach", type=float, default=25.0, show_default=True,
              help="1 lx road reach asked for, m (lamp 0.65 m high): the intensity along "
                   "the road line this far ahead is asked for 1 lx.")
@click.option("--reach-weight", type=float, default=1.0, show_default=True,
              help="Weight of the reach term in J (its hinge² × this; 1: as every rule).")
@click_option(lookup(SimulateOptions, "traffic"))
@click.option("--out", "check_dir", type=click.Path(file_okay=False), default="design-check",
              show_default=True, help="Folder of the final check run.")
@click.option("--start", default=None,
              help="Comma-separated start vector x (h0, then spread, drop, scale per ring); "
                   "default: the geometric start.")
@click.option("--sign-share", type=float, default=0.03, show_default=True,
              help="Share of a lit vertex-ring facet's azimuth given to each overhead-sign "
                   "sliver (dim light above the cut-off: points 1-8); 0: none.")
@click.option("--optimiser", type=click.Choice(["model", "simulator"]), default="model",
              show_default=True,
              help="model: Powell on per-facet aim shifts against a footprint model "
                   "measured once per round with the simulator (deterministic); simulator: "
                   "Powell on the start vector with a simulation per evaluation.")
@click.option("--model-rounds", type=int, default=1, show_default=True,
              help="Footprint-model rounds (each re-measures the footprints at the new "
                   "aims).")
@click.option("--model-photons", type=int, default=1_000_000, show_default=True,
              help="Photons per footprint run (one run per lit facet, plus the base).")
@click.option("--model-resolution", default="200x256", show_default=True,
              help="Wall pixels WxH of the footprint maps.")
@click.option("--model-evaluations", type=int, default=3000, show_default=True,
              help="Powell evaluations of the model per round.")
@click.option("--interval-photons", type=int, default=12_000_000, show_default=True,
              help="The model asks every point for the margin of the 95 % interval a check "
                   "run with this many photons shows (0: none).")
@click.option("--model-safety", type=float, default=0.05, show_default=True,
              help="Relative margin the model asks beyond every limit (on top of the "
                   "interval).")
@click.option("--ring-offsets", default=None,
              help="Comma-separated calibrated ring offsets (deg): skip the calibration.")
@click.option("--continue-from", "continue_from", type=click.Path(dir_okay=False),
              default=None,
              help="A lamp written by lightsim design: start from its x, layout and facet "
                   "shifts (no calibration) and run --model-rounds more rounds (their seeds "
                   "follow the rounds it has).")
@click.option("--foreground", type=float, default=5.0, show_default=True,
              help="m: ask for 1 lx on the road over ±this at 10 m and ±0.8× at 15 m "
                   "(0: no foreground term).")
@click.option("--shaded-spread", type=float, default=0.0, show_default=True,
              help="deg: extra horizontal spread (× cos φ) of the cup's edge facets, which "
                   "then light the foreground (0: they stay 8° down).")
@click.option("--foreground-share", type=float, default=0.0, show_default=True,
              help="Share of a lit second-ring facet per foreground sliver (× its weight; "
                   "0: none): light at 14–28° L/R, 2.6–3.9° D.")
@click.option("--shaded-drop", type=float, default=8.0, show_default=True,
              help="deg under the cut-off for those foreground facets.")
@click.option("--wing-facets", default="", show_default=True,
              help="Comma-separated main facets (indices, ring-major) re-aimed to the wide "
                   "foreground beside the car (the wings); empty: none.")
@click.option("--wing", "wing_deg", type=float, default=16.5, show_default=True,
              help="deg: the wings' image medians lie at ±(this ± 2.5°), on each facet's "
                   "side of V.")
@click.option("--wing-drop", type=float, default=2.5, show_default=True,
              help="deg under the cut-off level v0 of the wings' image medians.")
@click.option("--aim-photons", type=int, default=4_000_000, show_default=True,
              help="Photons of the aim step (before each model round and twice at the end: "
                   "every facet moves by the aim correction a 320x128 run's cut-off asks "
                   "for, so the lamp needs no --aim; 0: no aim step).")
@click.option("--linearity-photons", type=int, default=4_000_000, show_default=True,
              help="Photons of every simulated try of the linearity step (after the final "
                   "aim steps, model optimiser: the facets that make the cut-off at annex "
                   "9's 1.5°/2.5°/3.5° scans are moved up or down until the scans' "
                   "inflections lie within 0.12°; 0: no linearity step).")
@click.option("--aim-rounds/--no-aim-rounds", default=True, show_default=True,
              help="Aim step also before each model round (--no-aim-rounds: only the two "
                   "final ones; the rounds keep the model finder's own cut-off).")
@click.option("--remeasure/--no-remeasure", default=True, show_default=True,
              help="Re-simulate each model round's lamp and keep its shifts (halved up to "
                   "twice) only if J got better.")
@click.option("--model-smooth", type=float, default=0.0, show_default=True,
              help="σ (model-wall pixels) of a Gaussian applied to every footprint (0: none).")
@click.option("--restarts", type=int, default=1, show_default=True,
              help="Design this many lamps (seeds SEED, SEED+1, …), check each with the "
                   "README demo's run (--restart-photons at every --restart-seeds; every rule "
                   "and annex 9's linearity) and keep the one that passes best: fewest rows "
                   "not passing, then the largest smallest margin, then the lowest J (1: one "
                   "design, no check).")
@click.option("--restart-photons", type=int, default=32_000_000, show_default=True,
              help="Photons of each restart check run.")
@click.option("--restart-resolution", default="320x128", show_default=True,
              help="Wall pixels WxH of the restart check runs.")
@click.option("--restart-seeds", default="1,2,3", show_default=True,
              help="Comma-separated photon seeds of the restart check runs.")
@click.option("--quiet", "-q", is_flag=True)
def design(out_glb: str, bulb: str, regulation: str, rings: int, sectors: int,
           focal_length: float, opening: float, evaluations: int, rounds: int, photons: int,
           resolution: str, validate_factor: int, check_photons: int, seed: int,
           safety: float, reach: float, reach_weight: float, traffic: str, check_dir: str,
           start: str | None,
           sign_share: float, optimiser: str, model_rounds: int, model_photons: int,
           model_resolution: str, model_evaluations: int, interval_photons: int,
           model_safety: float, ring_offsets: str | None, continue_from: str | None,
           foreground: float, foreground_share: float, shaded_spread: float,
           shaded_drop: float, wing_facets: str, wing_deg: float, wing_drop: float,
           aim_photons: int, linearity_photons: int, aim_rounds: bool,
           remeasure: bool, model_smooth: float, restarts: int, restart_photons: int,
           restart_resolution: str, restart_seeds: str, quiet: bool) -> None:
    """Design a multi-facet low-beam reflector for BULB aimed at REGULATION; write OUT_GLB
    (reflector, bulb, shield, lens) and print the objective's terms."""
    from rich.console import Console

    from lightsim.luminaires.analyses import for_options
    from lightsim.luminaires.bulbs import get_bulb
    from lightsim.luminaires.design import Layout, design_lowbeam, write_design
    from lightsim.luminaires.regulations.check import format_regulation
    from lightsim.simulate import check_out_dir, run_simulation

    name = "H4-low" if bulb.strip().upper() == "H4" else get_bulb(bulb).name
    if not str(out_glb).lower().endswith(".glb"):
        raise InputError(f"{out_glb}: the output must be a .glb file")
    if check_photons < 0:
        raise InputError(f"--check-photons must be ≥ 0, got {check_photons}")
    res = _resolution(resolution)
    if restarts < 1:
        raise InputError(f"--restarts must be ≥ 1, got {restarts}")
    if restart_photons < 1:
        raise InputError(f"--restart-photons must be ≥ 1, got {restart_photons}")
    check_res = _resolution(restart_resolution, "--restart-resolution")
    try:
        check_seeds = [int(t) for t in restart_seeds.split(",")]
    except ValueError:
        raise InputError(f"--restart-seeds must be comma-separated integers, got "
                         f"{restart_seeds!r}") from None
    if not check_seeds or min(check_seeds) < 0:
        raise InputError(f"--restart-seeds must be integers ≥ 0, got {restart_seeds!r}")
    offsets: tuple[float, ...] = ()
    if ring_offsets is not None:
        try:
            offsets = tuple(float(t) for t in ring_offsets.split(","))
        except ValueError:
            raise InputError(f"--ring-offsets must be comma-separated numbers, got "
                             f"{ring_offsets!r}") from None
        if len(offsets) != rings or not all(map(math.isfinite, offsets)):
            raise InputError(f"--ring-offsets needs {rings} finite numbers")
    try:
        wings = tuple(int(t) for t in wing_facets.split(",") if t.strip())
    except ValueError:
        raise InputError(f"--wing-facets must be comma-separated facet indices, got "
                         f"{wing_facets!r}") from None
    layout = Layout(rings=rings, sectors=sectors, focal_length_m=focal_length * 1e-3,
                    aperture_m=opening * 1e-3, bulb=name, traffic=traffic,
                    sign_share=sign_share, ring_offsets_deg=offsets,
                    shaded_spread_deg=shaded_spread, shaded_drop_deg=shaded_drop,
                    foreground_share=foreground_share, wing_facets=wings,
                    wing_deg=wing_deg, wing_drop_deg=wing_drop)
    if continue_from is None:  # else the continued lamp's layout is checked below
        layout.check()
    mres = _resolution(model_resolution, "--model-resolution")
    first_round = 0
    previous: list = []
    if continue_from is not None:  # its geometry; this command's sliver options
        from lightsim.luminaires.design import read_design

        x_prev, layout, rec = read_design(continue_from)
        # the continued lamp takes the foreground options of this command
        layout = replace(layout, shaded_spread_deg=shaded_spread,
                         shaded_drop_deg=shaded_drop, foreground_share=foreground_share,
                         sign_share=sign_share, wing_facets=wings, wing_deg=wing_deg,
                         wing_drop_deg=wing_drop)
        layout.check()
        previous = list(rec.get("model") or [])
        first_round = len(previous)
        start = ",".join(repr(float(t)) for t in x_prev)
        ring_offsets = "given"
    x0 = None
    if start is not None:
        try:
            x0 = [float(t) for t in start.split(",")]
        except ValueError:
            raise InputError(f"--start must be comma-separated numbers, got {start!r}") from None
        if len(x0) != layout.n_params or not all(map(math.isfinite, x0)):
            raise InputError(f"--start needs {layout.n_params} finite numbers for "
                             f"{rings} rings, got {len(x0)}")
    check_out_dir(str(Path(out_glb).resolve().parent))
    t0 = time.perf_counter()

    def note(text: str) -> None:
        if not quiet:
            click.echo(text, err=True)

    def progress(i: int, e: dict) -> None:
        if not quiet and "model_evaluation" in e:
            click.echo(f"model round {e['round']} eval {e['model_evaluation']:5d}  "
                       f"J={e['objective']:.4f}  {e['seconds']:.0f} s  short: "
                       f"{', '.join(e['failing']) or '-'}", err=True)
        elif not quiet:
            x = ", ".join(f"{v:+.2f}" for v in e["x"])
            click.echo(f"round {e['round']} eval {i:3d}  J={e['objective']:.4f}  "
                       f"{e['seconds']:.1f} s  x=({x})  short: "
                       f"{', '.join(e['failing']) or '-'}", err=True)

    def run(seed_k: int):
        return design_lowbeam(regulation, layout=layout, photons=photons, resolution=res,
                              evaluations=evaluations, rounds=rounds, seed=seed_k,
                              safety=safety, reach_m=reach, validate_factor=validate_factor,
                              x0=x0, progress=progress, optimiser=optimiser,
                              model_rounds=model_rounds, model_photons=model_photons,
                              model_resolution=mres, model_evaluations=model_evaluations,
                              calibrate=ring_offsets is None, note=note,
                              interval_photons=interval_photons, model_safety=model_safety,
                              first_round=first_round, foreground_m=foreground,
                              aim_photons=aim_photons, remeasure_steps=remeasure,
                              aim_rounds=aim_rounds, reach_weight=reach_weight,
                              model_smooth_px=model_smooth,
                              linearity_photons=linearity_photons)

    def record(out, seed_k: int) -> dict:
        return {"command": "lightsim design", "regulation": regulation, "seed": seed_k,
                "photons": photons, "resolution": list(res),
                "evaluations": len(out.history),
                "objective": out.objective if math.isfinite(out.objective) else None,
                "optimiser": optimiser,
                "model": previous + out.model,
                "validation_objective": (out.validation_objective
                                         if math.isfinite(out.validation_objective)
                                         else None)}

    if restarts == 1:
        out = run(seed)
        info = record(out, seed)
    else:
        out, info = _restarts(run, record, restarts, seed, out_glb, regulation, traffic,
                              restart_photons, check_res, check_seeds, aim_photons == 0,
                              note)
    size = write_design(out_glb, out.x, out.layout, info)
    what = ("model improvements" if out.model else "evaluations")
    click.echo(f"design: {len(out.history)} {what} in {out.seconds:.1f} s; "
               f"J = {out.objective:.4f} (validation, fresh seed ×{validate_factor} "
               f"photons: {out.validation_objective:.4f}); wrote {out_glb} ({size:,} bytes)")
    click.echo("x = (" + ", ".join(f"{v:+.4f}" for v in out.x) + "); ring offsets = ("
               + ", ".join(f"{d:+.3f}" for d in out.layout.ring_offsets_deg)
               + ")° from " + str(len(out.calibration_deg)) + " calibration steps")
    rows = out.validation or out.terms
    click.echo(f"{'term':14s} {'value':>10s}  {'log-margin':>10s}  target")
    for t in rows:
        v = "-" if t.value is None else f"{t.value:,.4g}"
        click.echo(f"{t.name:14s} {v:>10s}  {t.margin:+10.3f}  {t.target}"
                   + ("   SHORT" if t.margin < 0 else ""))
    for m in out.model:
        if m["round"] == "aim":
            click.echo(f"final aim step: every facet {m['aim_step_deg']:+.3f}°")
            continue
        if m["round"] == "linearity":
            def deg(v):
                return "-" if v is None else f"{v:.3f}°"

            moved = ", ".join(f"facet {k} {d:+.2f}°"
                              for k, d in zip(m["candidates"], m["shifts_deg"]))
            click.echo(f"linearity step: annex-9 scans' spread {deg(m['spread_before_deg'])}"
                       f" → {deg(m['spread_after_deg'])} ({moved or 'nothing moved'}; "
                       f"{m['evaluations']} simulated tries in {m['seconds']:.0f} s)")
            continue
        again = "; ".join(f"× {t['step']:g} re-measured J {t['objective']:.4f}"
                          for t in m.get("remeasured", []))
        click.echo(f"model round {m['round']}: {m['facets']} facets' footprints measured in "
                   f"{m['footprint_seconds']:.0f} s; J {m['start_objective']:.4f} → "
                   f"{m['objective']:.4f} in {m['evaluations']} model evaluations"
                   + (f"; {again}; kept × {m['accepted_step']:g}" if again else ""))
    for rs in (regulation.split(",") if check_photons else []):
        opts = SimulateOptions(out_glb, out_dir=str(Path(check_dir) / rs.strip()),
                               photons=check_photons, regulation=rs.strip(),
                               traffic=traffic, aim=aim_photons == 0,
                               config={"seed": seed + 2000})
        sim = run_simulation(opts, analyses=for_options(opts))
        Console(width=120).print(format_regulation(sim.summary["regulation"]))
    if restarts > 1:
        click.echo(f"{'restart':>7s} {'seed':>5s} {'J':>8s} {'not passing':>11s} "
                   f"{'min margin':>10s}")
        for k, r in enumerate(info["restarts"]):
            m = float(r["check"]["min_margin"])
            j = math.nan if r["objective"] is None else r["objective"]
            click.echo(f"{k:7d} {r['seed']:5d} {j:8.4f} "
                       f"{len(r['check']['not_passing']):11d} {m:+10.3f}"
                       + ("   chosen" if k == info["chosen"] else ""))
    click.echo(f"total {time.perf_counter() - t0:.1f} s")


def _restarts(run, record, n: int, seed: int, out_glb: str, regulation: str, traffic: str,
              photons: int, resolution: tuple[int, int], seeds: list[int], aim: bool,
              note) -> tuple:
    """Design ``n`` lamps at seeds ``seed`` … ``seed + n − 1``, check each
    (:func:`lightsim.luminaires.design_check.check_lamp`) and return the chosen design and
    its record (with every restart's check)."""
    import shutil
    import tempfile

    from lightsim.luminaires.design import write_design
    from lightsim.luminaires.design_check import check_lamp, choose

    work = Path(tempfile.mkdtemp(prefix=".lightsim-restarts-",
                                 dir=str(Path(out_glb).resolve().parent)))
    outs, checks, seeds_k = [], [], []
    try:
        for k in range(n):
            s = seed + k
            note(f"restart {k + 1}/{n}: design seed {s}")
            out = run(s)
            glb = work / f"restart{k}.glb"
            write_design(glb, out.x, out.layout, record(out, s))
            note(f"restart {k + 1}/{n}: checking ({photons:,} photons, "
                 f"{resolution[0]}x{resolution[1]}, seeds {', '.join(map(str, seeds))})")
            chk = check_lamp(glb, regulation, photons=photons, resolution=resolution,
                             seeds=seeds, traffic=traffic, aim=aim, note=note)
            note(f"restart {k + 1}/{n}: {len(chk.not_passing)} of {chk.rows} rows not "
                 f"passing, smallest margin {chk.min_margin:+.3f}")
            outs.append(out)
            checks.append(chk)
            seeds_k.append(s)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    best = choose(checks, [o.objective for o in outs])
    info = record(outs[best], seeds_k[best])
    info["restarts"] = [{"seed": s, "objective": (o.objective if math.isfinite(o.objective)
                                                  else None), "check": c.to_dict()}
                        for s, o, c in zip(seeds_k, outs, checks)]
    info["chosen"] = best
    return outs[best], info
