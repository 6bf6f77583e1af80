"""Engineering outputs of a finished run that need no rule set: detector-aperture
intensities with their intervals, the iso-lux and road views, the light that leaves the
lamp (for far-field files).

The last stage of the data flow (scene → photons → photon maps → images → **reports**).
Rule sets and photometric files build on these (:mod:`lightsim.luminaires.regulations.
check`, :mod:`lightsim.luminaires.photometric.analysis`) and are handed to the run as
:class:`~lightsim.analysis.Analysis` objects: this module imports neither.

======================  =====  =========  ===============================================
parameter               unit   default    meaning
======================  =====  =========  ===============================================
``mount_height``        m      0.65       lamp height above the road (road view)
``photons``             –      10⁶        photons traced without the wall (far field)
``confidence``          –      0.95       two-sided level of the aperture intervals
``SPARSE_PHOTONS_PER``  –      1          photons per set below which an aperture's
``_SET``                                  interval is the photon-count one
======================  =====  =========  ===============================================

Detector apertures (``lightsim.engine.apertures``) count every wall photon inside a square
of the sky around a direction: I = flux / solid angle, unbiased per interleave set, so the
Student-t interval over the sets is an interval for the aperture's mean intensity.
"""


from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.render.frame import luminous

SPARSE_PHOTONS_PER_SET = 1.0
"""Below this many counted photons per set an aperture's interval is the photon-count
(Garwood) one instead of Student-t over the sets."""


def _frame_dict(frame: Any) -> dict[str, Any]:
    return frame.to_dict() if hasattr(frame, "to_dict") else dict(frame)


def aperture_values(session, shift_deg: float = 0.0, confidence: float = 0.95
                    ) -> dict[str, Any]:
    """Per-set aperture intensities (cd) of a finished session's test points and Imax.

    Returns
    -------
    dict with ``cd`` (S, P) test points (last column H-V), ``tiles`` (S, nc, nv) Imax
    raster, ``tile_h_deg``, ``tile_v_deg``, ``layout``, ``shift_deg`` (applied, rounded),
    ``n_eff`` (P,) photons counted (effective number, pooled over sets) and
    ``intervals_cd`` (P, 2): the photon-count interval where fewer than
    ``SPARSE_PHOTONS_PER_SET`` photons per set were counted (the sets' spread says
    nothing there: most sets saw none), NaN elsewhere (Student-t over the sets).
    """
    from lightsim.engine.apertures import (
        count_statistics,
        intensities,
        layout_from_config,
        raster_tiles,
    )

    stats = session.backend.stats()
    sets = sorted(stats)
    per_set = session.backend.apertures()
    counts = np.stack([per_set[s] for s in sets])
    emitted = np.array([stats[s]["emitted"] for s in sets], dtype=np.float64)
    layout = layout_from_config(session.config, session.scene.wall.distance_m)
    try:
        _k, applied = layout.quantize_shift(shift_deg)
    except ValueError as exc:
        raise InputError(f"--aim: {exc}") from None
    cd = luminous(intensities(counts, emitted, layout, applied))
    power = np.stack([stats[s]["emitted_power"] for s in sets])
    count = np.stack(count_statistics(counts, emitted, power, layout, applied))  # (4, P)
    intervals = sparse_intervals(count, len(sets), confidence)
    n_eff = count[0]
    tiles = raster_tiles(counts, emitted, layout)
    return {"cd": cd, "tiles": luminous(tiles.values), "tile_h_deg": tiles.h_deg,
            "tile_v_deg": tiles.v_deg, "layout": layout, "shift_deg": applied,
            "n_eff": n_eff, "intervals_cd": intervals, "count_stats": count}


def sparse_intervals(count: np.ndarray, n_sets: int, confidence: float) -> np.ndarray:
    """(P, 2) photon-count intervals (cd) where an aperture caught fewer than
    ``SPARSE_PHOTONS_PER_SET`` photons per set, NaN elsewhere; ``count`` is the (4, P)
    stack of :func:`~lightsim.engine.apertures.count_statistics`."""
    from lightsim.engine.apertures import interval_from_counts

    n_eff, q, q0, mean = count
    lo, hi = interval_from_counts(n_eff, q, q0, mean, confidence)
    sparse = n_eff < SPARSE_PHOTONS_PER_SET * n_sets
    return np.where(sparse[:, None], np.stack([lo, hi], axis=1), np.nan)


