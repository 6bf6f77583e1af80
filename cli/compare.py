"""``lightsim compare PHOTO``: measure a photographed beam's aim and match against a simulation.

The work is done by :mod:`lightsim.validation.compare`; this module parses options, prints
the transform and the metrics, and turns failed ``--fail-below``/``--fail-above`` limits
into exit code 1 (input errors exit with 2).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.table import Table

from lightsim.errors import InputError
from lightsim.validation.compare import (
    CompareOptions,
    failed_thresholds,
    load_transform,
    parse_threshold,
    run_compare,
)
from lightsim.validation.photo_pair import PairOptions, run_pair
from lightsim.validation.photo_register import RegistrationOptions


class ThresholdFailed(click.ClickException):
    """A metric missed its ``--fail-below``/``--fail-above`` limit (exit code 1)."""

    exit_code = 1

    def show(self, file=None) -> None:
        """Print one line naming the failed metrics (instead of click's 'Error: …')."""
        click.echo(f"lightsim: compare: {self.message}", err=True)


def _pair(text: str, name: str) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"{name} must be MIN,MAX, got {text!r}") from None
    return lo, hi


@click.command()
@click.argument("photo", type=click.Path(path_type=Path, dir_okay=False))
@click.option("--sim", "sim_path", type=click.Path(path_type=Path), default=Path("."),
              show_default=True, help="Result folder (with wall_lux.exr) or the EXR itself.")
@click.option("--out", "out_dir", type=click.Path(path_type=Path, file_okay=False),
              help="Output folder  [default: compare-<photo name>].")
@click.option("--homography/--similarity", "homography", default=False,
              help="Transform fitted: similarity (rotation, scale, shift; the default) or a "
                   "homography for photos taken at an angle.")
@click.option("--fit-gamma", is_flag=True, help="Also fit the tone curve's exponent.")
@click.option("--fail-below", multiple=True, metavar="METRIC=VALUE",
              help="Exit with code 1 if METRIC < VALUE (repeatable).")
@click.option("--fail-above", multiple=True, metavar="METRIC=VALUE",
              help="Exit with code 1 if METRIC > VALUE, for error metrics (repeatable).")
@click.option("--transform", "transform_file", type=click.Path(path_type=Path, dir_okay=False),
              help="Use this photo→simulation matrix (JSON with 'matrix', a comparison.json "
                   "or a synthetic photo's .truth.json) instead of registering.")
@click.option("--traffic", type=click.Choice(["right", "left"]), default="right",
              show_default=True, help="Side of the cut-off scans (R112).")
@click.option("--max-rotation", type=float, default=20.0, show_default=True,
              help="Rotations searched, ± degrees.")
@click.option("--scale-range", default="0.5,2", show_default=True,
              help="Scales searched MIN,MAX, relative to 'photo width = simulation width'.")
@click.option("--points", metavar='"x,y=H,V; …"',
              help="Control points: photo pixel (x = column, y = row) = screen angle H,V in "
                   "degrees; 4 or more fix the screen geometry (no registration by the beam).")
@click.option("--markers", default="auto", show_default=True, metavar="auto|off|LAYOUT.json",
              help="Find screen-target markers on the photo (default layout, or a "
                   "layout.json from 'lightsim screen-target').")
@click.option("--screen-distance", type=float, metavar="M",
              help="Lamp → screen distance of the photo in m  [default: the simulation's].")
@click.option("--normalise-at", metavar="POINT|H,V",
              help="Test point (or H,V degrees) the photo's relative test-point values are "
                   "normalised at  [default: 50R].")
@click.option("--lamp", type=click.Choice(["left", "right"]),
              help="The photo shows two lamps: compare this one (the other side is left out).")
@click.option("--against", "against", type=click.Path(path_type=Path, dir_okay=False),
              help="Compare PHOTO with this second photo of the same wall instead of a "
                   "simulation: aligned by the static scene, writes pair.json and "
                   "relative_difference.png.")
@click.option("--credit", help="Attribution printed on the figures (e.g. a photo's licence).")
@click.option("-q", "--quiet", is_flag=True, help="Print only failures.")
def compare(photo: Path, sim_path: Path, out_dir: Path | None, fail_below: tuple[str, ...],
            fail_above: tuple[str, ...], against: Path | None, quiet: bool,
            **settings: Any) -> None:
    """Compare PHOTO (PNG/JPEG/TIFF/EXR/camera raw) with a simulation, or with --against.

    With screen geometry (--points or markers on the photo) the aim is measured without
    moving the photo onto the beam; otherwise the photo is registered by the beam and the
    report says that aim cannot be judged. Writes comparison.json, overlay.png,
    difference.png and contours.png (or pair.json and relative_difference.png) to --out.
    """
    if against is not None:
        _compare_pair(photo, against, out_dir, settings, quiet)
        return
    below = [parse_threshold(t) for t in fail_below]
    above = [parse_threshold(t) for t in fail_above]
    options = _options(**settings)
    out = out_dir or Path(f"compare-{photo.stem}")
    result = run_compare(photo, sim_path, out, options)
    if not quiet:
        for line in result.photo.info.get("warnings", []):
            click.echo(f"lightsim: warning: {line}", err=True)
        _report(result, out)
    fails = failed_thresholds(result.metrics, below, above)
    if fails:
        raise ThresholdFailed("; ".join(fails))


