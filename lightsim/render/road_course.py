"""Sensors along a test road: illuminance at the road edges and at an oncoming driver's eye.

A vehicle stands at the start of an *approach* in the middle of its lane, heading along the
road. The road is straight or bends left or right with a constant radius (curves of 150 m
and 250 m are the usual choice of consumer headlamp tests). Illuminance sensors stand along
the road at every distance ``s`` (arc length along the vehicle's lane centre):

* **edge sensors** at 0.25 m above the road on the right and on the left road edge (the
  left edge is the far edge of the oncoming lane);
* a **glare sensor** at 1.1 m (an oncoming driver's eye) in the middle of the oncoming
  lane.

Every sensor is a vertical plane facing back along the road towards the vehicle (its
normal is minus the road's tangent at the sensor), so a lamp of intensity I in the
direction of the sensor gives ``E = I·cosθ/r²``, with r the lamp–sensor distance and θ the
angle between the incoming light and the sensor normal. Each lamp (left and right, at
their mounting positions) is a far-field source: its intensity towards a sensor is read in
the lamp's own angles, ``h = atan(x/z)``, ``v = atan(y/z)`` (wall degrees, see
``docs/reference/conventions.md``), after turning the direction by the lamp's pitch (a
positive pitch aims the beam up). The sensitivity to aim and mounting height is therefore
a re-projection of the same far field: no photons are traced.

Coordinates (metres): x to the driver's right, y up from the road, z ahead; right-hand
traffic (the oncoming lane on the left). Left-hand traffic mirrors x.

Parameters
----------
=====================  =====  =======  ====================================================
name                   unit   default  meaning
=====================  =====  =======  ====================================================
``kind``               –      –        "straight", "left" or "right" (the bend's direction)
``radius_m``           m      –        curve radius (> 0; None for straight)
``lane_width_m``       m      3.6      width of each of the two lanes
``mount_height_m``     m      0.65     lamp height above the road
``lamp_spacing_m``     m      1.2      distance between the left and right lamps' centres
``pitch_deg``          deg    0        extra lamp pitch (+ = up) for the aim study
``edge_height_m``      m      0.25     height of the edge (visibility) sensors
``glare_height_m``     m      1.1      height of the glare sensor (oncoming driver's eye)
``s_range_m``          m      5–200    distances along the approach that are sampled
``step_m``             m      0.25     sampling step along the approach
``levels_lux``         lx     5, 3, 1  illuminance levels whose reach is reported
=====================  =====  =======  ====================================================
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import stdtrit

from lightsim.errors import InputError

__all__ = ["APPROACH_KINDS", "EDGE_LEVELS_LUX", "SENSORS", "Approach", "LampPair",
           "SensorCurve", "approach_by_name", "crossing_distance", "default_approaches",
           "distance_grid", "exceedance", "sensor_curves", "sensor_points"]

APPROACH_KINDS = ("straight", "left", "right")
EDGE_LEVELS_LUX = (5.0, 3.0, 1.0)
"""Levels (lx) whose reach along each road edge is reported."""
SENSORS = ("right_edge", "left_edge", "glare")

IntensityFn = Callable[[NDArray, NDArray], NDArray]
"""``I(h_deg, v_deg)`` → cd, shape (S, …) for S interleave sets or (…) for one map."""


@dataclass(frozen=True)
class Approach:
    """A road to drive along: straight, or a constant-radius bend to the left or right.

    Attributes
    ----------
    kind : {"straight", "left", "right"}
        Which way the road bends (as seen by the driver).
    radius_m : float or None
        Bend radius of the vehicle's lane centre (m); None for a straight road.
    lane_width_m : float
        Width of each lane (m).
    """

    kind: str
    radius_m: float | None = None
    lane_width_m: float = 3.6

    def __post_init__(self) -> None:
        if self.kind not in APPROACH_KINDS:
            raise InputError(f"road: approach must be one of {', '.join(APPROACH_KINDS)}, "
                             f"got {self.kind!r}")
        if self.kind != "straight":
            r = self.radius_m
            if r is None or not np.isfinite(r) or not r > 0:
                raise InputError(f"road: curve radius must be > 0 m, got {r!r}")
        if not (np.isfinite(self.lane_width_m) and self.lane_width_m > 0):
            raise InputError(f"road: lane width must be > 0 m, got {self.lane_width_m!r}")

    @property
    def name(self) -> str:
        """``straight``, ``left-150`` or ``right-250``: the key in tables and files."""
        return "straight" if self.kind == "straight" else f"{self.kind}-{self.radius_m:g}"

    def centre(self, s_m: ArrayLike) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """Lane centre point (x, z) and unit tangent (tx, tz) at arc length ``s_m``."""
        s = np.asarray(s_m, dtype=float)
        if self.kind == "straight":
            return np.zeros_like(s), s.copy(), np.zeros_like(s), np.ones_like(s)
        r = float(self.radius_m)
        phi = s / r
        sign = 1.0 if self.kind == "right" else -1.0
        return (sign * r * (1.0 - np.cos(phi)), r * np.sin(phi), sign * np.sin(phi),
                np.cos(phi))

    def point(self, s_m: ArrayLike, offset_m: float) -> tuple[NDArray, NDArray, NDArray,
                                                               NDArray]:
        """Road point ``offset_m`` to the right of the lane centre at ``s_m`` (x, z) and the
        road's tangent there (tx, tz)."""
        x, z, tx, tz = self.centre(s_m)
        # the right-hand normal of the heading (tx, tz) is (tz, −tx)
        return x + offset_m * tz, z - offset_m * tx, tx, tz


