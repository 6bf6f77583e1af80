"""Does a written far-field file give the run back? Its apertures against the run's.

The run measured intensities in detector apertures (:mod:`lightsim.engine.apertures`): a
rule set's test points and zone samples, and the tiles of the Imax raster, each with a 95 %
interval over the interleave sets (:func:`lightsim.report.aperture_values`). A file used
as a light source gives an aperture the mean of its interpolated intensity over the
aperture's solid angle (:func:`aperture_means`). :func:`reproduction` compares the two —
the file's peak tile with the run's Imax, and every test-point aperture that counted
``MIN_PHOTONS`` photons — and says in one
line (:attr:`Reproduction.warning`) when the file falls outside the run's interval
widened by ``SLACK`` of the value: such a file cannot reproduce the run (a grid too coarse
for the cut-off, for instance).

Parameters
----------
==========  =====  =======  ===========================================================
name        unit   default  meaning
==========  =====  =======  ===========================================================
SLACK       1      0.02     share of the run's value added to both ends of its interval
MIN_PHOTONS 1      20       photons an aperture must have counted to be compared
SAMPLES     1      6        sample points per aperture side (n × n midpoints)
confidence  1      0.95     two-sided level of the run's intervals
==========  =====  =======  ===========================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import stdtrit

from lightsim.engine.apertures import layout_from_config
from lightsim.report import aperture_values

from .runfield import BeamBins

__all__ = ["MIN_PHOTONS", "SAMPLES", "SLACK", "Reproduction", "aperture_means", "position_text",
           "reproduction"]

SLACK = 0.02
"""Share of the run's value by which a file may lie outside the run's interval."""
SAMPLES = 6
"""Sample points per aperture side."""
MIN_PHOTONS = 20.0
"""Photons (effective, over all sets) an aperture must have counted to be compared: below,
the run's value rests on a few photons whose places inside the aperture a file of the
run's bin size cannot keep (they are spread over the neighbouring bins)."""


def aperture_means(grid: Any, frame: Any, h_deg: NDArray, v_deg: NDArray, width_deg: float,
                   height_deg: float, samples: int = SAMPLES) -> NDArray:
    """Mean intensity (cd) of ``grid`` over wall rectangles seen from the lamp.

    Rectangle k spans wall angles ``h_deg[k] ± width/2``, ``v_deg[k] ± height/2``
    (atan(h/D) from the wall centre, as the run's apertures count); the mean is over its
    solid angle, from ``samples`` × ``samples`` midpoints weighted by their dΩ.
    """
    h = np.asarray(h_deg, dtype=np.float64).reshape(-1)
    v = np.asarray(v_deg, dtype=np.float64).reshape(-1)
    f = (np.arange(samples) + 0.5) / samples - 0.5
    hh = np.radians(h[:, None, None] + f[None, :, None] * width_deg)
    vv = np.radians(v[:, None, None] + f[None, None, :] * height_deg)
    x, y = np.broadcast_arrays(np.tan(hh), np.tan(vv))
    d = float(frame.distance_m)
    p = frame.to_world(d * x, d * y)
    dirs = p / np.linalg.norm(p, axis=-1, keepdims=True)
    # dΩ of a wall-angle element: sec²H sec²V dH dV / (1 + tan²H + tan²V)^(3/2)
    w = (1 + x * x) * (1 + y * y) / (1 + x * x + y * y) ** 1.5
    cd = grid.intensity_towards(dirs)
    return (cd * w).sum(axis=(1, 2)) / w.sum(axis=(1, 2))


def position_text(h_deg: float, v_deg: float) -> str:
    """A direction as a rule set's table writes it: ``0.57D 1.15R``, ``H-V``."""
    def part(x: float, pos: str, neg: str, zero: str) -> str:
        if abs(x) < 5e-3:
            return zero
        return f"{abs(x):.2f}".rstrip("0").rstrip(".") + (pos if x > 0 else neg)

    if abs(h_deg) < 5e-3 and abs(v_deg) < 5e-3:
        return "H-V"
    return f"{part(v_deg, 'U', 'D', 'H')} {part(h_deg, 'R', 'L', 'V')}"


