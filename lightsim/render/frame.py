"""Server side of a frame: assemble the interleaved sub-images, filter, and estimate the error.

The M² interleave sets are independent, unbiased estimates (each has its own scrambled
photons), so their spread is an error estimate that needs no reference solution. Every
set also estimates the illuminance at a fixed list of *probe points* on the wall; at a
probe the S = M² values give a mean Ē and a standard error se = s / √S, which is the
standard error of the filtered image there (the n = M box filter averages one value of
every set). The **relative error over the lit region** is

    rel_error = √(mean over lit probes of se²) / mean over lit probes of Ē,

with *lit* = Ē ≥ 10 % of the brightest probe (Ē of the pixel windows below, where
measured, as the blur spreads light beyond a bright edge). That is the noise. A kNN (or
fixed-radius) estimate also has a **blur bias**: it averages E over a disk of radius r_k,
not over the pixel. Every set therefore also counts its photons in a pixel-sized *window*
centred on each grid probe — an unbiased estimate B of the pixel mean, noisier than the kNN
value K.
Per set the difference D = K − B has expectation b (the bias) and the sets' spread gives
its standard error se_D, so

    rel_bias² = max(0, mean over lit probes of (D̄² − se_D²)) / (mean over lit probes of Ē)²

is an unbiased estimate of the mean squared bias (noise subtracted). The reported error is
rel_error = √(rel_noise² + rel_bias²); ``lightsim converge`` checks it against exact
answers (the ratio estimated / actual). With few photons per pixel window the bias
estimate scatters; ``rel_bias_upper`` (the estimate plus two standard errors of the mean
over the lit probes) says how much blur could hide in it (:func:`probe_error`: the figure
of the kNN and binning maps; the ICI map measures its own,
:mod:`lightsim.render.written_map`).

=====================  =====  ========  =================================================
parameter              unit   default   meaning
=====================  =====  ========  =================================================
``lit_fraction``       –      0.1       probes at ≥ this × max count as lit
=====================  =====  ========  =================================================
"""

from __future__ import annotations

import math
from collections.abc import Callable
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
    windows : (S, G, C) float64 or None
        Per-set photon counts in a pixel-sized window at each of the G grid probes, as
        illuminance (lx): the unbiased reference for the blur bias (None for binning).
    """

    mean: np.ndarray
    se: np.ndarray
    values: np.ndarray
    windows: np.ndarray | None = None

    @property
    def n_sets(self) -> int:
        return self.values.shape[0]


def probe_stats(probes: dict[int, np.ndarray],
                windows: dict[int, np.ndarray] | None = None) -> ProbeStats:
    """Mean and standard error over sets of the probe estimates {set: (P, C)}.

    ``windows`` {set: (G, C)}: the sets' pixel-window estimates at the grid probes.
    """
    values = np.stack([np.asarray(probes[s], dtype=np.float64) for s in sorted(probes)])
    S = values.shape[0]
    mean = values.mean(axis=0)
    if S > 1:
        se = values.std(axis=0, ddof=1) / math.sqrt(S)
    else:
        se = np.full_like(mean, np.inf)
    win = None
    if windows and sorted(windows) == sorted(probes):
        win = np.stack([np.asarray(windows[s], dtype=np.float64) for s in sorted(windows)])
    return ProbeStats(mean, se, values, win)


@dataclass(frozen=True)
class ErrorEstimate:
    """Relative error of an image over the lit region (dimensionless fractions).

    ``total`` = √(noise² + bias²); ``bias`` is None where it is not measured (binning,
    whose pixel means carry no blur, or a single set). ``bias_upper``: the bias estimate
    plus two of its standard errors (in the square) — with few photons per pixel window
    the blur cannot be resolved below it, which a bias of 0 would hide. ``bias2`` and
    ``bias2_se``: the unbiased estimate of the squared blur (may be negative) and its
    standard error, relative² (None where no blur is measured); the target-error stop
    reads them (:func:`lightsim.engine.server.stop_level`).
    """

    total: float
    noise: float
    bias: float | None
    bias_upper: float | None = None
    bias2: float | None = None
    bias2_se: float | None = None

    @property
    def upper(self) -> float:
        """√(noise² + bias_upper²): the error the blur could still hide (for stopping rules)."""
        return math.hypot(self.noise, self.bias_upper or 0.0)

    @property
    def bias_resolved(self) -> bool:
        """Whether the blur estimate stands out of its own scatter (≥ 2 standard errors)."""
        return (self.bias is not None and self.bias_upper is not None
                and self.bias**2 >= 0.5 * self.bias_upper**2)

    def describe(self) -> str:
        """'4.2% (noise 3.1%, blur 2.8%)', with 'blur ≤ x%' where it is not resolved."""
        text = f"{self.total:.2%}"
        if self.bias is None:
            return text
        blur = (f"blur {self.bias:.2%}" if self.bias_resolved or self.bias_upper is None
                else f"blur ≤ {self.bias_upper:.2%}, not resolved")
        return f"{text} (noise {self.noise:.2%}, {blur})"


def _mean_over_sets(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S, G) → mean and standard error of the mean over the S sets, (G,) each."""
    return values.mean(axis=0), values.std(axis=0, ddof=1) / math.sqrt(values.shape[0])


