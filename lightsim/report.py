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
======================  =====  =========  ===============================================
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
                          distance_m: float, traffic: str, confidence: float = 0.95
                          ) -> tuple[list[dict[str, Any]], list[dict[str, str]], np.ndarray]:
    """Per-set lux at the probes (S, P) → candela → verdicts with intervals."""
    from lightsim.luminaires.regulations import evaluate, unevaluated_rules
    from lightsim.luminaires.regulations.units import candela_from_lux

    cd = candela_from_lux(values_lux, hv[:, 0][None, :], hv[:, 1][None, :], distance_m)
    results = evaluate(rs, probes, cd, traffic=traffic, confidence=confidence)
    return results, unevaluated_rules(rs, probes), cd


def regulation_check(session, lux: np.ndarray, ruleset: str, traffic: str = "right",
                     aim: bool = False, confidence: float = 0.95) -> dict[str, Any]:
    """Evaluate a rule set on a finished session (every set estimates every probe)."""
    frame = session.scene.wall
    rs, probes, aim_info, hv = regulation_probes(ruleset, traffic, frame, lux, aim)
    stats = session.probe(hv) if len(hv) else None
    values = (luminous(stats.values) if stats is not None
              else np.zeros((session.config.n_sets, 0)))
    results, unevaluated, cd = evaluate_probe_values(rs, probes, hv, values, frame.distance_m,
                                                     traffic, confidence)
    return {"ruleset": rs.id, "title": rs.title, "version": rs.version, "traffic": traffic,
            "confidence": confidence, "aim": aim_info, "results": results,
            "unevaluated": unevaluated, "_probes": probes, "_hv": hv, "_values_lux": values,
            "_cd": cd}


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
    results, unevaluated, _ = evaluate_probe_values(
        rs, probes, hv, values, float(summary["wall"]["distance_m"]), traffic, confidence)
    prev = summary.get("regulation", {})
    return {"ruleset": rs.id, "title": rs.title, "version": rs.version, "traffic": traffic,
            "confidence": confidence,
            "aim": prev.get("aim", {"applied": dv != 0.0, "dh_deg": 0.0, "dv_deg": dv}),
            "results": results, "unevaluated": unevaluated}


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
    paths = [isolux_plot(Path(out) / "isolux.png", lux, fd, results=results,
                         title="iso-lux on the screen", noise_floor_lx=floor)]
    road = road_view_plot(Path(out) / "road.png", lux, fd, mount_height_m=mount_height_m)
    paths.append(Path(out) / "road.png")
    if summary is not None:
        from lightsim.render.road import REACH_LEVELS

        summary["isolux"] = {"noise_floor_lx": floor,
                             "noise_floor_rule": "levels where an estimate holds < 16 "
                                                 "photons (relative noise > 25 %) are "
                                                 "not drawn"}
        summary["road"] = {**road.summary(REACH_LEVELS), "text": road.reach_text()}
    return paths


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
                  threads: int | None = None):
    """Far-field intensity (Type C grid, cd) from photons leaving the lamp (no wall).

    Photons are traced through the luminaire alone; those escaping to infinity are
    binned by direction (I = ΔΦ/ΔΩ).
    """
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
    return farfield_from_photons(np.concatenate(dirs), np.concatenate(power), photons,
                                 dc_deg=step_deg, dgamma_deg=step_deg,
                                 lamp_lumens=scene.total_flux,
                                 metadata={"luminaire": Path(scene.source).name or "lightsim",
                                           "test": f"lightsim far field, {photons} photons"})


def format_regulation(reg: dict[str, Any]):
    """A rich table of the verdicts (for the terminal)."""
    from lightsim.luminaires.regulations import format_table

    aim = reg.get("aim", {})
    note = f", aimed {aim['dv_deg']:+.2f}° V" if aim.get("applied") else ""
    return format_table(reg["results"], title=f"{reg['ruleset']} ({reg['traffic']}-hand "
                        f"traffic{note}; {int(reg['confidence'] * 100)}% intervals)",
                        unevaluated=reg.get("unevaluated"))


def finite(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)
