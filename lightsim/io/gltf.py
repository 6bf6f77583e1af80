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

Before any geometry is read, :func:`lightsim.io.gltf_check.check_document` validates every
field used here (types, ranges, finiteness, accessor counts and offsets against their
buffers); while the node hierarchy is walked, each mesh node's world transform must be
finite and invertible and put its vertices within ``MAX_COORD_M`` of the origin. Problems
raise :class:`~lightsim.errors.InputError` with one line naming the node, accessor or
material; repairs are reported through the ``warnings`` list.

==================  =====  =======  =====================================================
parameter           unit   default  meaning
==================  =====  =======  =====================================================
``MAX_COORD_M``     m      1e6      largest world coordinate accepted (the lamp sits at
                                    the origin, the wall tens of metres away)
``MIN_SIZE_M``      m      1e-9     smallest part a transform may shrink a mesh to
``SINGULAR_RATIO``  –      1e-12    smallest/largest singular value of a transform below
                                    which it is singular (flattens the mesh)
==================  =====  =======  =====================================================
"""

from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.gltf_check import check_document, name_of

MAX_COORD_M = 1e6
MIN_SIZE_M = 1e-9
SINGULAR_RATIO = 1e-12

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
    if not isinstance(doc, dict):
        raise InputError(f"{path}: the glTF JSON is a {type(doc).__name__}, not an object")
    bufs = doc.get("buffers", [])
    if not isinstance(bufs, list):
        raise InputError(f"{path}: 'buffers' must be a list")
    buffers: list[bytes] = []
    for i, buf in enumerate(bufs):
        if not isinstance(buf, dict):
            raise InputError(f"{path}: buffer {i} must be a JSON object")
        uri = buf.get("uri")
        length = buf.get("byteLength")
        if not isinstance(length, int) or isinstance(length, bool) or length < 1:
            raise InputError(f"{path}: buffer {i}: byteLength must be a positive integer, "
                             f"got {length!r}")
        if uri is None:
            data = blob
        elif not isinstance(uri, str):
            raise InputError(f"{path}: buffer {i}: uri must be a string, got {uri!r}")
        elif uri.startswith("data:"):
            try:
                data = base64.b64decode(uri.split(",", 1)[1], validate=True)
            except (IndexError, ValueError):
                raise InputError(f"{path}: buffer {i}: corrupt base64 data URI") from None
        else:
            ext = path.parent / uri
            try:
                found = ext.is_file()
            except (OSError, ValueError):
                found = False
            if not found:
                raise InputError(f"{path}: buffer {i} file '{uri}' not found")
            data = ext.read_bytes()
        if len(data) < length:
            raise InputError(f"{path}: buffer {i} is truncated "
                             f"({len(data)} of {length} bytes)")
        buffers.append(data[:length])
    return doc, buffers


def _read_accessor(doc: dict[str, Any], buffers: list[bytes], index: int) -> np.ndarray:
    """An accessor's elements as a (count, components) array (checked by gltf_check)."""
    acc = doc["accessors"][index]
    dtype = np.dtype(_COMPONENT[acc["componentType"]]).newbyteorder("<")
    ncomp = _NCOMP[acc["type"]]
    count = acc["count"]
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
    if acc.get("normalized") and dtype.kind in "iu":  # glTF §3.11: signed ones clamp at −1
        arr = np.maximum(arr.astype(np.float64) / np.iinfo(dtype).max, -1.0)
    return arr


def _node_matrix(node: dict[str, Any]) -> np.ndarray:
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major
    m = np.eye(4)
    t = node.get("translation", [0.0, 0.0, 0.0])
    q = np.asarray(node.get("rotation", [0.0, 0.0, 0.0, 1.0]), dtype=np.float64)
    x, y, z, w = q / np.linalg.norm(q)  # gltf_check warned if it was off unit length
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


