"""Validation of a glTF 2.0 document before anything is read from it.

:func:`check_document` looks at every field :mod:`lightsim.io.gltf` and
:func:`lightsim.materials.material_from_gltf` read — scenes, nodes (children, mesh, TRS or
matrix), meshes and primitives, accessors (type, component type, count, offsets and
alignment against their buffer view), buffer views (against their buffer), buffers and
materials (factors and the extensions lightsim maps) — and raises
:class:`~lightsim.errors.InputError` with one line naming the element (``node 3 'lens'``,
``accessor 5``, ``material 1 'glass'``) and the problem. Repairs that cannot change the
result (a rotation quaternion a little off unit length, ``scenes: []``) are appended to
``warnings``. World-space checks (a transform that is singular, not finite, or puts the
geometry out of range) need the node hierarchy and are done by the reader.

===============================  =====  =========  ========================================
parameter                        unit   default    meaning
===============================  =====  =========  ========================================
``MAX_ACCESSOR_COUNT``           –      2**28      largest element count of one accessor
``QUATERNION_TOLERANCE``         –      1e-3       |‖q‖ − 1| repaired silently below this,
                                                   with a warning up to 0.5, error beyond
===============================  =====  =========  ========================================

Only what is read is checked: the accessors (and their buffer views) of mesh primitives:
``POSITION``, ``NORMAL`` and indices, the materials primitives use; texture coordinates,
animations or unused materials may be anything. Rules are the glTF 2.0 specification's
(§3.6 buffers and accessors: alignment, strides 4…252 bytes in multiples of 4; §3.7
POSITION/NORMAL are float VEC3, indices unsigned SCALAR; §5 JSON schema ranges), except
where lightsim is stricter: sparse accessors and accessors without a buffer view are not
supported, and quantised positions need
``KHR_mesh_quantization`` declared.
"""

from __future__ import annotations

import math
from typing import Any

from lightsim.errors import InputError

MAX_ACCESSOR_COUNT = 2**28
QUATERNION_TOLERANCE = 1e-3

COMPONENT_SIZE = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
COMPONENT_NAME = {5120: "BYTE", 5121: "UNSIGNED_BYTE", 5122: "SHORT", 5123: "UNSIGNED_SHORT",
                  5125: "UNSIGNED_INT", 5126: "FLOAT"}
