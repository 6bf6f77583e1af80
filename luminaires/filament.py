"""Filament emitter geometry: the coil's envelope as a closed cylinder (or box) mesh.

A halogen filament is a tightly wound tungsten coil; at the scale of a headlamp reflector it
is modelled by the envelope of the coil, a closed cylinder of the coil's length and outer
diameter (the paper's HEADLIGHT used "a simple isotropically emitting box"; ``shape="box"``
gives that). Meshes are closed, wound counter-clockwise seen from outside (outward face
normals), in metres, in glTF axes.

:func:`filament_mesh` is also used by the scene loader to place a preset filament into a
plain CAD reflector (``simulate --filament H7 --filament-at X,Y,Z --filament-axis ...``);
:func:`filament_part` wraps it into an emitting glTF part following
``docs/reference/conventions.md`` (non-zero ``emissiveFactor``; node
``extras.lightsim.flux_lm``, ``emission``, ``bulb``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np

from lightsim.errors import InputError

from .bulbs import BulbSpec, check_flux
from .gltf_writer import GltfMaterial, GltfPart

__all__ = [
    "EMISSION_MODES",
    "FILAMENT_MATERIAL",
    "filament_mesh",
    "filament_part",
    "orthonormal_basis",
]

EMISSION_MODES = ("isotropic", "lambertian")

#: Emitter material: white ``emissiveFactor`` keeps the flux monochrome (luminous, lm);
#: the flux itself is in the node extras, not in the material.
FILAMENT_MATERIAL = GltfMaterial(
    name="filament (emitter)",
    base_color=(1.0, 1.0, 1.0),
    metallic=0.0,
    roughness=1.0,
    emissive=(1.0, 1.0, 1.0),
)


def _vector3(value: Sequence[float], what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{what} must be 3 finite numbers, got {value!r}")
    return arr


def orthonormal_basis(axis: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Right-handed orthonormal basis ``(u, v, w)`` with ``w`` along ``axis``.

    Parameters
    ----------
    axis : sequence of 3 float
        Direction (any non-zero length).

    Returns
    -------
    u, v, w : ndarray, shape (3,)
        Unit vectors with ``u × v = w``; deterministic for a given axis.
    """
    w = _vector3(axis, "filament axis")
    norm = float(np.linalg.norm(w))
    if norm < 1e-12:
        raise InputError("filament axis must be a non-zero vector")
    w = w / norm
    # aux: the world axis least aligned with w, so the cross product is well conditioned
    aux = np.zeros(3)
    aux[int(np.argmin(np.abs(w)))] = 1.0
    u = np.cross(aux, w)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    return u, v, w


