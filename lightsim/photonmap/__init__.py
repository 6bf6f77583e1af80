"""Photon maps: spatial indices over photons and kNN density estimation (numba).

Structures (Günther, Wald & Slusallek 2004, sections 5.2–5.4 and Table 5):

* :class:`KdTree` — spatial-middle split, unbalanced, incremental insertion (the default);
* :class:`MedianKdTree` — median split, balanced (the classic baseline);
* :class:`UniformGrid` — cell-sorted photons with a 4-byte start table, hashed when large;
* :class:`HashGrid` — fixed-radius hashed grid (the IGI baseline).

:class:`PhotonMap` wraps one of them and turns photons into power per m² at query points.
Units: positions and radii in m, photon power Φ in lm (or any power unit), estimates in
that unit per m².
"""

from lightsim.photonmap.common import KERNELS, Estimate, RadiusNeighbours
from lightsim.photonmap.density import STRUCTURES, PhotonMap
from lightsim.photonmap.grid import GRID_PRESETS, UniformGrid
from lightsim.photonmap.hashgrid import HashGrid
from lightsim.photonmap.kdtree import DEFAULT_LEAF_SIZE, KdTree
from lightsim.photonmap.median import MedianKdTree

__all__ = [
    "DEFAULT_LEAF_SIZE",
    "GRID_PRESETS",
    "KERNELS",
    "STRUCTURES",
    "Estimate",
    "HashGrid",
    "KdTree",
    "MedianKdTree",
    "PhotonMap",
    "RadiusNeighbours",
    "UniformGrid",
]
