"""The measuring wall: its pixel grid, metres on the wall, H/V degrees, lux ↔ candela.

One frame class, :class:`WallFrame`, answers every "which pixel, which place, which
direction" question of the engine, the plots and the regulation checks. Conventions
(``docs/reference/conventions.md``): the lamp sits at the origin and shines along +Z; the wall is a
plane facing it, by default z = D (D = 25 m, the UN regulations' measuring distance);
**H** runs to the driver's right (world −X), **V** up (+Y).

Two sets of wall coordinates, both in metres along ``h_axis``/``v_axis``:

* *wall coordinates* (h, v) relative to the frame's ``centre``: what photons hit and what
  the pixel grid spans (``h_range_m``, ``v_range_m``); :meth:`WallFrame.to_hv`,
  :meth:`WallFrame.pixel_centres`, :meth:`WallFrame.pixel_index`;
* *H-V coordinates* (h_m, v_m) relative to the **H-V point**, where the lamp axis (+Z from
  the lamp) meets the wall: h_m = h − offset_h. Angles are taken from these:
  h_deg = atan(h_m / D), v_deg = atan(v_m / D) (the regulations' H/V test-point angles,
  U/D = up/down, L/R = left/right of H-V); :meth:`WallFrame.h_m`, :meth:`WallFrame.h_deg`,
  :meth:`WallFrame.pixel_of`. For the default wall the two coincide (offset 0).

Pixel (row i, column j) of an (H, W) image covers the cell whose centre is at
``h = h_min + (j + 0.5)·Δh``, ``v = v_max − (i + 0.5)·Δv`` (row 0 on top, column 0 on the
left), ``Δh = (h_max − h_min)/W``, ``Δv = (v_max − v_min)/H``; cells are half-open.

Photometry on a flat wall (lamp at the origin, wall plane at distance D):
``r = sqrt(D² + h_m² + v_m²)``, ``cos θ = D / r``, illuminance from intensity
``E = I·cos θ / r² = I·D / r³`` (lx, I in cd), so ``I = E·r³ / D``; at H-V ``I = E·D²``
(1 lx at 25 m is 625 cd). Spherical direction of a wall point: the unit vector
``(−h_m, v_m, D) / r`` in world axes for the default wall (:meth:`WallFrame.directions`).

Parameters
----------
===================  ======  ===========  =================================================
name                 unit    default      meaning
===================  ======  ===========  =================================================
``centre``           m       (0, 0, D)    world point of wall coordinates (0, 0)
``h_axis``           –       (−1, 0, 0)   unit vector of +H on the wall (driver's right)
``v_axis``           –       (0, 1, 0)    unit vector of +V on the wall (up)
``normal``           –       (0, 0, −1)   wall normal, towards the lamp
``h_range_m``        m       –            [min, max] of the image in wall coordinates
``v_range_m``        m       –            [min, max] of the image in wall coordinates
``distance_m`` / D   m       25.0         lamp → wall distance along +Z
``resolution``       px      (640, 256)   image size (W, H)
``hv_offset``        m       from axes    H-V point in wall coordinates; None: where the
                                          lamp axis from ``lamp_position`` meets the wall
                                          ((0, 0) if it never does: a floor)
``lamp_position``    m       (0, 0, 0)    lamp position (world) for the H-V point
h_deg, v_deg         deg     –            angular wall position, atan(h_m/D), atan(v_m/D)
lux / E              lx      –            illuminance on the wall
candela / I          cd      –            luminous intensity towards a wall point
===================  ======  ===========  =================================================
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lightsim.errors import InputError
from lightsim.render.filters import map_coordinates  # = scipy.ndimage's, in numpy

DEFAULT_DISTANCE_M = 25.0
"""Measuring distance of the UN regulations (m)."""

__all__ = [
    "DEFAULT_DISTANCE_M",
    "WallFrame",
    "candela_from_lux",
    "deg_from_wall_m",
    "lux_from_candela",
    "sample_wall",
    "wall_m_from_deg",
]


# ---- angles and photometric units --------------------------------------------------------

def wall_m_from_deg(angle_deg: ArrayLike, distance_m: float = DEFAULT_DISTANCE_M) -> NDArray:
    """Wall coordinate (m, relative to H-V) of an angular position: ``D·tan(angle)``.

    Parameters
    ----------
    angle_deg : array_like
        h_deg or v_deg in degrees (|angle| < 90°).
    distance_m : float, default 25.0
        Lamp → wall distance D in metres.

    Returns
    -------
    ndarray
        h_m or v_m in metres.
    """
    return distance_m * np.tan(np.radians(np.asarray(angle_deg, dtype=float)))


def deg_from_wall_m(pos_m: ArrayLike, distance_m: float = DEFAULT_DISTANCE_M) -> NDArray:
    """Angular position (deg) of a wall coordinate in metres: ``atan(pos / D)``.

    Parameters
    ----------
    pos_m : array_like
        h_m or v_m in metres, relative to H-V.
    distance_m : float, default 25.0
        Lamp → wall distance D in metres.
    """
    return np.degrees(np.arctan2(np.asarray(pos_m, dtype=float), distance_m))


def candela_from_lux(lux: ArrayLike, h_m: ArrayLike = 0.0, v_m: ArrayLike = 0.0,
                     distance_m: float = DEFAULT_DISTANCE_M) -> NDArray:
    """Intensity (cd) that produces illuminance ``lux`` at wall point (h_m, v_m).

    ``I = E·r² / cos θ = E·r³ / D`` with ``r = sqrt(D² + h² + v²)``; at H-V ``I = E·D²``.

    Parameters
    ----------
    lux : array_like
        Illuminance E on the wall in lx.
    h_m, v_m : array_like, default 0
        Wall position relative to H-V in metres (broadcast against ``lux``).
    distance_m : float, default 25.0
        Lamp → wall distance D in metres.

    Returns
    -------
    ndarray
        Luminous intensity in cd.
    """
    h = np.asarray(h_m, dtype=float)
    v = np.asarray(v_m, dtype=float)
    r2 = distance_m**2 + h**2 + v**2
    return np.asarray(lux, dtype=float) * r2 * np.sqrt(r2) / distance_m


def lux_from_candela(candela: ArrayLike, h_m: ArrayLike = 0.0, v_m: ArrayLike = 0.0,
                     distance_m: float = DEFAULT_DISTANCE_M) -> NDArray:
    """Illuminance (lx) on the wall at (h_m, v_m) from an intensity in cd: ``E = I·D / r³``.

    Parameters
    ----------
    candela : array_like
        Luminous intensity I in cd towards the wall point.
    h_m, v_m : array_like, default 0
        Wall position relative to H-V in metres.
    distance_m : float, default 25.0
        Lamp → wall distance D in metres.
    """
    h = np.asarray(h_m, dtype=float)
    v = np.asarray(v_m, dtype=float)
    r2 = distance_m**2 + h**2 + v**2
    return np.asarray(candela, dtype=float) * distance_m / (r2 * np.sqrt(r2))


# ---- input checks -------------------------------------------------------------------------

def _vec(value: Any, name: str) -> NDArray | None:
    if value is None:
        return None
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(f"wall frame: '{name}' must be three finite numbers, got {value!r}")
    return arr


def _pair(value: Any, name: str) -> tuple[float, float]:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)) or not arr[1] > arr[0]:
        raise InputError(f"wall frame: '{name}' must be [min, max] with min < max, got {value!r}")
    return float(arr[0]), float(arr[1])


def hv_point_offset(centre: ArrayLike, h_axis: ArrayLike, v_axis: ArrayLike,
                    normal: ArrayLike | None, lamp_position: Sequence[float] = (0.0, 0.0, 0.0)
                    ) -> tuple[float, float] | None:
    """Wall coordinates (m) of the H-V point: where the lamp axis (+Z from
    ``lamp_position``) meets the wall plane; None when the axis is parallel to the wall."""
    c = np.asarray(centre, dtype=float)
    ha, va = np.asarray(h_axis, dtype=float), np.asarray(v_axis, dtype=float)
    n = np.asarray(normal, dtype=float) if normal is not None else np.cross(ha, va)
    lamp = np.asarray(lamp_position, dtype=float)
    denom = float(n[2])  # n · e_z, the lamp axis
    if abs(denom) < 1e-9:
        return None
    t = float(np.dot(n, c - lamp)) / denom
    rel = lamp + t * np.array([0.0, 0.0, 1.0]) - c
    return float(np.dot(rel, ha)), float(np.dot(rel, va))


# ---- the frame ----------------------------------------------------------------------------

@dataclass(eq=False)
class WallFrame:
    """Geometry of the measuring wall and its image (see the module docstring).

    Attributes
    ----------
    centre, h_axis, v_axis, normal : ndarray, shape (3,)
        World origin of the wall coordinates (m) and the unit axes/normal.
    h_range_m, v_range_m : tuple of float
        Image extent [min, max] in wall coordinates (m).
    distance_m : float
        Lamp → wall distance D (m).
    resolution : tuple of int
        Image size (W, H) in pixels.
    hv_offset : tuple of float or None
        H-V point in wall coordinates (m); None: computed from the axes for a lamp at the
        origin, (0, 0) when the lamp axis is parallel to the wall.
    extra : mapping
        The description the frame was read from (``summary.json["wall"]``), if any.
    """

    centre: NDArray
    h_axis: NDArray
    v_axis: NDArray
    normal: NDArray
    h_range_m: tuple[float, float]
    v_range_m: tuple[float, float]
    distance_m: float
    resolution: tuple[int, int] = (640, 256)
    hv_offset: tuple[float, float] | None = None
    extra: Mapping[str, Any] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.hv_offset is None:
            self.hv_offset = hv_point_offset(self.centre, self.h_axis, self.v_axis,
                                             self.normal) or (0.0, 0.0)

    def __eq__(self, other: object) -> bool:
        """Same wall and pixel grid (the description it was read from is not compared)."""
        if not isinstance(other, WallFrame):
            return NotImplemented
        return (all(np.array_equal(getattr(self, k), getattr(other, k))
                    for k in ("centre", "h_axis", "v_axis", "normal"))
                and tuple(self.h_range_m) == tuple(other.h_range_m)
                and tuple(self.v_range_m) == tuple(other.v_range_m)
                and self.distance_m == other.distance_m
                and tuple(self.resolution) == tuple(other.resolution)
                and tuple(self.hv_offset_m) == tuple(other.hv_offset_m))

    __hash__ = None  # type: ignore[assignment]  # mutable arrays inside

    # ---- construction and serialisation ------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The JSON description (``summary.json["wall"]``, EXR metadata)."""
        return {
            "centre": [float(x) for x in self.centre],
            "h_axis": [float(x) for x in self.h_axis],
            "v_axis": [float(x) for x in self.v_axis],
            "normal": [float(x) for x in self.normal],
            "h_range_m": [float(x) for x in self.h_range_m],
            "v_range_m": [float(x) for x in self.v_range_m],
            "distance_m": float(self.distance_m),
            "resolution": [int(x) for x in self.resolution],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> WallFrame:
        """The frame of a complete :meth:`to_dict` description (no checks)."""
        return cls(np.asarray(d["centre"], float), np.asarray(d["h_axis"], float),
                   np.asarray(d["v_axis"], float), np.asarray(d["normal"], float),
                   tuple(d["h_range_m"]), tuple(d["v_range_m"]), float(d["distance_m"]),
                   tuple(int(x) for x in d["resolution"]))

    @classmethod
    def from_any(cls, frame: Any, lamp_position: Sequence[float] = (0.0, 0.0, 0.0),
                 resolution: Sequence[int] | None = None) -> WallFrame:
        """A checked frame from a dict (``summary.json["wall"]``), a frame or an object.

        Recognised keys/attributes: ``distance_m``, ``h_range_m``, ``v_range_m``,
        ``resolution`` ([W, H]; or the ``resolution`` argument) and optionally
        ``centre``, ``h_axis``, ``v_axis``, ``normal`` (world vectors) from which the H-V
        point is found for a lamp at ``lamp_position`` (m) shining along +Z. Without them
        the wall is the conventions' default wall (z = D, H = −X, V = +Y) centred on H-V.
        Without ``distance_m`` the distance is taken from ``centre``/``normal``.

        Raises
        ------
        InputError
            If a required key is missing or malformed. A wall parallel to the lamp axis (a
            floor) has no H-V point: its angles are taken from the wall centre.
        """
        if isinstance(frame, WallFrame):
            out = frame
            if resolution is not None:
                out = out.with_resolution(*resolution)
            if any(float(x) != 0.0 for x in lamp_position):
                off = hv_point_offset(out.centre, out.h_axis, out.v_axis, out.normal,
                                      lamp_position)
                out = replace(out, hv_offset=off or (0.0, 0.0))
            return out
        if isinstance(frame, Mapping):
            get = frame.get
        else:
            def get(key: str, default: Any = None) -> Any:
                return getattr(frame, key, default)
        centre = _vec(get("centre", None), "centre")
        h_axis = _vec(get("h_axis", None), "h_axis")
        v_axis = _vec(get("v_axis", None), "v_axis")
        normal = _vec(get("normal", None), "normal")
        lamp = np.asarray(lamp_position, dtype=float)
        dist = get("distance_m", None)
        if dist is None:
            if centre is None or normal is None:
                raise InputError("wall frame: needs 'distance_m' (or 'centre' and 'normal')")
            dist = abs(float(np.dot(normal, centre - lamp)))
        dist = float(dist)
        if not np.isfinite(dist) or dist <= 0:
            raise InputError(f"wall frame: 'distance_m' must be > 0, got {dist!r}")
        if resolution is None:
            resolution = get("resolution", None)
        for key, value in (("h_range_m", get("h_range_m", None)),
                           ("v_range_m", get("v_range_m", None)), ("resolution", resolution)):
            if value is None:
                raise InputError(f"wall frame: missing '{key}'")
        h_range = _pair(get("h_range_m"), "h_range_m")
        v_range = _pair(get("v_range_m"), "v_range_m")
        res = np.asarray(resolution, dtype=float).reshape(-1)
        if res.shape != (2,) or np.any(res < 1) or np.any(res != np.round(res)):
            raise InputError(f"wall frame: 'resolution' must be [W, H] pixels, "
                             f"got {resolution!r}")
        offset = (0.0, 0.0)
        if centre is not None and h_axis is not None and v_axis is not None:
            offset = hv_point_offset(centre, h_axis, v_axis, normal, lamp) or (0.0, 0.0)
            if normal is None:
                normal = np.cross(h_axis, v_axis)
        else:  # a bare image description: the conventions' wall, centred on H-V
            centre = np.array([0.0, 0.0, dist])
            h_axis, v_axis = np.array([-1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
            normal = np.array([0.0, 0.0, -1.0])
        extra = dict(frame) if isinstance(frame, Mapping) else {}
        return cls(centre, h_axis, v_axis, normal, h_range, v_range, dist,
                   (int(res[0]), int(res[1])), offset, extra)

    def with_resolution(self, width: int, height: int) -> WallFrame:
        """The same wall sampled with ``width`` × ``height`` pixels."""
        return replace(self, resolution=(int(width), int(height)))

    # ---- pixel grid ---------------------------------------------------------------------
    @property
    def width(self) -> int:
        """Image width W in pixels."""
        return self.resolution[0]

    @property
    def height(self) -> int:
        """Image height H in pixels."""
        return self.resolution[1]

    @property
    def pixel_size_m(self) -> tuple[float, float]:
        """Pixel pitch (Δh, Δv) in metres."""
        w, h = self.resolution
        return ((self.h_range_m[1] - self.h_range_m[0]) / w,
                (self.v_range_m[1] - self.v_range_m[0]) / h)

    @property
    def pixel_pitch_deg(self) -> tuple[float, float]:
        """Pixel pitch (deg) at H-V, small-angle: (Δh/D, Δv/D) in degrees."""
        dh, dv = self.pixel_size_m
        return float(np.degrees(dh / self.distance_m)), float(np.degrees(dv / self.distance_m))

    @property
    def hv_offset_m(self) -> tuple[float, float]:
        """The H-V point in wall coordinates (m): (0, 0) when the wall is centred on it."""
        assert self.hv_offset is not None  # set in __post_init__
        return self.hv_offset

    def cell_centres(self, rows: ArrayLike, cols: ArrayLike) -> tuple[NDArray, NDArray]:
        """Wall coordinates (m) of the centres of columns ``cols`` and rows ``rows``:
        ``h = h_min + (col + 0.5)·Δh``, ``v = v_max − (row + 0.5)·Δv``."""
        dh, dv = self.pixel_size_m
        h = self.h_range_m[0] + (np.asarray(cols, dtype=np.float64) + 0.5) * dh
        v = self.v_range_m[1] - (np.asarray(rows, dtype=np.float64) + 0.5) * dv
        return h, v

    def pixel_centres(self) -> tuple[NDArray, NDArray]:
        """Wall coordinates h (W,) and v (H,) of the pixel centres: column 0 the smallest
        h, row 0 the largest v."""
        w, hres = self.resolution
        return self.cell_centres(np.arange(hres), np.arange(w))

    def pixel_index(self, h: ArrayLike, v: ArrayLike, clip: bool = False
                    ) -> tuple[NDArray, NDArray]:
        """Integer (row, column) of the pixel holding wall coordinates (h, v) (m).

        Cells are half-open; points outside the image get indices outside [0, H) × [0, W)
        unless ``clip`` moves them to the nearest edge pixel.
        """
        dh, dv = self.pixel_size_m
        col = np.floor((np.asarray(h) - self.h_range_m[0]) / dh).astype(np.int64)
        row = np.floor((self.v_range_m[1] - np.asarray(v)) / dv).astype(np.int64)
        if clip:
            col = np.clip(col, 0, self.width - 1)
            row = np.clip(row, 0, self.height - 1)
        return row, col

    def inside(self, row: NDArray, col: NDArray) -> NDArray:
        """True where integer (row, col) is a pixel of the image."""
        return (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)

    # ---- world ↔ wall ---------------------------------------------------------------------
    def to_hv(self, points: ArrayLike) -> tuple[NDArray, NDArray]:
        """World points (n, 3) → wall coordinates h, v (m)."""
        d = np.asarray(points, dtype=np.float64) - self.centre
        return d @ self.h_axis, d @ self.v_axis

    def to_world(self, h: ArrayLike, v: ArrayLike) -> NDArray:
        """Wall coordinates h, v (m) → world points (…, 3)."""
        h = np.asarray(h, dtype=np.float64)[..., None]
        v = np.asarray(v, dtype=np.float64)[..., None]
        return self.centre + h * self.h_axis + v * self.v_axis

    # ---- H-V metres and degrees -------------------------------------------------------------
    def h_m(self) -> NDArray:
        """H of each column centre in m relative to H-V, shape (W,), increasing."""
        dh = self.pixel_size_m[0]
        return self.h_range_m[0] + (np.arange(self.width) + 0.5) * dh - self.hv_offset_m[0]

    def v_m(self) -> NDArray:
        """V of each row centre in m relative to H-V, shape (H,), decreasing (row 0 on top)."""
        dv = self.pixel_size_m[1]
        return self.v_range_m[1] - (np.arange(self.height) + 0.5) * dv - self.hv_offset_m[1]

    def h_deg(self) -> NDArray:
        """H of each column centre in degrees, shape (W,)."""
        return deg_from_wall_m(self.h_m(), self.distance_m)

    def v_deg(self) -> NDArray:
        """V of each row centre in degrees, shape (H,)."""
        return deg_from_wall_m(self.v_m(), self.distance_m)

    def degrees(self, h: ArrayLike, v: ArrayLike) -> tuple[NDArray, NDArray]:
        """Wall coordinates (m, relative to the centre) → H/V angles (deg) from H-V."""
        return (deg_from_wall_m(np.asarray(h, float) - self.hv_offset_m[0], self.distance_m),
                deg_from_wall_m(np.asarray(v, float) - self.hv_offset_m[1], self.distance_m))

    def edges_deg(self) -> tuple[NDArray, NDArray]:
        """H/V angles (deg) of the column edges (W + 1,), increasing, and of the row edges
        (H + 1,), decreasing (row 0 on top)."""
        h = np.linspace(self.h_range_m[0], self.h_range_m[1], self.width + 1)
        v = np.linspace(self.v_range_m[1], self.v_range_m[0], self.height + 1)
        return self.degrees(h, v)

    def extent_deg(self) -> tuple[float, float, float, float]:
        """Angular extent of the image edges (h_min, h_max, v_min, v_max) in degrees."""
        hd, vd = self.degrees(np.array(self.h_range_m), np.array(self.v_range_m))
        return float(hd[0]), float(hd[1]), float(vd[0]), float(vd[1])

    def pixel_of(self, h_m: ArrayLike, v_m: ArrayLike) -> tuple[NDArray, NDArray]:
        """Fractional (row, column) of wall points given in m relative to H-V.

        Pixel centres are at integer positions; suitable for
        :func:`scipy.ndimage.map_coordinates`.
        """
        dh, dv = self.pixel_size_m
        col = (np.asarray(h_m, float) + self.hv_offset_m[0] - self.h_range_m[0]) / dh - 0.5
        row = (self.v_range_m[1] - (np.asarray(v_m, float) + self.hv_offset_m[1])) / dv - 0.5
        return row, col

    def directions(self, h_deg: ArrayLike, v_deg: ArrayLike) -> NDArray:
        """Unit world directions (…, 3) from the lamp towards H/V angles (deg) on the wall
        (the spherical form of a wall position)."""
        h = wall_m_from_deg(h_deg, self.distance_m) + self.hv_offset_m[0]
        v = wall_m_from_deg(v_deg, self.distance_m) + self.hv_offset_m[1]
        p = self.to_world(h, v)
        return p / np.linalg.norm(p, axis=-1, keepdims=True)

    # ---- photometry ------------------------------------------------------------------------
    def check_image(self, image: ArrayLike, name: str = "lux image") -> NDArray:
        """Return ``image`` as a float array after checking its shape is (H, W)."""
        arr = np.asarray(image, dtype=float)
        if arr.ndim != 2 or arr.shape != (self.height, self.width):
            raise InputError(f"{name}: shape {arr.shape} does not match the wall frame's "
                             f"{self.height}×{self.width} (H×W) pixels")
        return arr

    def intensity_image(self, lux: ArrayLike) -> NDArray:
        """Convert a wall lux image (lx) to the intensity (cd) towards each pixel centre."""
        arr = self.check_image(lux)
        return candela_from_lux(arr, self.h_m()[None, :], self.v_m()[:, None], self.distance_m)

    def lux_at(self, candela: ArrayLike, h_m: ArrayLike, v_m: ArrayLike) -> NDArray:
        """Illuminance (lx) from intensity (cd) at H-V coordinates (m) on this wall."""
        return lux_from_candela(candela, h_m, v_m, self.distance_m)

    def sample(self, lux: ArrayLike, h_deg: ArrayLike, v_deg: ArrayLike,
               outside: float = np.nan) -> NDArray:
        """Intensity (cd) towards H/V angles, bilinear between the pixel centres of a wall
        lux image (:func:`sample_wall`)."""
        intensity = self.intensity_image(lux)
        h, v = np.broadcast_arrays(np.asarray(h_deg, float), np.asarray(v_deg, float))
        row, col = self.pixel_of(wall_m_from_deg(h, self.distance_m),
                                 wall_m_from_deg(v, self.distance_m))
        inside = (row >= -1e-9) & (row <= self.height - 1 + 1e-9) & (col >= -1e-9) & (
            col <= self.width - 1 + 1e-9)
        out = map_coordinates(intensity, [row.ravel(), col.ravel()], order=1, mode="nearest")
        out = out.reshape(h.shape)
        return np.where(inside, out, outside)


def sample_wall(lux: ArrayLike, frame: Any, h_deg: ArrayLike, v_deg: ArrayLike,
                outside: float = np.nan) -> NDArray:
    """Intensity (cd) towards wall directions, read from a wall lux image.

    The lux image is converted to intensity per pixel (``I = E·r³/D``) and interpolated
    bilinearly between pixel centres at the requested angular positions.

    Parameters
    ----------
    lux : array_like, shape (H, W)
        Illuminance on the wall in lx (row 0 on top).
    frame : WallFrame or mapping
        The wall frame (see :meth:`WallFrame.from_any`).
    h_deg, v_deg : array_like
        Angular positions in degrees (broadcast together).
    outside : float, default nan
        Value (cd) for positions outside the pixel centres' span.

    Returns
    -------
    ndarray
        Intensity in cd, shape of the broadcast h/v arrays.
    """
    return WallFrame.from_any(frame).sample(lux, h_deg, v_deg, outside)
