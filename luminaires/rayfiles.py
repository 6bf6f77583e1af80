"""Ray sets of simple sources with exactly known radiance, written as ray files.

:func:`lambertian_square` makes the rays of a flat square Lambertian emitter (an LED die):
positions uniform over the square, directions cosine-distributed about its normal +Z,
every ray the same share of the flux. Its luminance is exactly L = Φ / (π A), so the
illuminance it gives on any plane follows from Lambert's contour integral — the check of
the ray-file readers and the sampler. Samples are stratified (a jittered grid in each of
the two 2-D spaces, paired by a seeded permutation) so a modest file is already smooth.

==============  =====  =========  ==================================================
parameter       unit   default    meaning
==============  =====  =========  ==================================================
``side_m``      m      1e-3       edge length of the square (centred on the origin)
``n_rays``      –      100 000    rays in the file (rounded down to a square number)
``flux_lm``     lm     1000       total luminous flux
``seed``        –      1          jitter and pairing
==============  =====  =========  ==================================================
"""

from __future__ import annotations

import math

import numpy as np

from lightsim.errors import InputError


def _jittered(m: int, rng: np.random.Generator) -> np.ndarray:
    """m² stratified points in the unit square (one per cell of an m × m grid)."""
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    u = (i.ravel() + rng.random(m * m)) / m
    v = (j.ravel() + rng.random(m * m)) / m
    return np.column_stack([u, v])


def lambertian_square(side_m: float = 1e-3, n_rays: int = 100_000, flux_lm: float = 1000.0,
                      seed: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays of a Lambertian square emitter in the plane z = 0 facing +Z.

    Returns
    -------
    positions : (n, 3) float64, m
    directions : (n, 3) float64, unit
    flux : (n,) float64, lm (each Φ / n)
    """
    if not (math.isfinite(side_m) and side_m > 0):
        raise InputError(f"side must be a positive length, got {side_m} m")
    if not (math.isfinite(flux_lm) and flux_lm > 0):
        raise InputError(f"flux must be a positive number of lumens, got {flux_lm}")
    m = math.isqrt(int(n_rays))
    if m < 1:
        raise InputError(f"need at least one ray, got {n_rays}")
    rng = np.random.default_rng(seed)
    p = _jittered(m, rng)
    d = _jittered(m, rng)[rng.permutation(m * m)]
    pos = np.column_stack([(p[:, 0] - 0.5) * side_m, (p[:, 1] - 0.5) * side_m,
                           np.zeros(m * m)])
    r = np.sqrt(d[:, 0])
    phi = 2.0 * math.pi * d[:, 1]
    dirs = np.column_stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - d[:, 0])])
    return pos, dirs, np.full(m * m, flux_lm / (m * m))


def lambertian_square_luminance(side_m: float, flux_lm: float) -> float:
    """L = Φ / (π A) (cd/m²) of the square emitter."""
    return flux_lm / (math.pi * side_m * side_m)
