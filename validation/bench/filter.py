"""Benchmark of the O(1)-per-pixel box filter (paper section 4.1) against baselines.

Measures frames/s of :func:`lightsim.render.boxfilter.box_filter` on a lux-like W×H image
for n×n windows (paper: 3×3 … 6×6), in its exact (drift-free, default) and plain (the
paper's running sums) variants, serial and in one band per CPU, against two baselines
measured in the same run on the same image: a naive O(n²) numba filter
(:func:`~lightsim.render.boxfilter.box_filter_naive`) and ``scipy.ndimage.uniform_filter``.
The paper reports 300 frames/s at 640×480 on one 2.2 GHz Pentium 4; the target here is
≥ 1000 frames/s single-threaded, single channel, with 3×3 and 6×6 within 20 % of each
other.

Parameters (user documentation)
-------------------------------
============  ======  ============  ======================================================
name          unit    default       meaning
============  ======  ============  ======================================================
``width``     pixels  640           image width
``height``    pixels  480           image height
``sizes``     pixels  (3, 4, 5, 6)  window sides n
``repeats``   –       50            timed calls per (method, n); the median is reported
``channels``  –       1             image channels (1: lux; 3: RGB)
``seed``      –       0             RNG seed of the test image
============  ======  ============  ======================================================
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy.ndimage import uniform_filter

from lightsim.render.boxfilter import box_filter, box_filter_naive, n_workers

__all__ = ["METHODS", "make_image", "run"]

#: Method names in table order.
METHODS = ("O(1) exact", "O(1) plain", "O(1) exact par", "naive O(n²)", "scipy")


def make_image(width: int, height: int, channels: int = 1, seed: int = 0) -> np.ndarray:
    """A lux-like float32 test image: a smooth beam with photon noise and a 1e6 lx spot.

    Parameters
    ----------
    width, height : int
        Size in pixels.
    channels : int, default 1
        1 gives (H, W); more gives (H, W, C).
    seed : int, default 0
        RNG seed.

    Returns
    -------
    ndarray, float32
        Illuminance in lx, ≥ 0.
    """
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    beam = 50.0 * np.exp(-(((x - 0.6 * width) / (0.2 * width)) ** 2
                           + ((y - 0.45 * height) / (0.1 * height)) ** 2)) + 0.5
    shape = (height, width) if channels == 1 else (height, width, channels)
    if channels > 1:
        beam = beam[:, :, None]
    img = rng.gamma(4.0, 0.25, size=shape) * beam
    img[height // 2: height // 2 + 2, width // 3: width // 3 + 2] = 1e6
    return img.astype(np.float32)


def _time(fn: Callable[[], Any], repeats: int) -> tuple[float, float]:
    fn()  # warm-up (JIT compilation, caches)
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), min(times)


def run(width: int = 640, height: int = 480, sizes: Sequence[int] = (3, 4, 5, 6),
        repeats: int = 50, channels: int = 1, seed: int = 0
        ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Time every method for every window size.

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    sizes : sequence of int
        Window sides n in pixels.
    repeats : int
        Timed calls per (method, n).
    channels : int
        Image channels.
    seed : int
        RNG seed of the image.

    Returns
    -------
    rows : list of dict
        One row per (method, n): ``method`` ("O(1) exact", "O(1) plain", "O(1) exact par"
        = one band per CPU, "naive O(n²)", "scipy"), ``n``, ``ms_median``, ``ms_best``,
        ``fps`` (1 / median), ``vs_scipy`` and ``vs_naive`` (median-time ratios, > 1 =
        faster than that baseline).
    summary : dict
        Image size, CPUs, the 1-minute load average at the start (other processes make
        medians noisy), and per O(1) method the ratio of the slowest to the fastest n
        (``size_spread`` from medians, ``size_spread_best`` from best times; target
        ≤ 1.2) and the worst fps (from medians and from best times).
    """
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    img = make_image(width, height, channels, seed)
    out = np.empty_like(img)
    scipy_size = lambda n: (n, n) if channels == 1 else (n, n, 1)  # noqa: E731
    methods: dict[str, Callable[[int], Callable[[], Any]]] = {
        "O(1) exact": lambda n: lambda: box_filter(img, n, out=out),
        "O(1) plain": lambda n: lambda: box_filter(img, n, exact=False, out=out),
        "O(1) exact par": lambda n: lambda: box_filter(img, n, parallel=True, out=out),
        "naive O(n²)": lambda n: lambda: box_filter_naive(img, n),
        "scipy": lambda n: lambda: uniform_filter(
            img, scipy_size(n), output=out, mode="nearest"),
    }
    timings: dict[tuple[str, int], tuple[float, float]] = {}
    for n in sizes:
        for name, make in methods.items():
            reps = repeats if not name.startswith("naive") else max(3, repeats // 5)
            timings[name, n] = _time(make(int(n)), reps)

    rows: list[dict[str, Any]] = []
    for name in METHODS:
        for n in sizes:
            med, best = timings[name, n]
            rows.append({
                "method": name, "n": int(n),
                "ms_median": med * 1e3, "ms_best": best * 1e3, "fps": 1.0 / med,
                "vs_scipy": timings["scipy", n][0] / med,
                "vs_naive": timings["naive O(n²)", n][0] / med,
            })
    summary: dict[str, Any] = {"width": width, "height": height, "channels": channels,
                               "repeats": repeats, "sizes": [int(n) for n in sizes],
                               "threads": n_workers(), "load_average_1min": load}
    for name in METHODS[:3]:
        meds = [timings[name, n][0] for n in sizes]
        bests = [timings[name, n][1] for n in sizes]
        summary[name] = {"size_spread": max(meds) / min(meds),
                         "size_spread_best": max(bests) / min(bests),
                         "worst_fps": 1.0 / max(meds), "worst_fps_best": 1.0 / max(bests)}
    return rows, summary
