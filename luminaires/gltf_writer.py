"""A small, general binary glTF 2.0 (GLB) writer for triangle meshes, built on pygltflib.

Used by the parametric headlight (:mod:`lightsim.luminaires.headlight`) and by validation
scenes. It writes exactly what the scene loader reads (``docs/reference/conventions.md``): one node
per part, named after the part, with the part's ``extras``; one mesh with one triangle
primitive per node; PBR materials with ``emissiveFactor`` and the extensions
``KHR_materials_transmission``, ``KHR_materials_ior`` and ``KHR_materials_volume``.

Units: positions in metres (m), normals unit vectors, ``attenuation_distance`` and
``thickness`` in metres. Axes are glTF's (+Y up, the lamp shines along +Z).

Storage: positions and normals are stored as little-endian float32 (the only type glTF
allows for ``POSITION``/``NORMAL``), indices as ``UNSIGNED_INT``. Reading the file back
gives exactly ``np.asarray(values, np.float32)`` and the original indices.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pygltflib

from lightsim import __version__
from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes

__all__ = ["GltfMaterial", "GltfPart", "glb_bytes", "triangle_count", "write_glb"]

# glTF enumerations
_FLOAT = 5126
_UNSIGNED_INT = 5125
_ARRAY_BUFFER = 34962
_ELEMENT_ARRAY_BUFFER = 34963
_TRIANGLES = 4

_EXT_TRANSMISSION = "KHR_materials_transmission"
_EXT_IOR = "KHR_materials_ior"
_EXT_VOLUME = "KHR_materials_volume"


@dataclass(frozen=True)
class GltfMaterial:
    """A glTF metallic-roughness material with the lightsim-relevant extensions.

    Parameters
    ----------
    name : str
        Material name.
    base_color : tuple of 3 float
        Linear RGB ``baseColorFactor`` in [0, 1]: albedo of a diffuse surface, reflectance
        of a mirror (``metallic ≥ 0.5``).
    metallic : float
        ``metallicFactor`` in [0, 1]; ≥ 0.5 makes a mirror for lightsim.
    roughness : float
        ``roughnessFactor`` in [0, 1] (only used by viewers; lightsim mirrors are perfect).
    emissive : tuple of 3 float
        ``emissiveFactor`` in [0, 1]; non-zero marks an emitter (its flux, in lm, is in the
        node's ``extras.lightsim.flux_lm``).
    transmission : float
        ``KHR_materials_transmission.transmissionFactor`` in [0, 1]; > 0 makes a dielectric.
    ior : float, optional
        ``KHR_materials_ior.ior`` (refractive index, ≥ 1); written when given.
    attenuation_distance : float, optional
        ``KHR_materials_volume.attenuationDistance`` in m (> 0); absent means no absorption.
    attenuation_color : tuple of 3 float, optional
        ``KHR_materials_volume.attenuationColor``: linear RGB transmittance after
        ``attenuation_distance``.
    thickness : float, optional
        ``KHR_materials_volume.thicknessFactor`` in m: a hint for rasterising viewers that the
        mesh encloses a volume (``0``/absent means thin-walled). lightsim ignores it.
    double_sided : bool
        glTF ``doubleSided`` (viewers then do not cull back faces of open sheets).
    """

    name: str
    base_color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    metallic: float = 0.0
    roughness: float = 0.5
    emissive: tuple[float, float, float] = (0.0, 0.0, 0.0)
    transmission: float = 0.0
    ior: float | None = None
    attenuation_distance: float | None = None
    attenuation_color: tuple[float, float, float] | None = None
    thickness: float | None = None
    double_sided: bool = False

    def validate(self) -> None:
        """Raise :class:`InputError` if a factor is out of its glTF range."""
        for label, rgb in (("base_color", self.base_color), ("emissive", self.emissive)):
            _check_rgb(self.name, label, rgb)
        for label, value in (
            ("metallic", self.metallic),
            ("roughness", self.roughness),
            ("transmission", self.transmission),
        ):
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise InputError(f"material {self.name!r}: {label} {value} is not in [0, 1]")
        if self.ior is not None and not (math.isfinite(self.ior) and self.ior >= 1.0):
            raise InputError(f"material {self.name!r}: ior {self.ior} must be a number ≥ 1")
        if self.attenuation_distance is not None and not (
            math.isfinite(self.attenuation_distance) and self.attenuation_distance > 0
        ):
            raise InputError(
                f"material {self.name!r}: attenuation_distance {self.attenuation_distance} m "
                "must be > 0"
            )
        if self.attenuation_color is not None:
            _check_rgb(self.name, "attenuation_color", self.attenuation_color)
        if self.thickness is not None and not (
            math.isfinite(self.thickness) and self.thickness >= 0
        ):
            raise InputError(f"material {self.name!r}: thickness {self.thickness} m must be ≥ 0")

    def extension_names(self) -> list[str]:
        """Names of the glTF extensions this material writes."""
        names = []
        if self.transmission > 0:
            names.append(_EXT_TRANSMISSION)
        if self.ior is not None:
            names.append(_EXT_IOR)
        if self._has_volume():
            names.append(_EXT_VOLUME)
        return names

    def _has_volume(self) -> bool:
        return (
            self.attenuation_distance is not None
            or self.attenuation_color is not None
            or self.thickness is not None
        )

    def to_pygltf(self) -> pygltflib.Material:
        """This material as a :class:`pygltflib.Material`."""
        extensions: dict[str, Any] = {}
        if self.transmission > 0:
            extensions[_EXT_TRANSMISSION] = {"transmissionFactor": float(self.transmission)}
        if self.ior is not None:
            extensions[_EXT_IOR] = {"ior": float(self.ior)}
        if self._has_volume():
            volume: dict[str, Any] = {}
            if self.thickness is not None:
                volume["thicknessFactor"] = float(self.thickness)
            if self.attenuation_distance is not None:
                volume["attenuationDistance"] = float(self.attenuation_distance)
            if self.attenuation_color is not None:
                volume["attenuationColor"] = [float(c) for c in self.attenuation_color]
            extensions[_EXT_VOLUME] = volume
        return pygltflib.Material(
            name=self.name,
            pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
                baseColorFactor=[*(float(c) for c in self.base_color), 1.0],
                metallicFactor=float(self.metallic),
                roughnessFactor=float(self.roughness),
            ),
            emissiveFactor=[float(c) for c in self.emissive],
            doubleSided=bool(self.double_sided),
            extensions=extensions,
        )


@dataclass
class GltfPart:
    """One named triangle mesh → one glTF node (with its mesh and material).

    Parameters
    ----------
    name : str
        Node (and mesh) name, e.g. ``"reflector"``; the loader recognises parts by it.
    vertices : array_like, shape (n, 3)
        Vertex positions in m (stored as float32).
    faces : array_like of int, shape (m, 3)
        Triangles as vertex indices, counter-clockwise seen from the side the face normal
        points to (glTF's front face).
    normals : array_like, shape (n, 3), or None
        Unit vertex normals (shading normals for mirrors and dielectrics), or None to let
        readers use flat face normals.
    material : GltfMaterial
        The part's material.
    extras : dict, optional
        JSON-serialisable node ``extras`` (e.g. ``{"lightsim": {"flux_lm": 1000.0}}``).
    translation : tuple of 3 float, optional
        Node translation in m.
    rotation : tuple of 4 float, optional
        Node rotation as a unit quaternion ``(x, y, z, w)`` (glTF order).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    material: GltfMaterial
    extras: dict[str, Any] | None = None
    translation: tuple[float, float, float] | None = None
    rotation: tuple[float, float, float, float] | None = None

    @property
    def triangle_count(self) -> int:
        """Number of triangles."""
        return int(np.shape(self.faces)[0])


def triangle_count(parts: Sequence[GltfPart]) -> int:
    """Total number of triangles of ``parts``."""
    return sum(p.triangle_count for p in parts)


def _check_rgb(owner: str, label: str, rgb: Sequence[float]) -> None:
    values = list(rgb)
    if len(values) != 3 or not all(math.isfinite(c) and 0.0 <= c <= 1.0 for c in values):
        raise InputError(f"material {owner!r}: {label} {tuple(values)} must be 3 values in [0, 1]")


def _json_clean(value: Any, where: str) -> Any:
    """Convert numpy scalars/arrays to plain JSON values; reject NaN/inf and non-JSON types."""
    if isinstance(value, Mapping):
        return {str(k): _json_clean(v, where) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_json_clean(v, where) for v in (value.tolist() if isinstance(value, np.ndarray)
                                                 else value)]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(float(value)):
            raise InputError(f"{where}: extras contain a non-finite number ({value})")
        return float(value)
    if value is None or isinstance(value, str):
        return value
    raise InputError(f"{where}: extras value of type {type(value).__name__} is not JSON")


def _prepare_part(part: GltfPart) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Validate one part; return (positions float32, normals float32 or None, indices uint32)."""
    if not part.name:
        raise InputError("glTF part without a name")
    v = np.asarray(part.vertices)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise InputError(f"part {part.name!r}: vertices must have shape (n, 3), got {v.shape}")
    v32 = np.ascontiguousarray(v, dtype="<f4")
    if not np.all(np.isfinite(v32)):
        raise InputError(f"part {part.name!r}: vertices contain NaN/inf (or overflow float32)")
    f = np.asarray(part.faces)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise InputError(f"part {part.name!r}: faces must have shape (m, 3), got {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"part {part.name!r}: faces must be integer vertex indices")
    if f.min() < 0 or f.max() >= len(v32):
        raise InputError(f"part {part.name!r}: face index out of range 0..{len(v32) - 1}")
    n32 = None
    if part.normals is not None:
        n = np.asarray(part.normals)
        if n.shape != v.shape:
            raise InputError(
                f"part {part.name!r}: normals shape {n.shape} differs from vertices {v.shape}"
            )
        n32 = np.ascontiguousarray(n, dtype="<f4")
        lengths = np.linalg.norm(n32.astype(np.float64), axis=1)
        if not np.all(np.isfinite(lengths)) or np.max(np.abs(lengths - 1.0)) > 1e-3:
            raise InputError(f"part {part.name!r}: normals must be finite unit vectors")
    part.material.validate()
    return v32, n32, np.ascontiguousarray(f, dtype="<u4")


def glb_bytes(
    parts: Sequence[GltfPart],
    asset_extras: Mapping[str, Any] | None = None,
    generator: str | None = None,
) -> bytes:
    """Encode ``parts`` as a binary glTF 2.0 file and return its bytes.

    Parameters
    ----------
    parts : sequence of GltfPart
        The parts; each becomes one node (in this order) of the single scene.
    asset_extras : mapping, optional
        JSON-serialisable ``asset.extras`` (e.g. the generator's parameters).
    generator : str, optional
        ``asset.generator``; defaults to ``"lightsim <version>"``.

    Returns
    -------
    bytes
        The GLB file content (deterministic for equal input).

    Raises
    ------
    InputError
        Malformed geometry, out-of-range material factors, non-JSON extras.
    """
    if not parts:
        raise InputError("cannot write a glTF file without parts")
    names = [p.name for p in parts]
    if len(set(names)) != len(names):
        raise InputError(f"glTF part names must be unique, got {names}")

    blob = bytearray()
    buffer_views: list[pygltflib.BufferView] = []
    accessors: list[pygltflib.Accessor] = []

    def add_view(data: np.ndarray, target: int) -> int:
        raw = data.tobytes()
        # every view holds 4-byte components; keep offsets 4-byte aligned regardless
        blob.extend(b"\0" * (-len(blob) % 4))
        buffer_views.append(
            pygltflib.BufferView(
                buffer=0, byteOffset=len(blob), byteLength=len(raw), target=target
            )
        )
        blob.extend(raw)
        return len(buffer_views) - 1

    def add_accessor(data: np.ndarray, target: int, component_type: int, kind: str,
                     **bounds: list[float]) -> int:
        accessors.append(
            pygltflib.Accessor(
                bufferView=add_view(data, target),
                componentType=component_type,
                count=len(data),
                type=kind,
                **bounds,
            )
        )
        return len(accessors) - 1

    materials: list[GltfMaterial] = []
    meshes: list[pygltflib.Mesh] = []
    nodes: list[pygltflib.Node] = []
    for part in parts:
        v32, n32, idx = _prepare_part(part)
        # glTF requires POSITION bounds; float32 values widen exactly to float64
        pos_acc = add_accessor(v32, _ARRAY_BUFFER, _FLOAT, "VEC3",
                               min=[float(x) for x in v32.min(axis=0)],
                               max=[float(x) for x in v32.max(axis=0)])
        attributes = pygltflib.Attributes(POSITION=pos_acc)
        if n32 is not None:
            attributes.NORMAL = add_accessor(n32, _ARRAY_BUFFER, _FLOAT, "VEC3")
        idx_acc = add_accessor(idx.reshape(-1), _ELEMENT_ARRAY_BUFFER, _UNSIGNED_INT, "SCALAR")
        if part.material in materials:
            mat_index = materials.index(part.material)
        else:
            materials.append(part.material)
            mat_index = len(materials) - 1
        meshes.append(
            pygltflib.Mesh(
                name=part.name,
                primitives=[
                    pygltflib.Primitive(
                        attributes=attributes, indices=idx_acc, material=mat_index, mode=_TRIANGLES
                    )
                ],
            )
        )
        node = pygltflib.Node(name=part.name, mesh=len(meshes) - 1)
        if part.extras:
            node.extras = _json_clean(part.extras, f"part {part.name!r}")
        if part.translation is not None:
            t = [float(x) for x in part.translation]
            if len(t) != 3 or not all(math.isfinite(x) for x in t):
                raise InputError(f"part {part.name!r}: translation must be 3 finite numbers")
            node.translation = t
        if part.rotation is not None:
            q = [float(x) for x in part.rotation]
            if len(q) != 4 or abs(math.sqrt(sum(x * x for x in q)) - 1.0) > 1e-6:
                raise InputError(f"part {part.name!r}: rotation must be a unit quaternion xyzw")
            node.rotation = q
        nodes.append(node)

    used = sorted({name for m in materials for name in m.extension_names()})
    asset = pygltflib.Asset(version="2.0", generator=generator or f"lightsim {__version__}")
    if asset_extras:
        asset.extras = _json_clean(asset_extras, "asset")
    gltf = pygltflib.GLTF2(
        asset=asset,
        scene=0,
        scenes=[pygltflib.Scene(nodes=list(range(len(nodes))))],
        nodes=nodes,
        meshes=meshes,
        materials=[m.to_pygltf() for m in materials],
        accessors=accessors,
        bufferViews=buffer_views,
        buffers=[pygltflib.Buffer(byteLength=len(blob))],
        extensionsUsed=used,
    )
    gltf.set_binary_blob(bytes(blob))
    data = b"".join(gltf.save_to_bytes())
    # pygltflib drops empty containers itself; make sure the JSON chunk is valid JSON anyway
    json.loads(data[20 : 20 + int.from_bytes(data[12:16], "little")])
    return data


def write_glb(
    path: str | os.PathLike,
    parts: Sequence[GltfPart],
    asset_extras: Mapping[str, Any] | None = None,
    generator: str | None = None,
) -> int:
    """Write ``parts`` as a GLB file, atomically (temporary name + rename).

    Parameters
    ----------
    path : path-like
        Destination ``.glb`` file.
    parts, asset_extras, generator
        See :func:`glb_bytes`.

    Returns
    -------
    int
        Size of the written file in bytes.
    """
    data = glb_bytes(parts, asset_extras=asset_extras, generator=generator)
    write_bytes(path, data)
    return len(data)
