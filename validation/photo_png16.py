"""Read and write 16-bit-per-channel PNG files at full precision, with pypng.

Pillow (and so imageio and scikit-image) reads 16-bit RGB/RGBA PNGs as 8-bit, dropping
the low byte that raw converters export for a reason. pypng (a small, pure-Python PNG
codec) keeps all 16 bits; 8-bit and palette PNGs are left to Pillow.

Parameters
----------
=====  ====  ========  ===========================================================
name   unit  default   meaning
=====  ====  ========  ===========================================================
path   –     required  PNG file
image  –     required  (H, W), (H, W, 3) or (H, W, 4) uint16 array to write
=====  ====  ========  ===========================================================
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import png
from numpy.typing import NDArray

from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path

__all__ = ["is_png16", "read_png16", "write_png16"]

_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def is_png16(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a PNG with 16 bits per channel (False for anything else)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(29)
    except OSError:
        return False
    if head[:8] != _SIGNATURE or head[12:16] != b"IHDR" or len(head) < 29:
        return False
    return struct.unpack(">B", head[24:25])[0] == 16


def read_png16(path: str | os.PathLike) -> NDArray:
    """A 16-bit PNG as uint16 (H, W) or (H, W, C); palette/8-bit files are refused."""
    p = Path(path)
    try:
        width, height, rows, info = png.Reader(filename=str(p)).asDirect()
        data = np.vstack([np.asarray(r, dtype=np.uint16) for r in rows])
    except (png.Error, OSError, ValueError, EOFError) as exc:
        raise InputError(f"cannot read photo {p}: {exc}") from None
    if info.get("bitdepth") != 16:
        raise InputError(f"cannot read photo {p}: not a 16-bit PNG")
    planes = int(info["planes"])
    img = data.reshape(height, width, planes)
    return img[..., 0] if planes == 1 else img


def write_png16(path: str | os.PathLike, image: NDArray) -> None:
    """Write a uint16 (H, W), (H, W, 3) or (H, W, 4) array as a 16-bit PNG, atomically."""
    a = np.asarray(image)
    if a.dtype != np.uint16 or a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)):
        raise ValueError(f"write_png16: need uint16 (H, W[, 3|4]), got {a.dtype} {a.shape}")
    h, w = a.shape[:2]
    planes = 1 if a.ndim == 2 else a.shape[2]
    writer = png.Writer(width=w, height=h, bitdepth=16, greyscale=planes == 1,
                        alpha=planes == 4)
    with atomic_path(path, suffix=".png") as tmp, open(tmp, "wb") as fh:
        writer.write(fh, a.reshape(h, w * planes))
