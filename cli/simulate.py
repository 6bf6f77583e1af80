"""``lightsim simulate``: parse options, run :func:`lightsim.simulate.run_simulation`, print."""

from __future__ import annotations

import math
import signal
import sys
import time
from typing import Any

import click

from lightsim.errors import InputError


def _pair(text: str | None, what: str, cast=float) -> tuple | None:
    if text is None:
        return None
    parts = text.lower().replace("×", "x").split("x")
    try:
        vals = tuple(cast(p) for p in parts)
    except ValueError:
        raise InputError(f"{what} must look like AxB, got '{text}'") from None
    if len(vals) != 2 or not all(v > 0 and math.isfinite(v) for v in vals):
        raise InputError(f"{what} must be two positive numbers AxB, got '{text}'")
    return vals


def _triple(text: str | None, what: str) -> tuple[float, float, float] | None:
    if text is None:
        return None
    try:
        vals = tuple(float(p) for p in text.split(","))
    except ValueError:
        raise InputError(f"{what} must be X,Y,Z in metres, got '{text}'") from None
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise InputError(f"{what} must be three finite numbers X,Y,Z, got '{text}'")
    return vals  # type: ignore[return-value]


def _part_materials(items: tuple[str, ...]) -> dict[str, str]:
    out = {}
    for item in items:
        name, sep, spec = item.partition("=")
        if not sep or not name or not spec:
            raise InputError(f"--part-material must be NAME=KIND[:VALUE], got '{item}'")
        out[name] = spec
    return out


class _Progress:
    """Progress line: photons, photons/s, frames/s, estimated error, ETA."""

    def __init__(self, quiet: bool, photons: int | None, seconds: float | None,
                 target: float | None) -> None:
        self.quiet = quiet
        self.photons, self.seconds, self.target = photons, seconds, target
        self.progress = None
        self.task = None
        self.t0 = time.perf_counter()
        self.frames = 0

    def __enter__(self) -> _Progress:
        if not self.quiet:
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

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
        self.progress.update(self.task, completed=frac, info=info)


@click.command()
@click.argument("scene_file", required=False, type=click.Path(dir_okay=False))
@click.option("--photons", "-n", type=int, help="Photons to shoot in total (default 1 frame).")
@click.option("--time", "seconds", type=float, help="Stop after this many seconds.")
@click.option("--target-error", type=float,
              help="Stop when the estimated relative error over the lit region is ≤ this.")
@click.option("--seed", type=int, default=1, show_default=True)
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="lightsim-out",
              show_default=True, help="Output folder.")
@click.option("--resolution", default="640x256", show_default=True, help="Wall pixels WxH.")
@click.option("--wall-distance", type=float, default=25.0, show_default=True,
              help="Distance of the added wall (m), if the file has none.")
@click.option("--wall-size", default="30x12", show_default=True,
              help="Size WxH of the added wall (m), centred on H-V.")
@click.option("--estimator", type=click.Choice(["knn", "bin", "radius"]), default="knn",
              show_default=True, help="Density estimator on the wall.")
@click.option("-k", "k", type=int, default=64, show_default=True, help="Photons per kNN estimate.")
@click.option("--max-radius", type=float,
              help="Largest kNN radius (m); default 2 × min radius; 'inf' = unlimited.")
@click.option("--min-radius", type=float,
              help="Smallest kNN radius (m); default: the filter window's area.")
@click.option("--bandwidth", type=click.Choice(["ici", "knn"]), default="ici", show_default=True,
              help="Written map's radius: ici = per pixel, the largest window the photon "
                   "counts do not contradict (consistent); knn = r_k in [pixel disk, 4×].")
@click.option("--kernel", type=click.Choice(["box", "cone", "epanechnikov"]), default="box",
              show_default=True)
@click.option("--interleave", "-M", type=int, default=4, show_default=True,
              help="M: M×M interleave sets.")
@click.option("--filter", "filter_size", type=int, help="Box filter size n (default M).")
@click.option("--final", type=click.Choice(["pooled", "interleaved"]), default="pooled",
              show_default=True,
              help="Written lux map: every set at every pixel (full resolution, honest "
                   "error) or the paper's interleaved + box-filtered frame (fast, blurred).")
@click.option("--frame-photons", type=int, default=200_000, show_default=True,
              help="Photons per frame (all sets).")
@click.option("--structure", type=click.Choice(["middle", "median", "grid-lo", "grid-hi"]),
              default="middle", show_default=True, help="Photon map index.")
@click.option("--spt/--no-spt", default=None, help="Force Selective Photon Tracing on/off.")
@click.option("--flux", type=float, help="Luminous flux of the emitter(s) in lm.")
@click.option("--emission", type=click.Choice(["isotropic", "lambertian"]))
@click.option("--filament", help="Bulb preset for a mesh without emitter (e.g. H7).")
@click.option("--filament-at", help="Filament centre X,Y,Z (m).")
@click.option("--filament-axis", default="0,0,1", show_default=True,
              help="Filament axis X,Y,Z.")
