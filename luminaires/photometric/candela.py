"""Type C goniometer grids of luminous intensity (cd): the far field of a lamp.

Axes (binding for every photometric file lightsim reads or writes). The lamp shines along
world **+Z** with **+Y** up (glTF axes, ``docs/reference/conventions.md``). Type C angles are:

* **γ** (gamma, 0…180°): the polar angle from the **nadir −Y**; γ = 90° is horizontal,
  γ = 180° the zenith +Y;
* **C** (0…360°): the azimuth of the vertical half-plane, measured about +Y,
  counter-clockwise seen from above (right-hand rule about +Y), **C = 0° straight ahead
  (+Z)**, C = 90° towards +X (the driver's **left**, since H is world −X), C = 270° towards
  −X (the driver's right, H > 0).

So the unit direction of (C, γ) is ``(sin γ·sin C, −cos γ, sin γ·cos C)`` and straight
ahead (H-V) is C = 0°, γ = 90°. A wall position (h_deg, v_deg) is the direction
``(−tan h, tan v, 1)/‖·‖`` (see :func:`direction_from_hv`).

Interpolation. Between nodes the intensity is **bilinear in (C, γ)** (C periodic), zero
outside [γ_first, γ_last]: :meth:`CandelaGrid.intensity` (and ``intensity_towards`` /
``intensity_hv``) return exactly that interpolant, :meth:`CandelaGrid.total_flux` is its
exact integral and :func:`~lightsim.luminaires.photometric.sampling.sample_directions` draws
directions from it (see :mod:`~lightsim.emitters.polar`), so the far field
of a simulated point source converges to ``intensity`` itself. :meth:`node_solid_angles`
gives each node's share Ω (sr) of that integral, ``total_flux = Σ I·Ω``. The older cells
halfway between nodes (:meth:`solid_angles`, :meth:`cell_flux`) remain for reference: the
midpoint rule other tools (e.g. photompy's ``total_optical_power``) use.

Parameters
----------
============  ======  ========  ============================================================
name          unit    default   meaning
============  ======  ========  ============================================================
c_deg         deg     –         C-plane angles, strictly increasing in [0, 360)
gamma_deg     deg     –         γ angles, strictly increasing in [0, 180]
candela       cd      –         (nC, nG) intensities, ≥ 0
lamp_lumens   lm      None      rated flux of the lamp(s) (IES "lumens per lamp" × lamps);
                                None = absolute photometry
metadata      –       {}        free text (manufacturer, luminaire, test, …)
============  ======  ========  ============================================================
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

from .checks import freeze_grid

__all__ = [
    "CandelaGrid",
    "angles_from_directions",
    "direction_from_hv",
    "directions_from_angles",
    "hv_from_directions",
]


def directions_from_angles(c_deg: ArrayLike, gamma_deg: ArrayLike) -> NDArray:
    """Unit world directions (…, 3) of Type C angles (deg), per the module's axes."""
    c = np.radians(np.asarray(c_deg, dtype=float))
    g = np.radians(np.asarray(gamma_deg, dtype=float))
    c, g = np.broadcast_arrays(c, g)
    sg = np.sin(g)
    return np.stack([sg * np.sin(c), -np.cos(g), sg * np.cos(c)], axis=-1)


def angles_from_directions(directions: ArrayLike) -> tuple[NDArray, NDArray]:
    """Type C angles (C in [0, 360), γ in [0, 180]) in degrees of world directions (…, 3).

    Directions need not be normalised; zero vectors give γ = 90°, C = 0°.
    """
    d = np.asarray(directions, dtype=float)
    norm = np.linalg.norm(d, axis=-1)
    norm = np.where(norm > 0, norm, 1.0)
    y = np.clip(-d[..., 1] / norm, -1.0, 1.0)
    gamma = np.degrees(np.arccos(y))
    c = np.degrees(np.arctan2(d[..., 0], d[..., 2])) % 360.0
    c = np.where(c >= 360.0, 0.0, c)
    return c, gamma


