"""Iso-lux lines that follow the beam, not the photon noise: per-level smoothing.

A photon-map estimate at illuminance E over an area A rests on n = E·A·N/Φ photons, so its
relative noise is 1/√n. Near the map's noise floor (n = 16, 25 % noise,
:func:`lightsim.io.plots.isolux_noise_floor`) a contour drawn on the raw map wobbles and
breaks into speckle islands wherever the true illuminance is a noise-width below the
level. Each level L is therefore drawn on the map smoothed just enough that an estimate at
L rests on ``target_photons`` photons: a Gaussian of width σ adds an averaging area 4πσ²
(the equivalent area of a Gaussian for uncorrelated noise), so

    σ² = A · (n_target / n(L) − 1) / (4π),   n(L) = n_floor · L / E_floor,

and levels with n(L) ≥ n_target are drawn on the raw map (no blur where the estimate is
good). The blur is the price of a clean line near the floor and is said on the plot.

==================  =====  =======  ===============================================
parameter           unit   default  meaning
==================  =====  =======  ===============================================
noise_floor_lx      lx     –        illuminance where an estimate holds ``floor_photons``
floor_photons       –      16       photons of an estimate at the floor (25 % noise)
estimate_area_px    px²    –        area an estimate at the floor averages over
target_photons      –      256      photons wanted at a drawn level (6.25 % noise)
==================  =====  =======  ===============================================
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.ndimage import gaussian_filter

FLOOR_PHOTONS = 16.0
TARGET_PHOTONS = 256.0


def level_sigma_px(level_lx: float, noise_floor_lx: float, estimate_area_px: float,
                   target_photons: float = TARGET_PHOTONS,
                   floor_photons: float = FLOOR_PHOTONS) -> float:
    """Gaussian width (pixels) that brings an estimate at ``level_lx`` to
    ``target_photons`` photons; 0 when it already rests on that many (or input is bad)."""
    vals = (level_lx, noise_floor_lx, estimate_area_px, target_photons, floor_photons)
    if not all(math.isfinite(x) and x > 0 for x in vals):
        return 0.0
    n = floor_photons * level_lx / noise_floor_lx
    if n >= target_photons:
        return 0.0
    return math.sqrt(estimate_area_px * (target_photons / n - 1.0) / (4.0 * math.pi))


def smoothed_for_levels(img: np.ndarray, levels: Sequence[float], noise_floor_lx: float,
                        estimate_area_px: float, target_photons: float = TARGET_PHOTONS
                        ) -> tuple[list[np.ndarray], np.ndarray, list[float]]:
    """Per-level contour images and one band image for the fills.

    Parameters
    ----------
    img : (H, W) array
        Wall illuminance (lx), finite.
    levels : sequence of float
        Increasing iso-lux levels (lx).
    noise_floor_lx, estimate_area_px, target_photons
        See the module docstring.

    Returns
    -------
    images : list of (H, W) arrays
        The map each level is contoured on (the raw map where no smoothing is needed).
    band : (H, W) float array
        Index of the highest level reached at each pixel on its own image (−1 below the
        first), for ``contourf(levels = −0.5, 0.5, …)``.
    sigmas : list of float
        The Gaussian width (px) used per level.
    """
    img = np.asarray(img, dtype=np.float64)
    images, sigmas = [], []
    band = np.full(img.shape, -1.0)
    cache: dict[float, np.ndarray] = {}
    for i, lv in enumerate(levels):
        s = level_sigma_px(lv, noise_floor_lx, estimate_area_px, target_photons)
        s = round(s, 2)
        if s not in cache:
            cache[s] = gaussian_filter(img, s, mode="nearest") if s > 0 else img
        images.append(cache[s])
        sigmas.append(s)
        band[cache[s] >= lv] = i
    return images, band, sigmas