def engineering_plots(out: Path, lux: np.ndarray, frame: Any,
                      results: list[dict[str, Any]] | None = None,
                      mount_height_m: float = 0.65,
                      summary: dict[str, Any] | None = None, *,
                      which: tuple[str, ...] = ("isolux", "road"),
                      plots: Any = None) -> list[Path]:
    """Write ``isolux.png`` (screen, H/V degrees) and ``road.png`` (bird's-eye view), or
    those of them named in ``which``; drawn by ``plots`` (:mod:`lightsim.io.plot_worker`:
    a helper process, or here by default).

    With the run's ``summary`` the iso-lux levels start at the map's noise floor, and
    ``summary["isolux"]`` (floor, levels) and ``summary["road"]`` (reach per level) are
    filled in — whether or not the plots are drawn.
    """
    from lightsim.io.plot_worker import InProcess
    from lightsim.io.plots import road_view_data

    plots = plots if plots is not None else InProcess()
    fd = _frame_dict(frame)
    floor = noise_floor_from_summary(summary, fd) if summary is not None else None
    area_px = estimate_area_px_from_summary(summary, fd) if summary is not None else None
    iso = rd = None
    if "isolux" in which:
        iso = plots.draw("isolux", Path(out) / "isolux.png", lux, fd, results=results,
                         title="iso-lux on the screen", noise_floor_lx=floor,
                         estimate_area_px=area_px)
    if "road" in which:
        rd = plots.draw("road", Path(out) / "road.png", lux, fd,
                        mount_height_m=mount_height_m)
    paths = []
    if iso is not None:
        iso.result()
        paths.append(Path(out) / "isolux.png")  # as given (the helper's path is absolute)
    if rd is not None:
        road = rd.result()
        paths.append(Path(out) / "road.png")
    else:
        road = road_view_data(lux, fd, mount_height_m=mount_height_m)
    if summary is not None:
        from lightsim.render.road import REACH_LEVELS

        summary["isolux"] = {"noise_floor_lx": floor,
                             "noise_floor_rule": "levels where an estimate holds < 16 "
                                                 "photons (relative noise > 25 %) are "
                                                 "not drawn"}
        if road is None:  # nothing to show (the plot says why): no reach either
            summary["road"] = {"mount_height_m": mount_height_m, "reach_m": None,
                               "text": "no road illuminance to show (see road.png)"}
        else:
            summary["road"] = {**road.summary(REACH_LEVELS), "text": road.reach_text()}
    return paths


def estimate_area_px_from_summary(summary: dict[str, Any], frame: dict[str, Any]
                                  ) -> float | None:
    """Area (wall pixels) the largest estimate of a run averages over: the kNN/radius
    disk π r_max², or one pixel when binning; None when the summary does not say."""
    try:
        w, h = frame["resolution"]
        px = ((frame["h_range_m"][1] - frame["h_range_m"][0]) / w
              * (frame["v_range_m"][1] - frame["v_range_m"][0]) / h)
        est = summary.get("estimator", {})
        if est.get("name") == "bin":
            return 1.0
        r = est.get("max_radius_m")
        area = math.pi * float(r) ** 2 / px if r is not None else math.inf
        return area if math.isfinite(area) and area > 0 else None
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return None


def noise_floor_from_summary(summary: dict[str, Any], frame: dict[str, Any]) -> float | None:
    """The iso-lux noise floor (lx) of a run from its summary: photons, lamp flux and the
    largest area an estimate averages over (kNN or radius disk, or a pixel for binning)."""
    from lightsim.io.plots import isolux_noise_floor

    try:
        est = summary.get("estimator", {})
        if est.get("name") == "bin":
            w, h = frame["resolution"]
            area = ((frame["h_range_m"][1] - frame["h_range_m"][0]) / w
                    * (frame["v_range_m"][1] - frame["v_range_m"][0]) / h)
        else:
            r = est.get("max_radius_m")
            area = math.pi * float(r) ** 2 if r is not None else math.inf
        return isolux_noise_floor(int(summary["photons"]),
                                  float(summary["scene"]["flux_lm"]), area)
    except (KeyError, TypeError, ValueError):
        return None  # an older or partial summary: draw all levels


@dataclass(frozen=True)
class EscapedLight:
    """Photons that left the lamp with the wall taken away: the far field's raw data.

    Attributes
    ----------
    directions : ndarray, shape (n, 3)
        Unit directions of the escaping photons (world axes).
    power_lm : ndarray, shape (n,)
        Luminous flux of each (lm), normalised by ``photons`` (sums to the escaping flux).
    photons : int
        Photons emitted.
    lamp_lumens : float
        The scene's emitted flux (lm).
    luminaire : str
        Name of the scene file.
    """

    directions: np.ndarray
    power_lm: np.ndarray
    photons: int
    lamp_lumens: float
    luminaire: str


def escaped_light(scene, photons: int = 1_000_000, seed: int = 1,
                  threads: int | None = None) -> EscapedLight:
    """Trace ``photons`` through the luminaire alone (no wall) and keep those escaping to
    infinity, as the far field sees them (binned by :func:`lightsim.luminaires.
    photometric.farfield_from_photons`).
    """
    from lightsim.sampling import digit_permutations, halton_points, photon_keys
    from lightsim.scene import WALL, Scene
    from lightsim.tracer import PhotonTracer

    if photons < 1000:
        raise InputError(f"far field needs at least 1000 photons, got {photons}")
    lamp = Scene([p for p in scene.parts if p.role != WALL], None, scene.source,
                 list(scene.warnings), 1)
    tracer = PhotonTracer(lamp, threads=threads)
    farfield_set = (1 << 21) + 1  # a key space no interleave set uses
    dirs, power = [], []
    batch = 250_000
    for lo in range(0, photons, batch):
        idx = np.arange(lo, min(photons, lo + batch), dtype=np.int64)
        pts = halton_points(idx, digit_permutations(seed, farfield_set, None))
        res = tracer.trace_points(pts, photon_keys(seed, farfield_set, 0, idx),
                                  record_escaped=True)
        dirs.append(res.escaped_dir)
        power.append(res.escaped_power[:, 0] / photons)  # lm per photon
    tracer.caster.close()
    return EscapedLight(np.concatenate(dirs), np.concatenate(power), int(photons),
                        float(scene.total_flux), Path(scene.source).name or "lightsim")

