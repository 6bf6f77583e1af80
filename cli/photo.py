"""``lightsim photo SIM OUT``: a synthetic camera's "photo" of a simulated wall.

The camera model and its parameters are documented in
:mod:`lightsim.validation.synthetic_photo`; the true transform (photo px → simulation px)
goes to ``OUT``'s sidecar ``<name>.truth.json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from lightsim.errors import InputError
from lightsim.validation.photo_io import load_simulation
from lightsim.validation.synthetic_photo import CameraSettings, photograph_simulation


def _numbers(text: str | None, n: int, name: str, kind: type = float) -> tuple | None:
    if text is None:
        return None
    parts = text.replace("x", ",").split(",")
    try:
        values = tuple(kind(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != n:
        raise InputError(f"{name} needs {n} comma-separated numbers, got {text!r}")
    return values


@click.command()
@click.argument("sim_path", metavar="RESULT_DIR|wall_lux.exr", type=click.Path(path_type=Path))
@click.argument("out", metavar="OUT.(jpg|png|tif|exr|dng)", type=click.Path(path_type=Path,
                                                                        dir_okay=False))
@click.option("--rotate", type=float, default=0.0, show_default=True,
              help="Camera roll: the pattern turns counter-clockwise by DEG.")
@click.option("--scale", type=float, default=None,
              help="Magnification, photo px per simulation px  [default: 1; with --markers "
                   "the least at which the markers are found, and --size the whole wall].")
@click.option("--shift", default="0,0", show_default=True, metavar="DX,DY",
              help="Pattern moved right/down by DX,DY photo px.")
@click.option("--tilt", type=float, default=0.0, show_default=True,
              help="Camera yaw about the vertical axis, DEG (perspective).")
@click.option("--size", metavar="WxH", help="Photo size in px  [default: the simulation's].")
@click.option("--blur", type=float, default=0.0, show_default=True, metavar="SIGMA_PX",
              help="Gaussian optics blur σ in photo px.")
@click.option("--noise", type=float, default=0.0, show_default=True, metavar="SIGMA",
              help="Noise σ at full scale (fraction of full scale).")
@click.option("--vignetting", type=float, default=0.0, show_default=True,
              metavar="STRENGTH", help="Light fall-off in the corners, 0–1.")
@click.option("--gamma", type=float, default=None, metavar="G",
              help="Tone curve x^(1/G) instead of the sRGB curve.")
@click.option("--exposure", type=float, default=0.0, show_default=True, metavar="EV",
              help="Exposure change in EV (+1 = twice as bright).")
@click.option("--saturate", type=float, default=None, metavar="FRACTION",
              help="Full scale at FRACTION of the peak: the hot spot clips.")
@click.option("--bits", type=click.Choice(["8", "16"]), default="8", show_default=True,
              help="Bits per channel (PNG/TIFF).")
@click.option("--seed", type=int, default=0, show_default=True, help="Noise seed.")
@click.option("--markers", is_flag=True,
              help="Put the default screen-target marker board on the wall (4× finer "
                   "wall grid; see 'lightsim screen-target').")
@click.option("--wall-texture", type=int, metavar="SEED",
              help="Give the wall a static texture (random grey rectangles, seeded), the "
                   "background 'compare --against' aligns two photos by.")
@click.option("--ambient", type=float, default=0.5, show_default=True, metavar="LX",
              help="Room light on the wall with --markers or --wall-texture (lx).")
@click.option("--reaim", metavar="DH,DV", help="Turn the lamp by DH right, DV up (deg) "
              "before photographing: a lamp aimed off (the truth records it).")
def photo(sim_path: Path, out: Path, markers: bool, wall_texture: int | None, ambient: float,
          reaim: str | None, **camera: Any) -> None:
    """Photograph a simulated wall with a synthetic camera (truth in OUT's .truth.json)."""
    cam = _camera(**camera)
    sim = load_simulation(sim_path)
    aim = _numbers(reaim, 2, "--reaim")
    path, side, shot = photograph_simulation(sim, out, cam, aim, markers, wall_texture,
                                             ambient)
    truth = shot.truth()
    click.echo(f"wrote {path} ({truth['photo_size'][0]}×{truth['photo_size'][1]}, "
               f"{100 * truth['clipped_fraction']:.1f} % clipped) and {side}")
    click.echo(f"true transform photo px → simulation px: rotation {truth['rotation_deg']:+.3f}°, "
               f"scale {truth['scale']:.5g}, translation ({truth['translation_px'][0]:.2f}, "
               f"{truth['translation_px'][1]:.2f}) px")


def _camera(rotate: float, scale: float | None, shift: str, tilt: float, size: str | None,
            blur: float, noise: float, vignetting: float, gamma: float | None,
            exposure: float, saturate: float | None, bits: str, seed: int) -> CameraSettings:
    """The camera of the command's options."""
    dims = _numbers(size, 2, "--size", int)
    return CameraSettings(rotate_deg=rotate, scale=scale,
                          shift_px=_numbers(shift, 2, "--shift"),  # type: ignore[arg-type]
                          tilt_deg=tilt, size=dims, blur_px=blur,  # type: ignore[arg-type]
                          noise=noise, vignetting=vignetting, gamma=gamma,
                          exposure_ev=exposure, saturate=saturate, bits=int(bits), seed=seed)
