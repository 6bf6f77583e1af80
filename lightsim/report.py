"""Lighting-engineering reports: regulation test points with intervals, aim, isolux and
road views, far-field intensity files.

The last stage of the data flow (scene → photons → photon maps → images → **reports**).
:func:`regulation_check` asks every interleave set for its estimate at the rule set's
test points and zone samples, so each value comes with a confidence interval from the
independent sets; the per-set values are saved in ``probes.npz`` so that
``lightsim report`` can re-evaluate (or evaluate another rule set's limits) without
shooting again.

======================  =====  =========  ===============================================
parameter               unit   default    meaning
======================  =====  =========  ===============================================
``ruleset``             –      –          rule-set id or file (``lightsim.luminaires.
                                          regulations``), e.g. ``r112-b-passing``
``traffic``             –      right      right- or left-hand traffic (mirrors H)
``aim``                 –      off        shift the pattern so the cut-off inflection sits
                                          at 0.57° D (R112 annex 9) before testing
``confidence``          –      0.95       two-sided level of the intervals
``mount_height``        m      0.65       lamp height above the road (road view)
``farfield_photons``    –      10⁶        photons traced without the wall for IES/LDT
``farfield_step``       deg    1          Type C grid step in C and γ
``aperture``            deg    0.15       side of the square detector aperture of every
                                          test point (0: kNN density estimate instead)
``aim_reach``           deg    1.5        how far the apertures can follow ``--aim``
``aim_substeps``        –      5          aim resolution: aperture / 5 = 0.03°
``imax_raster``         deg    see below  H −20…20°, V −6…4° (within the wall) tiled with
                                          apertures for Imax
======================  =====  =========  ===============================================

Test points as a goniophotometer measures them (default). Every interleave set counts the
wall photons inside a square aperture of side ``aperture`` around each test point and zone
sample (``lightsim.engine.apertures``): I = flux / solid angle, unbiased per set, so the
Student-t interval over the sets is an interval for the aperture's mean intensity. The
default 0.15° is the angular size of a 65 mm square receiver at 25 m — the receiver size
we recall from the ECE headlamp regulations' measuring conditions (not confirmed against
the regulation text here: check it, or pass ``--aperture``). A smaller aperture resolves a
cut-off more finely but catches fewer photons (wider intervals).
"""


from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path
from lightsim.render.frame import luminous

PROBES_FILE = "probes.npz"

DEFAULT_APERTURE_DEG = 0.15
"""Side of the square detector aperture (deg): 65 mm at 25 m."""
AIM_REACH_DEG = 1.5
AIM_SUBSTEPS = 5
IMAX_RASTER_DEG = (-20.0, 20.0, -6.0, 4.0)
MEASURE_NAMES = {"HV": "HV", "Imax": "Imax"}
"""Names of the reported rows (suffixed when a rule set has rules of that name)."""
SPARSE_PHOTONS_PER_SET = 1.0
"""Below this many counted photons per set an aperture's interval is the photon-count
(Garwood) one instead of Student-t over the sets."""


def _frame_dict(frame: Any) -> dict[str, Any]:
    return frame.to_dict() if hasattr(frame, "to_dict") else dict(frame)


def regulation_probes(ruleset: str, traffic: str, frame: Any, lux: np.ndarray, aim: bool
                      ) -> tuple[Any, Any, dict[str, Any], np.ndarray]:
    """Probe directions for ``ruleset`` and their wall positions in the *unaimed* pattern.

    Returns
    -------
    rs, probes, aim_info, hv : RuleSet, Probes, dict, (P, 2) wall metres
    """
    from lightsim.luminaires.regulations import load_ruleset, probe_points
    from lightsim.render.cutoff import find_cutoff

    rs = load_ruleset(ruleset)
    fd = _frame_dict(frame)
    cut = find_cutoff(lux, fd, traffic)
    dv = 0.0
    if aim:
        if not cut.found:
            raise InputError(f"--aim: {cut.message}")
        dv = float(cut.aim_dv_deg)
    probes = probe_points(rs, traffic, frame=fd)
    d = float(fd["distance_m"])
    # aiming moves the pattern up by dv: the aimed value at v is the unaimed one at v − dv
    hv = np.stack([d * np.tan(np.radians(probes.h_deg)),
                   d * np.tan(np.radians(probes.v_deg - dv))], axis=1)
    aim_info = {"applied": bool(aim), "dh_deg": 0.0, "dv_deg": dv, "cutoff": cut.to_dict()}
    return rs, probes, aim_info, hv