@click.option("--rayfile", type=click.Path(dir_okay=False),
              help="LED/bulb ray file (IES TM-25 .tm25ray or Zemax binary .dat/.ray) as the "
                   "light source, replacing the scene's emitters.")
@click.option("--rayfile-at", help="Where the ray file's origin goes, X,Y,Z (m).")
@click.option("--rayfile-axis", default="0,0,1", show_default=True,
              help="Where the ray file's +Z points, X,Y,Z.")
@click.option("--materials", "materials", type=click.Path(dir_okay=False),
              help="Material map (TOML): part-name pattern → mirror/glass/diffuse/emitter/"
                   "ignore, for CAD files without optics.")
@click.option("--cad-linear-tol", type=float, default=0.01, show_default=True,
              help="STEP/IGES tessellation: largest facet-to-surface distance (mm).")
@click.option("--cad-angular-tol", type=float, default=2.0, show_default=True,
              help="STEP/IGES tessellation: largest angle between facet normals (deg).")
@click.option("--part-material", multiple=True,
              help="NAME=mirror[:R]|glass[:n]|diffuse[:ρ]|wall|ignore (repeatable).")
@click.option("--regulation", help="Rule set to check, e.g. r112-b-passing (see "
              "`lightsim report --list-rulesets`).")
@click.option("--traffic", type=click.Choice(["right", "left"]), default="right",
              show_default=True)
@click.option("--aim", is_flag=True, help="Aim the cut-off at 0.57° D before checking.")
@click.option("--aperture", type=float, default=0.15, show_default=True,
              help="Side (deg) of the square detector aperture each regulation test point "
              "counts photons in (0.15° ≈ 65 mm at 25 m); 0 = kNN estimate instead.")
@click.option("--spt-points/--no-spt-points", default=False, show_default=True,
              help="Aim Selective Photon Tracing at the regulation's test points.")
@click.option("--ies", "ies_out", type=click.Path(dir_okay=False),
              help="Write the far-field intensity as IES LM-63-2002.")
@click.option("--ldt", "ldt_out", type=click.Path(dir_okay=False),
              help="Write the far-field intensity as EULUMDAT.")
@click.option("--ies-type", default="auto", show_default=True, metavar="auto|A|C",
              help="Photometric type of --ies: A (vehicle lamps: H right, "
              "V up), C; auto = A for lamp models and Type A inputs, else C.")
@click.option("--lamp-set", default=None, metavar="N",
              help="EULUMDAT scene file: which lamp set (1-based) scales the intensities "
              "(default: the first, with a warning when there are several).")
@click.option("--farfield-photons", type=int, default=1_000_000, show_default=True)
@click.option("--mount-height", type=float, default=0.65, show_default=True,
              help="Lamp height above the road for the road view (m).")
@click.option("--log", "log_scale", is_flag=True, help="Logarithmic colour scale in the PNG.")
@click.option("--workers", type=int, default=0, show_default=True,
              help="0: in-process; N: N Ray actors on this machine.")
@click.option("--address", help="Ray cluster address HOST:PORT (or set RAY_ADDRESS).")
@click.option("--resume", "resume_dir", type=click.Path(file_okay=False),
              help="Continue an interrupted run from its output folder.")
