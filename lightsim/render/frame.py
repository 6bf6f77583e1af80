"""Server side of a frame: assemble the interleaved sub-images, filter, and estimate the error.

The M² interleave sets are independent, unbiased estimates (each has its own scrambled
photons), so their spread is an error estimate that needs no reference solution. Every
set also estimates the illuminance at a fixed list of *probe points* on the wall; at a
probe the S = M² values give a mean Ē and a standard error se = s / √S, which is the
standard error of the filtered image there (the n = M box filter averages one value of
every set). The **relative error over the lit region** is

    rel_error = √(mean over lit probes of se²) / mean over lit probes of Ē,

with *lit* = Ē ≥ 10 % of the brightest probe. It covers noise, not the blur bias of the
density estimate (``lightsim converge`` measures that against exact answers).

=====================  =====  ========  =================================================
parameter              unit   default   meaning
=====================  =====  ========  =================================================
``lit_fraction``       –      0.1       probes at ≥ this × max count as lit
``confidence``         –      0.95      two-sided level of probe intervals (Student t)
=====================  =====  ========  =================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lightsim.materials import LUMA
from lightsim.render.boxfilter import box_filter
from lightsim.render.interleave import InterleavePattern


def luminous(values: np.ndarray) -> np.ndarray:
    """(…, C) channel values → (…) luminous values (Rec. 709 weights for RGB)."""
    v = np.asarray(values, dtype=np.float64)
    return v[..., 0] if v.shape[-1] == 1 else v @ LUMA


def assemble_interleaved(pattern: InterleavePattern, sub_images: dict[int, np.ndarray],
                         filter_n: int) -> tuple[np.ndarray, np.ndarray]:
    """Scatter the sets' sub-images into the full image and box-filter it.

    Returns
    -------
    filtered, raw : (H, W, C) float64 arrays (lx)
    """
    subs = [np.asarray(sub_images[s], dtype=np.float64) for s in range(pattern.n_sets)]
    raw = pattern.scatter(subs)
    filtered = box_filter(raw, filter_n) if filter_n > 1 else raw.copy()
    return np.asarray(filtered, dtype=np.float64), raw


def pool_full_images(full_images: dict[int, np.ndarray], emitted: dict[int, int]) -> np.ndarray:
    """Average per-set full images weighted by photons (identical to pooling the photons)."""
    total = sum(emitted.values())
    if total == 0:
        first = next(iter(full_images.values()))
        return np.zeros_like(first, dtype=np.float64)
    out = None
    for s in sorted(full_images):
        term = np.asarray(full_images[s], dtype=np.float64) * (emitted[s] / total)
        out = term if out is None else out + term
    return out


@dataclass
class ProbeStats:
    """Statistics of the per-set probe estimates.

    Attributes
    ----------
    mean : (P, C) float64
        Mean over sets (lx).
    se : (P, C) float64
        Standard error of the mean over sets (lx).
    values : (S, P, C) float64
        The per-set estimates.
    """

    mean: np.ndarray
    se: np.ndarray
    values: np.ndarray

    @property
    def n_sets(self) -> int:
        return self.values.shape[0]

    def interval(self, confidence: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """Two-sided Student-t interval (lo, hi) of the mean, (P, C) each."""
        from scipy.stats import t as student_t

        S = self.n_sets
        q = student_t.ppf(0.5 + confidence / 2, S - 1) if S > 1 else math.inf
        half = q * self.se
        return self.mean - half, self.mean + half


def probe_stats(probes: dict[int, np.ndarray]) -> ProbeStats:
    """Mean and standard error over sets of the probe estimates {set: (P, C)}."""
    values = np.stack([np.asarray(probes[s], dtype=np.float64) for s in sorted(probes)])
    S = values.shape[0]
    mean = values.mean(axis=0)
    if S > 1:
        se = values.std(axis=0, ddof=1) / math.sqrt(S)
    else:
        se = np.full_like(mean, np.inf)
    return ProbeStats(mean, se, values)


def relative_error(stats: ProbeStats, grid_count: int, lit_fraction: float = 0.1
                   ) -> float | None:
    """Relative standard error over the lit probes of the grid (see module docstring).

    Only the first ``grid_count`` probes (the regular grid) count; extra probes (test
    points) would bias the average. ``None`` when nothing is lit.
    """
    m = luminous(stats.mean[:grid_count])
    # the luminous standard error of RGB: propagate through the (linear) weights
    if stats.values.shape[-1] == 1:
        se = stats.se[:grid_count, 0]
    else:
        y = luminous(stats.values[:, :grid_count])
        se = y.std(axis=0, ddof=1) / math.sqrt(y.shape[0])
    if len(m) == 0 or not np.any(m > 0):
        return None
    lit = m >= lit_fraction * m.max()
    value = math.sqrt(float(np.mean(se[lit] ** 2))) / float(np.mean(m[lit]))
    return value if math.isfinite(value) else None


def probe_grid(h_range: tuple[float, float], v_range: tuple[float, float],
               shape: tuple[int, int]) -> np.ndarray:
    """(nh·nv, 2) wall coordinates (h, v in m) of a regular grid of cell centres."""
    nh, nv = shape
    h = h_range[0] + (np.arange(nh) + 0.5) * (h_range[1] - h_range[0]) / nh
    v = v_range[0] + (np.arange(nv) + 0.5) * (v_range[1] - v_range[0]) / nv
    hh, vv = np.meshgrid(h, v)
    return np.stack([hh.ravel(), vv.ravel()], axis=1)