def direction_from_hv(h_deg: ArrayLike, v_deg: ArrayLike) -> NDArray:
    """Unit world direction (…, 3) towards the wall position (h_deg, v_deg).

    H (driver's right) is world −X, V is +Y, the lamp axis +Z:
    ``(−tan h, tan v, 1)`` normalised.
    """
    th = np.tan(np.radians(np.asarray(h_deg, dtype=float)))
    tv = np.tan(np.radians(np.asarray(v_deg, dtype=float)))
    th, tv = np.broadcast_arrays(th, tv)
    d = np.stack([-th, tv, np.ones_like(th)], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def hv_from_directions(directions: ArrayLike) -> tuple[NDArray, NDArray]:
    """Wall angles (h_deg, v_deg) of forward world directions (z > 0), in degrees."""
    d = np.asarray(directions, dtype=float)
    z = d[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.degrees(np.arctan(-d[..., 0] / z))
        v = np.degrees(np.arctan(d[..., 1] / z))
    bad = ~(z > 0)
    return np.where(bad, np.nan, h), np.where(bad, np.nan, v)


def _c_edges(c: NDArray) -> NDArray:
    if len(c) == 1:
        return np.array([c[0] - 180.0, c[0] + 180.0])
    first = 0.5 * (c[-1] - 360.0 + c[0])
    return np.concatenate([[first], 0.5 * (c[1:] + c[:-1]), [first + 360.0]])


def _gamma_edges(g: NDArray) -> NDArray:
    return np.concatenate([[g[0]], 0.5 * (g[1:] + g[:-1]), [g[-1]]])


@dataclass(frozen=True)
class CandelaGrid:
    """Luminous intensity (cd) on a Type C grid; axes in the module docstring.

    Attributes
    ----------
    c_deg : ndarray, shape (nC,)
        C-plane angles in degrees, strictly increasing in [0, 360). A single plane means a
        rotationally symmetric distribution.
    gamma_deg : ndarray, shape (nG,)
        γ angles in degrees, strictly increasing in [0, 180], nG ≥ 2. The intensity is zero
        outside [γ_first, γ_last].
    candela : ndarray, shape (nC, nG)
        Intensity in cd (absolute, not per klm).
    lamp_lumens : float or None
        Rated lamp flux in lm (None for absolute photometry).
    metadata : mapping of str to str
        Descriptive fields (``manufacturer``, ``luminaire``, ``test``, ``lamp``, …).
    warnings : tuple of str
        What the reader repaired or noticed (one line each; shown by the CLI).
    """

    c_deg: NDArray
    gamma_deg: NDArray
    candela: NDArray
    lamp_lumens: float | None = None
    metadata: Mapping[str, str] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    photometric_type = "C"

    def __post_init__(self) -> None:
        c = np.array(self.c_deg, dtype=float).reshape(-1)  # copies: we freeze them below
        g = np.array(self.gamma_deg, dtype=float).reshape(-1)
        cd = np.array(self.candela, dtype=float)
        if c.size < 1 or g.size < 2:
            raise InputError("candela grid needs at least one C-plane and two γ angles")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(g))):
            raise InputError("candela grid: angles must be finite")
        if np.any(np.diff(c) <= 0) or c[0] < 0 or c[-1] >= 360:
            raise InputError("candela grid: C angles must increase strictly within [0, 360)")
        if np.any(np.diff(g) <= 0) or g[0] < 0 or g[-1] > 180:
            raise InputError("candela grid: γ angles must increase strictly within [0, 180]")
        freeze_grid(self, "candela grid", {"c_deg": c, "gamma_deg": g}, cd,
                    "C planes × γ angles")

    @cached_property
    def table(self) -> PolarTable:
        """The grid as a polar web: pole −Y (γ = 0), C = 0° → +Z, C = 90° → +X."""
        return PolarTable(self.c_deg, self.gamma_deg, self.candela, True,
                          np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0]),
                          np.array([1.0, 0.0, 0.0]))

    # ---- cells and integrals -----------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        """(nC, nG)."""
        return self.candela.shape  # type: ignore[return-value]

    def c_edges_deg(self) -> NDArray:
        """C cell edges in degrees, shape (nC + 1,), covering exactly 360° (may start < 0)."""
        return _c_edges(self.c_deg)

    def gamma_edges_deg(self) -> NDArray:
        """γ cell edges in degrees, shape (nG + 1,), from γ_first to γ_last."""
        return _gamma_edges(self.gamma_deg)

    def node_solid_angles(self) -> NDArray:
        """Each node's share Ω (sr) of the interpolant's integral, shape (nC, nG):
        ``total_flux() == Σ candela·Ω``; Ω sums to the covered band."""
        return self.table.node_weights()

    def cell_flux(self) -> float:
        """Σ I·ΔΩ over the midpoint cells (lm): the rule of photompy's total_optical_power."""
        return float(np.sum(self.candela * self.solid_angles()))

    def solid_angles(self) -> NDArray:
        """Solid angle of every midpoint cell in sr, shape (nC, nG); sums to the band."""
        dc = np.radians(np.diff(self.c_edges_deg()))
        ge = np.radians(self.gamma_edges_deg())
        band = np.cos(ge[:-1]) - np.cos(ge[1:])
        return dc[:, None] * band[None, :]

    def total_flux(self) -> float:
        """Luminous flux (lm) leaving the luminaire: the exact ∫ I dΩ of the interpolant."""
        return self.table.total_flux()

    def downward_flux_fraction(self) -> float:
        """Share (0…1) of the flux going below the horizontal (γ < 90°)."""
        total = self.total_flux()
        if total <= 0:
            return 0.0
        return float(self.table.flux_below(90.0) / total)

    def max_candela(self) -> float:
        """Peak intensity in cd."""
        return float(self.candela.max())

    def scaled(self, factor: float) -> CandelaGrid:
        """A copy with intensities (and lamp lumens) multiplied by ``factor``."""
        lm = None if self.lamp_lumens is None else self.lamp_lumens * factor
        return CandelaGrid(self.c_deg, self.gamma_deg, self.candela * factor, lm,
                           dict(self.metadata), self.warnings)

    # ---- evaluation -------------------------------------------------------------------
    def intensity(self, c_deg: ArrayLike, gamma_deg: ArrayLike) -> NDArray:
        """Intensity (cd) at Type C angles, bilinear between nodes (C periodic).

        Outside [γ_first, γ_last] the intensity is 0.
        """
        return self.table.evaluate(c_deg, gamma_deg)

    def intensity_towards(self, directions: ArrayLike) -> NDArray:
        """Intensity (cd) towards world directions (…, 3)."""
        return self.table.evaluate_towards(directions)

    def intensity_hv(self, h_deg: ArrayLike, v_deg: ArrayLike) -> NDArray:
        """Intensity (cd) towards wall angles (h_deg, v_deg) in degrees."""
        return self.intensity_towards(direction_from_hv(h_deg, v_deg))

    def wall_lux(self, frame: Any) -> NDArray:
        """Illuminance (lx) this lamp, placed at the origin, gives on a wall image.

        Parameters
        ----------
        frame : WallFrame or mapping
            Wall description (see ``lightsim.wall.WallFrame``).

        Returns
        -------
        ndarray, shape (H, W)
            ``E = I·D / r³`` at the pixel centres.
        """
        wf = WallFrame.from_any(frame)
        hm, vm = np.meshgrid(wf.h_m(), wf.v_m())
        d = np.stack([-hm, vm, np.full_like(hm, wf.distance_m)], axis=-1)
        return lux_from_candela(self.intensity_towards(d), hm, vm, wf.distance_m)

    def summary(self) -> dict[str, Any]:
        """JSON-ready description: grid size, peak cd, flux (lm), lamp lumens, metadata."""
        return {"photometric_type": "C",
                "c_planes": int(self.shape[0]), "gamma_angles": int(self.shape[1]),
                "gamma_range_deg": [float(self.gamma_deg[0]), float(self.gamma_deg[-1])],
                "max_cd": self.max_candela(), "total_flux_lm": self.total_flux(),
                "lamp_lumens": self.lamp_lumens, "metadata": dict(self.metadata)}
