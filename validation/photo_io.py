"""Read a photograph of a beam pattern as linear luminance, and a simulated wall lux map.

Photographs (:func:`read_photo`)
    PNG, JPEG and TIFF with 8 or 16 bits per channel are taken as **sRGB-encoded**: code
    values are scaled to [0, 1] and decoded with the exact sRGB EOTF (IEC 61966-2-1,
    linear toe below 0.04045, power 2.4 above). Float TIFF and OpenEXR files are taken as
    already linear. Colour is reduced to relative luminance with the Rec. 709 / sRGB
    weights ``Y = 0.2126 R + 0.7152 G + 0.0722 B``; an alpha channel is ignored. A pixel is
    **clipped** (saturated) when any of its channels reaches ``clip_code`` of full scale
    (JPEG compression leaves saturated areas a few codes below 255, hence < 1). The result
    is relative: 1.0 = a pixel at full scale in every channel; the exposure is unknown.
    Camera raw files (DNG, CR2, NEF, …) are read as linear sensor data with their black and
    white levels (:mod:`~lightsim.validation.photo_raw`); EXIF exposure (time, f-number,
    ISO) is kept in ``info["exif"]`` where the file has it. What the image libraries warn
    or log while reading (e.g. tifffile on a bad tag) is collected into
    ``info["warnings"]``, one line each, for the command line to print (or not, under
    ``--quiet``) instead of reaching the terminal directly.

Simulations (:func:`load_simulation`)
    A result folder holding ``wall_lux.exr`` (channel ``Y`` in lx, or ``R``/``G``/``B`` or a
    single channel) and ``summary.json``, or a ``wall_lux.exr`` file directly. The wall
    frame (``docs/reference/conventions.md``) comes from the EXR metadata ``wall`` or, failing that,
    from ``summary.json["wall"]`` beside the EXR.

Parameters
----------
=============  ====  =========  ===========================================================
name           unit  default    meaning
=============  ====  =========  ===========================================================
path           –     required   photo (PNG/JPEG/TIFF/EXR) or result folder / EXR file
clip_code      1     0.98       fraction of the full code range at which a channel counts
                                as clipped (8/16-bit files only)
black_level    1     2/255      a photo whose brightest pixels (99.9th percentile) stay at
                                or below this encoded level is "all black"
=============  ====  =========  ===========================================================
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
from numpy.typing import NDArray

from lightsim.errors import InputError
from lightsim.io.exr import read_exr
from lightsim.io.summary import read_json
from lightsim.materials import LUMA
from lightsim.validation.photo_png16 import is_png16, read_png16
from lightsim.validation.photo_raw import RAW_SUFFIXES, exposure_info, read_raw
from lightsim.wall import WallFrame

__all__ = [
    "PhotoImage",
    "Simulation",
    "load_simulation",
    "luminance",
    "read_photo",
    "srgb_decode",
    "srgb_encode",
]

_RASTER_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff"}


# ---------------------------------------------------------------------------------------
# colour
# ---------------------------------------------------------------------------------------

def srgb_decode(v: NDArray) -> NDArray:
    """Exact sRGB EOTF: encoded values in [0, 1] → linear light in [0, 1].

    Parameters
    ----------
    v : ndarray
        Encoded sRGB values (dimensionless, 0–1).

    Returns
    -------
    ndarray
        Linear values (dimensionless, 0–1), float64.
    """
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((np.maximum(v, 0.04045) + 0.055) / 1.055) ** 2.4)


def srgb_encode(x: NDArray) -> NDArray:
    """Exact sRGB OETF (inverse of :func:`srgb_decode`): linear [0, 1] → encoded [0, 1].

    Parameters
    ----------
    x : ndarray
        Linear values (dimensionless); clipped to [0, 1] first.

    Returns
    -------
    ndarray
        Encoded values (dimensionless, 0–1), float64.
    """
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x,
                    1.055 * np.maximum(x, 0.0031308) ** (1 / 2.4) - 0.055)


def luminance(rgb: NDArray) -> NDArray:
    """Relative luminance of linear RGB with the Rec. 709 weights
    (:data:`lightsim.materials.LUMA`).

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3) or (H, W)
        Linear colour (any unit); a 2-D array is returned unchanged (already grey).

    Returns
    -------
    ndarray, shape (H, W)
        ``0.2126 R + 0.7152 G + 0.0722 B`` in the unit of ``rgb``.
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim == 2:
        return rgb
    r, g, b = LUMA.tolist()
    return rgb[..., 0] * r + rgb[..., 1] * g + rgb[..., 2] * b


