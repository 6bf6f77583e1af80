"""Photon-map density estimation: the :class:`PhotonMap` every later stage uses.

A photon map stores photons (position, surface normal, power Φ per channel) in one of the
acceleration structures of Günther, Wald & Slusallek (2004, Table 5) and turns them into
a power density (power per m²) at query points by exact k-nearest-neighbour density
estimation [Jensen 1996]. The caller divides E by the number of emitted photons (when Φ is
the lamp's flux) to get illuminance in lux.

Structures
----------
============  ======================================================================
name          structure
============  ======================================================================
``middle``    kd-tree split at the spatial middle, incremental :meth:`PhotonMap.add`
              (:class:`~lightsim.photonmap.kdtree.KdTree`, the paper's choice)
``median``    balanced kd-tree split at the median (baseline; ``add`` rebuilds)
``grid-lo``   uniform grid, ≈ 32 photons per cell (``add`` rebuilds)
``grid-hi``   uniform grid, ≈ 4 photons per cell (``add`` rebuilds)
``hash``      fixed-radius hashed grid (IGI); R = ``max_radius``, k is ignored
============  ======================================================================

Estimate parameters (:meth:`PhotonMap.estimate`)
-----------------------------------------------
================  =====  ========  ===================================================
name              unit   default   meaning
================  =====  ========  ===================================================
``points``        m      —         (Q, 3) query points
``normals``       —      None      (Q, 3) query surface normals (enables the filter)
``k``             —      64        photons per estimate (ignored by ``hash``)
``max_radius``    m      inf       photons farther than this are never used
``min_radius``    m      0         floor of the radius (see below)
``kernel``        —      "box"     ``box``, ``cone`` (k_c = 1) or ``epanechnikov``
``normal_cos``    —      0.5       photons with n_photon · n_query < this are ignored
================  =====  ========  ===================================================

Semantics
---------
* **Normal filter** — with query normals, photons whose stored normal disagrees
  (dot < ``normal_cos``) are not counted and take no neighbour slot: light does not leak
  through a thin wall.
* **Radius** — r = r_k, the distance of the k-th counted photon, if k counted photons lie
  within ``max_radius``; otherwise r = ``max_radius`` with all counted photons inside it;
  with an infinite ``max_radius`` and fewer than k photons in the map, r is the farthest
  counted photon's distance; with none at all E = 0 (r = ``max_radius`` if finite, else 0).
* **min_radius** — whenever that r ≤ ``min_radius``, all counted photons within
  ``min_radius`` are used and r = ``min_radius``. A point focus (r_k → 0) thus gives the
  finite value ΣΦ/(π·min_radius²) (box kernel), and in bright regions the estimate becomes
  a fixed-radius one whose noise falls as 1/√N. The radius never drops below
  ``r_floor = 2⁻²⁰·max(1 m, largest |coordinate|)`` (≈ 8 float32 ulps of the positions), so
  E stays finite even for millions of coincident photons with ``min_radius = 0``.
* **Kernels** (d = photon distance):
  box E = ΣΦ / (πr²) — when r = r_k the k-th photon, which lies on the circle, counts
  half: counting it fully overestimates by k/(k − 1) for independent photons, leaving it
  out underestimates by (k − 1)/k for evenly stratified (quasi-random) ones; half keeps
  either within ±1/(2k); cone E = ΣΦ(1 − d/r) / ((1 − 2/3)πr²);
  Epanechnikov E = ΣΦ·2(1 − d²/r²) / (πr²). Sums are accumulated in float64.
* ``hash`` — a fixed radius R = ``max_radius`` (must be finite), k and ``min_radius`` are
  ignored, r = R.

Results are an :class:`~lightsim.photonmap.common.Estimate`: ``E`` (Q, C) float64 power per
m² (lm/m² for Φ in lm), ``r`` (Q,) float64 radius used (m), ``count`` (Q,) int64 photons
used.
"""

from __future__ import annotations

import numpy as np

from lightsim.errors import InputError
from lightsim.photonmap.common import (
    Estimate,
    as_positions,
    as_powers,
    as_unit_normals,
    check_radius,
)
from lightsim.photonmap.grid import DEFAULT_MAX_CELLS, GRID_PRESETS, UniformGrid
from lightsim.photonmap.hashgrid import HashGrid
from lightsim.photonmap.kdtree import DEFAULT_LEAF_SIZE, KdTree
from lightsim.photonmap.median import MedianKdTree

STRUCTURES = ("middle", "median", "grid-lo", "grid-hi", "hash")


