"""Two small image filters in numpy, equal to scipy.ndimage's to rounding.

The cut-off scan and the wall's intensity sampling (road view) need only a bilinear
sample with edge clamping and a 1-D Gaussian; importing scipy.ndimage for them costs a
run about half a second of start-up.

==============  =====  =======  ======================================================
parameter       unit   default  meaning
==============  =====  =======  ======================================================
``order``       –      1        interpolation order (only 1: bilinear)
``mode``        –      nearest  beyond the edge: the edge value (only ``nearest``)
``truncate``    σ      4.0      Gaussian kernel radius ⌊truncate σ + ½⌋ samples
==============  =====  =======  ======================================================
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def map_coordinates(img: NDArray, coords: list[NDArray], order: int = 1,
                    mode: str = "nearest") -> NDArray:
    """Bilinear samples of a 2-D image at fractional (row, col), coordinates outside the
    image clamped to its edge: ``scipy.ndimage.map_coordinates(img, coords, order=1,
    mode="nearest")`` (to rounding)."""
    if order != 1 or mode != "nearest":
        raise ValueError("only order=1, mode='nearest' is implemented")
    a = np.asarray(img, dtype=np.float64)
    H, W = a.shape
    r = np.clip(np.asarray(coords[0], np.float64), 0.0, H - 1)
    c = np.clip(np.asarray(coords[1], np.float64), 0.0, W - 1)
    r0 = np.minimum(np.floor(r).astype(np.int64), max(H - 2, 0))
    c0 = np.minimum(np.floor(c).astype(np.int64), max(W - 2, 0))
    r1, c1 = np.minimum(r0 + 1, H - 1), np.minimum(c0 + 1, W - 1)
    fr, fc = r - r0, c - c0
    top = a[r0, c0] * (1.0 - fc) + a[r0, c1] * fc
    bottom = a[r1, c0] * (1.0 - fc) + a[r1, c1] * fc
    return top * (1.0 - fr) + bottom * fr


def gaussian_filter1d(x: NDArray, sigma: float, mode: str = "nearest",
                      truncate: float = 4.0) -> NDArray:
    """Gaussian smoothing of a 1-D profile, edges extended by their value:
    ``scipy.ndimage.gaussian_filter1d(x, sigma, mode="nearest")`` (same kernel: radius
    ⌊truncate σ + ½⌋, normalised samples of exp(−x²/2σ²); equal to rounding)."""
    if mode != "nearest":
        raise ValueError("only mode='nearest' is implemented")
    x = np.asarray(x, dtype=np.float64)
    radius = int(truncate * float(sigma) + 0.5)
    if x.size == 0 or radius == 0:
        return x.copy()
    k = np.arange(-radius, radius + 1)
    w = np.exp(-0.5 / (float(sigma) ** 2) * k * k)
    w /= w.sum()
    return np.correlate(np.pad(x, radius, mode="edge"), w, mode="valid")