def approach_by_name(name: str, lane_width_m: float = 3.6) -> Approach:
    """``straight``, ``left-150``, ``right-250`` … → :class:`Approach`."""
    text = str(name).strip().lower()
    if text == "straight":
        return Approach("straight", None, lane_width_m)
    kind, _, radius = text.partition("-")
    try:
        r = float(radius)
    except ValueError:
        raise InputError(f"road: approach '{name}' is not straight, left-R or right-R "
                         "(R the curve radius in m)") from None
    return Approach(kind, r, lane_width_m)


def default_approaches(lane_width_m: float = 3.6) -> list[Approach]:
    """The straight road and left and right curves of 150 m and 250 m radius."""
    return [Approach("straight", None, lane_width_m)] + [
        Approach(k, r, lane_width_m) for k in ("left", "right") for r in (150.0, 250.0)]


@dataclass(frozen=True)
class LampPair:
    """Where the two lamps sit and how they are aimed.

    Attributes
    ----------
    mount_height_m : float
        Height of the lamps' centres above the road (m).
    spacing_m : float
        Distance between the left and right lamps (m), centred on the lane.
    pitch_deg : float
        Aim change (deg, + = up) applied to both lamps (0 = as the far field was computed).
    traffic : {"right", "left"}
        Traffic side; "left" puts the oncoming lane on the right (mirrors x).
    """

    mount_height_m: float = 0.65
    spacing_m: float = 1.2
    pitch_deg: float = 0.0
    traffic: str = "right"

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mount_height_m) and self.mount_height_m > 0):
            raise InputError(f"road: mounting height must be > 0 m, got "
                             f"{self.mount_height_m!r}")
        if not (np.isfinite(self.spacing_m) and self.spacing_m >= 0):
            raise InputError(f"road: lamp spacing must be ≥ 0 m, got {self.spacing_m!r}")
        if not (np.isfinite(self.pitch_deg) and abs(self.pitch_deg) <= 10):
            raise InputError(f"road: pitch must lie in [−10°, 10°], got {self.pitch_deg!r}")
        if self.traffic not in ("right", "left"):
            raise InputError(f"road: traffic must be right or left, got {self.traffic!r}")

    def moved(self, pitch_deg: float = 0.0, height_m: float = 0.0) -> LampPair:
        """The same pair pitched by ``pitch_deg`` more and mounted ``height_m`` higher."""
        return replace(self, pitch_deg=self.pitch_deg + pitch_deg,
                       mount_height_m=self.mount_height_m + height_m)

    def lamp_x(self) -> dict[str, float]:
        """Lateral position (m, right +) of the left and right lamps."""
        return {"left": -0.5 * self.spacing_m, "right": 0.5 * self.spacing_m}


