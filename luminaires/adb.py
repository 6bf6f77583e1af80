"""Adaptive driving beam (ADB): mask a matrix lamp for a traffic scene from its per-source maps.

A ``simulate --per-source`` run keeps every segment's (emitter group's) wall map
(:mod:`lightsim.persource`). Light adds up, so a mask — a dimming level w_g in [0, 1] per
segment — gives the map Σ_g w_g E_g without re-tracing. For every frame of a traffic
scene (:func:`read_traffic`) this module places the other road users on the measuring
screen from the lamp's mounting height and the lane geometry, and chooses the levels
with a linear programme (:func:`choose_levels`, ``scipy.optimize.linprog``):

    maximise Σ_g w_g Φ_g   (Φ_g: segment g's flux on the screen)
    subject to  Σ_g w_g (I_gp + z σ_gp) ≤ I_max,p   at every glare position p,

I_gp the intensity segment g sends to position p (mean over a square detector aperture),
σ_gp its standard error, z the two-sided normal quantile of the confidence level. Since
√(Σ w² σ²) ≤ Σ w σ, a mask that meets the constraints has the upper end of its interval
within the limit. Each position's verdict: *pass* when the interval's upper end is within
the limit, *fail* when its lower end is above it, else *undecided*. The **residual light**
in the masked zone — each road user's outline on the screen — is the mean intensity there
with the mask, with its interval, and as a fraction of the all-on value: it is not zero,
because the segments' light spreads beyond their stripes (lens scatter, stray paths).

The limits (:class:`AdbLimits`) come from the rule set ``r149-adb`` (its ``[meta.adb]``
table: which line of the regulation's ADB table holds for which road user at which
distance); a road user between the tabulated distances gets the line of the largest
tabulated distance not beyond it (the stricter neighbour).

=========================  =====  ========  =============================================
parameter                  unit   default   meaning
=========================  =====  ========  =============================================
``mount_height_m``         m      0.65      lamp height above the road
``lane_width_m``           m      3.5       lane width
``lamp_offset_m``          m      0         lamp beside its lane's centre (+ = right)
``aperture_deg``           °      0.15      side of the square detector at a glare position
``confidence``             –      0.95      two-sided level of the intervals
``EYE_HEIGHT_M``           m      1.15      a driver's eyes (0.57° U at 50 m from 0.65 m)
``MIRROR_HEIGHT_M``        m      1.0       exterior mirrors (interior mirror 1.25 m)
``VEHICLE_SIZE_M``         m      1.8×1.5   a road user's outline (width × height)
=========================  =====  ========  =============================================

Glare positions of a road user (right-hand traffic; mirrored for left-hand traffic),
lateral offsets from its centre as seen from the lamp (+ = right): an oncoming vehicle's
driver's eyes (+0.4 m, its left-hand drive seat) and its driver-side mirror (+0.95 m); a
preceding vehicle's interior mirror (0 m, 1.25 m high) and both exterior mirrors
(±0.95 m). A traffic file may give its own (``points``).
"""

from __future__ import annotations

import math
import os
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.sparse import block_diag
from scipy.stats import norm

from lightsim import options
from lightsim.errors import InputError
from lightsim.options import option
from lightsim.persource import PerSourceMaps, compose
from lightsim.wall import WallFrame, candela_from_lux

from .regulations.ruleset import load_ruleset

EYE_HEIGHT_M = 1.15
MIRROR_HEIGHT_M = 1.0
INTERIOR_MIRROR_HEIGHT_M = 1.25
VEHICLE_SIZE_M = (1.8, 1.5)
KINDS = ("oncoming", "preceding")
RULESET = "r149-adb"

#: Glare positions of each kind: (label, lateral offset m (+ = right, right-hand traffic),
#: height m).
DEFAULT_POINTS = {
    "oncoming": (("driver's eyes", 0.4, EYE_HEIGHT_M), ("driver-side mirror", 0.95,
                                                         MIRROR_HEIGHT_M)),
    "preceding": (("interior mirror", 0.0, INTERIOR_MIRROR_HEIGHT_M),
                  ("left mirror", -0.95, MIRROR_HEIGHT_M),
                  ("right mirror", 0.95, MIRROR_HEIGHT_M)),
}


# -- limits -------------------------------------------------------------------------------
@dataclass(frozen=True)
class AdbLine:
    """One line of the regulation's ADB table for a kind of road user."""

    kind: str
    line: str
    distance_m: float
    max_cd: float
    source: str
    certainty: str


