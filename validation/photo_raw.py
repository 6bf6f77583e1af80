"""Camera raw files (DNG, CR2, NEF, …) as linear sensor data, and EXIF exposure.

Raw files (:func:`read_raw`) are decoded by LibRaw through :mod:`rawpy`. For the usual
2×2 colour filter arrays (RGGB and its variants) the visible sensor area is read as it is
— no demosaicing, no tone curve: each sample becomes ``(raw − black_c)/(white − black_c)``
with the per-channel black level and the white level the file states, every 2×2 cell is
one photo pixel (half the sensor's resolution, in the sensor's orientation turned by the
file's flip), the channels are scaled by the camera's as-shot white balance (green = 1)
and combined with the Rec. 709 weights into a relative luminance. (Camera RGB is not
colour-corrected to sRGB primaries: for the grey-ish light of a headlamp on a white wall
this matters little, and it never moves a cut-off.) A cell is **clipped** when any of its
samples reaches ``clip_code`` of the white level. Other sensor layouts (X-Trans, Foveon)
go through LibRaw's demosaicing with a linear curve and no auto-brightening.

When LibRaw cannot decode the raw data but the file holds an embedded preview, the
preview is used **with a warning** (it is an 8-bit, tone-mapped JPEG, not sensor data).

EXIF exposure (:func:`exposure_info`)
    Exposure time t (s), f-number N and ISO S from the file's EXIF (tifffile for TIFF-based
    raws and TIFF, Pillow for JPEG and PNG). A pixel's value is proportional to the scene
    luminance × ``t·S/N²``, the **relative exposure** reported (s·ISO); two photos of one
    camera compare after dividing by it.

Parameters
----------
==========  ====  =======  ==================================================================
name        unit  default  meaning
==========  ====  =======  ==================================================================
path        –     –        raw file (suffix in :data:`RAW_SUFFIXES`)
clip_code   1     0.98     fraction of (white − black) at which a sample counts as clipped
==========  ====  =======  ==================================================================
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray
from PIL import Image

from lightsim.errors import InputError
from lightsim.materials import LUMA

__all__ = ["RAW_SUFFIXES", "exposure_info", "read_raw"]

#: File suffixes read as camera raw files.
RAW_SUFFIXES = (".dng", ".cr2", ".cr3", ".nef", ".nrw", ".arw", ".orf", ".rw2", ".raf",
                ".pef", ".srw", ".raw", ".rwl", ".3fr", ".iiq", ".erf", ".kdc", ".mos")

_WEIGHTS = dict(zip("RGB", LUMA.tolist()))  # Rec. 709 luminance weight of each CFA colour


def _flip(img: NDArray, flip: int) -> NDArray:
    """Apply LibRaw's ``flip`` (0 none, 3 180°, 5 90° counter-clockwise, 6 90° clockwise)."""
    return {3: lambda a: a[::-1, ::-1], 5: lambda a: np.rot90(a, 1),
            6: lambda a: np.rot90(a, -1)}.get(int(flip), lambda a: a)(img)