def read_gltf(path: str | Path, warnings: list[str] | None = None) -> list[GltfPrimitive]:
    """Read the default scene of a glTF/GLB file as world-space triangle primitives.

    Parameters
    ----------
    path : path-like
        ``.glb`` or ``.gltf`` file.
    warnings : list of str, optional
        What was repaired or skipped is appended here (one line each).

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
    warnings = [] if warnings is None else warnings
    try:
        doc, buffers = _load_json_and_buffers(path)
    except (KeyError, IndexError, ValueError, struct.error, RecursionError) as exc:
        raise InputError(f"{path}: corrupt glTF ({_one_line(exc)})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        check_document(doc, buffers, warnings)
        with np.errstate(all="ignore"):  # overflow is detected below, not printed
            return _collect(doc, buffers, warnings)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: corrupt glTF ({exc.__class__.__name__}: "
                         f"{_one_line(exc)})") from None


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200]


def _check_world(what: str, world: np.ndarray, local: np.ndarray, warnings: list[str]) -> None:
    """A mesh node's world transform must be finite, invertible and keep it in range."""
    if not np.all(np.isfinite(world)):
        raise InputError(f"{what}: world transform is not finite (overflowing scale or "
                         "translation)")
    s = np.linalg.svd(world[:3, :3], compute_uv=False)
    if not s[0] > 0 or s[-1] <= SINGULAR_RATIO * s[0]:
        raise InputError(f"{what}: transform is singular (scale {s[-1]:.3g} along one axis: "
                         "it flattens the mesh)")
    if len(local):
        lo, hi = local.min(axis=0), local.max(axis=0)
        corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1])
                            for c in (lo[2], hi[2])])
        world_pts = corners @ world[:3, :3].T + world[:3, 3]
        reach = float(np.abs(world_pts).max())
        if not reach <= MAX_COORD_M:
            raise InputError(f"{what}: vertices reach {reach:.3g} m from the origin (more than "
                             f"{MAX_COORD_M:g} m; glTF lengths are metres)")
        size = float(np.ptp(world_pts, axis=0).max())
        if float(np.ptp(local, axis=0).max()) > 0 and size < MIN_SIZE_M:
            raise InputError(f"{what}: transform shrinks the mesh to {size:.3g} m (below "
                             f"{MIN_SIZE_M:g} m: scale {s[0]:.3g}?)")
    if np.linalg.det(world[:3, :3]) < 0:
        warnings.append(f"{what}: mirroring transform (negative determinant): triangle "
                        "winding reversed to keep the front faces")


def _collect(doc: dict[str, Any], buffers: list[bytes], warnings: list[str]
             ) -> list[GltfPrimitive]:
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
    seen: set[int] = set()
    while stack:
        idx, parent, depth = stack.pop()
        if idx in seen:
            raise InputError(f"{name_of('node', idx, nodes[idx])} is reached twice (a cycle "
                             "in the hierarchy, or two parents)")
        seen.add(idx)
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
        what = name_of("node", idx, node)
        checked = False
        for prim in mesh.get("primitives", []):
            mode = prim.get("mode", _TRIANGLES)
            if mode not in (_TRIANGLES, _TRIANGLE_STRIP, _TRIANGLE_FAN):
                continue
            attrs = prim.get("attributes", {})
            if "POSITION" not in attrs:
                continue
            pos = _read_accessor(doc, buffers, attrs["POSITION"]).astype(np.float64)
            if not np.all(np.isfinite(pos)):
                bad = int((~np.isfinite(pos)).any(axis=1).sum())
                raise InputError(f"{what}: accessor {attrs['POSITION']} (POSITION) has {bad} "
                                 "vertices with NaN/inf coordinates")
            # the transform is the node's: warn once, check every primitive's extent
            _check_world(what, world, pos, [] if checked else warnings)
            normal_m = np.linalg.inv(lin).T
            flip = bool(np.linalg.det(lin) < 0)
            checked = True
            if "indices" in prim:
                ind = _read_accessor(doc, buffers, prim["indices"]).reshape(-1).astype(np.int64)
            else:
                ind = np.arange(len(pos), dtype=np.int64)
            faces = _triangulate(ind, mode)
            if len(faces) and (faces.max() >= len(pos) or faces.min() < 0):
                raise InputError(f"{what}: triangle index {int(faces.max())} out of range "
                                 f"(POSITION accessor {attrs['POSITION']} has {len(pos)} "
                                 "vertices)")
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
