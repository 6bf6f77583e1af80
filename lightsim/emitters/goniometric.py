"""A goniometric point source: photons from one point, directions from an intensity table.

The intensity is the bilinear interpolant of a polar web of candela values
(:class:`~lightsim.emitters.polar.PolarTable`: IES Types A, B, C and EULUMDAT all map onto
it); directions are drawn exactly from I(direction)/Φ (:func:`~lightsim.emitters.polar.
sample_table`): u[:, 0] picks the plane angle, u[:, 1] the polar angle. The map is
continuous and monotone in both, so Halton points stay well distributed.

==============  =====  ==========================================================
parameter       unit   meaning
==============  =====  ==========================================================
``position``    m      (3,) where every photon starts
``table``       cd     :class:`~lightsim.emitters.polar.PolarTable` (angles in degrees,
                       world frame of the web)
``flux_lm``     lm     the source's flux (usually ``table.total_flux()``)
``name``        –      for :meth:`describe`
==============  =====  ==========================================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lightsim.emitters.polar import PolarTable, sample_table


@dataclass
class GoniometricEmitter:
    """A point source with a measured intensity distribution (see the module docstring)."""

    position: np.ndarray
    table: PolarTable
    flux_lm: float
    name: str = "goniometric source"

    def __post_init__(self) -> None:
        self.position = np.asarray(self.position, dtype=np.float64).reshape(3)

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins (all ``position``, m) and unit directions for sample points u (n, ≥ 2)."""
        u = np.asarray(u, dtype=np.float64)
        directions = sample_table(self.table, u[:, 0], u[:, 1])[2]
        return np.broadcast_to(self.position, directions.shape).copy(), directions

    def describe(self) -> str:
        return f"{self.name}: point source, {self.flux_lm:.6g} lm from an intensity table"