def filament_mesh(
    length_m: float,
    diameter_m: float,
    centre: Sequence[float],
    axis: Sequence[float],
    segments: int = 16,
    shape: Literal["cylinder", "box"] = "cylinder",
) -> tuple[np.ndarray, np.ndarray]:
    """Closed mesh of a filament envelope (outward normals).

    Parameters
    ----------
    length_m : float
        Filament (coil) length along ``axis`` in m.
    diameter_m : float
        Outer coil diameter in m (the cylinder's ring vertices lie on this diameter; for
        ``shape="box"`` the side of the square cross-section).
    centre : sequence of 3 float
        Centre of the filament in m.
    axis : sequence of 3 float
        Filament axis (normalised here).
    segments : int
        Number of sides of the cylinder (≥ 3); ignored for a box.
    shape : {"cylinder", "box"}
        Envelope shape.

    Returns
    -------
    vertices : ndarray, shape (n, 3), float64
        Positions in m.
    faces : ndarray, shape (m, 3), int64
        Triangles, counter-clockwise seen from outside.
    """
    if not (math.isfinite(length_m) and length_m > 0):
        raise InputError(f"filament length must be > 0 m, got {length_m}")
    if not (math.isfinite(diameter_m) and diameter_m > 0):
        raise InputError(f"filament diameter must be > 0 m, got {diameter_m}")
    if max(length_m, diameter_m) > 0.1:
        raise InputError(
            f"filament of {length_m * 1e3:g} mm × Ø{diameter_m * 1e3:g} mm is implausibly "
            "large (sizes are in metres)"
        )
    c = _vector3(centre, "filament centre")
    u, v, w = orthonormal_basis(axis)
    half = 0.5 * length_m
    if shape == "box":
        s = 0.5 * diameter_m
        corners = np.array(
            [[i, j, k] for k in (-1, 1) for j in (-1, 1) for i in (-1, 1)], dtype=np.float64
        )
        local = corners * np.array([s, s, half])
        vertices = c + local[:, :1] * u + local[:, 1:2] * v + local[:, 2:3] * w
        # indices: bit 0 = u, bit 1 = v, bit 2 = w; each face CCW seen from outside
        faces = np.array(
            [
                [0, 2, 3], [0, 3, 1],  # -w
                [4, 5, 7], [4, 7, 6],  # +w
                [0, 1, 5], [0, 5, 4],  # -v
                [2, 6, 7], [2, 7, 3],  # +v
                [0, 4, 6], [0, 6, 2],  # -u
                [1, 3, 7], [1, 7, 5],  # +u
            ],
            dtype=np.int64,
        )  # fmt: skip
        return vertices, faces
    if shape != "cylinder":
        raise InputError(f"unknown filament shape {shape!r} (cylinder or box)")
    if segments < 3:
        raise InputError(f"a filament cylinder needs at least 3 segments, got {segments}")
    r = 0.5 * diameter_m
    theta = 2.0 * np.pi * np.arange(segments) / segments
    ring = r * (np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * v)
    bottom, top = c - half * w, c + half * w
    vertices = np.vstack([bottom, top, bottom + ring, top + ring])
    i = np.arange(segments)
    j = (i + 1) % segments
    b_i, b_j, t_i, t_j = 2 + i, 2 + j, 2 + segments + i, 2 + segments + j
    faces = np.vstack(
        [
            np.column_stack([b_i, b_j, t_j]),  # side, outward radial
            np.column_stack([b_i, t_j, t_i]),
            np.column_stack([np.zeros_like(i), b_j, b_i]),  # base cap, normal -w
            np.column_stack([np.ones_like(i), t_i, t_j]),  # top cap, normal +w
        ]
    ).astype(np.int64)
    return vertices, faces


def filament_part(
    spec: BulbSpec,
    centre: Sequence[float],
    axis: Sequence[float],
    flux_lm: float,
    emission: str = "isotropic",
    segments: int = 16,
    shape: Literal["cylinder", "box"] = "cylinder",
    name: str = "filament",
) -> GltfPart:
    """The emitting filament of a bulb preset as a glTF part.

    Parameters
    ----------
    spec : BulbSpec
        Bulb preset (filament length and diameter are taken from it).
    centre : sequence of 3 float
        Filament centre in m (world).
    axis : sequence of 3 float
        Filament axis direction (world).
    flux_lm : float
        Luminous flux in lm (> 0) written to ``extras.lightsim.flux_lm``.
    emission : {"isotropic", "lambertian"}
        Angular emission law: isotropic points in the volume, or cosine-weighted from the
        envelope surface.
    segments, shape
        See :func:`filament_mesh`.
    name : str
        Node name (``"filament"`` by the conventions).

    Returns
    -------
    GltfPart
        Closed mesh, no vertex normals (flat facets are the envelope), emissive material,
        extras ``{"lightsim": {"flux_lm", "emission", "bulb", "filament"}}``.
    """
    flux = check_flux(flux_lm)
    if emission not in EMISSION_MODES:
        raise InputError(f"unknown emission {emission!r} (isotropic or lambertian)")
    vertices, faces = filament_mesh(
        spec.filament_length_m, spec.filament_diameter_m, centre, axis, segments, shape
    )
    _, _, w = orthonormal_basis(axis)
    extras = {
        "lightsim": {
            "flux_lm": flux,
            "emission": emission,
            "bulb": spec.name,
            # the exact envelope, for loaders that prefer sampling it analytically
            "filament": {
                "shape": shape,
                "length_m": spec.filament_length_m,
                "diameter_m": spec.filament_diameter_m,
                "centre_m": [float(x) for x in _vector3(centre, "filament centre")],
                "axis": [float(x) for x in w],
            },
        }
    }
    return GltfPart(name, vertices, faces, None, FILAMENT_MATERIAL, extras=extras)