@dataclass(frozen=True)
class SensorCurve:
    """Illuminance of one sensor line along one approach.

    Attributes
    ----------
    approach, sensor : str
        Which approach and sensor (``right_edge``, ``left_edge``, ``glare``).
    s_m : ndarray, shape (N,)
        Distances along the approach (m).
    x_m, z_m, y_m : ndarray
        Sensor positions (m; y the sensor height).
    lux : ndarray, shape (N,)
        Illuminance of both lamps (lx) from the pooled map; NaN where a lamp's direction
        to the sensor lies outside its known far field.
    lux_lo, lux_hi : ndarray or None
        Pointwise two-sided interval (from the interleave sets); None without sets.
    """

    approach: str
    sensor: str
    s_m: NDArray
    x_m: NDArray
    z_m: NDArray
    y_m: float
    lux: NDArray
    lux_lo: NDArray | None = None
    lux_hi: NDArray | None = None


def sensor_points(approach: Approach, s_m: ArrayLike, sensor: str, traffic: str = "right",
                  edge_height_m: float = 0.25, glare_height_m: float = 1.1
                  ) -> tuple[NDArray, NDArray, float, NDArray, NDArray]:
    """Sensor positions along an approach: x, z (m), height y (m) and the road tangent.

    Right-hand traffic: the right edge lies half a lane to the right of the lane centre,
    the left edge one and a half lanes to the left, the glare sensor one lane to the left.
    Left-hand traffic: the oncoming lane is on the right (right edge 1.5 lanes right, left
    edge half a lane left, glare sensor one lane right); the curve's direction is kept.
    """
    w = approach.lane_width_m
    offsets = ({"right_edge": 0.5 * w, "left_edge": -1.5 * w, "glare": -w} if traffic == "right"
               else {"right_edge": 1.5 * w, "left_edge": -0.5 * w, "glare": w})
    if sensor not in offsets:
        raise InputError(f"road: sensor must be one of {', '.join(SENSORS)}, got {sensor!r}")
    off = offsets[sensor]
    x, z, tx, tz = approach.point(s_m, off)
    y = edge_height_m if sensor != "glare" else glare_height_m
    return x, z, float(y), tx, tz