@dataclass
class Reproduction:
    """A file's apertures against the run's (see the module docstring).

    Attributes
    ----------
    peak_cd, run_imax_cd : float or None
        The file's largest tile and the run's Imax (cd); None without an Imax raster.
    run_imax_interval_cd : list of float or None
        The run's interval of Imax (cd).
    points : int
        Test-point apertures compared (those that counted ``MIN_PHOTONS``).
    outside : int
        Of them, how many fall outside the run's widened interval.
    worst : dict or None
        The test point furthest outside (position, file and run values, interval).
    warning : str or None
        One line when the file cannot reproduce the run.
    """

    peak_cd: float | None = None
    run_imax_cd: float | None = None
    run_imax_interval_cd: list[float] | None = None
    points: int = 0
    outside: int = 0
    worst: dict[str, Any] | None = None
    warning: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (``summary.json["farfield"]["checks"][path]``)."""
        return {"peak_cd": self.peak_cd, "run_imax_cd": self.run_imax_cd,
                "run_imax_interval_cd": self.run_imax_interval_cd,
                "test_points": self.points, "outside": self.outside, "worst": self.worst}


def _student(samples: NDArray, confidence: float) -> tuple[NDArray, NDArray]:
    """Mean and half-width of the Student-t interval of per-set values (axis 0)."""
    s = samples.shape[0]
    mean = samples.mean(axis=0)
    if s < 2:
        return mean, np.zeros_like(mean)
    half = stdtrit(s - 1, 0.5 + confidence / 2) * samples.std(axis=0, ddof=1) / math.sqrt(s)
    return mean, half


def reproduction(grid: Any, name: str, session: Any, bins: BeamBins | None,
                 hint: str = "", confidence: float = 0.95) -> Reproduction:
    """Compare file ``grid`` (named ``name`` in the warning) with the run's apertures.

    ``hint`` ends the warning line (what to change).
    """
    out = Reproduction()
    frame = session.scene.wall
    cfg = session.config
    problems: list[str] = []
    if bins is not None and bins.tiles.size:
        mean, half = _student(bins.tiles, confidence)
        i, k = np.unravel_index(int(np.argmax(mean)), mean.shape)
        # an intensity is never negative: the interval's lower end is clipped at 0
        run, lo, hi = float(mean[i, k]), max(0.0, float(mean[i, k] - half[i, k])), float(
            mean[i, k] + half[i, k])
        cols, vs = np.meshgrid(bins.h_deg, bins.v_deg, indexing="ij")
        # an even count of midpoints is exact for a kink at the bin centre
        per_bin = aperture_means(grid, frame, cols.ravel(), vs.ravel(), bins.width_deg,
                                 bins.height_deg, samples=4).reshape(cols.shape)
        m = len(bins.v_deg) - len(bins.tile_v_deg) + 1  # bins per tile
        csum = np.concatenate([np.zeros((len(bins.h_deg), 1)), np.cumsum(per_bin, axis=1)],
                              axis=1)
        peak = float(((csum[:, m:] - csum[:, :-m]) / m).max())
        out.peak_cd, out.run_imax_cd, out.run_imax_interval_cd = peak, run, [lo, hi]
        if not lo - SLACK * run <= peak <= hi + SLACK * run:
            problems.append(f"peak {peak:,.0f} cd vs Imax {run:,.0f} ({lo:,.0f}–{hi:,.0f})")
    if cfg.apertures and cfg.aperture_deg:
        ap = aperture_values(session, 0.0, confidence)
        layout = layout_from_config(cfg, frame.distance_m)
        mean = ap["cd"].mean(axis=0)
        lo, hi = ap["intervals_cd"].T  # the regulation check's intervals (never below 0)
        file_cd = aperture_means(grid, frame, layout.h_deg, layout.v_deg, layout.size_deg,
                                 layout.size_deg)
        slack = SLACK * np.abs(mean)
        miss = np.maximum(lo - slack - file_cd, file_cd - hi - slack)
        counted = np.asarray(ap["n_eff"]) >= MIN_PHOTONS
        out.points = int(counted.sum())
        bad = np.flatnonzero(counted & (miss > 0))
        out.outside = len(bad)
        if len(bad):
            j = int(bad[np.argmax(miss[bad] / np.maximum(hi[bad] - lo[bad], 1e-9))])
            out.worst = {"position": position_text(layout.h_deg[j], layout.v_deg[j]),
                         "h_deg": float(layout.h_deg[j]), "v_deg": float(layout.v_deg[j]),
                         "file_cd": float(file_cd[j]), "run_cd": float(mean[j]),
                         "interval_cd": [float(lo[j]), float(hi[j])]}
            w = out.worst
            problems.append(f"{len(bad)} of {out.points} points outside their intervals "
                            f"(worst {w['position']}: {w['file_cd']:,.0f} vs "
                            f"{lo[j]:,.0f}–{hi[j]:,.0f} cd)")
    if problems:
        out.warning = (f"{name} does not reproduce the run: " + "; ".join(problems)
                       + (f"; {hint}" if hint else ""))
    return out