# ---------------------------------------------------------------------------------------
# photos
# ---------------------------------------------------------------------------------------

@dataclass
class PhotoImage:
    """A photo as relative linear luminance.

    Attributes
    ----------
    luminance : ndarray, shape (H, W)
        Linear relative luminance (1.0 = full scale in all channels), float64.
    clipped : ndarray of bool, shape (H, W)
        Pixels where at least one channel is saturated.
    path : str
        Source file.
    encoding : str
        ``"srgb-8"``, ``"srgb-16"`` or ``"linear"``.
    info : dict
        Size, channels and other facts for the report.
    """

    luminance: NDArray
    clipped: NDArray
    path: str = ""
    encoding: str = "linear"
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) in pixels."""
        return self.luminance.shape  # type: ignore[return-value]


def _read_raster(path: Path) -> NDArray:
    if is_png16(path):      # Pillow would cut 16-bit colour PNGs to 8 bits
        return read_png16(path)
    plugin = "tifffile" if path.suffix.lower() in (".tif", ".tiff") else "pillow"
    try:
        arr = np.asarray(iio.imread(path, plugin=plugin))
    except FileNotFoundError:
        raise InputError(f"photo not found: {path}") from None
    except IsADirectoryError:
        raise InputError(f"expected a photo file, got a directory: {path}") from None
    except Exception as exc:  # imageio/Pillow/tifffile raise many types for bad files
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"cannot read photo {path}: {msg}") from None
    return arr


def _read_exr_rgb(path: Path) -> NDArray:
    chans, _ = read_exr(path)
    names = {k.split(".")[-1]: v for k, v in chans.items()}
    if "Y" in names:
        return np.asarray(names["Y"], dtype=np.float64)
    if all(c in names for c in "RGB"):
        return np.stack([np.asarray(names[c], dtype=np.float64) for c in "RGB"], axis=-1)
    if len(chans) == 1:
        return np.asarray(next(iter(chans.values())), dtype=np.float64)
    raise InputError(f"photo {path}: EXR has no Y or R, G, B channels "
                     f"(found {', '.join(sorted(chans))})")


def _channels_last(arr: NDArray, path: Path) -> NDArray:
    """(H, W) or (H, W, C) without alpha; rejects stacks and odd layouts."""
    if arr.ndim == 3 and arr.shape[-1] in (2, 4):      # grey+alpha, RGBA
        arr = arr[..., :-1]
    if arr.ndim == 3 and arr.shape[-1] == 1:
        arr = arr[..., 0]
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[-1] != 3):
        raise InputError(f"photo {path}: unsupported image layout {arr.shape} "
                         "(expected grey or RGB)")
    if min(arr.shape[:2]) < 16:
        raise InputError(f"photo {path}: too small ({arr.shape[1]}×{arr.shape[0]} pixels)")
    return arr


def read_photo(path: str | os.PathLike, clip_code: float = 0.98,
               black_level: float = 2 / 255) -> PhotoImage:
    """Read a photo as linear relative luminance with its clipped pixels.

    Parameters
    ----------
    path : path-like
        PNG, JPEG, TIFF (8/16-bit sRGB or float linear) or OpenEXR (linear) file.
    clip_code : float, default 0.98
        A channel at or above this fraction of full scale is clipped (integer files).
    black_level : float, default 2/255
        Encoded level (0–1) at or below which the photo's 99.9th percentile makes it
        "all black".

    Returns
    -------
    PhotoImage
        Linear luminance (1.0 = full scale), clipped mask, encoding and facts.

    Raises
    ------
    InputError
        Missing or unreadable file, unsupported layout, non-finite values, or an all-black
        photo (one line each).
    """
    p = Path(path)

    with _library_messages() as messages:
        photo = _read_photo(p, clip_code, black_level)
        exif = exposure_info(p)
    photo.info["warnings"] = photo.info.get("warnings", []) + [
        f"photo {p.name}: {m}" for m in messages]
    if exif is not None:
        photo.info["exif"] = exif
    return photo


@contextlib.contextmanager
def _library_messages() -> Iterator[list[str]]:
    """Collect what image libraries print or warn (tifffile logs bad tags, Pillow and numpy
    warn) as one-line messages instead of letting them reach the terminal."""
    messages: list[str] = []

    class _Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            messages.append(f"{record.name.split('.')[0]}: {_one_line(record.getMessage())}")

    handler = _Collect(level=logging.WARNING)
    loggers = [logging.getLogger(n) for n in ("tifffile", "imageio", "PIL", "rawpy")]
    saved = [(lg.propagate, lg.handlers[:]) for lg in loggers]
    for lg in loggers:
        lg.handlers = [handler]
        lg.propagate = False
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield messages
        for w in caught:
            messages.append(_one_line(str(w.message)))
    finally:
        for lg, (prop, handlers) in zip(loggers, saved):
            lg.handlers = handlers
            lg.propagate = prop
    # de-duplicate, keep order
    seen: set[str] = set()
    messages[:] = [m for m in messages if not (m in seen or seen.add(m))]


def _one_line(text: str) -> str:
    lines = [ln.strip() for ln in str(text).strip().splitlines() if ln.strip()]
    return lines[0] if lines else "(empty message)"


def _read_photo(p: Path, clip_code: float, black_level: float) -> PhotoImage:
    suffix = p.suffix.lower()
    extra: dict[str, Any] = {}
    if suffix in RAW_SUFFIXES:
        lum_or_codes, clip, encoding, extra, warns = read_raw(p, clip_code)
        extra = {**extra, "warnings": warns}
        if encoding == "raw-linear":
            lum = lum_or_codes
            if min(lum.shape) < 16:
                raise InputError(f"photo {p}: too small ({lum.shape[1]}×{lum.shape[0]} pixels)")
            if not float(np.percentile(lum, 99.9)) > 1e-4:
                raise InputError(f"photo {p} is all black (no lit pixels): check the file "
                                 "and the exposure")
            info = {"width": int(lum.shape[1]), "height": int(lum.shape[0]), "channels": 1,
                    "encoding": encoding, "clipped_fraction": float(clip.mean()), **extra}
            return PhotoImage(lum, clip, str(p), encoding, info)
        raw = _channels_last(lum_or_codes, p)
    elif suffix == ".exr":
        raw = _channels_last(_read_exr_rgb(p), p)
    elif suffix in _RASTER_SUFFIXES or p.exists():
        raw = _channels_last(_read_raster(p), p)
    else:
        raise InputError(f"photo not found: {p}")
    if raw.dtype.kind in "ui":
        full = float(np.iinfo(raw.dtype).max)
        bits = 8 if full <= 255 else 16
        codes = raw.astype(np.float64) / full
        clipped = codes >= clip_code
        if clipped.ndim == 3:
            clipped = clipped.any(axis=-1)
        lum = luminance(srgb_decode(codes))
        encoding = f"srgb-{bits}"
        level = float(np.percentile(codes.max(axis=-1) if codes.ndim == 3 else codes, 99.9))
        black = level <= black_level
    elif raw.dtype.kind == "f":
        lin = raw.astype(np.float64)
        if not np.all(np.isfinite(lin)):
            raise InputError(f"photo {p}: contains NaN or infinite pixel values")
        lum = np.maximum(luminance(lin), 0.0)
        clipped = np.zeros(lum.shape, dtype=bool)
        encoding = "linear"
        peak = float(lum.max())
        black = peak <= 0 or float(np.percentile(lum, 99.9)) <= peak * 1e-6
    else:
        raise InputError(f"photo {p}: unsupported pixel type {raw.dtype}")
    if black:
        raise InputError(f"photo {p} is all black (no lit pixels): check the file and the "
                         "exposure")
    info = {"width": int(lum.shape[1]), "height": int(lum.shape[0]),
            "channels": 1 if raw.ndim == 2 else int(raw.shape[-1]), "encoding": encoding,
            "clipped_fraction": float(clipped.mean()), **extra}
    return PhotoImage(lum, clipped, str(p), encoding, info)


# ---------------------------------------------------------------------------------------
# simulations
# ---------------------------------------------------------------------------------------

@dataclass
class Simulation:
    """A simulated wall illuminance map and its frame.

    Attributes
    ----------
    lux : ndarray, shape (H, W)
        Illuminance in lx (row 0 on top = largest V); NaN where not computed.
    frame : dict
        The wall frame as in ``docs/reference/conventions.md``.
    wall : WallFrame
        The parsed frame (pixel ↔ H/V degrees).
    source : str
        Where it was read from.
    """

    lux: NDArray
    frame: dict[str, Any]
    wall: WallFrame
    source: str = ""

    @classmethod
    def from_arrays(cls, lux: NDArray, frame: dict[str, Any], source: str = "") -> Simulation:
        """Check ``lux`` (lx) against ``frame`` and build a :class:`Simulation`.

        Raises
        ------
        InputError
            Malformed frame, shape mismatch, no finite or no positive illuminance.
        """
        wall = WallFrame.from_any(frame)
        arr = wall.check_image(lux, name=f"simulation {source}".strip())
        finite = np.isfinite(arr)
        if not finite.any() or not float(np.max(arr[finite], initial=0.0)) > 0:
            where = f" {source}" if source else ""
            raise InputError(f"simulation{where} has no light (no positive lux)")
        return cls(arr, dict(frame), wall, source)


def _lux_channel(chans: dict[str, NDArray], path: Path) -> NDArray:
    if "Y" in chans:
        return np.asarray(chans["Y"], dtype=np.float64)
    if all(c in chans for c in "RGB"):
        return luminance(np.stack([chans[c] for c in "RGB"], axis=-1))
    if len(chans) == 1:
        return np.asarray(next(iter(chans.values())), dtype=np.float64)
    raise InputError(f"simulation {path}: no 'Y' channel (found {', '.join(sorted(chans))})")


def _frame_from_summary(folder: Path) -> dict[str, Any] | None:
    summary = folder / "summary.json"
    if not summary.is_file():
        return None
    doc = read_json(summary)
    wall = doc.get("wall") if isinstance(doc, dict) else None
    return wall if isinstance(wall, dict) else None


def load_simulation(path: str | os.PathLike) -> Simulation:
    """Load ``wall_lux.exr`` and its wall frame from a result folder or the EXR itself.

    Parameters
    ----------
    path : path-like
        Result folder (holding ``wall_lux.exr``) or an EXR file.

    Returns
    -------
    Simulation
        Lux map (lx) and frame.

    Raises
    ------
    InputError
        Missing folder/file, unreadable EXR, no wall frame, inconsistent frame or no light.
    """
    p = Path(path)
    if p.is_dir():
        exr = p / "wall_lux.exr"
        if not exr.is_file():
            raise InputError(f"simulation folder {p} has no wall_lux.exr")
    elif p.exists():
        exr = p
    else:
        raise InputError(f"simulation not found: {p}")
    chans, meta = read_exr(exr)
    lux = _lux_channel(chans, exr)
    frame = meta.get("wall") if isinstance(meta.get("wall"), dict) else None
    if frame is None:
        frame = _frame_from_summary(exr.parent)
    if frame is None:
        raise InputError(f"simulation {exr}: no wall frame (EXR metadata 'wall' or "
                         "summary.json beside it)")
    if "resolution" not in frame:
        frame = {**frame, "resolution": [int(lux.shape[1]), int(lux.shape[0])]}
    sim = Simulation.from_arrays(lux, frame, str(exr))
    if not math.isfinite(sim.wall.distance_m):  # pragma: no cover - WallFrame checks it
        raise InputError(f"simulation {exr}: bad wall distance")
    return sim