def evaluate_probe_values(rs: Any, probes: Any, hv: np.ndarray, values_lux: np.ndarray,
                          distance_m: float, traffic: str, confidence: float = 0.95,
                          intervals_cd: np.ndarray | None = None
                          ) -> tuple[list[dict[str, Any]], list[dict[str, str]], np.ndarray]:
    """Per-set lux at the probes (S, P) → candela → verdicts with intervals."""
    from lightsim.luminaires.regulations import evaluate, unevaluated_rules
    from lightsim.luminaires.regulations.units import candela_from_lux

    cd = candela_from_lux(values_lux, hv[:, 0][None, :], hv[:, 1][None, :], distance_m)
    results = evaluate(rs, probes, cd, traffic=traffic, confidence=confidence,
                       intervals_cd=intervals_cd)
    return results, unevaluated_rules(rs, probes), cd


def aperture_config(config: Any, ruleset: str, traffic: str, frame: Any,
                    aperture_deg: float | None = DEFAULT_APERTURE_DEG, aim: bool = False,
                    spt: bool = False) -> Any:
    """``config`` with the detector apertures of ``ruleset``'s probes (before the run).

    Apertures: every probe of :func:`~lightsim.luminaires.regulations.probe_points`, then
    H-V; the Imax raster; with ``aim`` strips reaching ±``AIM_REACH_DEG``; with ``spt``
    the rule set's *points* are the Selective Photon Tracing targets.
    """
    if aperture_deg is None or aperture_deg == 0:
        return config
    if not (math.isfinite(aperture_deg) and 0 < aperture_deg <= 2):
        raise InputError(f"--aperture must be between 0 and 2 degrees (0 = kNN), "
                         f"got {aperture_deg}")
    from lightsim.luminaires.regulations import load_ruleset, probe_points

    rs = load_ruleset(ruleset)
    fd = _frame_dict(frame)
    probes = probe_points(rs, traffic, frame=fd)
    h = np.append(probes.h_deg, 0.0)
    v = np.append(probes.v_deg, 0.0)
    kinds = {g.name: g.kind for g in rs.geometries}
    targets = tuple(i for i, lab in enumerate(probes.labels) if kinds.get(lab) == "point")
    wf_h = np.degrees(np.arctan2(np.asarray(fd["h_range_m"], float), fd["distance_m"]))
    wf_v = np.degrees(np.arctan2(np.asarray(fd["v_range_m"], float), fd["distance_m"]))
    r = IMAX_RASTER_DEG
    raster = (max(r[0], wf_h[0]), min(r[1], wf_h[1]), max(r[2], wf_v[0]), min(r[3], wf_v[1]))
    if raster[1] - raster[0] < aperture_deg or raster[3] - raster[2] < aperture_deg:
        raster = None
    return config.with_(apertures=tuple(zip(h.tolist(), v.tolist(), strict=True)),
                        aperture_deg=float(aperture_deg),
                        aperture_shift_deg=AIM_REACH_DEG if aim else 0.0,
                        aperture_substeps=AIM_SUBSTEPS if aim else 1,
                        aperture_targets=targets if spt else (),
                        aperture_raster=raster)


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


def _stat_row(name: str, h: float, v: float, samples: np.ndarray, confidence: float,
              note: str, interval: np.ndarray | None = None) -> dict[str, Any]:
    """A reported (not limited) row: mean and Student-t interval of per-set values
    (or ``interval`` where it is finite)."""
    from scipy.special import stdtrit

    S = len(samples)
    mean = float(np.mean(samples))
    half = (float(stdtrit(S - 1, 0.5 + confidence / 2) * np.std(samples, ddof=1) / math.sqrt(S))
            if S > 1 else 0.0)
    lo, hi = mean - half, mean + half
    if interval is not None and np.all(np.isfinite(interval)):
        lo, hi = float(interval[0]), float(interval[1])
    return {"name": name, "kind": "measure", "h_deg": float(h), "v_deg": float(v),
            "value_cd": mean, "interval_cd": [lo, hi], "limit": {},
            "verdict": "info", "certainty": "sure", "note": note, "source": "lightsim",
            "error_estimate": S > 1, "confidence": float(confidence)}


def measure_rows(ap: dict[str, Any], dv_deg: float, confidence: float) -> list[dict[str, Any]]:
    """HV and Imax rows (value, direction, interval) from :func:`aperture_values`.

    Imax is the raster tile with the largest mean over the sets; its interval is that
    tile's (the maximum of noisy tiles is biased upwards by about the tiles' noise).
    """
    rows = [_stat_row(MEASURE_NAMES["HV"], 0.0, 0.0, ap["cd"][:, -1], confidence,
                      "intensity towards H-V (aperture count)", ap["intervals_cd"][-1])]
    tiles = ap["tiles"]
    if tiles.size:
        mean = tiles.mean(axis=0)
        i, k = np.unravel_index(int(np.argmax(mean)), mean.shape)
        rows.append(_stat_row(MEASURE_NAMES["Imax"], ap["tile_h_deg"][i],
                              ap["tile_v_deg"][k] + dv_deg, tiles[:, i, k], confidence,
                              "largest aperture-tile mean over the raster"))
    return rows


