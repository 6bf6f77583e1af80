"""Is a triangle mesh closed, and which way do its faces point? (numpy, no trimesh import).

The scene loader asks this of every dielectric (a closed glass body with inward normals is
flipped) and of a wall that may be a CAD slab. trimesh answers it too, but importing
trimesh (and the scipy modules it pulls in) costs a run about a second of start-up; the
two questions need only vertex merging, an edge count and the divergence theorem.

==================  =====  ========  ===================================================
parameter           unit   default   meaning
==================  =====  ========  ===================================================
``merge_digits``    –      8         vertices equal after rounding to this many decimals
                                     (of metres) are one vertex, as trimesh's
                                     ``merge_vertices`` with its default ``tol.merge``
==================  =====  ========  ===================================================

A mesh is *closed* (watertight) when, after merging, every edge is shared by exactly two
triangles (trimesh's ``is_watertight``). Its signed volume Σ v₀ · (v₁ × v₂) / 6 is
positive when the triangles wind counter-clockwise seen from outside (outward normals).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MERGE_DIGITS = 8


@dataclass(frozen=True)
class ClosedMesh:
    """What :func:`closed_mesh` found.

    Attributes
    ----------
    watertight : bool
        Every edge (after merging coincident vertices) is shared by exactly two triangles.
    volume : float
        Signed volume (m³), > 0 for outward-facing triangles; meaningful only when closed.
    """

    watertight: bool
    volume: float


def closed_mesh(vertices: np.ndarray, faces: np.ndarray,
                merge_digits: int = MERGE_DIGITS) -> ClosedMesh:
    """Watertightness and signed volume of a triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) float
        Positions (m).
    faces : (F, 3) int
        Triangles (vertex indices).
    merge_digits : int
        Decimals of the vertex merge (see the module's table).
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) == 0 or len(v) == 0:
        return ClosedMesh(False, 0.0)
    tri = v[f]
    volume = float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()
                   / 6.0)
    _, merged = np.unique(np.round(v, merge_digits) + 0.0, axis=0, return_inverse=True)
    g = merged.reshape(-1)[f]
    edges = np.sort(np.concatenate([g[:, [0, 1]], g[:, [1, 2]], g[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return ClosedMesh(bool(np.all(counts == 2)), volume)
