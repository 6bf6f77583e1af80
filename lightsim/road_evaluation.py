"""Road evaluation of a finished run: visibility reach and glare on straight and curved roads.

``lightsim road RUN_DIR`` (and ``lightsim simulate --road``) places the run's lamp, as
the left and the right headlamp of a vehicle, at its mounting height and aim, and reads
the illuminance of sensors along five approaches (a straight road, left and right curves
of 150 m and 250 m radius; :mod:`lightsim.render.road_course`):

* **visibility**: along the right and the left road edge (sensors 0.25 m high), the
  distance at which the illuminance falls below 5, 3 and 1 lx;
* **glare**: at an oncoming driver's eye (1.1 m, middle of the oncoming lane), the
  illuminance against distance, its maximum and the stretches where it exceeds a limit.

The geometry follows the IIHS Headlight Test and Rating Protocol (Version II, November
2016, as summarised publicly: straightaway and 150 m / 250 m curves, visibility at the
road edges 25 cm high, glare at 110 cm in the middle of the oncoming lane, factory aim, the
5 lx distance). The protocol turns the distances into demerits against an ideal system and
downgrades for glare above thresholds derived from FMVSS No. 108; those thresholds and
weights could not be confirmed from a public source, so no score is computed: the measured
quantities are reported as they are.

Intervals come from the interleave sets: ``simulate --road`` stores every set's wall map
(``wall_sets.npz``, every ``WALL_SETS_STRIDE``-th pixel) so that each sensor's
illuminance has a pointwise Student-t interval over the sets; a reach distance's interval
is where the lower and the upper bound of the illuminance cross the level. A run without
that file gives distances without intervals (and says so).

The aim and mounting sensitivity (pitch ±0.5°, height ±0.1 m) re-projects the same far
field through the moved lamp: no photon is traced.

Parameters
----------
======================  =====  ===========  =================================================
name                    unit   default      meaning
======================  =====  ===========  =================================================
``approaches``          –      all five     straight, left-150, left-250, right-150, right-250
``mount_height``        m      0.65         lamp height above the road
``lamp_spacing``        m      1.2          distance between the two lamps
``lane_width``          m      3.6          width of each lane
``pitch``               deg    0            lamp aim change (+ up) from the run's aim
``mirror_left``         –      off          the left lamp's far field mirrored (h → −h)
``traffic``             –      right        traffic side (the oncoming lane's side)
``glare_limit``         lx     1.0          glare sensor level reported as exceeded (the
                                            user's choice, not a consumer-test threshold)
``max_distance``        m      200          farthest sensor along an approach
``step``                m      0.25         sensor spacing along an approach
``confidence``          1      0.95         two-sided level of the intervals
``sensitivity``         –      on           pitch ±0.5°, height ±0.1 m re-projections
``WALL_SETS_STRIDE``    px     2            pixel stride of the stored per-set maps
======================  =====  ===========  =================================================
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lightsim.analysis import AnalysisReport, FinishedRun
from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path
from lightsim.io.exr import read_exr
from lightsim.io.road_plots import plot_approach
from lightsim.io.summary import read_json, write_json
from lightsim.options import check_fields, option
from lightsim.render.frame import luminous
from lightsim.render.road_course import (
    EDGE_LEVELS_LUX,
    SENSORS,
    Approach,
    LampPair,
    SensorCurve,
    approach_by_name,
    crossing_distance,
    distance_grid,
    exceedance,
    sensor_curves,
)
from lightsim.report import plot_caption
from lightsim.wall import WallFrame

__all__ = ["DEFAULT_APPROACHES", "ROAD_FILE", "SENSITIVITY", "WALL_SETS_FILE", "FarField",
           "RoadAnalysis", "RoadEvaluation", "RoadSettings", "check_field", "evaluate_road",
           "load_far_field",
           "parse_approaches", "reach_lines", "save_wall_sets", "write_road"]

ROAD_FILE = "road.json"
WALL_SETS_FILE = "wall_sets.npz"
WALL_SETS_STRIDE = 2
DEFAULT_APPROACHES = ("straight", "left-150", "left-250", "right-150", "right-250")
SENSITIVITY = (("pitch +0.5°", 0.5, 0.0), ("pitch −0.5°", -0.5, 0.0),
               ("height +0.1 m", 0.0, 0.1), ("height −0.1 m", 0.0, -0.1))
"""The aim and mounting variants: (label, pitch change deg, height change m)."""
SCORE_NOTE = ("No rating score: the IIHS protocol's glare thresholds and demerit weights "
              "could not be confirmed from a public source; the measured distances and "
              "illuminances are reported instead.")


@dataclass(frozen=True)
class RoadSettings:
    """Settings of a road evaluation (see the module's parameter table)."""

    approaches: tuple[str, ...] = option(
        DEFAULT_APPROACHES, "Approaches: straight, left-R, right-R (R the curve radius in m).",
        kind="tuple", internal="lightsim road --approaches, read by parse_approaches")
    mount_height: float = option(0.65, "Lamp height above the road.", unit="m",
                                 flag=("--mount-height",), low=0, low_open=True, high=10)
    lamp_spacing: float = option(1.2, "Distance between the left and right lamps.",
                                 unit="m", flag=("--lamp-spacing",), low=0, high=5)
    lane_width: float = option(3.6, "Width of each lane.", unit="m", flag=("--lane-width",),
                               low=0, low_open=True, high=10)
    pitch: float = option(0.0, "Lamp aim change from the run's aim (+ = up).", unit="deg",
                          flag=("--pitch",), low=-5, high=5)
    traffic: str = option("right", "Traffic side (the oncoming lane is on the other side).",
                          flag=("--traffic",), choices=("right", "left"))
    glare_limit: float = option(
        1.0, "Glare sensor illuminance reported as exceeded (your limit; not a consumer-test "
        "threshold).", unit="lx", flag=("--glare-limit",), low=0, low_open=True)
    max_distance: float = option(200.0, "Farthest sensor along an approach.", unit="m",
                                 flag=("--max-distance",), low=10, high=1000)
    step: float = option(0.25, "Sensor spacing along an approach.", unit="m",
                         flag=("--step",), low=0.01, high=5)
    confidence: float = option(0.95, "Two-sided level of the intervals.",
                               flag=("--confidence",), low=0.5, high=0.999)
    mirror_left: bool = option(
        False, "The left lamp's far field is the run's mirrored left–right (h → −h), for "
        "lamp pairs whose optics are mirror images; by default both lamps have the run's "
        "far field (a low beam's asymmetry is the same on both sides).",
        flag=("--mirror-left",), kind="flag")
    sensitivity: bool = option(True, "Pitch ±0.5° and height ±0.1 m re-projections.",
                               flag=("--sensitivity/--no-sensitivity",), kind="onoff")

    def __post_init__(self) -> None:
        check_fields(self)

    def approach_list(self) -> list[Approach]:
        """The approaches as :class:`Approach` objects (checked: radius > 0)."""
        if not self.approaches:
            raise InputError("road: no approach given")
        return [approach_by_name(a, self.lane_width) for a in self.approaches]

    def lamps(self) -> LampPair:
        """The lamp pair of these settings."""
        return LampPair(self.mount_height, self.lamp_spacing, self.pitch, self.traffic)


@dataclass(frozen=True)
class FarField:
    """A lamp's far field as a finished run gives it.

    Attributes
    ----------
    lux : ndarray, shape (H, W)
        The written wall map (lx).
    frame : WallFrame
        Its wall frame.
    sets : ndarray, shape (S, H', W'), or None
        Every interleave set's wall map (lx) on ``sets_frame`` (None: not stored).
    sets_frame : WallFrame or None
        The frame of ``sets``.
    source : str
        Where it was read (for messages).
    """

    lux: NDArray
    frame: WallFrame
    sets: NDArray | None = None
    sets_frame: WallFrame | None = None
    source: str = ""

    def intensity(self, h_deg: NDArray, v_deg: NDArray) -> NDArray:
        """Intensity (cd) of the written map; NaN outside the wall."""
        return self.frame.sample(self.lux, h_deg, v_deg)

    def set_intensity(self, h_deg: NDArray, v_deg: NDArray) -> NDArray:
        """Every set's intensity (cd), shape (S, …)."""
        return np.stack([self.sets_frame.sample(m, h_deg, v_deg) for m in self.sets])

    @property
    def n_sets(self) -> int:
        """Interleave sets stored (0: none)."""
        return 0 if self.sets is None else int(self.sets.shape[0])


def load_far_field(run_dir: str | Path) -> FarField:
    """Read a finished run's wall map, frame and (if stored) per-set maps.

    Raises
    ------
    InputError
        Not a finished run, a corrupt file, a map that does not match its frame.
    """
    out = Path(run_dir)
    if not out.is_dir():
        raise InputError(f"road: {out} is not a folder (give a run folder written by "
                         "lightsim simulate)")
    summary = read_json(out / "summary.json")
    try:
        frame = WallFrame.from_any(summary["wall"])
    except (KeyError, TypeError):
        raise InputError(f"{out / 'summary.json'}: no wall frame (not a lightsim result?)"
                         ) from None
    if not (out / "wall_lux.exr").is_file():
        raise InputError(f"road: {out} has no wall_lux.exr (run simulate with the exr "
                         "output)")
    channels, _ = read_exr(out / "wall_lux.exr")
    if "Y" not in channels:
        raise InputError(f"{out / 'wall_lux.exr'} has no Y (illuminance) channel")
    lux = frame.check_image(channels["Y"].astype(float), "wall_lux.exr")
    if not np.isfinite(lux).all():
        raise InputError(f"{out / 'wall_lux.exr'}: the map holds NaN or infinite values")
    sets, sets_frame = None, None
    path = out / WALL_SETS_FILE
    if path.is_file():
        try:
            with np.load(path) as data:
                sets = np.asarray(data["lux"], dtype=float)
                sets_frame = WallFrame.from_any(json.loads(str(data["frame"])))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(f"{path}: not a per-set map file ({exc})") from None
        if sets.ndim != 3 or sets.shape[1:] != (sets_frame.height, sets_frame.width):
            raise InputError(f"{path}: maps of shape {sets.shape} do not match their frame")
        if not np.isfinite(sets).all():
            raise InputError(f"{path}: the maps hold NaN or infinite values")
    return FarField(lux, frame, sets, sets_frame, str(out))


def wall_sets_points(frame: WallFrame, stride: int = WALL_SETS_STRIDE
                     ) -> tuple[WallFrame, np.ndarray]:
    """The frame of every ``stride``-th pixel and its pixel centres (wall h, v in m,
    (P, 2), rows from the top): the points :func:`save_wall_sets` reads, known before
    the run so that the sets accumulate them and drop their photons."""
    sub = frame.with_resolution(max(2, -(-frame.width // stride)),
                                max(2, -(-frame.height // stride)))
    h, v = sub.pixel_centres()
    H, V = np.meshgrid(h, v)
    return sub, np.column_stack([H.ravel(), V.ravel()])  # wall coordinates, as probe takes


def save_wall_sets(out: Path, session: Any, stride: int = WALL_SETS_STRIDE) -> Path:
    """Every interleave set's wall map at every ``stride``-th pixel, as ``wall_sets.npz``.

    The sets' estimates at the pixel centres come from :meth:`Session.probe` (per-set
    density estimates at wall points), so that a later ``lightsim road`` has intervals.
    """
    sub, pts = wall_sets_points(session.scene.wall, stride)
    values = luminous(session.probe(pts).values)  # (S, P)
    maps = values.reshape(values.shape[0], sub.height, sub.width).astype(np.float32)
    path = out / WALL_SETS_FILE
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, lux=maps, frame=np.asarray(json.dumps(sub.to_dict())))
    return path


def check_field(frame: WallFrame, settings: RoadSettings) -> None:
    """The road must lie on the screen's field at the wall distance, for every height of
    the study (one :class:`InputError` line otherwise)."""
    _, _, v_low, v_high = frame.extent_deg()
    d = frame.distance_m
    heights = [settings.mount_height]
    if settings.sensitivity:
        heights += [settings.mount_height + dh for _, _, dh in SENSITIVITY]
    for hgt in heights:
        for sensor_h, what in ((0.25, "the road edge"), (1.1, "the glare sensor")):
            v = float(np.degrees(np.arctan2(sensor_h - hgt, d))) - settings.pitch
            if not v_low <= v <= v_high:
                raise InputError(
                    f"road: a lamp mounted {hgt:g} m high sees {what} at the wall distance "
                    f"({d:g} m) at {v:+.2f}°, outside the screen's field ({v_low:+.2f}° to "
                    f"{v_high:+.2f}°): lower --mount-height or simulate a taller wall")


def _reach_row(curve: SensorCurve, level: float) -> dict[str, Any]:
    best = crossing_distance(curve.s_m, curve.lux, level)
    row = {"approach": curve.approach, "sensor": curve.sensor, "level_lux": level,
           "distance_m": best["distance_m"], "beyond_range": best["beyond"]}
    if curve.lux_lo is not None:
        lo = crossing_distance(curve.s_m, curve.lux_lo, level)
        hi = crossing_distance(curve.s_m, curve.lux_hi, level)
        row["interval_m"] = [lo["distance_m"] if lo["distance_m"] is not None else 0.0,
                             hi["distance_m"]]
    return row


def _glare_row(curve: SensorCurve, limit: float) -> dict[str, Any]:
    e = np.nan_to_num(curve.lux, nan=0.0)
    i = int(np.argmax(e)) if e.size else 0
    row = {"approach": curve.approach, "sensor": "glare", "max_lux": float(e[i]),
           "at_m": float(curve.s_m[i]), "limit_lux": limit,
           "exceeds_m": exceedance(curve.s_m, curve.lux, limit)}
    if curve.lux_hi is not None:
        row["max_interval_lux"] = [float(np.nanmax(curve.lux_lo)),
                                   float(np.nanmax(curve.lux_hi))]
        row["exceeds_possibly_m"] = exceedance(curve.s_m, curve.lux_hi, limit)
        row["exceeds_surely_m"] = exceedance(curve.s_m, curve.lux_lo, limit)
    return row


@dataclass
class RoadEvaluation:
    """The result of :func:`evaluate_road`.

    Attributes
    ----------
    reach : list of dict
        Per approach, edge sensor and level: ``distance_m`` (and ``interval_m``).
    glare : list of dict
        Per approach: ``max_lux``, ``at_m``, ``exceeds_m`` stretches.
    curves : dict
        Per approach, the three :class:`SensorCurve` (for plots).
    sensitivity : list of dict
        Per variant (pitch, height), the reach distances and glare maxima.
    settings : RoadSettings
        What was evaluated.
    seconds : float
        Evaluation time (s).
    """

    reach: list[dict[str, Any]]
    glare: list[dict[str, Any]]
    curves: dict[str, list[SensorCurve]]
    sensitivity: list[dict[str, Any]]
    settings: RoadSettings
    n_sets: int = 0
    seconds: float = 0.0
    files: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (the table of ``road.json`` and ``summary.json``)."""
        s = self.settings
        return {"approaches": list(s.approaches), "mount_height_m": s.mount_height,
                "lamp_spacing_m": s.lamp_spacing, "lane_width_m": s.lane_width,
                "pitch_deg": s.pitch, "traffic": s.traffic, "mirror_left": s.mirror_left,
                "edge_sensor_height_m": 0.25, "glare_sensor_height_m": 1.1,
                "levels_lux": list(EDGE_LEVELS_LUX), "max_distance_m": s.max_distance,
                "step_m": s.step, "confidence": s.confidence, "interleave_sets": self.n_sets,
                "intervals": self.n_sets > 1,
                "reach": self.reach, "glare": self.glare, "sensitivity": self.sensitivity,
                "score": None, "score_note": SCORE_NOTE, "seconds": self.seconds,
                "files": self.files}


def _mirrored(fn: Callable) -> Callable:
    """The far field ``fn`` mirrored left–right (h → −h)."""
    return lambda h, v: fn(-np.asarray(h), v)


def _lamp_fns(far: FarField, left: FarField | None, sets: bool, mirror_left: bool = False
              ) -> Callable | dict[str, Callable] | None:
    """The intensity of both lamps: one far field, or the left lamp's own (a second run, or
    the run's mirrored)."""
    if sets and (far.n_sets < 2 or (left is not None and left.n_sets < 2)):
        return None
    right_fn = far.set_intensity if sets else far.intensity
    if left is not None:
        return {"right": right_fn, "left": left.set_intensity if sets else left.intensity}
    if mirror_left:
        return {"right": right_fn, "left": _mirrored(right_fn)}
    return right_fn


def evaluate_road(far: FarField, settings: RoadSettings, left: FarField | None = None
                  ) -> RoadEvaluation:
    """Reach and glare of the lamp pair on every approach (see the module docstring).

    Parameters
    ----------
    far : FarField
        The lamp's far field (both lamps, or the right lamp when ``left`` is given).
    settings : RoadSettings
        Approaches, mounting, sensors.
    left : FarField, optional
        The left lamp's own far field (a second run).

    Raises
    ------
    InputError
        A curve radius ≤ 0, a mounting height that puts the road off the screen's field.
    """
    t0 = time.perf_counter()
    approaches = settings.approach_list()
    for ff in (far,) if left is None else (far, left):
        check_field(ff.frame, settings)
    lamps = settings.lamps()
    s = distance_grid((settings.step, settings.max_distance), settings.step)
    pooled = _lamp_fns(far, left, False, settings.mirror_left)
    per_set = _lamp_fns(far, left, True, settings.mirror_left)
    reach, glare, curves = [], [], {}
    for ap in approaches:
        cs = sensor_curves(pooled, ap, lamps, s, per_set, settings.confidence)
        curves[ap.name] = cs
        for c in cs:
            if c.sensor == "glare":
                glare.append(_glare_row(c, settings.glare_limit))
            else:
                reach.extend(_reach_row(c, lv) for lv in EDGE_LEVELS_LUX)
    sens = []
    if settings.sensitivity:
        for label, dp, dh in SENSITIVITY:
            moved = lamps.moved(dp, dh)
            rows = []
            for ap in approaches:
                for c in sensor_curves(pooled, ap, moved, s):
                    if c.sensor == "glare":
                        g = _glare_row(c, settings.glare_limit)
                        rows.append({"approach": ap.name, "sensor": "glare",
                                     "max_lux": g["max_lux"], "at_m": g["at_m"]})
                    else:
                        rows.extend({k: r[k] for k in ("approach", "sensor", "level_lux",
                                                       "distance_m")}
                                    for r in (_reach_row(c, lv) for lv in EDGE_LEVELS_LUX))
            sens.append({"variant": label, "pitch_deg": moved.pitch_deg,
                         "mount_height_m": moved.mount_height_m, "photons_traced": 0,
                         "rows": rows})
    n_sets = far.n_sets if per_set is not None else 0
    return RoadEvaluation(reach, glare, curves, sens, settings, n_sets,
                          time.perf_counter() - t0)


def write_road(out: Path, ev: RoadEvaluation, plots: bool = True) -> list[Path]:
    """``road.json`` and one plot per approach (``road_<approach>.png``) into ``out``,
    each written atomically."""
    written: list[Path] = []
    if plots:
        caption = run_caption(out)
        for name, curves in ev.curves.items():
            path = out / f"road_{name}.png"
            plot_approach(path, curves, ev.settings.lamps(), ev.settings.lane_width,
                          ev.settings.glare_limit, ev.settings.confidence, caption)
            written.append(path)
    ev.files = [p.name for p in written] + [ROAD_FILE]
    write_json(out / ROAD_FILE, ev.to_dict())
    written.append(out / ROAD_FILE)
    return written


def run_caption(run_dir: Path) -> str | None:
    """The caption of the run in ``run_dir`` (:func:`lightsim.report.plot_caption` of its
    ``summary.json``), None when it has no readable one."""
    try:
        summary = read_json(run_dir / "summary.json")
        cap = plot_caption(summary) if isinstance(summary, dict) else None
    except (InputError, OSError, ValueError, TypeError, AttributeError):
        return None
    return None if cap is None else cap.text()


def reach_lines(table: dict[str, Any]) -> list[str]:
    """Short text lines of a road table (:meth:`RoadEvaluation.to_dict`): per approach, the
    5/3/1 lx reach of both edges (with intervals) and the glare maximum."""
    lines = []
    by = {(r["approach"], r["sensor"], r["level_lux"]): r for r in table["reach"]}
    for name in table["approaches"]:
        parts = []
        for sensor in SENSORS[:2]:
            txt = []
            for lv in EDGE_LEVELS_LUX:
                r = by[(name, sensor, lv)]
                d = r["distance_m"]
                val = "–" if d is None else (f"≥{d:.0f}" if r["beyond_range"] else f"{d:.0f}")
                iv = r.get("interval_m")
                if d is not None and iv and iv[1] is not None:
                    val += f" [{iv[0]:.0f}, {iv[1]:.0f}]"
                txt.append(f"{lv:g} lx {val} m")
            parts.append(f"{sensor.replace('_', ' ')}: " + ", ".join(txt))
        g = next(x for x in table["glare"] if x["approach"] == name)
        parts.append(f"glare max {g['max_lux']:.2f} lx at {g['at_m']:.0f} m")
        lines.append(f"{name:<10} " + "; ".join(parts))
    return lines


@dataclass
class RoadAnalysis:
    """``simulate --road``: store the per-set maps, evaluate the road, write the plots
    (an :class:`~lightsim.analysis.Analysis`; its table goes to ``summary.json``)."""

    settings: RoadSettings = field(default_factory=RoadSettings)
    name: str = "road_evaluation"
    #: the per-set maps (``wall_sets.npz``) are kNN estimates at every few pixels, at
    #: points known before the run (:meth:`probe_points`): no photon need be kept
    reads_photons = None

    def probe_points(self, scene: Any) -> np.ndarray:
        """Wall points (h, v in m) read after the run: :func:`wall_sets_points`."""
        return wall_sets_points(WallFrame.from_any(scene.wall))[1]

    def prepare(self, config: Any, scene: Any) -> Any:
        """Check the road lies on the wall before any photon (the maps are read after the
        run); the configuration is unchanged."""
        self.settings.approach_list()
        check_field(WallFrame.from_any(scene.wall), self.settings)
        return config

    def report(self, run: FinishedRun, out: Path) -> AnalysisReport:
        """Per-set maps, the evaluation, ``road.json`` and the approach plots in ``out``."""
        files = []
        sets = sets_frame = None
        if run.session.config.n_sets > 1:
            files.append(save_wall_sets(out, run.session))
            with np.load(files[0]) as data:
                sets = np.asarray(data["lux"], dtype=float)
                sets_frame = WallFrame.from_any(json.loads(str(data["frame"])))
        far = FarField(np.asarray(run.lux, dtype=float), run.frame, sets, sets_frame)
        ev = evaluate_road(far, self.settings)
        files += write_road(out, ev)
        return AnalysisReport(ev.to_dict(), files=files)


def parse_approaches(text: str | Sequence[str]) -> tuple[str, ...]:
    """``straight,left-150`` → ("straight", "left-150"), each checked."""
    items = text.split(",") if isinstance(text, str) else list(text)
    names = tuple(i.strip().lower() for i in items if i.strip())
    if not names:
        raise InputError("--approaches: give at least one of straight, left-R, right-R")
    for n in names:
        approach_by_name(n)
    return names
