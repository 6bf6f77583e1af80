"""Read and write 16-bit-per-channel PNG files at full precision.

Pillow (and so imageio and scikit-image) reads 16-bit RGB/RGBA PNGs as 8-bit, dropping
the low byte that raw converters export for a reason. This module decodes such files
itself (PNG specification, ISO/IEC 15948: zlib-compressed scan lines, filters None, Sub,
Up, Average and Paeth undone by a numba kernel; interlaced files are refused) and writes
16-bit PNGs the same way (filter None). 8-bit and palette PNGs are left to Pillow.

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
import zlib
from pathlib import Path

import numba
import numpy as np
from numpy.typing import NDArray

from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path

__all__ = ["is_png16", "read_png16", "write_png16"]

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}        # colour type → samples per pixel


def _header(data: bytes) -> tuple[int, int, int, int, int]:
    """(width, height, bit depth, colour type, interlace) from the IHDR chunk."""
    if data[:8] != _SIGNATURE or data[12:16] != b"IHDR":
        raise ValueError("not a PNG file")
    w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", data[16:29])
    return w, h, depth, ctype, interlace


def is_png16(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a PNG with 16 bits per channel (False for anything else)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(29)
        return _header(head)[2] == 16
    except (OSError, ValueError, struct.error):
        return False


@numba.njit(cache=True)
def _unfilter(raw: NDArray, height: int, stride: int, bpp: int) -> NDArray:  # pragma: no cover
    out = np.zeros((height, stride), dtype=np.uint8)
    prev = np.zeros(stride, dtype=np.int32)
    for y in range(height):
        base = y * (stride + 1)
        ftype = raw[base]
        for i in range(stride):
            x = np.int32(raw[base + 1 + i])
            a = np.int32(out[y, i - bpp]) if i >= bpp else np.int32(0)
            b = prev[i]
            c = prev[i - bpp] if i >= bpp else np.int32(0)
            if ftype == 1:
                x += a
            elif ftype == 2:
                x += b
            elif ftype == 3:
                x += (a + b) // 2
            elif ftype == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                if pa <= pb and pa <= pc:
                    x += a
                elif pb <= pc:
                    x += b
                else:
                    x += c
            out[y, i] = x & 255
        for i in range(stride):
            prev[i] = out[y, i]
    return out


def read_png16(path: str | os.PathLike) -> NDArray:
    """Decode a 16-bit PNG.

    Returns
    -------
    ndarray of uint16
        (H, W) for grey, (H, W, C) for grey+alpha, RGB and RGBA (alpha kept).

    Raises
    ------
    InputError
        Interlaced, truncated or corrupt files, or not 16 bits per channel.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
        w, h, depth, ctype, interlace = _header(data)
        if depth != 16 or ctype not in _CHANNELS:
            raise ValueError(f"bit depth {depth}, colour type {ctype}")
        if interlace:
            raise ValueError("interlaced PNGs are not supported at 16 bits")
        idat, pos = [], 8
        while pos + 8 <= len(data):
            length, kind = struct.unpack(">I4s", data[pos:pos + 8])
            if kind == b"IDAT":
                idat.append(data[pos + 8:pos + 8 + length])
            elif kind == b"IEND":
                break
            pos += 12 + length
        raw = np.frombuffer(zlib.decompress(b"".join(idat)), dtype=np.uint8)
    except (OSError, ValueError, zlib.error, struct.error) as exc:
        raise InputError(f"cannot read photo {p}: {exc}") from None
    n = _CHANNELS[ctype]
    stride = w * n * 2
    if raw.size < h * (stride + 1):
        raise InputError(f"cannot read photo {p}: truncated image data")
    rows = _unfilter(raw[: h * (stride + 1)], h, stride, n * 2)
    img = rows.view(">u2").reshape(h, w, n).astype(np.uint16)
    return img[..., 0] if n == 1 else img


def write_png16(path: str | os.PathLike, image: NDArray) -> None:
    """Write a uint16 grey, RGB or RGBA image as a 16-bit PNG (atomically).

    Raises
    ------
    ValueError
        ``image`` is not uint16 with 1, 3 or 4 channels.
    """
    img = np.asarray(image)
    if img.dtype != np.uint16 or img.ndim not in (2, 3):
        raise ValueError("write_png16 needs a uint16 (H, W) or (H, W, C) array")
    if img.ndim == 2:
        img = img[..., None]
    n = img.shape[2]
    ctype = {1: 0, 3: 2, 4: 6}.get(n)
    if ctype is None:
        raise ValueError(f"write_png16: {n} channels (1, 3 or 4 supported)")
    h, w = img.shape[:2]
    rows = img.astype(">u2").reshape(h, w * n).view(np.uint8)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rows], axis=1).tobytes()

    def chunk(kind: bytes, payload: bytes) -> bytes:
        crc = zlib.crc32(kind + payload) & 0xFFFFFFFF
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", crc)

    blob = (_SIGNATURE + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, ctype, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    with atomic_path(path, suffix=".png") as tmp:
        tmp.write_bytes(blob)
