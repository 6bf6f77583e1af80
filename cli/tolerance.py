"""``lightsim tolerance``: bulb-tolerance study (parse, call
:func:`lightsim.validation.tolerance.run_tolerance`, print)."""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, fields, replace
from typing import Any

import click
from rich.console import Console
from rich.table import Table

from lightsim.engine.config import RunConfig
from lightsim.errors import InputError
from lightsim.luminaires.regulations import load_ruleset
from lightsim.luminaires.regulations.check import split_rulesets
from lightsim.options import click_option, lookup, parse_pair
from lightsim.simulate import SimulateOptions, check_out_dir, load
from lightsim.validation.tolerance import (
    MM,
    ToleranceBox,
    ToleranceStudy,
    box_for_scene,
    run_tolerance,
    write_study,
)


@dataclass(frozen=True)
class _Study:
    """The study's own options (those of the run every sample repeats go to
    :class:`~lightsim.simulate.SimulateOptions`)."""

    samples: int
    design_seed: int
    tilt: bool
    box_mm: str | None
    tilt_deg: float | None
    bulb: str | None
    centre_mm: str | None
    workers: int
    address: str | None


def _box(text: str | None, tilt_deg: float | None):
    """``DX,DY,DZ`` half-widths in mm → a ToleranceBox (None: the bulb's)."""
    if text is None:
        return None
    try:
        vals = [float(p) for p in text.split(",")]
    except ValueError:
        raise InputError(f"--box must be DX,DY,DZ in mm, got '{text}'") from None
    if len(vals) != 3 or not all(math.isfinite(v) and v >= 0 for v in vals):
        raise InputError(f"--box must be three half-widths ≥ 0 mm, got '{text}'")
    return ToleranceBox("given", tuple(v * MM for v in vals),  # type: ignore[arg-type]
                        1.0 if tilt_deg is None else tilt_deg, "given by the user (--box)")


def _centre(text: str | None) -> tuple[float, float, float]:
    """``DX,DY,DZ`` in mm → metres."""
    if text is None:
        return (0.0, 0.0, 0.0)
    try:
        vals = [float(p) * 1e-3 for p in text.split(",")]
    except ValueError:
        raise InputError(f"--centre must be DX,DY,DZ in mm, got '{text}'") from None
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise InputError(f"--centre must be three finite numbers in mm, got '{text}'")
    return (vals[0], vals[1], vals[2])


@click.command()
@click.argument("scene_file", type=click.Path(dir_okay=False))
@click.option("--regulation", required=True,
              help="Rule set(s), e.g. r112-b-passing or r112-b-passing,r149-b-passing "
                   "(several: point names carry the set, e.g. r149-b-passing:50V).")
@click.option("--samples", type=int, default=50, show_default=True,
              help="Latin-hypercube samples over the tolerance box (plus the nominal).")
@click.option("--photons", "-n", type=int, default=1_000_000, show_default=True,
              help="Photons per sample (the same photons for every sample; the 0.15° "
                   "apertures need ≥ 1 M for verdicts that are not 'uncertain'); with "
                   "--until decided, the most a sample may take.")
@click_option(lookup(SimulateOptions, "until"))  # each sample stops when decided
@click_option(lookup(RunConfig, "seed"))  # common to all samples
@click.option("--design-seed", type=int, default=1, show_default=True,
              help="Seed of the Latin-hypercube design.")
@click.option("--tilt", is_flag=True, help="Also tilt the filament (about X and Y).")
@click.option("--box", "box_mm", metavar="DX,DY,DZ",
              help="Half-widths of the box in mm (default: the bulb category's).")
@click.option("--tilt-deg", type=float, help="Half-width of the tilt in degrees.")
@click.option("--bulb", help="Bulb category when the scene does not name one (H1, H4, H7).")
@click.option("--resolution", default="160x64", show_default=True, help="Wall pixels WxH.")
@click_option(lookup(RunConfig, "frame_photons"))
@click_option(lookup(SimulateOptions, "traffic"))
@click.option("--aim", is_flag=True, help="Aim every sample's cut-off at 0.57° D first.")
@click_option(lookup(SimulateOptions, "aperture"))  # simulate's estimator, its default
@click.option("--centre", "centre_mm", metavar="DX,DY,DZ",
              help="Shift the whole box by this much in mm (a misplaced bulb holder).")
@click_option(lookup(SimulateOptions, "workers"))  # each sample one Ray task
@click.option("--address", help="Ray cluster address HOST:PORT.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="tolerance-out",
              show_default=True)