@dataclass(frozen=True)
class AdbLimits:
    """The ADB glare limits of a rule set (``[meta.adb]``), by kind and distance."""

    ruleset: str
    lines: tuple[AdbLine, ...]

    @classmethod
    def load(cls, ruleset: str = RULESET) -> AdbLimits:
        rs = load_ruleset(ruleset)
        with open(rs.path, "rb") as f:
            adb = (tomllib.load(f).get("meta") or {}).get("adb")
        if not isinstance(adb, dict):
            raise InputError(f"rule set {rs.id}: no [meta.adb] table of ADB lines")
        geo = {g.name: g for g in rs.geometries}
        lines = []
        for kind in KINDS:
            for row in adb.get(kind) or ():
                g = geo.get(row.get("line"))
                if g is None or g.max is None or float(row["max_cd"]) != g.max:
                    raise InputError(f"rule set {rs.id}: [meta.adb] {kind} names line "
                                     f"{row.get('line')!r}, which it does not limit so")
                lines.append(AdbLine(kind, g.name, float(row["distance_m"]), float(g.max),
                                     g.source or rs.source, g.certainty))
        for kind in KINDS:
            if not any(ln.kind == kind for ln in lines):
                raise InputError(f"rule set {rs.id}: no ADB line for {kind} road users")
        return cls(rs.id, tuple(lines))

    def for_user(self, kind: str, distance_m: float) -> AdbLine:
        """The line of a road user of ``kind`` at ``distance_m`` (see the module docstring)."""
        rows = sorted((ln for ln in self.lines if ln.kind == kind), key=lambda ln: ln.distance_m)
        best = rows[0]
        for ln in rows:
            if ln.distance_m <= distance_m:
                best = ln
        return best


# -- traffic ------------------------------------------------------------------------------
@dataclass(frozen=True)
class RoadUser:
    """Another road user in one frame: its kind, distance (m, along the road from the lamp),
    lateral position of its centre (m, from the lamp, + = right) and glare positions."""

    name: str
    kind: str
    distance_m: float
    lateral_m: float
    points: tuple[tuple[str, float, float], ...]  # (label, lateral offset m, height m)


@dataclass
class Traffic:
    """A traffic scene: its frames (each a list of road users), the road, fixed levels."""

    frames: list[list[RoadUser]]
    mount_height_m: float = 0.65
    lane_width_m: float = 3.5
    lamp_offset_m: float = 0.0
    side: str = "right"
    fixed: dict[str, float] = field(default_factory=dict)
    path: str = ""