N_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
MODES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES",
         5: "TRIANGLE_STRIP", 6: "TRIANGLE_FAN"}


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_num(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _index(value: Any, n: int, what: str, of: str) -> int:
    if not _is_int(value):
        raise InputError(f"{what}: {of} index must be an integer, got {value!r}")
    if not 0 <= value < n:
        raise InputError(f"{what}: {of} {value} does not exist (the file has {n})")
    return value


def numbers(value: Any, n: int | tuple[int, ...], what: str, field: str, *,
            lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False) -> list[float]:
    """``value`` as a list of ``n`` finite numbers in [lo, hi] (or (lo, hi]), else one line.

    Parameters
    ----------
    value : any
        The JSON value.
    n : int or tuple of int
        Allowed lengths.
    what, field : str
        The element (``material 1 'glass'``) and the field name, for the message.
    lo, hi : float
        Allowed range; ``lo_open`` excludes ``lo``.
    """
    lengths = (n,) if isinstance(n, int) else n
    if not isinstance(value, list) or len(value) not in lengths:
        want = " or ".join(str(k) for k in lengths)
        raise InputError(f"{what}: {field} must be a list of {want} numbers, got {value!r}")
    for x in value:
        if not _is_num(x):
            raise InputError(f"{what}: {field} must hold numbers, got {value!r}")
        if not math.isfinite(x):
            raise InputError(f"{what}: {field} must be finite, got {value!r}")
        if x < lo or x > hi or (lo_open and x == lo):
            rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
            raise InputError(f"{what}: {field} must lie in {rng}, got {value!r}")
    return [float(x) for x in value]


def number(value: Any, what: str, field: str, *, lo: float = -math.inf, hi: float = math.inf,
           lo_open: bool = False, allow_inf: bool = False) -> float:
    """``value`` as one finite number in range (``allow_inf``: +inf allowed), else one line."""
    if not _is_num(value):
        raise InputError(f"{what}: {field} must be a number, got {value!r}")
    if math.isnan(value) or (math.isinf(value) and not (allow_inf and value > 0)):
        raise InputError(f"{what}: {field} must be finite, got {value!r}")
    if value < lo or value > hi or (lo_open and value == lo):
        rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise InputError(f"{what}: {field} must lie in {rng}, got {value!r}")
    return float(value)


def _dict(value: Any, what: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise InputError(f"{what} must be a JSON object, got {type(value).__name__}")
    return value


def _list(doc: dict[str, Any], key: str) -> list[Any]:
    value = doc.get(key, [])
    if not isinstance(value, list):
        raise InputError(f"'{key}' must be a list, got {type(value).__name__}")
    return value


def name_of(kind: str, i: int, obj: Any) -> str:
    """``node 3 'lens'`` (the name only when it is a string)."""
    name = obj.get("name") if isinstance(obj, dict) else None
    return f"{kind} {i} '{name}'" if isinstance(name, str) and name else f"{kind} {i}"


def check_document(doc: Any, buffers: list[bytes], warnings: list[str]) -> None:
    """Validate a parsed glTF document and its buffers (see the module docstring).

    Parameters
    ----------
    doc : any
        The parsed JSON document.
    buffers : list of bytes
        The buffers' data, in order.
    warnings : list of str
        Repairs are appended here.

    Raises
    ------
    InputError
        One line naming the element and the problem.
    """
    doc = _dict(doc, "the glTF document")
    used = doc.get("extensionsUsed", []) or []
    required = doc.get("extensionsRequired", []) or []
    if not isinstance(used, list) or not isinstance(required, list):
        raise InputError("extensionsUsed/extensionsRequired must be lists")
    quantized = "KHR_mesh_quantization" in used or "KHR_mesh_quantization" in required
    nodes = _list(doc, "nodes")
    meshes = _list(doc, "meshes")
    accessors = _list(doc, "accessors")
    views = _list(doc, "bufferViews")
    materials = _list(doc, "materials")
    _list(doc, "buffers")

    # only what the loader reads: accessors and materials of mesh primitives (texture
    # coordinates, animations, unused materials are not our business)
    read_acc, read_mat = _referenced(meshes, len(accessors), len(materials))
    read_views: set[int] = set()
    for i in sorted(read_acc):
        acc = _dict(accessors[i], name_of("accessor", i, accessors[i]))
        if "bufferView" in acc:
            read_views.add(_index(acc["bufferView"], len(views), name_of("accessor", i, acc),
                                  "bufferView"))
    for i in sorted(read_views):
        _check_view(i, views[i], buffers)
    for i in sorted(read_acc):
        _check_accessor(i, accessors[i], views)
    for i in sorted(read_mat):
        check_material(name_of("material", i, materials[i]), materials[i])
    for i, mesh in enumerate(meshes):
        _check_mesh(i, mesh, accessors, len(materials), quantized, warnings)
    for i, node in enumerate(nodes):
        check_node(i, node, len(nodes), len(meshes), warnings)
    _check_scenes(doc, len(nodes), warnings)


def _referenced(meshes: list[Any], n_acc: int, n_mat: int) -> tuple[set[int], set[int]]:
    """Indices of the accessors (POSITION, NORMAL, indices) and materials of primitives."""
    acc: set[int] = set()
    mat: set[int] = set()
    for i, mesh in enumerate(meshes):
        what = name_of("mesh", i, mesh)
        prims = _dict(mesh, what).get("primitives")
        if not isinstance(prims, list):
            raise InputError(f"{what}: primitives must be a list, got {prims!r}")
        for j, prim in enumerate(prims):
            pw = f"{what} primitive {j}"
            prim = _dict(prim, pw)
            attrs = prim.get("attributes")
            if not isinstance(attrs, dict):
                raise InputError(f"{pw}: attributes must be a JSON object, got {attrs!r}")
            for key, label in (("POSITION", "POSITION accessor"), ("NORMAL", "NORMAL accessor")):
                if key in attrs:
                    acc.add(_index(attrs[key], n_acc, pw, label))
            if "indices" in prim:
                acc.add(_index(prim["indices"], n_acc, pw, "indices accessor"))
            if "material" in prim:
                mat.add(_index(prim["material"], n_mat, pw, "material"))
    return acc, mat


def _check_scenes(doc: dict[str, Any], n_nodes: int, warnings: list[str]) -> None:
    if "scenes" in doc and doc["scenes"] == []:
        warnings.append("'scenes' is empty: every root node is loaded")
        return
    scenes = _list(doc, "scenes")
    if "scene" in doc:
        if not scenes:
            raise InputError(f"'scene' is {doc['scene']!r} but the file has no scenes")
        _index(doc["scene"], len(scenes), "the default scene", "scene")
    for i, sc in enumerate(scenes):
        what = name_of("scene", i, sc)
        sc = _dict(sc, what)
        roots = sc.get("nodes", [])
        if not isinstance(roots, list):
            raise InputError(f"{what}: 'nodes' must be a list")
        for r in roots:
            _index(r, n_nodes, what, "node")


def check_node(i: int, node: Any, n_nodes: int, n_meshes: int, warnings: list[str]) -> None:
    """Types and ranges of one node's fields (its world transform is checked by the reader)."""
    what = name_of("node", i, node)
    node = _dict(node, what)
    if "name" in node and not isinstance(node["name"], str):
        raise InputError(f"{what}: name must be a string, got {node['name']!r}")
    children = node.get("children", [])
    if not isinstance(children, list):
        raise InputError(f"{what}: children must be a list")
    for c in children:
        _index(c, n_nodes, what, "child node")
    if "mesh" in node:
        _index(node["mesh"], n_meshes, what, "mesh")
    if "matrix" in node:
        numbers(node["matrix"], 16, what, "matrix")
        if any(k in node for k in ("translation", "rotation", "scale")):
            warnings.append(f"{what}: has both a matrix and TRS: the matrix is used")
    else:
        if "translation" in node:
            numbers(node["translation"], 3, what, "translation")
        if "scale" in node:
            numbers(node["scale"], 3, what, "scale")
        if "rotation" in node:
            q = numbers(node["rotation"], 4, what, "rotation")
            norm = math.sqrt(sum(x * x for x in q))
            if abs(norm - 1.0) > 0.5:
                raise InputError(f"{what}: rotation {q} is not a unit quaternion "
                                 f"(length {norm:.3g})")
            if abs(norm - 1.0) > QUATERNION_TOLERANCE:
                warnings.append(f"{what}: rotation quaternion of length {norm:.4g} normalised")
    if "extras" in node and node["extras"] is not None and not isinstance(node["extras"], dict):
        raise InputError(f"{what}: extras must be a JSON object, got {node['extras']!r}")
    ls = (node.get("extras") or {}).get("lightsim")
    if ls is not None and not isinstance(ls, dict):
        raise InputError(f"{what}: extras.lightsim must be a JSON object, got {ls!r}")


def _check_mesh(i: int, mesh: Any, accessors: list[Any], n_materials: int, quantized: bool,
                warnings: list[str]) -> None:
    what = name_of("mesh", i, mesh)
    mesh = _dict(mesh, what)
    if "name" in mesh and not isinstance(mesh["name"], str):
        raise InputError(f"{what}: name must be a string, got {mesh['name']!r}")
    prims = mesh.get("primitives")
    if not isinstance(prims, list):
        raise InputError(f"{what}: primitives must be a list, got {prims!r}")
    if "extras" in mesh and mesh["extras"] is not None and not isinstance(mesh["extras"], dict):
        raise InputError(f"{what}: extras must be a JSON object, got {mesh['extras']!r}")
    for j, prim in enumerate(prims):
        pw = f"{what} primitive {j}"
        prim = _dict(prim, pw)
        mode = prim.get("mode", 4)
        if not _is_int(mode) or mode not in MODES:
            raise InputError(f"{pw}: mode must be 0…6, got {mode!r}")
        if mode < 4:
            warnings.append(f"{pw}: {MODES[mode]} primitive skipped (only triangles are traced)")
        if "material" in prim:
            _index(prim["material"], n_materials, pw, "material")
        attrs = prim.get("attributes")
        if not isinstance(attrs, dict):
            raise InputError(f"{pw}: attributes must be a JSON object, got {attrs!r}")
        if mode >= 4 and "POSITION" not in attrs:
            raise InputError(f"{pw}: has no POSITION attribute")
        for key in ("POSITION", "NORMAL"):
            if key not in attrs:
                continue
            a = _index(attrs[key], len(accessors), pw, f"{key} accessor")
            acc = accessors[a]
            ct = acc["componentType"]
            if acc["type"] != "VEC3":
                raise InputError(f"accessor {a} ({key} of {pw}): type must be VEC3, "
                                 f"got {acc['type']}")
            if ct != 5126 and not (quantized and ct in (5120, 5121, 5122, 5123)):
                raise InputError(f"accessor {a} ({key} of {pw}): componentType "
                                 f"{COMPONENT_NAME[ct]} is not FLOAT (quantised attributes "
                                 "need KHR_mesh_quantization)")
        if "indices" in prim:
            a = _index(prim["indices"], len(accessors), pw, "indices accessor")
            acc = accessors[a]
            if acc["type"] != "SCALAR" or acc["componentType"] not in (5121, 5123, 5125):
                raise InputError(f"accessor {a} (indices of {pw}): must be an unsigned "
                                 f"SCALAR, got {COMPONENT_NAME[acc['componentType']]} "
                                 f"{acc['type']}")
            if acc.get("normalized"):
                raise InputError(f"accessor {a} (indices of {pw}): must not be normalized")


def _check_accessor(i: int, acc: Any, views: list[Any]) -> None:
    what = name_of("accessor", i, acc)
    acc = _dict(acc, what)
    if "sparse" in acc:
        raise InputError(f"{what}: sparse accessors are not supported")
    ct = acc.get("componentType")
    if not _is_int(ct) or ct not in COMPONENT_SIZE:
        raise InputError(f"{what}: componentType must be one of "
                         f"{', '.join(map(str, COMPONENT_SIZE))}, got {ct!r}")
    kind = acc.get("type")
    if kind not in N_COMPONENTS:
        raise InputError(f"{what}: type must be one of {', '.join(N_COMPONENTS)}, got {kind!r}")
    count = acc.get("count")
    if not _is_int(count) or not 1 <= count <= MAX_ACCESSOR_COUNT:
        raise InputError(f"{what}: count must be an integer in 1…{MAX_ACCESSOR_COUNT}, "
                         f"got {count!r}")
    if "normalized" in acc and not isinstance(acc["normalized"], bool):
        raise InputError(f"{what}: normalized must be true or false, got {acc['normalized']!r}")
    if acc.get("normalized") and ct in (5125, 5126):
        raise InputError(f"{what}: a {COMPONENT_NAME[ct]} accessor cannot be normalized")
    if "bufferView" not in acc:
        raise InputError(f"{what}: has no bufferView (all-zero accessors are not supported)")
    v = _index(acc["bufferView"], len(views), what, "bufferView")
    view = views[v]
    offset = acc.get("byteOffset", 0)
    if not _is_int(offset) or offset < 0:
        raise InputError(f"{what}: byteOffset must be a non-negative integer, got {offset!r}")
    size = COMPONENT_SIZE[ct]
    ncomp = N_COMPONENTS[kind]
    elem = size * ncomp
    start = view.get("byteOffset", 0) + offset
    if start % size:
        raise InputError(f"{what}: starts at byte {start} of its buffer, not a multiple of "
                         f"its {size}-byte component (misaligned)")
    stride = view.get("byteStride") or elem
    if stride < elem:
        raise InputError(f"{what}: bufferView {v} byteStride {stride} is shorter than one "
                         f"{kind} element ({elem} bytes)")
    needed = offset + stride * (count - 1) + elem
    if needed > view["byteLength"]:
        raise InputError(f"{what}: {count} × {kind} {COMPONENT_NAME[ct]} needs {needed} bytes "
                         f"of bufferView {v}, which has {view['byteLength']}")


def _check_view(i: int, view: Any, buffers: list[bytes]) -> None:
    what = name_of("bufferView", i, view)
    view = _dict(view, what)
    b = _index(view.get("buffer"), len(buffers), what, "buffer")
    offset = view.get("byteOffset", 0)
    length = view.get("byteLength")
    if not _is_int(offset) or offset < 0:
        raise InputError(f"{what}: byteOffset must be a non-negative integer, got {offset!r}")
    if not _is_int(length) or length < 1:
        raise InputError(f"{what}: byteLength must be a positive integer, got {length!r}")
    if offset + length > len(buffers[b]):
        raise InputError(f"{what}: bytes {offset}…{offset + length} run past the end of "
                         f"buffer {b} ({len(buffers[b])} bytes; truncated file?)")
    if "byteStride" in view:
        s = view["byteStride"]
        if not _is_int(s) or not 4 <= s <= 252 or s % 4:
            raise InputError(f"{what}: byteStride must be 4…252 and a multiple of 4, got {s!r}")


def check_material(what: str, mat: Any) -> None:
    """Types and ranges of the material fields lightsim reads (one line on error)."""
    mat = _dict(mat, what)
    pbr = mat.get("pbrMetallicRoughness", {})
    pbr = _dict(pbr, f"{what}: pbrMetallicRoughness")
    if "baseColorFactor" in pbr:
        numbers(pbr["baseColorFactor"], (3, 4), what, "baseColorFactor", lo=0.0, hi=1.0)
    if "metallicFactor" in pbr:
        number(pbr["metallicFactor"], what, "metallicFactor", lo=0.0, hi=1.0)
    if "emissiveFactor" in mat:
        # > 1 is allowed (KHR_materials_emissive_strength style); only "non-zero" matters
        numbers(mat["emissiveFactor"], 3, what, "emissiveFactor", lo=0.0)
    ext = _dict(mat.get("extensions", {}), f"{what}: extensions")
    tr = _dict(ext.get("KHR_materials_transmission", {}), f"{what}: KHR_materials_transmission")
    if "transmissionFactor" in tr:
        number(tr["transmissionFactor"], what, "transmissionFactor", lo=0.0, hi=1.0)
    ior = _dict(ext.get("KHR_materials_ior", {}), f"{what}: KHR_materials_ior")
    if "ior" in ior:
        number(ior["ior"], what, "KHR_materials_ior ior", lo=1.0)
    vol = _dict(ext.get("KHR_materials_volume", {}), f"{what}: KHR_materials_volume")
    if "attenuationDistance" in vol:
        number(vol["attenuationDistance"], what, "attenuationDistance", lo=0.0, lo_open=True,
               allow_inf=True)
    if "attenuationColor" in vol:
        numbers(vol["attenuationColor"], 3, what, "attenuationColor", lo=0.0, hi=1.0,
                lo_open=True)
