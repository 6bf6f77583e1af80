"""``lightsim design``: a ring-and-sector multi-facet low beam aimed at a regulation target
(parse, call :func:`lightsim.luminaires.design.design_lowbeam`, write the GLB, check it,
print)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import click

from lightsim.engine.config import RunConfig
from lightsim.errors import InputError
from lightsim.options import click_option, lookup
from lightsim.simulate import SimulateOptions


def _resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(t) for t in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--resolution must be WxH, got {text!r}") from None
    if not (8 <= w <= 4096 and 8 <= h <= 4096):
        raise InputError(f"--resolution must be 8–4096 pixels a side, got {text!r}")
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
              help="1 lx road reach asked for, m (lamp 0.65 m high).")
@click_option(lookup(SimulateOptions, "traffic"))
@click.option("--out", "check_dir", type=click.Path(file_okay=False), default="design-check",
              show_default=True, help="Folder of the final check run.")
@click.option("--start", default=None,
              help="Comma-separated start vector x (h0, then spread, drop, scale per ring); "
                   "default: the geometric start.")
@click.option("--sign-share", type=float, default=0.03, show_default=True,
              help="Share of a lit vertex-ring facet's azimuth given to each overhead-sign "
                   "sliver (dim light above the cut-off: points 1-8); 0: none.")
@click.option("--quiet", "-q", is_flag=True)
def design(out_glb: str, bulb: str, regulation: str, rings: int, sectors: int,
           focal_length: float, opening: float, evaluations: int, rounds: int, photons: int,
           resolution: str, validate_factor: int, check_photons: int, seed: int,
           safety: float, reach: float, traffic: str, check_dir: str, start: str | None,
           sign_share: float, quiet: bool) -> None:
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
    layout = Layout(rings=rings, sectors=sectors, focal_length_m=focal_length * 1e-3,
                    aperture_m=opening * 1e-3, bulb=name, traffic=traffic,
                    sign_share=sign_share)
    layout.check()
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

    def progress(i: int, e: dict) -> None:
        if not quiet:
            x = ", ".join(f"{v:+.2f}" for v in e["x"])
            click.echo(f"round {e['round']} eval {i:3d}  J={e['objective']:.4f}  "
                       f"{e['seconds']:.1f} s  x=({x})  short: "
                       f"{', '.join(e['failing']) or '-'}", err=True)

    out = design_lowbeam(regulation, layout=layout, photons=photons, resolution=res,
                         evaluations=evaluations, rounds=rounds, seed=seed, safety=safety,
                         reach_m=reach, validate_factor=validate_factor, x0=x0,
                         progress=progress)
    info = {"command": "lightsim design", "regulation": regulation, "seed": seed,
            "photons": photons, "resolution": list(res), "evaluations": len(out.history),
            "objective": out.objective,
            "validation_objective": (out.validation_objective
                                     if math.isfinite(out.validation_objective) else None)}
    size = write_design(out_glb, out.x, out.layout, info)
    click.echo(f"design: {len(out.history)} evaluations in {out.seconds:.1f} s; "
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
    if check_photons:
        opts = SimulateOptions(out_glb, out_dir=check_dir, photons=check_photons,
                               regulation=regulation, traffic=traffic, aim=True,
                               config={"seed": seed + 2000})
        sim = run_simulation(opts, analyses=for_options(opts))
        Console(width=120).print(format_regulation(sim.summary["regulation"]))
    click.echo(f"total {time.perf_counter() - t0:.1f} s")
