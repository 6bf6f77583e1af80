"""Read glTF 2.0 / GLB files into flat triangle parts with their materials and extras.

trimesh's glTF loader drops what lightsim needs (material extensions
``KHR_materials_transmission``/``_ior``/``_volume``, node ``extras``, and it quantises
``baseColorFactor`` to 8 bits), so glTF is read here; OBJ/STL/PLY still go through trimesh
(see :mod:`lightsim.scene`). The GLB container is parsed directly rather than with pygltflib
because the accessor decoding has to be written anyway and a direct parse can name the
exact problem in a truncated or corrupt file.

Every mesh primitive of every node in the default scene becomes one :class:`GltfPrimitive`
with world-space vertices (node transforms applied), per-vertex world normals (if the file
has ``NORMAL``), triangle indices (strips and fans converted) and the material/extras as
plain dicts. Units are whatever the file uses; glTF prescribes metres.
"""

from __future__ import annotations

import base64
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16,
              5125: np.uint32, 5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_TRIANGLES, _TRIANGLE_STRIP, _TRIANGLE_FAN = 4, 5, 6


@dataclass
class GltfPrimitive:
    """One triangle primitive in world space.

    Attributes
    ----------
    name : str
        Node name (``node<i>`` when the node has none).
    vertices : (n, 3) float64 array
        World positions (m).
    faces : (m, 3) int64 array
        Counter-clockwise triangles (front face per glTF).
    normals : (n, 3) float64 array or None
        World unit vertex normals, if the primitive has ``NORMAL``.
    material : dict
        The glTF material JSON (empty dict if the primitive has none).
    extras : dict
        Node extras merged over mesh extras.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    material: dict[str, Any] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)


def _load_json_and_buffers(path: Path) -> tuple[dict[str, Any], list[bytes]]:
    """Parse a .glb or .gltf file into its JSON document and the raw buffers."""
    import json

    raw = path.read_bytes()
    if raw[:4] == b"glTF":
        if len(raw) < 20:
            raise InputError(f"{path}: truncated GLB header")
        _, version, length = struct.unpack_from("<III", raw, 0)
        if version != 2:
            raise InputError(f"{path}: GLB version {version} is not supported (need 2)")
        if length > len(raw):
            raise InputError(f"{path}: truncated GLB ({len(raw)} of {length} bytes)")
        offset, doc, blob = 12, None, b""
        while offset + 8 <= length:
            chunk_len, chunk_type = struct.unpack_from("<II", raw, offset)
            chunk = raw[offset + 8: offset + 8 + chunk_len]
            if len(chunk) != chunk_len:
                raise InputError(f"{path}: truncated GLB chunk")
            if chunk_type == 0x4E4F534A:  # JSON
                doc = json.loads(chunk.decode("utf-8"))
            elif chunk_type == 0x004E4942:  # BIN
                blob = chunk
            offset += 8 + chunk_len
        if doc is None:
            raise InputError(f"{path}: GLB has no JSON chunk")
    else:
        try:
            doc = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{path}: not a glTF file ({exc.__class__.__name__})") from None
        blob = b""
    buffers: list[bytes] = []
    for i, buf in enumerate(doc.get("buffers", [])):
        uri = buf.get("uri")
        if uri is None:
            data = blob
        elif uri.startswith("data:"):
            data = base64.b64decode(uri.split(",", 1)[1])
        else:
            ext = path.parent / uri
            if not ext.is_file():
                raise InputError(f"{path}: buffer {i} file '{uri}' not found")
            data = ext.read_bytes()
        if len(data) < buf.get("byteLength", 0):
            raise InputError(f"{path}: buffer {i} is truncated "
                             f"({len(data)} of {buf['byteLength']} bytes)")
        buffers.append(data)
    return doc, buffers


def _read_accessor(doc: dict[str, Any], buffers: list[bytes], index: int) -> np.ndarray:
    acc = doc["accessors"][index]
    if "sparse" in acc:
        raise InputError(f"accessor {index}: sparse accessors are not supported")
    dtype = np.dtype(_COMPONENT[acc["componentType"]])
    ncomp = _NCOMP[acc["type"]]
    count = acc["count"]
    if "bufferView" not in acc:
        return np.zeros((count, ncomp), dtype=dtype)
    view = doc["bufferViews"][acc["bufferView"]]
    data = buffers[view["buffer"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    elem = dtype.itemsize * ncomp
    stride = view.get("byteStride", elem) or elem
    needed = start + stride * (count - 1) + elem if count else start
    if needed > len(data):
        raise InputError(f"accessor {index}: data runs past the end of its buffer "
                         "(truncated file?)")
    arr = np.ndarray((count, ncomp), dtype=dtype, buffer=data, offset=start,
                     strides=(stride, dtype.itemsize)).copy()
    if acc.get("normalized") and dtype.kind in "iu":
        arr = arr.astype(np.float64) / np.iinfo(dtype).max
    return arr


def _node_matrix(node: dict[str, Any]) -> np.ndarray:
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major
    m = np.eye(4)
    t = node.get("translation", [0.0, 0.0, 0.0])
    x, y, z, w = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    s = node.get("scale", [1.0, 1.0, 1.0])
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
    m[:3, :3] = r * np.asarray(s, dtype=np.float64)[None, :]
    m[:3, 3] = t
    return m


def _triangulate(indices: np.ndarray, mode: int) -> np.ndarray:
    if mode == _TRIANGLES:
        n = len(indices) // 3 * 3
        return indices[:n].reshape(-1, 3)
    if mode == _TRIANGLE_STRIP:
        k = np.arange(len(indices) - 2)
        tri = np.stack([indices[k], indices[k + 1], indices[k + 2]], axis=1)
        odd = (k % 2) == 1
        tri[odd] = tri[odd][:, [1, 0, 2]]  # keep the winding consistent
        return tri
    if mode == _TRIANGLE_FAN:
        k = np.arange(1, len(indices) - 1)
        return np.stack([np.full_like(k, indices[0]), indices[k], indices[k + 1]], axis=1)
    return np.zeros((0, 3), dtype=np.int64)


def read_gltf(path: str | Path) -> list[GltfPrimitive]:
    """Read the default scene of a glTF/GLB file as world-space triangle primitives.

    Parameters
    ----------
    path : path-like
        ``.glb`` or ``.gltf`` file.

    Returns
    -------
    list of GltfPrimitive
        Triangle primitives; points/lines primitives are skipped.

    Raises
    ------
    InputError
        Missing, truncated or malformed file.
    """
    path = Path(path)
    try:
        doc, buffers = _load_json_and_buffers(path)
    except (KeyError, IndexError, ValueError, struct.error) as exc:
        raise InputError(f"{path}: corrupt glTF ({exc})") from None
    try:
        return _collect(doc, buffers)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: corrupt glTF ({exc.__class__.__name__}: {exc})") from None


def _collect(doc: dict[str, Any], buffers: list[bytes]) -> list[GltfPrimitive]:
    nodes = doc.get("nodes", [])
    scenes = doc.get("scenes", [])
    if scenes:
        roots = scenes[doc.get("scene", 0)].get("nodes", [])
    else:  # no scene: every node that is nobody's child is a root
        children = {c for n in nodes for c in n.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    materials = doc.get("materials", [])
    meshes = doc.get("meshes", [])
    out: list[GltfPrimitive] = []
    stack = [(i, np.eye(4), 0) for i in roots]
    while stack:
        idx, parent, depth = stack.pop()
        if depth > 256:
            raise InputError("node hierarchy deeper than 256 (cycle?)")
        node = nodes[idx]
        world = parent @ _node_matrix(node)
        for child in node.get("children", []):
            stack.append((child, world, depth + 1))
        if "mesh" not in node:
            continue
        mesh = meshes[node["mesh"]]
        name = node.get("name") or mesh.get("name") or f"node{idx}"
        extras = dict(mesh.get("extras") or {})
        extras.update(node.get("extras") or {})
        lin = world[:3, :3]
        normal_m = np.linalg.inv(lin).T if abs(np.linalg.det(lin)) > 0 else lin
        flip = np.linalg.det(lin) < 0
        for prim in mesh.get("primitives", []):
            mode = prim.get("mode", _TRIANGLES)
            if mode not in (_TRIANGLES, _TRIANGLE_STRIP, _TRIANGLE_FAN):
                continue
            attrs = prim.get("attributes", {})
            if "POSITION" not in attrs:
                continue
            pos = _read_accessor(doc, buffers, attrs["POSITION"]).astype(np.float64)
            if "indices" in prim:
                ind = _read_accessor(doc, buffers, prim["indices"]).reshape(-1).astype(np.int64)
            else:
                ind = np.arange(len(pos), dtype=np.int64)
            faces = _triangulate(ind, mode)
            if len(faces) and (faces.max() >= len(pos) or faces.min() < 0):
                raise InputError(f"node '{name}': triangle index out of range")
            verts = pos @ lin.T + world[:3, 3]
            normals = None
            if "NORMAL" in attrs:
                nrm = _read_accessor(doc, buffers, attrs["NORMAL"]).astype(np.float64) @ normal_m.T
                length = np.linalg.norm(nrm, axis=1, keepdims=True)
                normals = np.divide(nrm, length, out=np.zeros_like(nrm), where=length > 0)
            if flip:  # a mirroring transform turns counter-clockwise into clockwise
                faces = faces[:, ::-1].copy()
            mat = materials[prim["material"]] if "material" in prim else {}
            out.append(GltfPrimitive(name=name, vertices=verts, faces=faces, normals=normals,
                                     material=dict(mat), extras=extras))
    return out
