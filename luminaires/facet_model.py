"""Deterministic beam model for the optimiser: the lamp's pattern as a sum of measured,
shifted facet footprints.

A facet of the multi-facet reflector (:mod:`lightsim.luminaires.reflector`) is a
paraboloid about the lamp's focus with its own aim (h_k, v_k): changing the aim by a few
degrees moves the facet's filament images by the same angle and hardly changes their
shape. So the wall pattern of a lamp whose movable facets are shifted by s_k = (Δh_k, Δv_k)
from a reference lamp is, to first order,

    E(s) = E_base + Σ_k T(s_k) F_k,      F_k = E(facet k alone) − E_base

where E_base is the simulated lamp with every movable facet (the lit main facets and the
overhead-sign slivers) aimed away (off the wall: only the bulb's direct light and the
cup-shaded facets' stray light remain), E(facet k alone) the same lamp with facet k at
its reference aim, and T(s) a bilinear image shift by s (in wall pixels at the wall's
centre). The footprints F_k are
**measured once with the simulator** (one run per movable facet, all with the same photon
seed: common random numbers, so E(k alone) − E_base cancels the noise of the light that
does not come from facet k). Evaluating E(s) then costs a few image shifts (milliseconds)
and is deterministic and continuous in s: the optimiser sees geometry, not photon noise.

The objective evaluated on E(s) is :func:`lightsim.luminaires.design_terms.map_terms`
(every rule of every rule set, cut-off sharpness and linearity, aim, smoothness, road
reach; rule values from the model map, so their "interval" is the value) plus a small
regulariser ``ρ·Σ|s_k|²/(1°)²`` that keeps the shifts where the model is valid.

Parameters

==================  =====  =========  ===================================================
name                unit   default    meaning
==================  =====  =========  ===================================================
AWAY_V_DEG          deg    −25        aim of a facet "away" (below the wall's ±13.5°)
photons             –      1 000 000  photons per footprint run
resolution          px     200×256    footprint map W×H (0.34° × 0.107° pixels)
shift_bounds_deg    deg    ±1, ±0.5   bounds of Δh, Δv per facet
regulariser         –      0.01       ρ above
smooth_px           px     0          Gaussian σ applied to every footprint
foreground_m        m      0          road foreground term (``foreground_term``)
aim_offset_deg      deg    None       check-run minus model-finder aim on the reference
==================  =====  =========  ===================================================
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter

from lightsim.errors import InputError
from lightsim.wall import WallFrame

from .design_lamp import (
    FG_LIT_MIN,
    LIT_MIN,
    Layout,
    facet_images,
    facets_for,
    hole_diameter,
    simulate_lamp,
    write_facets,
)
from .design_terms import Term, map_terms
from .reflector import Facet

__all__ = ["AWAY_V_DEG", "NOISE_CD", "NOISE_PHOTONS", "FootprintModel", "ShiftResult",
           "add_shifted", "measure_footprints", "model_terms", "movable_facets",
           "optimise_shifts"]

AWAY_V_DEG = -25.0  # the wall spans ±13.5° at 25 m; −25° puts a facet's images below it
SHIFT_BOUNDS_DEG = (1.0, 0.5)  # measured: with ±3°, ±1.5° (rms 0.8°) the re-measured
# lamp's J was 20× the model's; with rms 0.3° the model held within ~5 % at most points
REGULARISER = 0.01
NOISE_CD = 6.2
"""Half-width of the 95 % interval of a test point (relative) × √I, for the README demo's
run (12 M photons, 320×128, 0.15° apertures, ``--aim``): measured on the designed lamp
(B8 145 cd ±38 %, III 335 ±30 %, IV 2 860 ±14 %, 25L2 3 045 ±11 %, 50R 21 221 ±3.6 %:
≈ 6.2/√I). It scales as √(12 M / photons)."""
NOISE_PHOTONS = 12_000_000


@dataclass
class FootprintModel:
    """Measured footprints of the movable facets and the base map.

    Attributes
    ----------
    frame : dict
        Wall frame of the maps (:meth:`lightsim.wall.WallFrame.to_dict`).
    base : ndarray, shape (H, W)
        Wall lux of the lamp with every movable facet aimed away.
    footprints : ndarray, shape (K, H, W)
        Wall lux of each movable facet alone at its reference aim, minus ``base``.
    facets : list of int
        Index (in the lamp's facet list) of each movable facet.
    px_deg : tuple of float
        Pixel size (h, v) in degrees at the wall's centre.
    seconds : float
        Wall-clock time of the measurement, s.
    residual : ndarray, shape (H, W) or None
        Whole lamp simulated (more photons, same seed) − (base + Σ footprints): the kNN
        estimate is not additive where footprints overlap; with it the model reproduces
        the simulated reference lamp exactly at zero shift.
    """

    frame: dict[str, Any]
    base: np.ndarray
    footprints: np.ndarray
    facets: list[int]
    px_deg: tuple[float, float]
    seconds: float = 0.0
    residual: np.ndarray | None = None

    def lux(self, shifts_deg: np.ndarray) -> np.ndarray:
        """Model wall lux for facet shifts (K, 2) = (Δh, Δv) in degrees (H right, V up)."""
        s = np.asarray(shifts_deg, float).reshape(len(self.facets), 2)
        out = self.base.copy() if self.residual is None else self.base + self.residual
        for fp, (dh, dv) in zip(self.footprints, s):
            # rows run top→bottom (V up = −row); columns run with H (left → right)
            add_shifted(out, fp, -dv / self.px_deg[1], dh / self.px_deg[0])
        return np.maximum(out, 0.0)


def add_shifted(out: np.ndarray, img: np.ndarray, dr: float, dc: float) -> None:
    """out += img shifted by (dr, dc) pixels, bilinear, zero outside (in place)."""
    H, W = img.shape
    r0, c0 = math.floor(dr), math.floor(dc)
    fr, fc = dr - r0, dc - c0
    for ir, wr in ((r0, 1.0 - fr), (r0 + 1, fr)):
        for ic, wc in ((c0, 1.0 - fc), (c0 + 1, fc)):
            w = wr * wc
            if w <= 0 or abs(ir) >= H or abs(ic) >= W:
                continue
            # destination rows/cols [a, b) take source rows/cols [a − ir, b − ir)
            ra, rb = max(0, ir), min(H, H + ir)
            ca, cb = max(0, ic), min(W, W + ic)
            out[ra:rb, ca:cb] += w * img[ra - ir:rb - ir, ca - ic:cb - ic]


def movable_facets(facets: Sequence[Facet], layout: Layout, hole_m: float) -> list[int]:
    """Indices of the main (ring × sector) facets the cup leaves lit (with
    ``layout.shaded_spread_deg`` > 0 also the cup's edge facets, lit ≥ ``FG_LIT_MIN``, which
    light the foreground) and of every overhead-sign sliver (the other shaded facets carry
    only stray light and stay put)."""
    n = layout.rings * layout.sectors
    images = facet_images(list(facets[:n]), layout, hole_m)
    lit = LIT_MIN if layout.shaded_spread_deg <= 0 else FG_LIT_MIN
    return ([k for k, im in enumerate(images) if im.lit_fraction >= lit]
            + list(range(n, len(facets))))


def measure_footprints(x: np.ndarray, layout: Layout, regulation: str, *, photons: int,
                       resolution: tuple[int, int], seed: int, residual_factor: int = 0,
                       progress: Callable[[str], None] | None = None,
                       smooth_px: float = 0.0) -> FootprintModel:
    """Simulate the base lamp and each movable facet alone (same seed); see the module
    docstring. ``x`` and ``layout`` (with its facet shifts) define the reference lamp.
    ``residual_factor`` > 0: also simulate the whole lamp with that many times the photons
    (:attr:`FootprintModel.residual`). ``smooth_px`` > 0: each footprint is smoothed
    with a Gaussian of that σ (pixels; the residual keeps the model exact at zero shift),
    so that the optimiser cannot move a footprint's photon-noise peaks onto a test point."""
    t0 = time.perf_counter()
    hole = hole_diameter(layout)
    facets = facets_for(np.asarray(x, float), layout, hole)
    movable = movable_facets(facets, layout, hole)
    if not movable:
        raise InputError("no facet of this layout is lit: nothing to optimise")
    away = [replace(f, v_deg=AWAY_V_DEG) if k in movable else f for k, f in enumerate(facets)]
    maps = []
    frame = None
    with tempfile.TemporaryDirectory(prefix="lightsim-footprints-") as tmp:
        glb = Path(tmp) / "footprint.glb"
        runs: list[int | str | None] = [None, *movable]
        if residual_factor > 0:
            runs.append("whole")
        for i, k in enumerate(runs):
            fl = list(facets) if k == "whole" else list(away)
            if isinstance(k, int):
                fl[k] = facets[k]
            write_facets(glb, fl, layout)
            t1 = time.perf_counter()
            n = photons * residual_factor if k == "whole" else photons
            _reg, lux, frame = simulate_lamp(glb, regulation, photons=n,
                                             resolution=resolution, seed=seed,
                                             traffic=layout.traffic, aim=False)
            maps.append(np.nan_to_num(np.asarray(lux, float)))
            if progress is not None:
                what = ("base (movable facets away)" if k is None else
                        f"whole lamp ({n:,} photons)" if k == "whole" else f"facet {k}")
                progress(f"footprint run {i + 1}/{len(runs)}: {what}, "
                         f"{time.perf_counter() - t1:.1f} s")
    wf = WallFrame.from_any(frame)
    fd = wf.to_dict()
    h0, h1 = fd["h_range_m"]
    v0, v1 = fd["v_range_m"]
    d = float(fd["distance_m"])
    H, W = maps[0].shape
    px = (math.degrees(math.atan2((h1 - h0) / W, d)), math.degrees(math.atan2((v1 - v0) / H, d)))
    base = maps[0]
    fps = np.stack([m - base for m in maps[1:len(movable) + 1]])
    if smooth_px > 0:
        fps = np.stack([gaussian_filter(f, smooth_px, mode="constant") for f in fps])
    res = maps[-1] - base - fps.sum(axis=0) if residual_factor > 0 else None
    return FootprintModel(fd, base, fps, movable, px, time.perf_counter() - t0, res)


def model_terms(model: FootprintModel, shifts_deg: np.ndarray, regulations: Sequence[str],
                traffic: str, *, safety: float, reach_m: float, smooth_max: float,
                regulariser: float = REGULARISER, noise_cd: float = 0.0,
                foreground_m: float = 0.0, aim_offset_deg: float | None = None,
                lux: np.ndarray | None = None, reach_weight: float = 1.0) -> list[Term]:
    """The objective's terms (:func:`lightsim.luminaires.design_terms.map_terms`) of every
    rule set on the model map, plus the shift regulariser.

    ``noise_cd``: the model's values get the interval I·(1 ± noise_cd/√I) (cd) that a
    verification run is expected to show (photon-count noise of the detector apertures;
    :data:`NOISE_CD`), so a faint point is asked for more margin than a bright one."""
    lux = model.lux(shifts_deg) if lux is None else np.asarray(lux, float)
    terms = map_terms(lux, model.frame, regulations, traffic, safety=safety,
                      reach_m=reach_m, smooth_max=smooth_max, noise_cd=noise_cd,
                      foreground_m=foreground_m, aim_offset_deg=aim_offset_deg,
                      reach_weight=reach_weight)
    s = np.asarray(shifts_deg, float)
    reg_pen = float(regulariser * np.sum(s * s))
    terms.append(Term("shift size", 0.0, reg_pen, float(np.sqrt(np.mean(s * s))),
                      "rms shift, deg"))
    return terms


@dataclass
class ShiftResult:
    """Outcome of :func:`optimise_shifts`: best shifts (K, 2) deg, J, terms, evaluations."""

    shifts_deg: np.ndarray
    objective: float
    start_objective: float
    terms: list[Term]
    evaluations: int


def optimise_shifts(model: FootprintModel, regulations: Sequence[str], traffic: str, *,
                    safety: float, reach_m: float, smooth_max: float, evaluations: int,
                    start: np.ndarray | None = None, noise_cd: float = 0.0,
                    foreground_m: float = 0.0, aim_offset_deg: float | None = None,
                    progress: Callable[[int, float, list[Term]], None] | None = None,
                    reach_weight: float = 1.0) -> ShiftResult:
    """Minimise J(s) on the model with :func:`scipy.optimize.minimize` (Powell, bounded
    |Δh| ≤ 1°, |Δv| ≤ 0.5° per facet); deterministic (the model is).

    The variables are a common shift g of every movable facet (|g_h| ≤ 0.5°, |g_v| ≤ 0.3°:
    the cut-off's level and the hot spot's side move as a whole, which one facet at a time
    cannot do) and each facet's own shift; facet k moves by g + s_k."""
    from scipy.optimize import minimize

    K = len(model.facets)
    s0 = np.zeros(2 * K) if start is None else np.asarray(start, float).ravel()
    z0 = np.concatenate([[0.0, 0.0], s0])
    bh, bv = SHIFT_BOUNDS_DEG
    bnds = [(-0.5, 0.5), (-0.3, 0.3)] + [(-bh, bh), (-bv, bv)] * K
    kw = dict(safety=safety, reach_m=reach_m, smooth_max=smooth_max, noise_cd=noise_cd,
              foreground_m=foreground_m, aim_offset_deg=aim_offset_deg,
              reach_weight=reach_weight)
    count = [0]
    best: dict[str, Any] = {"j": math.inf}

    def shifts(z: np.ndarray) -> np.ndarray:
        return np.clip(z[2:].reshape(K, 2) + z[None, :2], [-bh, -bv], [bh, bv])

    def j_of(z: np.ndarray) -> float:
        terms = model_terms(model, shifts(z), regulations, traffic, **kw)
        j = float(sum(t.penalty for t in terms))
        count[0] += 1
        if j < best["j"]:
            best.update(j=j, s=shifts(z), terms=terms)
            if progress is not None:
                progress(count[0], j, terms)
        return j

    j0 = j_of(z0)
    minimize(j_of, z0, method="Powell", bounds=bnds,
             options={"maxfev": int(evaluations), "xtol": 0.02, "ftol": 1e-4})
    return ShiftResult(best["s"], best["j"], j0, best["terms"], count[0])