def _options(homography: bool, fit_gamma: bool, transform_file: Path | None, traffic: str,
             max_rotation: float, scale_range: str, points: str | None, markers: str,
             screen_distance: float | None, normalise_at: str | None, lamp: str | None,
             credit: str | None) -> CompareOptions:
    """The comparison settings of the command's options (input errors in option order)."""
    reg = RegistrationOptions(max_rotation_deg=max_rotation,
                              scale_range=_pair(scale_range, "--scale-range"))
    options = CompareOptions(model="homography" if homography else "similarity",
                             fit_gamma=fit_gamma, traffic=traffic,
                             transform=load_transform(transform_file) if transform_file else None,
                             registration=reg, credit=credit, points=points,
                             markers=markers, screen_distance_m=screen_distance,
                             normalise_at=normalise_at, lamp=lamp)
    if screen_distance is not None and not (math.isfinite(screen_distance)
                                            and screen_distance > 0):
        raise InputError(f"--screen-distance must be > 0 m, got {screen_distance!r}")
    return options


def _report(result, out: Path) -> None:
    console = Console()
    _report_aim(console, result)
    t = result.transform_dict()
    console.print(f"transform ({t['model']}, photo px → simulation px): rotation "
                  f"{t['rotation_deg']:+.3f}°, scale {t['scale']:.5g}, translation "
                  f"({t['translation_px'][0]:.2f}, {t['translation_px'][1]:.2f}) px, overlap "
                  f"{100 * t['overlap_fraction']:.0f} %")
    if result.registration is not None and result.registration.blur_at_cap:
        console.print(f"registration: the fitted blur reached its cap "
                      f"({t['blur_cap_px']:.3g} simulation px): blur and cut-off offsets are "
                      "only bounds")
    p = result.photometric
    console.print(f"exposure: 1 lx → {p.gain:.4g} of full scale, gamma {p.gamma:.3f}, "
                  f"clips at {p.clip_lx:.4g} lx")
    table = Table(title="photo vs simulation")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for name, value in result.metrics.items():
        table.add_row(name, "–" if value is None else f"{value:.4g}")
    console.print(table)
    console.print(f"wrote {out}/comparison.json, overlay.png, difference.png, contours.png "
                  f"({result.seconds:.1f} s)")


def _report_aim(console, result) -> None:
    """The headline: the aim as measured, or why it cannot be judged."""
    aim = result.aim
    if aim is None:
        return
    if aim.markers is not None and (aim.judgeable or aim.refused):
        console.print(aim.markers["text"])
    if not aim.judgeable:
        console.print(f"[bold]AIM: {aim.statement}[/bold]")
    else:
        cut = aim.cutoff
        if cut.offset_deg is None:
            console.print(f"[bold]AIM: cut-off not measured[/bold] ({cut.message})")
        else:
            word = "higher" if cut.offset_deg > 0 else "lower"
            console.print(f"[bold]AIM: cut-off {cut.offset_deg:+.3f}° ± "
                          f"{cut.interval_deg:.3f}° (photo {word} than the simulation)"
                          f"[/bold] — {cut.message}")
        if aim.hotspot_dh_deg is not None:
            pm = f" ± {aim.hotspot_interval_deg:.3f}°" if aim.hotspot_interval_deg else ""
            console.print(f"hot spot: ΔH {aim.hotspot_dh_deg:+.2f}°, ΔV "
                          f"{aim.hotspot_dv_deg:+.2f}°{pm} (photo − simulation)")
        console.print(aim.statement)
    n = aim.normalised_at
    rows = ", ".join(
        f"{p.name} {'–' if p.photo_rel is None else f'{p.photo_rel:.3g}'}"
        f"{'≥' if p.clipped else ''} (sim {'–' if p.sim_rel is None else f'{p.sim_rel:.3g}'})"
        for p in aim.points)
    console.print(f"test points relative to {n['point']}: {rows}")


def _compare_pair(a_path: Path, b_path: Path, out_dir: Path | None, settings: dict[str, Any],
                  quiet: bool) -> None:
    """``compare A --against B``: photo against photo."""
    out = out_dir or Path(f"compare-{a_path.stem}-vs-{b_path.stem}")
    result, warnings = run_pair(a_path, b_path, out, settings["points"],
                                PairOptions(markers=settings["markers"]),
                                settings["screen_distance"], settings["traffic"],
                                settings["credit"])
    if quiet:
        return
    for line in warnings:
        click.echo(f"lightsim: warning: {line}", err=True)
    click.echo(result.statement)
    click.echo(f"exposure: B × {result.exposure_ratio:.4g} ({result.exposure_source})")
    for p in result.points:
        ch = "–" if p["change"] is None else f"{100 * p['change']:+.1f} %"
        flag = " (clipped/masked)" if p["unusable"] else ""
        click.echo(f"  {p['name']:>5} (H {p['h_deg']:+.2f}°, V {p['v_deg']:+.2f}°): {ch}{flag}")
    click.echo(f"wrote {out}/pair.json, relative_difference.png")
