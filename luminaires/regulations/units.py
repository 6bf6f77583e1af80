"""Wall geometry and photometric unit helpers: H/V degrees ↔ wall metres, lux ↔ candela.

Everything follows ``docs/conventions.md``: the lamp sits at the origin and shines along +Z,
the measuring wall is the plane z = D facing it (default D = 25 m), **H** runs to the
driver's right (world −X), **V** up (+Y), and a wall point (h, v) in metres has the
angular position h_deg = atan(h / D), v_deg = atan(v / D). Regulations give test points in
those degrees (U/D = up/down, L/R = left/right of H-V).

Photometric relations on a flat wall (lamp at the origin, wall plane z = D):

* distance lamp → wall point ``r = sqrt(D² + h² + v²)``;
* angle between the ray and the wall normal: ``cos θ = D / r``;
* illuminance from an intensity ``E = I·cos θ / r² = I·D / r³`` (lx, with I in cd);
* so ``I = E·r² / cos θ = E·r³ / D``; at H-V ``I = E·D²``: 1 lx at 25 m is 625 cd.

Wall frames arrive as the dictionary written to ``summary.json["wall"]`` / EXR metadata
(see :class:`WallFrame` for the keys) or as any object with those attributes.

Parameters used in this module
------------------------------
=================  ======  =========  ============================================
name               unit    default    meaning
=================  ======  =========  ============================================
distance_m / D     m       25.0       lamp → wall distance along +Z
h_deg, v_deg       deg     –          angular wall position, atan(h/D), atan(v/D)
h_m, v_m           m       –          wall position relative to H-V
lux / E            lx      –          illuminance on the wall
candela / I        cd      –          luminous intensity towards the wall point
lamp_position      m       (0, 0, 0)  lamp position in world coordinates
=================  ======  =========  ============================================
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lightsim.errors import InputError

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


@dataclass(frozen=True)
class WallFrame:
    """Geometry of a wall image: which H/V position (m and deg) each pixel shows.

    Built from the conventions' wall description with :meth:`from_any`. Pixel (row i,
    column j) of a ``(H, W)`` image covers the cell whose **centre** is at
    ``h = h_range_m[0] + (j + 0.5)·Δh``, ``v = v_range_m[1] − (i + 0.5)·Δv`` (row 0 at the
    top, column 0 on the left), relative to the wall centre; ``Δh = (max − min)/W``.
    Coordinates relative to H-V subtract :attr:`hv_offset_m`, the position of the H-V point
    (where the lamp's +Z axis meets the wall) relative to the wall centre.

    Attributes
    ----------
    distance_m : float
        Lamp → wall distance D (m).
    h_range_m, v_range_m : tuple of float
        Wall extent [min, max] in m relative to the wall centre.
    resolution : tuple of int
        Image size (W, H) in pixels.
    hv_offset_m : tuple of float
        H-V point relative to the wall centre (m), (0, 0) when the wall is centred on the
        lamp axis.
    """

    distance_m: float
    h_range_m: tuple[float, float]
    v_range_m: tuple[float, float]
    resolution: tuple[int, int]
    hv_offset_m: tuple[float, float] = (0.0, 0.0)
    extra: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def from_any(cls, frame: Any, lamp_position: Sequence[float] = (0.0, 0.0, 0.0)
                 ) -> WallFrame:
        """Make a :class:`WallFrame` from a dict (``summary.json["wall"]``) or an object.

        Recognised keys/attributes: ``distance_m``, ``h_range_m``, ``v_range_m``,
        ``resolution`` ([W, H]) and optionally ``centre``, ``h_axis``, ``v_axis``,
        ``normal`` (world vectors) from which the H-V offset is computed for a lamp at
        ``lamp_position`` (m) shining along +Z. Without ``distance_m`` the distance is
        taken from ``centre``/``normal``.

        Raises
        ------
        InputError
            If a required key is missing or malformed.
        """
        if isinstance(frame, WallFrame):
            return frame
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
        for key in ("h_range_m", "v_range_m", "resolution"):
            if get(key, None) is None:
                raise InputError(f"wall frame: missing '{key}'")
        h_range = _pair(get("h_range_m"), "h_range_m")
        v_range = _pair(get("v_range_m"), "v_range_m")
        res = np.asarray(get("resolution"), dtype=float).reshape(-1)
        if res.shape != (2,) or np.any(res < 1) or np.any(res != np.round(res)):
            raise InputError(f"wall frame: 'resolution' must be [W, H] pixels, "
                             f"got {get('resolution')!r}")
        offset = (0.0, 0.0)
        if centre is not None and h_axis is not None and v_axis is not None:
            n = normal if normal is not None else np.cross(h_axis, v_axis)
            denom = float(n[2])  # n · e_z, the lamp axis
            if abs(denom) < 1e-9:
                raise InputError("wall frame: the wall is parallel to the lamp axis (+Z)")
            t = float(np.dot(n, centre - lamp)) / denom
            hv_point = lamp + t * np.array([0.0, 0.0, 1.0])
            rel = hv_point - centre
            offset = (float(np.dot(rel, h_axis)), float(np.dot(rel, v_axis)))
        extra = dict(frame) if isinstance(frame, Mapping) else {}
        return cls(distance_m=dist, h_range_m=h_range, v_range_m=v_range,
                   resolution=(int(res[0]), int(res[1])), hv_offset_m=offset, extra=extra)

    # ---- pixel grid -------------------------------------------------------------------
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
        return ((self.h_range_m[1] - self.h_range_m[0]) / self.width,
                (self.v_range_m[1] - self.v_range_m[0]) / self.height)

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

    def extent_deg(self) -> tuple[float, float, float, float]:
        """Angular extent of the image edges (h_min, h_max, v_min, v_max) in degrees."""
        h = np.array(self.h_range_m) - self.hv_offset_m[0]
        v = np.array(self.v_range_m) - self.hv_offset_m[1]
        hd = deg_from_wall_m(h, self.distance_m)
        vd = deg_from_wall_m(v, self.distance_m)
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
    from scipy.ndimage import map_coordinates

    wf = WallFrame.from_any(frame)
    intensity = wf.intensity_image(lux)
    h, v = np.broadcast_arrays(np.asarray(h_deg, float), np.asarray(v_deg, float))
    row, col = wf.pixel_of(wall_m_from_deg(h, wf.distance_m), wall_m_from_deg(v, wf.distance_m))
    inside = (row >= -1e-9) & (row <= wf.height - 1 + 1e-9) & (col >= -1e-9) & (
        col <= wf.width - 1 + 1e-9)
    out = map_coordinates(intensity, [row.ravel(), col.ravel()], order=1, mode="nearest")
    out = out.reshape(h.shape)
    return np.where(inside, out, outside)