@click.option("--quiet", "-q", is_flag=True)
def tolerance(scene_file: str, regulation: str, photons: int, out_dir: str, quiet: bool,
              **values: Any) -> None:
    """Move the filament of SCENE_FILE within its bulb's tolerance box, simulate every
    sample with common random numbers and report regulation pass rates."""
    study = _Study(**{f.name: values.pop(f.name) for f in fields(_Study)})
    if study.samples < 1:
        raise InputError(f"--samples must be ≥ 1, got {study.samples}")
    if photons < 1:
        raise InputError(f"--photons must be ≥ 1, got {photons}")
    if study.workers < 0:
        raise InputError(f"--workers must be ≥ 0, got {study.workers}")
    tilt_deg = study.tilt_deg
    if tilt_deg is not None and not (math.isfinite(tilt_deg) and tilt_deg >= 0):
        raise InputError(f"--tilt-deg must be ≥ 0, got {tilt_deg}")
    for rs in split_rulesets(regulation):
        load_ruleset(rs)
    opts = SimulateOptions(scene_path=scene_file, out_dir=out_dir, photons=photons,
                           resolution=parse_pair(values["resolution"], "--resolution", int),
                           config={"seed": values["seed"],
                                   "frame_photons": values["frame_photons"]},
                           regulation=regulation, traffic=values["traffic"], aim=values["aim"],
                           aperture=values["aperture"], until=values["until"])
    opts.run_config()
    box = _box(study.box_mm, tilt_deg)
    if box is None:
        box = box_for_scene(load(opts), study.bulb)
        if tilt_deg is not None:
            box = replace(box, tilt_deg=tilt_deg)
    out = check_out_dir(out_dir)
    t0 = time.perf_counter()

    def progress(i: int, s) -> None:
        if not quiet:
            o = s.offset
            fails = [n for n, ok in zip(s.names, s.value_pass) if not ok]
            used = ("" if s.photons is None else f"{s.photons:>12,} photons "
                    + ("decided  " if s.decided else "cap      "))
            click.echo(f"sample {i:3d}  d=({o[0] * 1e3:+.3f}, {o[1] * 1e3:+.3f}, "
                       f"{o[2] * 1e3:+.3f}) mm tilt=({o[3]:+.2f}, {o[4]:+.2f})°  "
                       f"{s.seconds:5.1f} s  {used}fails: {', '.join(fails) or '-'}",
                       err=True)

    result = run_tolerance(opts, samples=study.samples, seed=study.design_seed,
                           tilt=study.tilt, box=box, centre_m=_centre(study.centre_mm),
                           workers=study.workers,
                           address=study.address or os.environ.get("RAY_ADDRESS"),
                           progress=progress)
    files = write_study(result, out)
    _print(result)
    used = result.photons_used()
    each = (f"{photons:,} photons each" if used is None else
            f"{used['min']:,}–{used['max']:,} photons each (median {used['median']:,.0f}; "
            f"{used['decided']} of {used['samples']} decided before the cap of {photons:,})")
    click.echo(f"{len(result.samples) - 1} samples + nominal, {each}, in "
               f"{time.perf_counter() - t0:.1f} s; wrote "
               + ", ".join(str(f.name) for f in files) + f" in {out}")


def _print(study: ToleranceStudy) -> None:
    b = study.box
    rate, ci = study.all_pass_rate()
    how = (f"{study.aperture_deg:g}° apertures" if study.aperture_deg else "kNN at the points")
    table = Table(title=f"{study.regulation}: filament box ±{b.half_m[0] * 1e3:.2f} × "
                  f"±{b.half_m[1] * 1e3:.2f} × ±{b.half_m[2] * 1e3:.2f} mm"
                  + (f", tilt ±{b.tilt_deg:g}°" if study.tilt else "")
                  + f" ({b.category}), {how}; all points pass in {rate:.0%} "
                  f"[{ci[0]:.0%}–{ci[1]:.0%}]")
    for col in ("rule", "limit cd", "centre cd", "centre", "pass rate",
                f"{int(study.confidence * 100)}% interval", "sure pass", "sure fail",
                "worst cd", "worst at (mm)"):
        table.add_column(col)
    for p in study.points:
        lim = " ".join(f"{'≥' if k == 'min' else '≤'} {v:,.0f}" for k, v in p.limit.items())
        o = p.worst_offset
        table.add_row(p.name, lim, f"{p.nominal_cd:,.0f}", p.nominal_verdict,
                      f"{p.pass_rate:.0%}", f"{p.pass_interval[0]:.0%}–{p.pass_interval[1]:.0%}",
                      f"{p.sure_pass_rate:.0%}", f"{p.sure_fail_rate:.0%}",
                      f"{p.worst_cd:,.0f}",
                      f"{o[0] * 1e3:+.2f},{o[1] * 1e3:+.2f},{o[2] * 1e3:+.2f}")
    console = Console(width=160)
    console.print(table)
    console.print(_sensitivity_table(study))
    click.echo(f"box source: {b.source}")


def _sensitivity_table(study: ToleranceStudy) -> Table:
    """Slopes (cd per 0.1 mm, ± standard error) and the single-axis shift to the limit."""
    axes = ["dx", "dy", "dz"] + (["tilt_x", "tilt_y"] if study.tilt else [])
    table = Table(title="sensitivity: least-squares plane over the samples, cd per 0.1 mm"
                  + (" (tilts: per 0.1°)" if study.tilt else "")
                  + " ± standard error; reach = shift along that axis alone to the limit "
                  "(in parentheses: outside the box, extrapolated); low R² = not a plane")
    half_mm = [h * 1e3 for h in study.box.half_m]
    for col in ("rule", "plane at centre cd", "rms cd", "R²",
                *(f"{a} cd/step" for a in axes), *(f"reach {a} mm" for a in axes[:3])):
        table.add_column(col)
    for p in study.points:
        s = p.sensitivity
        if s is None:
            continue
        slope, reach = [], []
        for a in axes:
            k = s.axes.index(a) if a in s.axes else None
            slope.append("–" if k is None else
                         f"{s.per_step_cd[k]:+,.0f} ± {s.se_cd[k]:,.0f}")
            if a in axes[:3]:
                j = axes.index(a)
                r = None if k is None else s.reach_mm[k]
                inside = r is not None and abs(r) <= half_mm[j] + 1e-9  # r: from the centre
                reach.append("–" if r is None else f"{r:+.2f}" if inside else f"({r:+.2f})")
        table.add_row(p.name, f"{s.centre_cd:,.0f}", f"{s.rms_cd:,.0f}", f"{s.r2:.2f}",
                      *slope, *reach)
    return table