def regulation_check(session, lux: np.ndarray, ruleset: str, traffic: str = "right",
                     aim: bool = False, confidence: float = 0.95) -> dict[str, Any]:
    """Evaluate a rule set on a finished session.

    With the run's detector apertures (:func:`aperture_config`) the test points are the
    per-set aperture counts; without, every set's kNN estimate at the probes.
    """
    frame = session.scene.wall
    rs, probes, aim_info, hv = regulation_probes(ruleset, traffic, frame, lux, aim)
    cfg = session.config
    extra: list[dict[str, Any]] = []
    if cfg.apertures and len(cfg.apertures) == len(probes) + 1:
        ap = aperture_values(session, -aim_info["dv_deg"], confidence)
        intervals = ap["intervals_cd"][:-1]
        # the aimed value at v is the unaimed one at v − dv: apertures shift by −dv,
        # rounded to a strip bin (aperture / AIM_SUBSTEPS)
        if aim:
            aim_info["aperture_dv_deg"] = -ap["shift_deg"]
        cd = ap["cd"][:, :-1]
        count_stats = ap["count_stats"][:, :-1]
        values = lux_equivalent(cd, hv, frame.distance_m)
        taken = {g.name for g in rs.geometries}
        extra = [r if r["name"] not in taken else {**r, "name": f"{r['name']} (measured)"}
                 for r in measure_rows(ap, -ap["shift_deg"], confidence)]
        method = {"name": "aperture", **ap["layout"].to_dict(),
                  "spt_targets": len(cfg.aperture_targets)}
    else:
        intervals = count_stats = None
        stats = session.probe(hv) if len(hv) else None
        values = (luminous(stats.values) if stats is not None
                  else np.zeros((session.config.n_sets, 0)))
        method = {"name": "knn"}
    results, unevaluated, cd = evaluate_probe_values(rs, probes, hv, values, frame.distance_m,
                                                     traffic, confidence, intervals)
    return {"ruleset": rs.id, "title": rs.title, "version": rs.version, "traffic": traffic,
            "confidence": confidence, "aim": aim_info, "method": method,
            "results": results + extra, "unevaluated": unevaluated, "_probes": probes,
            "_hv": hv, "_values_lux": values, "_cd": cd, "_count_stats": count_stats}


def lux_equivalent(cd: np.ndarray, hv: np.ndarray, distance_m: float) -> np.ndarray:
    """Candela at the probes → the wall lux a point source there gives (I·D/r³), so that
    probes.npz keeps one unit whichever way the values were measured."""
    from lightsim.luminaires.regulations.units import lux_from_candela

    return lux_from_candela(cd, hv[:, 0][None, :], hv[:, 1][None, :], distance_m)


def public(reg: dict[str, Any]) -> dict[str, Any]:
    """The JSON part of a regulation check (drops the arrays)."""
    return {k: v for k, v in reg.items() if not k.startswith("_")}


def save_probes(out: Path, reg: dict[str, Any]) -> Path:
    """Write the per-set probe values of a regulation check to ``probes.npz``."""
    probes = reg["_probes"]
    path = Path(out) / PROBES_FILE
    with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
        np.savez(fh, h_deg=probes.h_deg, v_deg=probes.v_deg,
                 labels=np.asarray(probes.labels, dtype=str), hv_m=reg["_hv"],
                 values_lux=reg["_values_lux"], ruleset=np.asarray(reg["ruleset"]),
                 count_stats=(np.full((4, len(probes)), np.nan)
                              if reg.get("_count_stats") is None else reg["_count_stats"]),
                 traffic=np.asarray(reg["traffic"]), aim_dv_deg=reg["aim"]["dv_deg"])
    return path


