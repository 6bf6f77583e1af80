"""``lightsim compare PHOTO``: register a photo of a beam pattern to a simulation and score it.

The work is done by :mod:`lightsim.validation.compare`; this module parses options, prints
the transform and the metrics, and turns failed ``--fail-below``/``--fail-above`` limits
into exit code 1 (input errors exit with 2).
"""

from __future__ import annotations

from pathlib import Path

import click

from lightsim.errors import InputError


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
@click.option("--max-rotation", type=float, default=15.0, show_default=True,
              help="Rotations searched, ± degrees.")
@click.option("--scale-range", default="0.5,2", show_default=True,
              help="Scales searched MIN,MAX, relative to 'photo width = simulation width'.")
@click.option("--credit", help="Attribution printed on the figures (e.g. a photo's licence).")
@click.option("-q", "--quiet", is_flag=True, help="Print only failures.")
def compare(photo: Path, sim_path: Path, out_dir: Path | None, homography: bool,
            fit_gamma: bool, fail_below: tuple[str, ...], fail_above: tuple[str, ...],
            transform_file: Path | None, traffic: str, max_rotation: float, scale_range: str,
            credit: str | None, quiet: bool) -> None:
    """Compare PHOTO (PNG/JPEG/TIFF/EXR) with a simulated wall illuminance map.

    Writes comparison.json, overlay.png, difference.png and contours.png to --out.
    """
    from lightsim.validation.compare import (
        CompareOptions,
        failed_thresholds,
        load_transform,
        parse_threshold,
        run_compare,
    )
    from lightsim.validation.photo_register import RegistrationOptions

    below = [parse_threshold(t) for t in fail_below]
    above = [parse_threshold(t) for t in fail_above]
    reg = RegistrationOptions(max_rotation_deg=max_rotation,
                              scale_range=_pair(scale_range, "--scale-range"))
    options = CompareOptions(model="homography" if homography else "similarity",
                             fit_gamma=fit_gamma, traffic=traffic,
                             transform=load_transform(transform_file) if transform_file else None,
                             registration=reg, credit=credit)
    out = out_dir or Path(f"compare-{photo.stem}")
    result = run_compare(photo, sim_path, out, options)
    if not quiet:
        _report(result, out)
    fails = failed_thresholds(result.metrics, below, above)
    if fails:
        raise ThresholdFailed("; ".join(fails))


def _report(result, out: Path) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    t = result.transform_dict()
    console.print(f"transform ({t['model']}, photo px → simulation px): rotation "
                  f"{t['rotation_deg']:+.3f}°, scale {t['scale']:.5g}, translation "
                  f"({t['translation_px'][0]:.2f}, {t['translation_px'][1]:.2f}) px, overlap "
                  f"{100 * t['overlap_fraction']:.0f} %")
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
