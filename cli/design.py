"""``lightsim design``: aim a multi-facet reflector at a regulation target (parse, call
:func:`lightsim.luminaires.design.design_lowbeam`, write the GLB, check it, print)."""

from __future__ import annotations

import time

import click

from lightsim.errors import InputError


@click.command()
@click.argument("out_glb", type=click.Path(dir_okay=False))
@click.option("--bulb", default="H4", show_default=True,
              help="Bulb: H4 (its passing filament and shield cup) or a preset name.")
@click.option("--regulation", required=True, help="Rule set target, e.g. r112-b-passing.")
@click.option("--facets", type=int, default=8, show_default=True)
@click.option("--focal-length", type=float, default=25.0, show_default=True, help="mm")
@click.option("--opening", type=float, default=160.0, show_default=True,
              help="Lamp opening (reflector rim diameter), mm.")
@click.option("--evaluations", type=int, default=30, show_default=True,
              help="Nelder–Mead function evaluations (each one simulation).")
@click.option("--photons", "-n", type=int, default=100_000, show_default=True,
              help="Photons per evaluation (the same photons for every evaluation).")
@click.option("--check-photons", type=int, default=400_000, show_default=True,
              help="Photons of the final check of the written lamp (0: no check).")
@click.option("--seed", type=int, default=1, show_default=True)
@click.option("--safety", type=float, default=0.10, show_default=True,
              help="Relative margin asked beyond every limit.")
@click.option("--traffic", type=click.Choice(["right", "left"]), default="right",
              show_default=True)
@click.option("--out", "check_dir", type=click.Path(file_okay=False), default="design-check",
              show_default=True, help="Folder of the final check run.")
@click.option("--aim", is_flag=True,
              help="Aim every candidate's cut-off at 0.57° D before evaluating (and check).")
@click.option("--quiet", "-q", is_flag=True)
def design(out_glb: str, bulb: str, regulation: str, facets: int, focal_length: float,
           opening: float, evaluations: int, photons: int, check_photons: int, seed: int,
           safety: float, traffic: str, check_dir: str, aim: bool, quiet: bool) -> None:
    """Design a multi-facet low-beam reflector for BULB aimed at REGULATION; write OUT_GLB
    (reflector, bulb, shield, lens), then simulate it and print the regulation table."""
    from rich.console import Console

    from lightsim.luminaires.analyses import for_options
    from lightsim.luminaires.bulbs import get_bulb
    from lightsim.luminaires.design import design_lowbeam, write_design
    from lightsim.luminaires.regulations.check import format_regulation
    from lightsim.simulate import SimulateOptions, check_out_dir, run_simulation

    name = "H4-low" if bulb.strip().upper() == "H4" else get_bulb(bulb).name
    if not str(out_glb).lower().endswith(".glb"):
        raise InputError(f"{out_glb}: the output must be a .glb file")
    if check_photons < 0:
        raise InputError(f"--check-photons must be ≥ 0, got {check_photons}")
    check_out_dir(str(__import__("pathlib").Path(out_glb).resolve().parent))
    t0 = time.perf_counter()

    def progress(i: int, e: dict) -> None:
        if not quiet:
            x = ", ".join(f"{v:+.3f}" for v in e["x"])
            click.echo(f"eval {i:3d}  x=({x})°  J={e['objective']:.4f}  "
                       f"{e['seconds']:.1f} s  fails: {', '.join(e['failing']) or '-'}",
                       err=True)

    res = design_lowbeam(regulation, bulb=name, facets=facets,
                         focal_length_m=focal_length * 1e-3, aperture_m=opening * 1e-3,
                         photons=photons, evaluations=evaluations, seed=seed, safety=safety,
                         traffic=traffic, aim=aim, progress=progress)
    size = write_design(out_glb, res.x, facets, name, focal_length * 1e-3, opening * 1e-3,
                        traffic)
    click.echo(f"design: {len(res.history)} evaluations in {res.seconds:.1f} s; best "
               f"x = (v0, h0, spread, drop) = ({', '.join(f'{v:+.3f}' for v in res.x)})°, "
               f"J = {res.objective:.4f}; wrote {out_glb} ({size:,} bytes)")
    if check_photons:
        opts = SimulateOptions(out_glb, out_dir=check_dir, photons=check_photons,
                               regulation=regulation, traffic=traffic, aim=aim,
                               config={"seed": seed})
        sim = run_simulation(opts, analyses=for_options(opts))
        Console(width=120).print(format_regulation(sim.summary["regulation"]))
    click.echo(f"total {time.perf_counter() - t0:.1f} s")