@click.option("--explain", is_flag=True, help="Print which stages run and why.")
@click.option("--quiet", "-q", is_flag=True, help="No progress output.")
def simulate(scene_file: str | None, photons: int | None, seconds: float | None,
             target_error: float | None, seed: int, out_dir: str, resolution: str,
             wall_distance: float, wall_size: str, estimator: str, k: int,
             max_radius: float | None, min_radius: float | None, kernel: str, interleave: int,
             filter_size: int | None, final: str, frame_photons: int, structure: str,
             spt: bool | None,
             flux: float | None, emission: str | None, filament: str | None,
             filament_at: str | None, filament_axis: str, part_material: tuple[str, ...],
             regulation: str | None, traffic: str, aim: bool, aperture: float,
             spt_points: bool, ies_out: str | None,
             ldt_out: str | None, ies_type: str, lamp_set: str | None,
             farfield_photons: int, mount_height: float,
             log_scale: bool, workers: int, address: str | None, resume_dir: str | None,
             explain: bool, quiet: bool, rayfile: str | None = None,
             rayfile_at: str | None = None, rayfile_axis: str = "0,0,1",
             materials: str | None = None, cad_linear_tol: float = 0.01,
             cad_angular_tol: float = 2.0, bandwidth: str = "ici") -> None:
    """Simulate SCENE_FILE (GLB/glTF/OBJ/STL/PLY, STEP/IGES, a .tm25ray ray file) and write
    the wall illuminance in lux."""
    import os

    from lightsim.simulate import SimulateOptions, read_checkpoint, run_simulation

    resume = None
    if resume_dir is not None:
        if scene_file is not None:
            raise InputError("--resume continues a run with its own scene: give no SCENE_FILE")
        opts, resume = read_checkpoint(resume_dir)
    elif scene_file is None:
        raise InputError("missing SCENE_FILE (or --resume DIR)")
    else:
        res = _pair(resolution, "--resolution", int)
        if workers < 0:
            raise InputError(f"--workers must be ≥ 0, got {workers}")
        config: dict[str, Any] = {
            "seed": seed, "interleave": interleave, "estimator": estimator, "k": k,
            "kernel": kernel, "filter_size": filter_size, "final": final,
            "frame_photons": frame_photons,
            "structure": structure, "spt": spt, "min_radius": min_radius,
            "max_radius": max_radius, "bandwidth": bandwidth}
        opts = SimulateOptions(
            scene_path=scene_file, out_dir=out_dir, photons=photons, seconds=seconds,
            target_error=target_error, flux=flux, emission=emission, filament=filament,
            filament_at=_triple(filament_at, "--filament-at"),
            filament_axis=_triple(filament_axis, "--filament-axis") or (0.0, 0.0, 1.0),
            wall_distance=wall_distance, wall_size=_pair(wall_size, "--wall-size"),
            resolution=res, part_materials=_part_materials(part_material), config=config,
            log_scale=log_scale, workers=workers,
            address=address or os.environ.get("RAY_ADDRESS") or None,
            regulation=regulation, traffic=traffic, aim=aim, ies=ies_out, ldt=ldt_out,
            farfield_photons=farfield_photons, mount_height=mount_height, ies_type=ies_type,
            lamp_set=_lamp_set(lamp_set), aperture=aperture, spt_points=spt_points,
            rayfile=rayfile, rayfile_at=_triple(rayfile_at, "--rayfile-at"),
            rayfile_axis=_triple(rayfile_axis, "--rayfile-axis") or (0.0, 0.0, 1.0),
            materials=materials, cad_linear_tol_mm=cad_linear_tol,
            cad_angular_tol_deg=cad_angular_tol)
        opts.run_config()  # validate the settings before any work
    from lightsim.luminaires.analyses import for_options

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

    try:
        with _Progress(quiet, opts.photons, opts.seconds, opts.target_error) as prog:
            result = run_simulation(opts, progress=prog, should_stop=lambda: stop["signal"]
                                    is not None, on_plan=on_plan, resume=resume,
                                    analyses=analyses)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if result.interrupted:
        click.echo(f"lightsim: interrupted; checkpoint written to {result.out_dir}/"
                   f"checkpoint.json — continue with: lightsim simulate --resume "
                   f"{result.out_dir}", err=True)
        raise SystemExit(130)
    ff_note = result.summary.get("farfield", {}).get("warning")
    if ff_note:  # flux a written Type A file leaves out
        click.echo(f"lightsim: warning: {ff_note}", err=True)
    if not quiet:
        s = result.summary
        e = s["energy_lm"]
        err = s.get("error_text") or "–"
        click.echo(f"{s['photons']:,} photons in {s['seconds']:.1f} s, {s['frames']} frames; "
                   f"estimated error {err}; max {s['lux']['max_lx']:.4g} lx")
        absorbed = e["absorbed_diffuse"] + e["absorbed_mirror"] + e["absorbed_volume"]
        click.echo(f"energy (lm): emitted {e['emitted']:.6g} = wall {e['wall']:.6g} + "
                   f"absorbed {absorbed:.6g} + escaped {e['escaped']:.6g} + "
                   f"roulette {e['roulette']:.3g} + max depth {e['max_depth']:.3g}")
        if "road" in s:
            click.echo(f"road view (lamp {s['road']['mount_height_m']:g} m high): "
                       f"{s['road']['text']}")
        if "regulation" in s:
            from rich.console import Console

            from lightsim.luminaires.regulations.check import format_regulation

            Console(width=None if sys.stdout.isatty() else 160).print(
                format_regulation(s["regulation"]))
        extra = ", probes.npz" if "regulation" in s else ""
        click.echo(f"wrote {result.out_dir}/wall_lux.exr, wall_lux.png, isolux.png, road.png, "
                   f"error_vs_time.png, summary.json{extra}")
        for f in s.get("farfield", {}).get("files", []):
            click.echo(f"wrote {f} ({s['farfield']['total_flux_lm']:.1f} lm leave the lamp)")


def _lamp_set(text: str | None) -> int | None:
    """``--lamp-set N`` as a positive int (one error line otherwise)."""
    if text is None:
        return None
    try:
        n = int(text)
    except ValueError:
        raise InputError(f"--lamp-set must be a whole number ≥ 1, got '{text}'") from None
    if n < 1:
        raise InputError(f"--lamp-set must be a whole number ≥ 1, got {n}")
    return n