class PhotonMap:
    """Photons in an acceleration structure, with exact kNN density estimates.

    Parameters
    ----------
    structure : str
        One of :data:`STRUCTURES` (default ``"middle"``).
    leaf_size : int
        kd-tree leaf size (photons), for ``middle`` and ``median``.
    channels : int
        Number of power channels C (1 = luminous flux, 3 = RGB).
    photons_per_cell : float, optional
        Overrides the grid preset's photons per cell (``grid-lo``/``grid-hi``).
    max_cells : int
        Grids with more cells are hashed.

    Examples
    --------
    >>> pm = PhotonMap("middle", channels=1)
    >>> pm.add(positions, normals, powers)           # lm per photon
    >>> res = pm.estimate(points, point_normals, k=64, min_radius=0.01)
    >>> lux = res.E[:, 0] / n_emitted                 # if powers are the lamp flux (lm)
    """

    def __init__(self, structure: str = "middle", *, leaf_size: int = DEFAULT_LEAF_SIZE,
                 channels: int = 1, photons_per_cell: float | None = None,
                 max_cells: int = DEFAULT_MAX_CELLS) -> None:
        if structure not in STRUCTURES:
            raise InputError(f"unknown photon-map structure {structure!r}; choose one of "
                             f"{', '.join(STRUCTURES)}")
        if int(channels) != channels or channels < 1:
            raise InputError(f"channels must be a positive integer, got {channels!r}")
        self.structure = structure
        self.n_channels = int(channels)
        self._batches: list[tuple[np.ndarray, np.ndarray | None, np.ndarray]] = []
        self._hash: HashGrid | None = None
        self._n = 0
        if structure == "middle":
            self.index: KdTree | MedianKdTree | UniformGrid | None = KdTree(
                leaf_size=leaf_size, channels=channels)
        elif structure == "median":
            self.index = MedianKdTree(leaf_size=leaf_size, channels=channels)
        elif structure in ("grid-lo", "grid-hi"):
            ppc = GRID_PRESETS[structure[5:]] if photons_per_cell is None else photons_per_cell
            self.index = UniformGrid(photons_per_cell=ppc, max_cells=max_cells,
                                     channels=channels)
        else:
            self.index = None  # built on demand: the cell size is the estimate's radius

    def __len__(self) -> int:
        return self._n

    def add(self, positions: np.ndarray, normals: np.ndarray | None = None,
            powers: np.ndarray | None = None) -> None:
        """Add a batch of photons; indices continue after those already stored.

        Parameters
        ----------
        positions : (n, 3) array_like
            Photon positions (m), float32; NaN/inf raise
            :class:`~lightsim.errors.InputError`.
        normals : (n, 3) array_like, optional
            Surface normals at the photons (unit vectors; for the normal filter). Either
            every batch has them or none.
        powers : (n, C) array_like, optional
            Photon power Φ per channel (lm, or any power unit); zeros when omitted.
        """
        if self.index is not None:
            self.index.add(positions, normals, powers)
            self._n = len(self.index)
            return
        pts = as_positions(positions)
        if pts.shape[0] == 0:
            return
        if self._batches and (normals is None) != (self._batches[0][1] is None):
            raise InputError("photon normals must be given for every batch or for none")
        nrm = None if normals is None else as_unit_normals(normals, pts.shape[0])
        self._batches.append((pts, nrm, as_powers(powers, pts.shape[0], self.n_channels)))
        self._n += pts.shape[0]
        self._hash = None

    def _hash_grid(self, radius: float) -> HashGrid:
        if self._hash is None or self._hash.radius != radius:
            grid = HashGrid(radius, channels=self.n_channels)
            if self._batches:
                pts = np.concatenate([b[0] for b in self._batches])
                nrm = (None if self._batches[0][1] is None
                       else np.concatenate([b[1] for b in self._batches]))
                grid.add(pts, nrm, np.concatenate([b[2] for b in self._batches]))
            self._hash = grid
        return self._hash

    def estimate(self, points: np.ndarray, normals: np.ndarray | None = None, *, k: int = 64,
                 max_radius: float = np.inf, min_radius: float = 0.0, kernel: str = "box",
                 normal_cos: float = 0.5) -> Estimate:
        """Density estimate at each query point (see the module docstring).

        Returns
        -------
        Estimate
            ``E`` (Q, C) float64 power per m², ``r`` (Q,) radius used (m), ``count`` (Q,)
            photons used.
        """
        if self.index is None:
            r = check_radius(max_radius)
            if not (0 < r < np.inf):
                raise InputError("the 'hash' photon map needs a finite max_radius > 0 m "
                                 "(its fixed query radius)")
            return self._hash_grid(r).estimate_radius(points, normals, kernel=kernel,
                                                      normal_cos=normal_cos)
        return self.index.estimate(points, normals, k=k, max_radius=max_radius,
                                   min_radius=min_radius, kernel=kernel,
                                   normal_cos=normal_cos)

    def query(self, points: np.ndarray, k: int, *, max_radius: float = np.inf,
              normals: np.ndarray | None = None, normal_cos: float = 0.5,
              ) -> tuple[np.ndarray, np.ndarray]:
        """Exact k nearest photons: (d² (Q, k) float32 m², indices (Q, k) int64).

        Not available for ``hash`` (a fixed-radius structure): use its ``query_radius``.
        """
        if self.index is None:
            raise InputError("the 'hash' photon map answers fixed-radius queries only")
        return self.index.query(points, k, max_radius=max_radius, normals=normals,
                                normal_cos=normal_cos)

    def query_radius(self, points: np.ndarray, radius: float, *,
                     normals: np.ndarray | None = None, normal_cos: float = 0.5):
        """All photons within ``radius`` (m) of each query point, CSR
        (:class:`~lightsim.photonmap.common.RadiusNeighbours`: insertion-order indices and
        squared distances in m²). The normal filter works as in :meth:`query`."""
        if self.index is None:
            return self._hash_grid(check_radius(radius)).query_radius(
                points, radius, normals=normals, normal_cos=normal_cos)
        return self.index.query_radius(points, radius, normals=normals,
                                       normal_cos=normal_cos)