def _lamp_illuminance(intensity: IntensityFn, lamp_x: float, lamps: LampPair,
                      x: NDArray, y: float, z: NDArray, tx: NDArray, tz: NDArray) -> NDArray:
    """E (lx) at the sensors from one lamp; NaN where its far field is unknown."""
    dx, dy, dz = x - lamp_x, np.full_like(x, y - lamps.mount_height_m), z
    r2 = dx * dx + dy * dy + dz * dz
    r = np.sqrt(r2)
    # the lamp pitched up by p sees a world direction at p less elevation: rotate the
    # direction by −p about the lamp's x axis
    p = np.radians(lamps.pitch_deg)
    ly = dy * np.cos(p) - dz * np.sin(p)
    lz = dy * np.sin(p) + dz * np.cos(p)
    ahead = lz > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.degrees(np.arctan2(dx, lz))
        v = np.degrees(np.arctan2(ly, lz))
    cd = np.asarray(intensity(np.where(ahead, h, 0.0), np.where(ahead, v, 0.0)), dtype=float)
    # light arrives along d/r; the sensor faces back along the road (normal −t), so the
    # cosine of incidence is d·t/r
    cos_in = (dx * tx + dz * tz) / np.maximum(r, 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        e = cd * np.maximum(cos_in, 0.0) / r2
    return np.where(ahead, e, np.nan)


def _illuminance(intensity: IntensityFn | Mapping[str, IntensityFn], lamps: LampPair,
                 approach: Approach, s: NDArray, sensor: str, edge_height_m: float,
                 glare_height_m: float) -> tuple[NDArray, NDArray, float, NDArray]:
    x, z, y, tx, tz = sensor_points(approach, s, sensor, lamps.traffic, edge_height_m,
                                    glare_height_m)
    total = None
    for side, lx in lamps.lamp_x().items():
        fn = intensity[side] if isinstance(intensity, Mapping) else intensity
        e = _lamp_illuminance(fn, lx, lamps, x, y, z, tx, tz)
        total = e if total is None else total + e
    return x, z, y, total


def sensor_curves(intensity: IntensityFn | Mapping[str, IntensityFn], approach: Approach,
                  lamps: LampPair, s_m: ArrayLike,
                  set_intensity: IntensityFn | Mapping[str, IntensityFn] | None = None,
                  confidence: float = 0.95, edge_height_m: float = 0.25,
                  glare_height_m: float = 1.1) -> list[SensorCurve]:
    """Illuminance of the three sensor lines along ``approach``.

    Parameters
    ----------
    intensity : callable or mapping
        ``I(h_deg, v_deg)`` in cd of one lamp (the pooled far field; NaN = unknown), used
        for both lamps, or ``{"left": I_left, "right": I_right}`` (two runs).
    approach : Approach
        The road.
    lamps : LampPair
        Mounting and aim of the two lamps (same far field, mirrored positions).
    s_m : array_like
        Distances along the approach (m).
    set_intensity : callable, optional
        The S interleave sets' far fields: ``I_s(h, v)`` with a leading axis of S; gives
        a pointwise Student-t interval of the mean over sets (a mapping as above).
    confidence : float
        Two-sided level of the interval.
    edge_height_m, glare_height_m : float
        Sensor heights (m).
    """
    s = np.asarray(s_m, dtype=float)
    out = []
    for sensor in SENSORS:
        x, z, y, lux = _illuminance(intensity, lamps, approach, s, sensor, edge_height_m,
                                    glare_height_m)
        lo = hi = None
        if set_intensity is not None:
            _, _, _, per_set = _illuminance(set_intensity, lamps, approach, s, sensor,
                                            edge_height_m, glare_height_m)
            n_sets = per_set.shape[0]
            if n_sets > 1:
                mean = per_set.mean(axis=0)
                se = per_set.std(axis=0, ddof=1) / np.sqrt(n_sets)
                t = float(stdtrit(n_sets - 1, 0.5 + 0.5 * confidence))
                lo, hi = np.maximum(mean - t * se, 0.0), mean + t * se
        out.append(SensorCurve(approach.name, sensor, s, x, z, y, lux, lo, hi))
    return out


def crossing_distance(s_m: NDArray, lux: NDArray, level: float) -> dict[str, Any]:
    """Where illuminance along a sensor line falls below ``level`` for the last time.

    The farthest distance with ``lux ≥ level``, refined by linear interpolation to the
    crossing with the next sample; NaN samples (unknown far field) are skipped.

    Returns
    -------
    dict
        ``distance_m`` (None: never reached), ``beyond`` (True: still above the level at
        the last sample, so the distance is a lower bound).
    """
    s = np.asarray(s_m, dtype=float)
    e = np.asarray(lux, dtype=float)
    ok = np.isfinite(e)
    s, e = s[ok], e[ok]
    above = np.flatnonzero(e >= level)
    if not above.size:
        return {"distance_m": None, "beyond": False}
    i = int(above[-1])
    if i == len(s) - 1:
        return {"distance_m": float(s[i]), "beyond": True}
    e0, e1 = e[i], e[i + 1]
    frac = (e0 - level) / (e0 - e1) if e0 > e1 else 0.0
    return {"distance_m": float(s[i] + frac * (s[i + 1] - s[i])), "beyond": False}


def exceedance(s_m: NDArray, lux: NDArray, limit: float) -> list[list[float]]:
    """Stretches ``[s_from, s_to]`` (m) of a sensor line where illuminance exceeds
    ``limit``."""
    s = np.asarray(s_m, dtype=float)
    over = np.nan_to_num(np.asarray(lux, dtype=float), nan=0.0) > limit
    runs: list[list[float]] = []
    start = None
    for i, flag in enumerate(over):
        if flag and start is None:
            start = i
        if not flag and start is not None:
            runs.append([float(s[start]), float(s[i - 1])])
            start = None
    if start is not None:
        runs.append([float(s[start]), float(s[-1])])
    return runs


def distance_grid(s_range_m: Sequence[float] = (5.0, 200.0), step_m: float = 0.25
                  ) -> NDArray:
    """Distances along an approach (m), both ends included."""
    s0, s1 = (float(v) for v in s_range_m)
    if not (np.isfinite(step_m) and step_m > 0 and 0 <= s0 < s1 and np.isfinite(s1)):
        raise InputError(f"road: need 0 ≤ start < end and step > 0, got {s_range_m!r}, "
                         f"step {step_m!r}")
    n = round((s1 - s0) / step_m)
    return s0 + step_m * np.arange(n + 1)
