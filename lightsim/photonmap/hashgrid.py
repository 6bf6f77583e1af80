"""Fixed-radius hashed grid: the "hashed photon mapping" of Instant Global Illumination.

Wald, Kollig, Benthin, Keller & Slusallek (2002), as discussed by Günther, Wald & Slusallek
(2004, section 2.1): density estimation with a *fixed* query radius R instead of the k
nearest photons. Photons are hashed into cells of edge R, so the ball of radius R around
any query touches at most 2 × 2 × 2 cells; the estimate is fast but does not adapt to the
photon density (blurry caustics where photons are dense, noise where they are sparse).

This is the baseline the paper improves on; it is a
:class:`~lightsim.photonmap.grid.UniformGrid` with cell size R that is always hashed
(table of 2^⌈log₂ 2n⌉ buckets, 4 bytes each, cell keys filter collisions).

Parameters (constructor)
------------------------
=============  =====  ========  =======================================================
name           unit   default   meaning
=============  =====  ========  =======================================================
``radius``     m      —         fixed query radius R (> 0, finite) = cell size
``positions``  m      None      (n, 3) photon positions (NaN/inf rejected)
``normals``    —      None      (n, 3) photon normals (for the normal filter)
``powers``     lm     None      (n, C) photon powers Φ
``channels``   —      1         number of power channels C
=============  =====  ========  =======================================================
"""

from __future__ import annotations

import numpy as np

from lightsim.errors import InputError
from lightsim.photonmap.common import Estimate, RadiusNeighbours, check_radius
from lightsim.photonmap.grid import UniformGrid


class HashGrid(UniformGrid):
    """Hashed grid with cell size = the fixed query radius R (m); fixed-radius queries."""

    def __init__(self, radius: float, positions: np.ndarray | None = None,
                 normals: np.ndarray | None = None, powers: np.ndarray | None = None, *,
                 channels: int = 1) -> None:
        r = check_radius(radius, "radius", allow_inf=False)
        if r <= 0:
            raise InputError("the hashed grid's radius must be > 0 m")
        self.radius = r
        # max_cells = 0: always hashed, whatever the extent
        super().__init__(positions, normals, powers, cell_size=r, max_cells=0,
                         channels=channels)

    def query_radius(self, points: np.ndarray, radius: float | None = None, *,
                     normals: np.ndarray | None = None, normal_cos: float = 0.5,
                     ) -> RadiusNeighbours:
        """All photons within ``radius`` (default: the grid's R, m) of each query point."""
        return super().query_radius(points, self.radius if radius is None else radius,
                                    normals=normals, normal_cos=normal_cos)

    def estimate_radius(self, points: np.ndarray, normals: np.ndarray | None = None, *,
                        radius: float | None = None, kernel: str = "box",
                        normal_cos: float = 0.5) -> Estimate:
        """Fixed-radius density estimate with R = ``radius`` (default: the grid's R, m)."""
        return super().estimate_radius(points, normals,
                                       radius=self.radius if radius is None else radius,
                                       kernel=kernel, normal_cos=normal_cos)