def _number(where: str, key: str, value: Any, low: float | None = None,
            high: float | None = None, low_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{where}: {key} must be a number, got {value!r}")
    v = float(value)
    if low is not None and (v < low or (low_open and v == low)):
        raise InputError(f"{where}: {key} = {v:g} must be {'>' if low_open else '≥'} {low:g}")
    if high is not None and v > high:
        raise InputError(f"{where}: {key} = {v:g} must be ≤ {high:g}")
    return v


def check_level(where: str, name: str, value: Any) -> float:
    """A dimming level in [0, 1] (one line otherwise)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not 0.0 <= float(value) <= 1.0:
        raise InputError(f"{where}: dimming of '{name}' must be from 0 to 1, got {value!r}")
    return float(value)


_ROAD_KEYS = {"mount_height_m", "lane_width_m", "lamp_offset_m", "side"}
_VEHICLE_KEYS = {"name", "kind", "distance_m", "approach_m", "frames", "lane", "lateral_m",
                 "points"}


def read_traffic(path: str | os.PathLike) -> Traffic:
    """Read a traffic file (TOML; see ``docs/guides/led-lamps.md``): ``[road]``, optional
    ``[segments]`` (fixed levels by name) and ``[[vehicle]]`` tables; a vehicle has a
    ``distance_m`` or an ``approach_m = [from, to]`` with ``frames``. Bad input: one line
    (:class:`~lightsim.errors.InputError`)."""
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{p}: no such traffic file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: not a TOML traffic file ({exc})") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror or exc})") from None
    extra = sorted(set(doc) - {"road", "segments", "vehicle"})
    if extra:
        raise InputError(f"{p}: unknown table(s) {', '.join(extra)} (allowed: road, "
                         "segments, vehicle)")
    road = doc.get("road") or {}
    if not isinstance(road, dict) or set(road) - _ROAD_KEYS:
        raise InputError(f"{p}: [road] may have {', '.join(sorted(_ROAD_KEYS))}")
    tr = Traffic(frames=[], path=str(p))
    tr.mount_height_m = _number(f"{p} [road]", "mount_height_m",
                                road.get("mount_height_m", 0.65), 0, 10, low_open=True)
    tr.lane_width_m = _number(f"{p} [road]", "lane_width_m", road.get("lane_width_m", 3.5),
                              0, 20, low_open=True)
    tr.lamp_offset_m = _number(f"{p} [road]", "lamp_offset_m", road.get("lamp_offset_m", 0.0),
                               -10, 10)
    tr.side = road.get("side", "right")
    if tr.side not in ("right", "left"):
        raise InputError(f"{p} [road]: side must be right or left, got {tr.side!r}")
    segs = doc.get("segments") or {}
    if not isinstance(segs, dict):
        raise InputError(f"{p}: [segments] must be a table NAME = level")
    tr.fixed = {str(k): check_level(f"{p} [segments]", str(k), v) for k, v in segs.items()}
    vehicles = doc.get("vehicle") or []
    if not isinstance(vehicles, list) or not vehicles:
        raise InputError(f"{p}: no [[vehicle]]: give at least one road user")
    statics, series = [], []
    for i, v in enumerate(vehicles):
        where = f"{p} [[vehicle]] {i + 1}"
        if not isinstance(v, dict):
            raise InputError(f"{where}: must be a table")
        if set(v) - _VEHICLE_KEYS:
            raise InputError(f"{where}: unknown key(s) {', '.join(sorted(set(v) - _VEHICLE_KEYS))}")
        name = str(v.get("name", f"vehicle {i + 1}"))
        kind = v.get("kind")
        if kind not in KINDS:
            raise InputError(f"{where}: kind must be oncoming or preceding, got {kind!r}")
        sign = 1.0 if tr.side == "right" else -1.0
        if "lateral_m" in v:  # the vehicle's centre beside the lamp's lane centre
            lateral = _number(where, "lateral_m", v["lateral_m"], -100, 100)
        elif "lane" in v:  # lanes to the right of the lamp's (negative: to the left)
            lateral = _number(where, "lane", v["lane"], -10, 10) * tr.lane_width_m
        else:  # oncoming: the next lane on the other side; preceding: the lamp's lane
            lateral = (-sign if kind == "oncoming" else 0.0) * tr.lane_width_m
        lateral -= tr.lamp_offset_m
        points = _points(where, v.get("points"), kind, sign)
        if ("distance_m" in v) == ("approach_m" in v):
            raise InputError(f"{where}: give distance_m or approach_m = [from, to], one of them")
        if "distance_m" in v:
            d = _distance(where, "distance_m", v["distance_m"])
            statics.append(RoadUser(name, kind, d, lateral, points))
        else:
            ap = v["approach_m"]
            if not (isinstance(ap, list) and len(ap) == 2):
                raise InputError(f"{where}: approach_m must be [from, to] in m")
            d0, d1 = (_distance(where, "approach_m", x) for x in ap)
            n = v.get("frames", 100)
            if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 100_000:
                raise InputError(f"{where}: frames must be a whole number from 1 to 100000")
            series.append([RoadUser(name, kind, float(d), lateral, points)
                           for d in np.linspace(d0, d1, n)])
    n_frames = max((len(s) for s in series), default=1)
    if any(len(s) != n_frames for s in series):
        raise InputError(f"{p}: every approaching vehicle must have the same number of frames")
    tr.frames = [statics + [s[k] for s in series] for k in range(n_frames)]
    return tr


def _distance(where: str, key: str, value: Any) -> float:
    d = _number(where, key, value)
    if d <= 0:
        raise InputError(f"{where}: {key} = {d:g} m puts the vehicle behind the lamp "
                         "(distances are ahead of it, > 0)")
    return d


def _points(where: str, raw: Any, kind: str, sign: float
            ) -> tuple[tuple[str, float, float], ...]:
    if raw is None:
        return tuple((lab, sign * dx, h) for lab, dx, h in DEFAULT_POINTS[kind])
    if not isinstance(raw, list) or not raw:
        raise InputError(f"{where}: points must be a list of {{name, lateral_m, height_m}}")
    out = []
    for q in raw:
        if not isinstance(q, dict) or set(q) != {"name", "lateral_m", "height_m"}:
            raise InputError(f"{where}: each point needs exactly name, lateral_m, height_m")
        out.append((str(q["name"]), _number(where, "lateral_m", q["lateral_m"], -5, 5),
                    _number(where, "height_m", q["height_m"], 0, 10)))
    return tuple(out)


# -- the screen ---------------------------------------------------------------------------
class ScreenMaps:
    """The per-source maps as intensities (cd) with summed-area tables, so that the mean
    over any pixel rectangle of every segment costs four look-ups.

    Parameters
    ----------
    maps : PerSourceMaps
    """

    def __init__(self, maps: PerSourceMaps) -> None:
        self.maps = maps
        self.frame = WallFrame.from_dict(maps.wall)
        f = self.frame
        factor = candela_from_lux(np.ones((f.height, f.width)), f.h_m()[None, :],
                                  f.v_m()[:, None], f.distance_m)
        self.factor = factor  # cd per lx at each pixel
        cd = maps.lux.astype(np.float64) * factor
        var = maps.variance.astype(np.float64) * factor ** 2
        G = len(maps.names)
        self.sat = np.zeros((G, f.height + 1, f.width + 1))
        self.sat_var = np.zeros_like(self.sat)
        self.sat[:, 1:, 1:] = cd.cumsum(1).cumsum(2)
        self.sat_var[:, 1:, 1:] = var.cumsum(1).cumsum(2)
        dh, dv = f.pixel_size_m
        self.flux = maps.lux.astype(np.float64).sum(axis=(1, 2)) * dh * dv  # lm per segment

    def rect(self, h0: np.ndarray, h1: np.ndarray, v0: np.ndarray, v1: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel rectangles covering [h0, h1] × [v0, v1] (deg; at least one pixel each, the
        nearest inside the screen): (rows r0, r1, cols c0, c1) as a (4, n) int array, and
        whether each lies on the screen."""
        f = self.frame
        r_hi, c_lo = f.pixel_of(self._m(h0), self._m(v1))  # top-left
        r_lo, c_hi = f.pixel_of(self._m(h1), self._m(v0))
        c0 = np.ceil(c_lo - 1e-9).astype(np.int64)
        c1 = np.floor(c_hi + 1e-9).astype(np.int64)
        r0 = np.ceil(r_hi - 1e-9).astype(np.int64)
        r1 = np.floor(r_lo + 1e-9).astype(np.int64)
        cm = np.rint(0.5 * (c_lo + c_hi)).astype(np.int64)
        rm = np.rint(0.5 * (r_hi + r_lo)).astype(np.int64)
        c0, c1 = np.where(c1 < c0, cm, c0), np.where(c1 < c0, cm, c1)
        r0, r1 = np.where(r1 < r0, rm, r0), np.where(r1 < r0, rm, r1)
        on = (c1 >= 0) & (c0 < f.width) & (r1 >= 0) & (r0 < f.height)
        c0, c1 = np.clip(c0, 0, f.width - 1), np.clip(c1, 0, f.width - 1)
        r0, r1 = np.clip(r0, 0, f.height - 1), np.clip(r1, 0, f.height - 1)
        return np.stack([r0, r1 + 1, c0, c1 + 1]), on, (r1 + 1 - r0) * (c1 + 1 - c0)

    def _m(self, deg: np.ndarray) -> np.ndarray:
        return self.frame.distance_m * np.tan(np.radians(np.asarray(deg, np.float64)))

    def means(self, h0, h1, v0, v1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per segment, the mean intensity (cd) over each rectangle and its variance:
        (n, G) each, and whether each rectangle is on the screen (n,)."""
        idx, on, count = self.rect(np.atleast_1d(h0), np.atleast_1d(h1), np.atleast_1d(v0),
                                   np.atleast_1d(v1))
        r0, r1, c0, c1 = idx

        def box(s: np.ndarray) -> np.ndarray:
            return (s[:, r1, c1] - s[:, r0, c1] - s[:, r1, c0] + s[:, r0, c0]).T

        n = count.astype(np.float64)[:, None]
        # the tables' differences may round a zero to −1e−13: clipped
        return (np.maximum(box(self.sat), 0.0) / n,
                np.maximum(box(self.sat_var), 0.0) / (n * n), on)


# -- one frame ----------------------------------------------------------------------------
@dataclass
class GlarePosition:
    user: int
    label: str
    h_deg: float
    v_deg: float
    line: AdbLine


def place(users: list[RoadUser], traffic: Traffic, limits: AdbLimits
          ) -> tuple[list[GlarePosition], np.ndarray]:
    """Glare positions of every road user on the screen (deg) with their limits, and each
    user's outline (n_users, 4: h0, h1, v0, v1 in deg), from the mounting height and lanes."""
    pos, boxes = [], []
    hm = traffic.mount_height_m
    deg = math.degrees  # scalars: math is several times faster than NumPy here
    for k, u in enumerate(users):
        line = limits.for_user(u.kind, u.distance_m)
        d = u.distance_m
        for label, dx, height in u.points:
            pos.append(GlarePosition(k, label, deg(math.atan2(u.lateral_m + dx, d)),
                                     deg(math.atan2(height - hm, d)), line))
        w, h = VEHICLE_SIZE_M
        boxes.append([deg(math.atan2(u.lateral_m - 0.5 * w, d)),
                      deg(math.atan2(u.lateral_m + 0.5 * w, d)),
                      deg(math.atan2(-hm, d)), deg(math.atan2(h - hm, d))])
    return pos, np.asarray(boxes, np.float64).reshape(-1, 4)


def _bounds(G: int, fixed: dict[int, float]) -> list[tuple[float, float]]:
    return [(fixed[g], fixed[g]) if g in fixed else (0.0, 1.0) for g in range(G)]


def choose_levels(a_upper: np.ndarray, limit: np.ndarray, gain: np.ndarray,
                  fixed: dict[int, float]) -> tuple[np.ndarray, bool]:
    """Dimming levels w (G,) in [0, 1]: maximise gain·w subject to a_upper @ w ≤ limit
    (a_upper (P, G) cd, limit (P,) cd); ``fixed`` segments keep their level. Returns the
    levels and whether the limits can be met (if not, every free segment is off)."""
    levels, ok = choose_levels_batch([(a_upper, limit)], gain, fixed)
    return levels[0], bool(ok[0])


def choose_levels_batch(problems: list[tuple[np.ndarray, np.ndarray]], gain: np.ndarray,
                        fixed: dict[int, float]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`choose_levels` for many frames at once: the frames whose all-on mask breaks
    a limit are one block-diagonal linear programme (one solver call: the frames are
    independent, so its optimum is every frame's own). Returns levels (F, G) and whether
    each frame's limits can be met."""
    from scipy.optimize import linprog

    G = len(gain)
    bounds = _bounds(G, fixed)
    full = np.array([lo if lo == hi else 1.0 for lo, hi in bounds])
    off = np.array([lo if lo == hi else 0.0 for lo, hi in bounds])
    levels = np.tile(full, (len(problems), 1))
    ok = np.ones(len(problems), np.bool_)
    need = [k for k, (a, lim) in enumerate(problems) if a.size and np.any(a @ full > lim)]
    if not need:
        return levels, ok
    c = -np.maximum(np.asarray(gain, np.float64), 0.0)
    # a hair inside the limits: the solver's feasibility tolerance cannot push a
    # position's interval over its limit
    res = linprog(np.tile(c, len(need)),
                  A_ub=block_diag([problems[k][0] for k in need], format="csr"),
                  b_ub=np.concatenate([problems[k][1] for k in need]) * (1 - 1e-9),
                  bounds=bounds * len(need), method="highs")
    if res.status == 0:
        lo, hi = np.array(bounds).T
        levels[need] = np.clip(res.x.reshape(len(need), G), lo, hi)
        return levels, ok
    for k in need:  # some frame cannot meet its limits: find which, one by one
        a, lim = problems[k]
        r = linprog(c, A_ub=a, b_ub=lim * (1 - 1e-9), bounds=bounds, method="highs")
        if r.status == 0:
            levels[k] = np.clip(r.x, *np.array(bounds).T)
        else:
            levels[k], ok[k] = off, False
    return levels, ok


@dataclass
class FrameVerdict:
    """One frame's mask and verdicts (see :meth:`to_dict`)."""

    levels: np.ndarray
    feasible: bool
    positions: list[dict[str, Any]]
    residual: list[dict[str, Any]]

    def to_dict(self, names: tuple[str, ...]) -> dict[str, Any]:
        return {"levels": {n: float(w) for n, w in zip(names, self.levels, strict=True)},
                "limits_met": self.feasible, "positions": self.positions,
                "residual": self.residual}


@dataclass
class AdbSettings:
    """Settings of :func:`run_adb` (module table)."""

    aperture_deg: float = option(0.15, "Side of the square detector at each glare position.",
                                 unit="deg", flag=("--aperture",), low=0.01, high=2)
    confidence: float = option(0.95, "Two-sided level of the intervals (and of the margin "
                               "the levels keep below each limit).", flag=("--confidence",),
                               low=0.5, high=0.999)
    ruleset: str = option(RULESET, "Rule set with the ADB lines ([meta.adb]).",
                          flag=("--ruleset",))

    def __post_init__(self) -> None:
        options.check_fields(self)


class AdbComposer:
    """Masks and verdicts for frames of a traffic scene, from one run's per-source maps."""

    def __init__(self, maps: PerSourceMaps, traffic: Traffic,
                 settings: AdbSettings | None = None) -> None:
        self.settings = settings or AdbSettings()
        self.maps = maps
        self.screen = ScreenMaps(maps)
        self.traffic = traffic
        self.z = float(norm.ppf(0.5 + 0.5 * self.settings.confidence))
        self.fixed = {maps.index(n): w for n, w in traffic.fixed.items()}
        self.limits = AdbLimits.load(self.settings.ruleset)

    def frame(self, users: list[RoadUser]) -> FrameVerdict:
        """Choose the levels for one frame and judge them."""
        return self.frames([users])[0]

    def frames(self, frames: list[list[RoadUser]]) -> list[FrameVerdict]:
        """Every frame's levels and verdicts: the glare positions and outlines of all
        frames placed and measured at once, the levels in one solver call
        (:func:`choose_levels_batch`)."""
        pos: list[GlarePosition] = []
        pos_frame, boxes, box_frame = [], [], []
        for f, users in enumerate(frames):
            p, b = place(users, self.traffic, self.limits)
            pos += p
            pos_frame += [f] * len(p)
            boxes.append(b)
            box_frame += [f] * len(b)
        half = 0.5 * self.settings.aperture_deg
        h = np.array([p.h_deg for p in pos])
        v = np.array([p.v_deg for p in pos])
        limit = np.array([p.line.max_cd for p in pos])
        a, var, on = self.screen.means(h - half, h + half, v - half, v + half)
        upper = a + self.z * np.sqrt(var)
        cut = np.cumsum([0] + [sum(len(x.points) for x in u) for u in frames])
        levels, ok = choose_levels_batch(
            [(upper[cut[f]:cut[f + 1]], limit[cut[f]:cut[f + 1]]) for f in range(len(frames))],
            self.screen.flux, self.fixed)
        w = levels[np.asarray(pos_frame, np.int64)].reshape(len(pos), levels.shape[1])
        value = np.einsum("ig,ig->i", a, w)
        se = np.sqrt(np.einsum("ig,ig->i", var, w * w))
        lo, hi = np.maximum(value - self.z * se, 0.0), value + self.z * se
        out = [FrameVerdict(levels[f], bool(ok[f]), [], []) for f in range(len(frames))]
        for i, p in enumerate(pos):
            f = pos_frame[i]
            u = frames[f][p.user]
            verdict = ("off screen" if not on[i] else "pass" if hi[i] <= limit[i]
                       else "fail" if lo[i] > limit[i] else "undecided")
            out[f].positions.append({
                "user": u.name, "kind": u.kind, "distance_m": u.distance_m,
                "position": p.label, "h_deg": p.h_deg, "v_deg": p.v_deg, "cd": float(value[i]),
                "interval_cd": [float(lo[i]), float(hi[i])], "max_cd": p.line.max_cd,
                "line": p.line.line, "certainty": p.line.certainty, "verdict": verdict})
        bx = np.concatenate(boxes) if boxes else np.zeros((0, 4))
        if len(bx):  # the residual light in each road user's outline
            ba, bvar, bon = self.screen.means(bx[:, 0], bx[:, 1], bx[:, 2], bx[:, 3])
            wb = levels[np.asarray(box_frame, np.int64)]
            masked = np.einsum("ig,ig->i", ba, wb)
            mse = np.sqrt(np.einsum("ig,ig->i", bvar, wb * wb))
            allon = ba.sum(axis=1)
            k_in = 0
            for f, users in enumerate(frames):
                for u in users:
                    k = k_in
                    k_in += 1
                    out[f].residual.append({
                        "user": u.name, "zone_deg": [float(x) for x in bx[k]],
                        "on_screen": bool(bon[k]), "mean_cd": float(masked[k]),
                        "interval_cd": [float(max(masked[k] - self.z * mse[k], 0.0)),
                                        float(masked[k] + self.z * mse[k])],
                        "all_on_mean_cd": float(allon[k]),
                        "fraction_of_all_on": (float(masked[k] / allon[k]) if allon[k] > 0
                                               else None)})
        return out

    def composed(self, levels: np.ndarray) -> np.ndarray:
        """The composed wall map (H, W) lx, float32 (:func:`~lightsim.persource.compose`)."""
        return compose(self.maps.lux, levels)


@dataclass
class AdbResult:
    """Every frame's mask and verdicts, and which frame's map is written."""

    names: tuple[str, ...]
    frames: list[FrameVerdict]
    traffic: Traffic
    shown: int
    seconds: float
    settings: AdbSettings
    wall: dict[str, Any]
    limits: AdbLimits

    def summary(self) -> dict[str, Any]:
        counts = {"pass": 0, "fail": 0, "undecided": 0, "off screen": 0}
        for f in self.frames:
            for p in f.positions:
                counts[p["verdict"]] += 1
        return {"frames": len(self.frames), "verdict_counts": counts,
                "frames_with_limits_unmet": sum(not f.feasible for f in self.frames),
                "seconds": self.seconds}


def run_adb(maps: PerSourceMaps, traffic: Traffic, settings: AdbSettings | None = None,
            shown: int | None = None) -> AdbResult:
    """Masks and verdicts for every frame of ``traffic``; ``shown``: the frame whose map
    is written (default: the last)."""
    settings = settings or AdbSettings()
    for name in traffic.fixed:
        maps.index(name)  # an unknown segment fails here, before anything is written
    n = len(traffic.frames)
    shown = n - 1 if shown is None else shown
    if not -n <= shown < n:
        raise InputError(f"--frame {shown}: the traffic scene has frames 0…{n - 1}")
    composer = AdbComposer(maps, traffic, settings)
    t0 = time.perf_counter()
    frames = composer.frames(traffic.frames)
    seconds = time.perf_counter() - t0
    return AdbResult(maps.names, frames, traffic, shown % n, seconds, settings, maps.wall,
                     composer.limits)


def panel_solver(maps: PerSourceMaps, road: Traffic | None = None,
                 settings: AdbSettings | None = None) -> Any:
    """The ``/mask`` function of the view's ADB panel (:mod:`lightsim.view.adb_panel`): a
    request ``{"vehicles": [{"kind", "distance_m", "h_deg"}], "fixed": {name: level}}``
    (the road user's centre at H = ``h_deg`` on the screen) → its levels, verdicts and
    residual light; bad input: one line (:class:`~lightsim.errors.InputError`)."""
    road = road or Traffic(frames=[])
    composer = AdbComposer(maps, road, settings)

    def solve(req: dict[str, Any]) -> dict[str, Any]:
        vehicles = req.get("vehicles")
        fixed = req.get("fixed") or {}
        if not isinstance(vehicles, list) or not isinstance(fixed, dict) \
                or set(req) - {"vehicles", "fixed"}:
            raise InputError("a mask request has vehicles (a list) and fixed (a table)")
        users = []
        for i, v in enumerate(vehicles):
            where = f"vehicle {i + 1}"
            if not isinstance(v, dict) or v.get("kind") not in KINDS:
                raise InputError(f"{where}: kind must be oncoming or preceding")
            d = _distance(where, "distance_m", v.get("distance_m"))
            h = _number(where, "h_deg", v.get("h_deg"), -60, 60)
            sign = 1.0 if road.side == "right" else -1.0
            users.append(RoadUser(str(v.get("name", f"vehicle {i + 1}")), v["kind"], d,
                                  d * math.tan(math.radians(h)),
                                  _points(where, None, v["kind"], sign)))
        composer.fixed = {maps.index(str(n)): check_level("fixed", str(n), w)
                          for n, w in fixed.items()}
        f = composer.frame(users)
        return f.to_dict(maps.names) | {"segments": list(maps.names),
                                        "levels_list": [float(w) for w in f.levels]}

    return solve
