"""Balanced kd-tree split at the median of the largest extent: the paper's baseline.

Günther, Wald & Slusallek (2004), section 5.2 and Table 5 ("median"): the classic photon
map [Jensen 1996] balances the tree by splitting every node at the median photon along the
largest extent of its bounding box. Finding the median (quickselect, O(n) per node) is
what makes the build slower than the spatial-middle split of
:class:`~lightsim.photonmap.kdtree.KdTree`; a balanced tree cannot take new photons
without losing its balance, so :meth:`MedianKdTree.add` rebuilds from all photons.

Storage, queries and density estimates are those of :class:`~lightsim.photonmap.kdtree.KdTree`
(tight node boxes, exact kNN, normal filter); units: positions in m, powers in lm (or any
power unit), estimates per m².
"""

from __future__ import annotations

import numpy as np

from lightsim.photonmap.kdtree import BoxTree


class MedianKdTree(BoxTree):
    """Median-split balanced kd-tree (build only; :meth:`add` rebuilds).

    Parameters
    ----------
    positions : (n, 3) array_like, optional
        Photon positions (m), float32; NaN/inf raise :class:`~lightsim.errors.InputError`.
    normals : (n, 3) array_like, optional
        Photon surface normals for the normal filter.
    powers : (n, C) array_like, optional
        Photon powers Φ (lm).
    leaf_size : int
        Nodes with more photons than this are split (default 10).
    channels : int
        Number of power channels C (default 1).
    """

    _median = True

    def add(self, positions: np.ndarray, normals: np.ndarray | None = None,
            powers: np.ndarray | None = None) -> None:
        """Append a batch (indices continue) and rebuild the whole balanced tree."""
        self._add_rebuild(positions, normals, powers)