def recheck_from_probes(out: Path, summary: dict[str, Any], lux: np.ndarray,
                        ruleset: str | None = None, confidence: float = 0.95
                        ) -> dict[str, Any]:
    """Re-evaluate a finished run's regulation from ``probes.npz`` (no shooting)."""
    path = Path(out) / PROBES_FILE
    if not path.exists():
        raise InputError(f"{out}: no {PROBES_FILE}: run simulate with --regulation first")
    try:
        data = np.load(path, allow_pickle=False)
        old = str(data["ruleset"])
        traffic = str(data["traffic"])
        dv = float(data["aim_dv_deg"])
        values, hv = data["values_lux"], data["hv_m"]
        count = data["count_stats"] if "count_stats" in data else None
    except (KeyError, ValueError, OSError) as exc:
        raise InputError(f"{path}: corrupt probe file ({exc})") from None
    from lightsim.luminaires.regulations import load_ruleset, probe_points

    rs = load_ruleset(ruleset or old)
    probes = probe_points(rs, traffic, frame=summary["wall"])
    if ruleset and rs.id != old:
        raise InputError(f"{PROBES_FILE} holds the probes of '{old}', not '{rs.id}': run "
                         f"simulate --regulation {rs.id}")
    if len(probes) != values.shape[1]:
        raise InputError(f"{PROBES_FILE} does not match rule set '{rs.id}' (changed file?)")
    intervals = (None if count is None or not np.isfinite(count).all()
                 else sparse_intervals(count, values.shape[0], confidence))
    results, unevaluated, _ = evaluate_probe_values(
        rs, probes, hv, values, float(summary["wall"]["distance_m"]), traffic, confidence,
        intervals)
    prev = summary.get("regulation", {})
    measures = [r for r in prev.get("results", []) if r.get("kind") == "measure"]
    return {"ruleset": rs.id, "title": rs.title, "version": rs.version, "traffic": traffic,
            "confidence": confidence,
            "aim": prev.get("aim", {"applied": dv != 0.0, "dh_deg": 0.0, "dv_deg": dv}),
            "method": prev.get("method", {"name": "knn"}),
            "results": results + measures, "unevaluated": unevaluated}


def engineering_plots(out: Path, lux: np.ndarray, frame: Any,
                      results: list[dict[str, Any]] | None = None,
                      mount_height_m: float = 0.65,
                      summary: dict[str, Any] | None = None) -> list[Path]:
    """Write ``isolux.png`` (screen, H/V degrees) and ``road.png`` (bird's-eye view).

    With the run's ``summary`` the iso-lux levels start at the map's noise floor, and
    ``summary["isolux"]`` (floor, levels) and ``summary["road"]`` (reach per level) are
    filled in.
    """
    from lightsim.io.plots import isolux_plot, road_view_plot

    fd = _frame_dict(frame)
    floor = noise_floor_from_summary(summary, fd) if summary is not None else None
    area_px = estimate_area_px_from_summary(summary, fd) if summary is not None else None
    paths = [isolux_plot(Path(out) / "isolux.png", lux, fd, results=results,
                         title="iso-lux on the screen", noise_floor_lx=floor,
                         estimate_area_px=area_px)]
    road = road_view_plot(Path(out) / "road.png", lux, fd, mount_height_m=mount_height_m)
    paths.append(Path(out) / "road.png")
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


def farfield_grid(scene, photons: int = 1_000_000, seed: int = 1, step_deg: float = 1.0,
                  threads: int | None = None, photometric_type: str = "C"):
    """Far-field intensity (Type C grid, or Type A with ``photometric_type="A"``; cd) from
    photons leaving the lamp (no wall).

    Photons are traced through the luminaire alone; those escaping to infinity are
    binned by direction (I = ΔΦ/ΔΩ).
    """
    return farfield_grids(scene, photons, seed, step_deg, threads,
                          (photometric_type,))[photometric_type]


def farfield_grids(scene, photons: int = 1_000_000, seed: int = 1, step_deg: float = 1.0,
                   threads: int | None = None, photometric_types: tuple[str, ...] = ("C",)):
    """:func:`farfield_grid` for several photometric types from one set of traced photons."""
    from lightsim.luminaires.photometric import farfield_from_photons
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
    d, pw = np.concatenate(dirs), np.concatenate(power)
    meta = {"luminaire": Path(scene.source).name or "lightsim",
            "test": f"lightsim far field, {photons} photons"}
    return {t: farfield_from_photons(d, pw, photons, dc_deg=step_deg, dgamma_deg=step_deg,
                                     lamp_lumens=scene.total_flux, metadata=meta,
                                     photometric_type=t)
            for t in photometric_types}


def format_regulation(reg: dict[str, Any]):
    """A rich table of the verdicts (for the terminal)."""
    from lightsim.luminaires.regulations import format_table

    aim = reg.get("aim", {})
    note = f", aimed {aim['dv_deg']:+.2f}° V" if aim.get("applied") else ""
    ci = aim.get("cutoff_interval_deg")
    if aim.get("applied") and ci:
        note += f" (cut-off found at {0.5 * (ci[0] + ci[1]):+.3f}° ± {0.5 * (ci[1] - ci[0]):.3f}°)"
    return format_table(reg["results"], title=f"{reg['ruleset']} ({reg['traffic']}-hand "
                        f"traffic{note}; {int(reg['confidence'] * 100)}% intervals)",
                        unevaluated=reg.get("unevaluated"))
