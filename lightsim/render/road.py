"""Illuminance on the road (lx) from a lamp's wall pattern: the bird's-eye "road view".

The lamp sits at the origin shining along +Z (``docs/reference/conventions.md``), mounted
``mount_height_m`` above a flat road, the plane y = −height. Its intensity towards
direction (h_deg, v_deg) is derived from the wall lux map: ``I = E·r²/cos θ = E·r³/D`` at
every pixel centre (bilinear between them; :func:`~lightsim.wall.sample_wall`). A road
point at lateral position x (m, to the driver's right, i.e. world −X) and distance z
ahead (m) is seen under ``h = atan(x/z)``, ``v = atan(−height/z)``, at distance
``r = sqrt(x² + height² + z²)``; the road normal is +Y, so the angle of incidence
has ``cos = height / r`` and

    E_road = I·cos(incidence) / r² = I·height / r³   (lx).

Road points whose direction lies outside the wall image are NaN (unknown), not 0. Any
intensity function can be used instead of a wall map (:func:`road_illuminance_from`), e.g.
``CandelaGrid.intensity_hv`` of an IES file.

Parameters
----------
==============  =====  ============  ===============================================
name            unit   default       meaning
==============  =====  ============  ===============================================
lux             lx     –             wall illuminance image (H, W), row 0 on top
frame           –      –             wall frame (``WallFrame`` or its dict)
mount_height_m  m      0.65          lamp height above the road
x_range_m       m      (−15, 15)     lateral extent of the view (right positive)
z_range_m       m      (0, 100)      distance ahead covered
resolution_m    m      0.25          road grid step
level_lux       lx     1.0           iso-lux level of :meth:`RoadIlluminance.reach_m`
REACH_LEVELS    lx     1, 3, 10      levels whose reach is printed and in summary.json
==============  =====  ============  ===============================================
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lightsim.errors import InputError
from lightsim.wall import sample_wall

__all__ = ["REACH_LEVELS", "RoadIlluminance", "road_illuminance", "road_illuminance_from"]

REACH_LEVELS = (1.0, 3.0, 10.0)
"""Iso-lux levels (lx) whose reach down the road an engineer quotes."""


@dataclass(frozen=True)
class RoadIlluminance:
    """Road illuminance on a grid.

    Attributes
    ----------
    x_m : ndarray, shape (nx,)
        Lateral positions (m), positive to the driver's right.
    z_m : ndarray, shape (nz,)
        Distances ahead of the lamp (m), > 0.
    lux : ndarray, shape (nz, nx)
        Illuminance on the road in lx (NaN where the intensity is unknown).
    mount_height_m : float
        Lamp height above the road (m).
    """

    x_m: NDArray
    z_m: NDArray
    lux: NDArray
    mount_height_m: float

    def reach_m(self, level_lux: float = 1.0) -> float | None:
        """Farthest distance ahead (m) where the road gets at least ``level_lux`` lx."""
        lit = np.nan_to_num(self.lux, nan=0.0) >= level_lux
        rows = np.flatnonzero(lit.any(axis=1))
        return float(self.z_m[rows[-1]]) if rows.size else None

    def extent_m(self, distance_m: float, level_lux: float = 1.0
                 ) -> tuple[float, float] | None:
        """Lateral extent (left, right; m, right positive) of the road lit to at least
        ``level_lux`` lx on the grid row nearest ``distance_m`` ahead: its outermost lit
        positions (gaps inside are not subtracted); ``None`` if none of that row is lit."""
        row = int(np.argmin(np.abs(self.z_m - float(distance_m))))
        lit = np.flatnonzero(np.nan_to_num(self.lux[row], nan=0.0) >= level_lux)
        if not lit.size:
            return None
        return float(self.x_m[lit[0]]), float(self.x_m[lit[-1]])

    def lit_box_m(self, level_lux: float = 1.0, margin: float = 0.15
                  ) -> tuple[float, float, float] | None:
        """The view fitted to the road lit to at least ``level_lux`` lx: (left, right, far)
        in m — the lit area's extent widened by ``margin`` of its size, rounded out to
        whole metres (2 m across, 5 m ahead) and kept inside the grid; None if nothing
        is lit."""
        lit = np.nan_to_num(self.lux, nan=0.0) >= level_lux
        if not lit.any():
            return None
        rows, cols = np.flatnonzero(lit.any(axis=1)), np.flatnonzero(lit.any(axis=0))
        far = float(self.z_m[rows[-1]])
        x0, x1 = float(self.x_m[cols[0]]), float(self.x_m[cols[-1]])
        half = max(abs(x0), abs(x1), 1.0) * (1.0 + margin)
        half = min(2.0 * np.ceil(half / 2.0), max(abs(self.x_m[0]), abs(self.x_m[-1])))
        far = min(5.0 * np.ceil(max(far * (1.0 + margin), 5.0) / 5.0), float(self.z_m[-1]))
        return -float(half), float(half), float(far)

    def reach_text(self, levels: tuple[float, ...] = REACH_LEVELS) -> str:
        """One line, e.g. ``reach 1 lx 61 m, 3 lx 42 m, 10 lx 25 m`` ("–": never
        reached; "≥ 100 m": still lit at the far end of the view)."""
        far = float(self.z_m[-1])
        parts = []
        for lv in levels:
            r = self.reach_m(lv)
            txt = "–" if r is None else (f"≥ {far:.0f} m" if r >= far else f"{r:.0f} m")
            parts.append(f"{lv:g} lx {txt}")
        return "reach " + ", ".join(parts)

    def summary(self, levels: tuple[float, ...] = (1.0, 3.0, 5.0, 10.0, 20.0)
                ) -> dict[str, Any]:
        """JSON-ready: mount height, grid, max lux and the reach (m) of each iso-lux level."""
        return {"mount_height_m": self.mount_height_m,
                "x_range_m": [float(self.x_m[0]), float(self.x_m[-1])],
                "z_range_m": [float(self.z_m[0]), float(self.z_m[-1])],
                "max_lux": float(np.nanmax(self.lux)) if np.isfinite(self.lux).any() else None,
                "reach_m": {f"{lv:g}": self.reach_m(lv) for lv in levels}}


def _grid(x_range_m: tuple[float, float], z_range_m: tuple[float, float],
          resolution_m: float) -> tuple[NDArray, NDArray]:
    if not resolution_m > 0:
        raise InputError(f"road view: resolution_m must be > 0, got {resolution_m!r}")
    x0, x1 = (float(v) for v in x_range_m)
    z0, z1 = (float(v) for v in z_range_m)
    if not (x1 > x0 and z1 > max(z0, 0.0)):
        raise InputError("road view: need x_range_m min < max and z_range_m max > 0")
    x = np.arange(x0, x1 + 0.5 * resolution_m, resolution_m)
    z = np.arange(max(z0, resolution_m), z1 + 0.5 * resolution_m, resolution_m)
    return x, z


def road_illuminance_from(intensity_hv: Callable[[NDArray, NDArray], ArrayLike],
                          mount_height_m: float = 0.65,
                          x_range_m: tuple[float, float] = (-15.0, 15.0),
                          z_range_m: tuple[float, float] = (0.0, 100.0),
                          resolution_m: float = 0.25) -> RoadIlluminance:
    """Road illuminance (lx) from any intensity function ``I(h_deg, v_deg)`` in cd.

    Parameters
    ----------
    intensity_hv : callable
        Takes arrays of wall angles h_deg, v_deg (degrees) and returns cd (NaN = unknown).
    mount_height_m, x_range_m, z_range_m, resolution_m
        See the module's parameter table.
    """
    height = float(mount_height_m)
    if not height > 0:
        raise InputError(f"road view: mount_height_m must be > 0, got {mount_height_m!r}")
    x, z = _grid(x_range_m, z_range_m, resolution_m)
    X, Z = np.meshgrid(x, z)
    h_deg = np.degrees(np.arctan2(X, Z))
    v_deg = np.degrees(np.arctan2(-height, Z))
    intensity = np.asarray(intensity_hv(h_deg, v_deg), dtype=float).reshape(X.shape)
    r2 = X * X + height * height + Z * Z
    lux = intensity * height / (r2 * np.sqrt(r2))
    return RoadIlluminance(x, z, lux, height)


def road_illuminance(lux: ArrayLike, frame: Any, mount_height_m: float = 0.65,
                     x_range_m: tuple[float, float] = (-15.0, 15.0),
                     z_range_m: tuple[float, float] = (0.0, 100.0),
                     resolution_m: float = 0.25) -> RoadIlluminance:
    """Road illuminance (lx) of the lamp whose wall lux map is ``lux``.

    Parameters
    ----------
    lux : array_like, shape (H, W)
        Wall illuminance in lx.
    frame : WallFrame or mapping
        The wall frame.
    mount_height_m, x_range_m, z_range_m, resolution_m
        See the module's parameter table.

    Returns
    -------
    RoadIlluminance
        NaN where the road direction is not on the wall image.
    """
    return road_illuminance_from(lambda h, v: sample_wall(lux, frame, h, v),
                                 mount_height_m, x_range_m, z_range_m, resolution_m)