def probe_error(stats: ProbeStats, grid_count: int, lit_fraction: float = 0.1,
                restrict: Callable[[np.ndarray], np.ndarray] | None = None
                ) -> ErrorEstimate | None:
    """The error figure of the probes' estimates: noise and blur bias over the lit probes
    of the grid (see module docstring; the kNN and binning maps' figure).

    Only the first ``grid_count`` probes (the regular grid) count; extra probes (test
    points) would bias the average. ``restrict``: the figure's region within the lit
    probes (:func:`lightsim.render.region.restriction`; None: every lit probe). ``None``
    when nothing is lit or with one set.
    """
    if stats.n_sets < 2:
        return None
    y = luminous(stats.values[:, :grid_count])  # (S, G), luminous: linear in the channels
    if y.shape[1] == 0:
        return None
    m, se = _mean_over_sets(y)
    if not np.any(m > 0):
        return None
    windows = (luminous(stats.windows) if stats.windows is not None
               and stats.windows.shape[1] == grid_count else None)
    # lit: by the unbiased window means where there are any, as the blur spreads the
    # estimate beyond a bright edge onto probes the truth leaves dark
    lit = (m if windows is None else windows.mean(axis=0)) >= lit_fraction * m.max()
    if restrict is not None:
        lit = restrict(lit)
    if not lit.any():
        return None
    mean_lit = float(np.mean(m[lit]))
    noise = math.sqrt(float(np.mean(se[lit] ** 2))) / mean_lit
    if not math.isfinite(noise):
        return None
    bias = upper = b2_rel = se_rel = None
    if windows is not None:
        d_mean, d_se = _mean_over_sets(y - windows)
        terms = d_mean[lit] ** 2 - d_se[lit] ** 2  # each an unbiased estimate of b²
        b2 = float(np.mean(terms))
        se_b2 = float(np.std(terms, ddof=1) / math.sqrt(terms.size)) if terms.size > 1 else 0.0
        bias = math.sqrt(max(b2, 0.0)) / mean_lit
        upper = math.sqrt(max(b2 + 2.0 * se_b2, 0.0)) / mean_lit
        b2_rel, se_rel = b2 / mean_lit**2, se_b2 / mean_lit**2
        if not all(math.isfinite(x) for x in (bias, upper, b2_rel, se_rel)):
            bias = upper = b2_rel = se_rel = None
    total = math.hypot(noise, bias or 0.0)
    return ErrorEstimate(total, noise, bias, upper, b2_rel, se_rel)


def probe_grid(h_range: tuple[float, float], v_range: tuple[float, float],
               shape: tuple[int, int]) -> np.ndarray:
    """(nh·nv, 2) wall coordinates (h, v in m) of a regular grid of cell centres."""
    nh, nv = shape
    h = h_range[0] + (np.arange(nh) + 0.5) * (h_range[1] - h_range[0]) / nh
    v = v_range[0] + (np.arange(nv) + 0.5) * (v_range[1] - v_range[0]) / nv
    hh, vv = np.meshgrid(h, v)
    return np.stack([hh.ravel(), vv.ravel()], axis=1)