def _bayer_luminance(raw: Any, clip_code: float) -> tuple[NDArray, NDArray, dict[str, Any]]:
    data = np.asarray(raw.raw_image_visible, np.float64)
    colours = np.asarray(raw.raw_colors_visible)
    desc = raw.color_desc.decode("ascii", "replace")
    blacks = np.asarray(raw.black_level_per_channel, np.float64)
    white = float(raw.white_level)
    if not (np.all(np.isfinite(blacks)) and np.all(blacks < white)):
        raise InputError(f"raw file: black levels {blacks.tolist()} are not below the white "
                         f"level {white:g}")
    wb = np.asarray(raw.camera_whitebalance, np.float64)[:len(desc)]
    if not (np.all(np.isfinite(wb)) and np.all(wb > 0)):
        wb = np.ones(len(desc))
    g = [i for i, c in enumerate(desc) if c == "G"]
    wb = wb / (np.mean(wb[g]) if g else 1.0)
    h, w = (data.shape[0] // 2) * 2, (data.shape[1] // 2) * 2
    data, colours = data[:h, :w], colours[:h, :w]
    norm = (data - blacks[colours]) / (white - blacks[colours])
    clipped_s = norm >= clip_code
    norm = np.maximum(norm, 0.0) * wb[colours]
    # weight of each sample in its cell: the channel's luminance weight over its count
    weight = np.zeros_like(norm)
    cell = colours[:2, :2]
    letters = [desc[c] if c < len(desc) else "G" for c in cell.ravel()]
    for c in np.unique(cell):
        ch = desc[c] if c < len(desc) else "G"
        weight[colours == c] = _WEIGHTS.get(ch, 0.0) / max(letters.count(ch), 1)
    lum = (norm * weight).reshape(h // 2, 2, w // 2, 2).sum(axis=(1, 3))
    clip = clipped_s.reshape(h // 2, 2, w // 2, 2).any(axis=(1, 3))
    facts = {"black_level": blacks.tolist(), "white_level": white, "cfa": desc,
             "white_balance": wb.tolist(), "binning": "2x2 CFA cell per pixel"}
    return lum, clip, facts


def read_raw(path: str | os.PathLike, clip_code: float = 0.98
             ) -> tuple[NDArray, NDArray, str, dict[str, Any], list[str]]:
    """Read a camera raw file as linear relative luminance (module docstring).

    Returns
    -------
    luminance : ndarray, shape (H, W)
        Relative luminance, 1 = the white level.
    clipped : ndarray of bool
        Cells with a sample at or above ``clip_code`` of the white level.
    encoding : str
        ``"raw-linear"``, or ``"srgb-8"`` for a preview.
    info : dict
        Black/white levels, CFA, white balance, flip.
    warnings : list of str
        One line each (e.g. only a preview was usable).

    Raises
    ------
    InputError
        Missing file, or neither raw data nor a preview can be read (one line).
    """

    p = Path(path)
    if not p.is_file():
        raise InputError(f"photo not found: {p}" if not p.exists() else
                         f"expected a photo file, got a directory: {p}")
    warnings: list[str] = []
    printed: list[str] = []
    try:
        with _c_stderr(printed):
            out = _decode(p, clip_code, warnings)
    except InputError as exc:
        if printed:         # LibRaw's own words are usually the clearer reason
            raise InputError(f"{exc} (LibRaw: {printed[0].split(': ', 1)[-1]})") from None
        raise
    warnings.extend(f"photo {p.name}: LibRaw: {m.split(': ', 1)[-1]}" for m in printed)
    return (*out[:4], warnings)


@contextlib.contextmanager
def _c_stderr(lines: list[str]) -> Iterator[None]:
    """Collect what C code (LibRaw) writes to file descriptor 2 instead of the terminal."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode("utf-8", "replace")
            lines.extend(ln.strip() for ln in text.splitlines() if ln.strip())


def _decode(p: Path, clip_code: float, warnings: list[str]
            ) -> tuple[NDArray, NDArray, str, dict[str, Any]]:
    """The LibRaw part of :func:`read_raw` (its C messages are captured by the caller)."""
    import rawpy

    try:
        with rawpy.imread(str(p)) as raw:
            try:
                pattern = raw.raw_pattern
                if pattern is not None and np.asarray(pattern).shape == (2, 2):
                    lum, clip, info = _bayer_luminance(raw, clip_code)
                else:
                    rgb = raw.postprocess(gamma=(1, 1), no_auto_bright=True, output_bps=16,
                                          use_camera_wb=True, user_flip=0)
                    lin = rgb.astype(np.float64) / 65535.0
                    lum = lin @ LUMA
                    clip = (lin >= clip_code).any(axis=-1)
                    info = {"demosaiced": "LibRaw, linear curve"}
                flip = int(raw.sizes.flip)
                info["flip"] = flip
                return _flip(lum, flip).copy(), _flip(clip, flip).copy(), "raw-linear", info
            except (rawpy.LibRawError, ValueError) as exc:
                preview = _preview(p)      # a fresh handle: the failed unpack poisons this one
                if preview is None:
                    raise InputError(f"cannot read raw photo {p}: {_first_line(exc)}") from None
                warnings.append(f"photo {p.name}: raw data unreadable ({_first_line(exc)}); "
                                "using its embedded 8-bit preview, which is tone-mapped, not "
                                "linear sensor data")
                return preview, None, "srgb-8", {"preview": True}  # type: ignore[return-value]
    except rawpy.LibRawError as exc:
        raise InputError(f"cannot read raw photo {p}: {_first_line(exc)}") from None


def _preview(path: Path) -> NDArray | None:
    """The embedded preview as 8-bit codes, or None."""
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            thumb = raw.extract_thumb()
    except rawpy.LibRawError:
        return None
    if thumb.format == rawpy.ThumbFormat.JPEG:
        return np.asarray(Image.open(io.BytesIO(thumb.data)).convert("RGB"))
    if thumb.format == rawpy.ThumbFormat.BITMAP:
        return np.asarray(thumb.data)
    return None


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    if isinstance(exc.args[0] if exc.args else None, bytes):
        text = exc.args[0].decode("utf-8", "replace").strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _ratio(value: Any) -> float | None:
    try:
        if isinstance(value, tuple) and len(value) == 2:
            num, den = value
            return float(num) / float(den) if float(den) else None
        v = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return v if math.isfinite(v) else None


def exposure_info(path: str | os.PathLike) -> dict[str, Any] | None:
    """EXIF exposure time (s), f-number, ISO and the relative exposure ``t·ISO/N²``.

    Returns None when the file has no usable exposure data (never raises for a readable
    file; unreadable EXIF is treated as absent).
    """
    p = Path(path)
    tags: dict[str, Any] = {}
    try:
        if p.suffix.lower() in (".jpg", ".jpeg", ".png"):
            with Image.open(p) as im:
                exif = im.getexif()
                sub = exif.get_ifd(0x8769)
                tags = {"t": sub.get(33434), "n": sub.get(33437),
                        "iso": sub.get(34855)}
        else:
            with tifffile.TiffFile(p) as tif:
                page = tif.pages[0]
                found: dict[int, Any] = {t.code: t.value for t in page.tags.values()}
                ex = found.get(34665)
                if isinstance(ex, dict):
                    names = {"ExposureTime": 33434, "FNumber": 33437,
                             "ISOSpeedRatings": 34855, "PhotographicSensitivity": 34855}
                    for k, v in ex.items():
                        if k in names:
                            found.setdefault(names[k], v)
                tags = {"t": found.get(33434), "n": found.get(33437), "iso": found.get(34855)}
    except Exception:  # EXIF is optional: a file whose EXIF cannot be parsed has none
        return None
    t, n = _ratio(tags.get("t")), _ratio(tags.get("n"))
    iso_raw = tags.get("iso")
    if isinstance(iso_raw, tuple | list):
        iso_raw = iso_raw[0] if iso_raw else None
    iso = _ratio(iso_raw)
    if t is None or not t > 0:
        return None
    out = {"exposure_time_s": t, "f_number": n if n and n > 0 else None,
           "iso": iso if iso and iso > 0 else None}
    rel = t * (out["iso"] or 100.0) / ((out["f_number"] or 1.0) ** 2)
    out["relative_exposure"] = rel
    out["relative_exposure_unit"] = ("s·ISO/N²" if out["iso"] and out["f_number"] else
                                     "s (ISO or f-number missing: taken as 100 and 1)")
    return out
