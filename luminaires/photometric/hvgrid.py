"""IES Type A and Type B goniometer grids of luminous intensity (cd): (H, V) tables.

LM-63-2002 (§3, definitions) fixes the two systems; both list horizontal angles H
"clockwise" and vertical angles V, ``candela[h][v]`` per horizontal angle:

* **Type A** (vehicle headlamps and signal lamps): "the planes are all vertical and share a
  common vertical axis" (as in Type C); *photometric horizontal* is H = 0°, V = 0° and
  *photometric zero* (straight down) H = 0°, V = −90°. So H is the azimuth of the vertical
  plane, V the elevation within it: in lightsim's axes (+Z ahead, +Y up, the driver's right
  −X) ``d = (−cos V sin H, sin V, cos V cos H)`` — **H > 0 to the right, V > 0 up**, and
  dΩ = cos V dV dH. Type A (H, V) is Type C with C = −H mod 360°, γ = 90° + V (a project
  measurement on a real low-beam file agrees, see docs/reference/conventions.md).
* **Type B** (floodlights): "the planes share a common horizontal axis"; photometric zero
  (straight down) is H = 0°, V = 0° and photometric horizontal H = 0°, V = 90°. So V is the
  angle of the plane about the horizontal (lateral) axis, from the nadir towards ahead, and
  H the angle within the plane towards that axis (H > 0 to the right):
  ``d = (−sin H, −cos H cos V, cos H sin V)``, dΩ = cos H dH dV. As LM-63 defines it, a Type
  B beam around H = V = 0° points *down*; lightsim places it so and does not re-aim it.

Symmetry (LM-63-2002): first H = 0° (last 90°) means the lamp is laterally symmetric about
the vertical reference plane, I(−H, V) = I(H, V), and the reader mirrors it; first H = −90°
(last 90°) is a full table. LM-63 defines no vertical symmetry: a V list 0…90° means no data
(zero intensity) below V = 0, as a Type C γ list 0…90° does above the horizontal. Real
headlamp files often cover less than ±90° (e.g. H ±60°, V ±12.6°); outside the listed range
the intensity is zero.

Interpolation is bilinear in (H, V) — the table's own angles — and :meth:`HVGrid.total_flux`
is its exact integral; sampling draws from the same interpolant (see
:mod:`~lightsim.emitters.polar`).

Parameters
----------
================  =====  =======  ============================================================
name              unit   default  meaning
================  =====  =======  ============================================================
h_deg             deg    –        (nH,) horizontal angles, strictly increasing in [−90, 90]
v_deg             deg    –        (nV,) vertical angles, strictly increasing in [−90, 90]
candela           cd     –        (nH, nV) intensities ≥ 0 (one row per horizontal angle)
photometric_type  –      "A"      "A" or "B"
lamp_lumens       lm     None     rated flux of the lamp(s); None = absolute photometry
metadata          –      {}       free text (manufacturer, luminaire, test, …)
warnings          –      ()       what the reader repaired, one line each
================  =====  =======  ============================================================
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lightsim.emitters.polar import PolarTable
from lightsim.errors import InputError
from lightsim.wall import WallFrame, lux_from_candela

from .candela import direction_from_hv
from .checks import freeze_grid

__all__ = ["HVGrid", "hv_directions"]

_FRAMES = {  # pole (θ = 0), e0 (φ = 0°), e1 (φ = 90°) in world axes
    "A": (np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([-1.0, 0.0, 0.0])),
    "B": (np.array([-1.0, 0.0, 0.0]), np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0])),
}


def hv_directions(h_deg: ArrayLike, v_deg: ArrayLike, photometric_type: str = "A") -> NDArray:
    """World unit directions (…, 3) of Type A or B angles (degrees), per the module axes."""
    h = np.radians(np.asarray(h_deg, dtype=float))
    v = np.radians(np.asarray(v_deg, dtype=float))
    h, v = np.broadcast_arrays(h, v)
    if photometric_type == "A":
        return np.stack([-np.cos(v) * np.sin(h), np.sin(v), np.cos(v) * np.cos(h)], axis=-1)
    if photometric_type == "B":
        return np.stack([-np.sin(h), -np.cos(h) * np.cos(v), np.cos(h) * np.sin(v)], axis=-1)
    raise InputError(f"photometric type must be 'A' or 'B', got {photometric_type!r}")


@dataclass(frozen=True)
class HVGrid:
    """Luminous intensity (cd) on a Type A or Type B (H, V) grid; axes in the module docstring.

    Attributes
    ----------
    h_deg, v_deg : ndarray
        Horizontal and vertical angles in degrees, strictly increasing within [−90, 90].
    candela : ndarray, shape (nH, nV)
        Intensity in cd.
    photometric_type : {"A", "B"}
    lamp_lumens : float or None
        Rated lamp flux in lm (None: absolute photometry).
    metadata : mapping of str to str
    warnings : tuple of str
    """

    h_deg: NDArray
    v_deg: NDArray
    candela: NDArray
    photometric_type: str = "A"
    lamp_lumens: float | None = None
    metadata: Mapping[str, str] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        h = np.array(self.h_deg, dtype=float).reshape(-1)
        v = np.array(self.v_deg, dtype=float).reshape(-1)
        cd = np.array(self.candela, dtype=float)
        kind = self.photometric_type
        if kind not in ("A", "B"):
            raise InputError(f"H/V grid: photometric type must be 'A' or 'B', got {kind!r}")
        if h.size < 2 or v.size < 2:
            raise InputError(f"Type {kind} grid needs at least two horizontal and two vertical "
                             "angles")
        if not (np.all(np.isfinite(h)) and np.all(np.isfinite(v))):
            raise InputError(f"Type {kind} grid: angles must be finite")
        for name, a in (("horizontal", h), ("vertical", v)):
            if np.any(np.diff(a) <= 0) or a[0] < -90 or a[-1] > 90:
                raise InputError(f"Type {kind} grid: {name} angles must increase strictly "
                                 "within [−90°, 90°]")
        freeze_grid(self, f"Type {kind} grid", {"h_deg": h, "v_deg": v}, cd,
                    "horizontal × vertical angles")

    # ---- the table -----------------------------------------------------------------------
    @cached_property
    def table(self) -> PolarTable:
        """The grid as a polar web (Type A: φ = H, θ = 90° + V; Type B: φ = V, θ = 90° − H)."""
        pole, e0, e1 = _FRAMES[self.photometric_type]
        if self.photometric_type == "A":
            return PolarTable(self.h_deg, 90.0 + self.v_deg, self.candela, False, pole, e0, e1)
        return PolarTable(self.v_deg, (90.0 - self.h_deg)[::-1],
                          np.ascontiguousarray(self.candela[::-1].T), False, pole, e0, e1)

    @property
    def shape(self) -> tuple[int, int]:
        """(nH, nV)."""
        return self.candela.shape  # type: ignore[return-value]

    def total_flux(self) -> float:
        """Luminous flux (lm): the exact ∫ I dΩ of the bilinear interpolant."""
        return self.table.total_flux()

    def node_solid_angles(self) -> NDArray:
        """Each node's share Ω (sr) of the integral, shape (nH, nV): Σ candela·Ω = flux."""
        w = self.table.node_weights()
        return w if self.photometric_type == "A" else w.T[::-1]

    def downward_flux_fraction(self) -> float:
        """Share (0…1) of the flux going below the horizontal."""
        total = self.total_flux()
        if total <= 0:
            return 0.0
        if self.photometric_type == "B":
            return 1.0  # every Type B direction has y = −cos H cos V ≤ 0
        return float(self.table.flux_below(90.0) / total)

    def max_candela(self) -> float:
        """Peak intensity in cd."""
        return float(self.candela.max())

    def scaled(self, factor: float) -> HVGrid:
        """A copy with intensities (and lamp lumens) multiplied by ``factor``."""
        lm = None if self.lamp_lumens is None else self.lamp_lumens * factor
        return HVGrid(self.h_deg, self.v_deg, self.candela * factor, self.photometric_type, lm,
                      dict(self.metadata), self.warnings)

    # ---- evaluation ----------------------------------------------------------------------
    def directions(self, h_deg: ArrayLike, v_deg: ArrayLike) -> NDArray:
        """World unit directions of this grid's (H, V) angles in degrees."""
        return hv_directions(h_deg, v_deg, self.photometric_type)

    def intensity(self, h_deg: ArrayLike, v_deg: ArrayLike) -> NDArray:
        """Intensity (cd) at the file's own (H, V) angles, bilinear; 0 outside the table."""
        h = np.asarray(h_deg, dtype=float)
        v = np.asarray(v_deg, dtype=float)
        if self.photometric_type == "A":
            return self.table.evaluate(h, 90.0 + v)
        return self.table.evaluate(v, 90.0 - h)

    def intensity_towards(self, directions: ArrayLike) -> NDArray:
        """Intensity (cd) towards world directions (…, 3)."""
        return self.table.evaluate_towards(directions)

    def intensity_hv(self, h_deg: ArrayLike, v_deg: ArrayLike) -> NDArray:
        """Intensity (cd) towards *wall* angles (h_deg = atan(h/D), v_deg = atan(v/D))."""
        return self.intensity_towards(direction_from_hv(h_deg, v_deg))

    def wall_lux(self, frame: Any) -> NDArray:
        """Illuminance (lx) this lamp, at the origin, gives on a wall image (H, W)."""
        wf = WallFrame.from_any(frame)
        hm, vm = np.meshgrid(wf.h_m(), wf.v_m())
        d = np.stack([-hm, vm, np.full_like(hm, wf.distance_m)], axis=-1)
        return lux_from_candela(self.intensity_towards(d), hm, vm, wf.distance_m)

    def summary(self) -> dict[str, Any]:
        """JSON-ready description: type, grid size and range, peak cd, flux, lamp lumens."""
        return {"photometric_type": self.photometric_type,
                "horizontal_angles": int(self.shape[0]), "vertical_angles": int(self.shape[1]),
                "h_range_deg": [float(self.h_deg[0]), float(self.h_deg[-1])],
                "v_range_deg": [float(self.v_deg[0]), float(self.v_deg[-1])],
                "max_cd": self.max_candela(), "total_flux_lm": self.total_flux(),
                "lamp_lumens": self.lamp_lumens, "metadata": dict(self.metadata)}
