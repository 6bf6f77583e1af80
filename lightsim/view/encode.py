"""Frames as compressed binary for the WebSocket: log-encoded uint16 + zlib.

Layout of one message (little-endian)::

    b"LSV1" | uint32 n | n bytes UTF-8 JSON header | zlib(uint16[H, W])

=================  ======  ==================================================================
header field       unit    meaning
=================  ======  ==================================================================
``kind``           –       ``wall`` (illuminance, lx) or ``camera`` (luminance, cd/m²)
``width/height``   px      image size (row 0 = top, column 0 = smallest H)
``lo`` / ``hi``    lx      code 1 ↔ ``lo``, code 65535 ↔ ``hi``, logarithmic between;
                           code 0 = below ``lo`` (drawn black)
=================  ======  ==================================================================

Relative quantisation step: ln(hi/lo)/65534 (1.4·10⁻⁴ for the default 6 decades) — far
below any photon-map noise. The page decompresses with the browser's own
``DecompressionStream("deflate")`` (the zlib format), so no library is loaded.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from typing import Any

import numpy as np

MAGIC = b"LSV1"
DECADES = 6.0  # dynamic range kept below the frame's maximum
LEVEL = 1  # zlib level: fast; the image is smooth enough that level 1 is within ~10 % of 9


def log_range(image: np.ndarray, decades: float = DECADES) -> tuple[float, float]:
    """(lo, hi) of the log code for ``image``: hi = its finite maximum, lo = hi/10^decades."""
    finite = image[np.isfinite(image)]
    hi = float(finite.max()) if finite.size else 0.0
    if not hi > 0:
        return 1e-30, 1.0
    return hi * 10.0 ** (-decades), hi


def encode_image(image: np.ndarray, header: dict[str, Any],
                 decades: float = DECADES) -> bytes:
    """One (H, W) float image (lx or cd/m²) → a binary message (see the module docstring).

    NaN and negative values encode as 0 (black); ``header`` is copied into the JSON header.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"expected an (H, W) image, got shape {img.shape}")
    lo, hi = log_range(img, decades)
    span = math.log(hi / lo)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.log(np.where(img > lo, img, lo) / lo) / span
    code = np.where(np.isfinite(img) & (img >= lo), 1.0 + np.round(np.clip(t, 0, 1) * 65534), 0)
    raw = code.astype("<u2").tobytes()
    head = dict(header)
    head.update(width=int(img.shape[1]), height=int(img.shape[0]), lo=lo, hi=hi)
    hj = json.dumps(head, allow_nan=False).encode()
    return MAGIC + struct.pack("<I", len(hj)) + hj + zlib.compress(raw, LEVEL)


def decode_image(message: bytes) -> tuple[dict[str, Any], np.ndarray]:
    """Inverse of :func:`encode_image` (what the page does): (header, (H, W) float image)."""
    if message[:4] != MAGIC:
        raise ValueError("not a lightsim frame")
    (n,) = struct.unpack("<I", message[4:8])
    head = json.loads(message[8:8 + n])
    code = np.frombuffer(zlib.decompress(message[8 + n:]), dtype="<u2").astype(np.float64)
    code = code.reshape(head["height"], head["width"])
    lo, hi = head["lo"], head["hi"]
    img = lo * np.exp((code - 1.0) / 65534.0 * math.log(hi / lo))
    return head, np.where(code == 0, 0.0, img)
