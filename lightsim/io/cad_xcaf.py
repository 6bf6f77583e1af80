"""STEP and IGES through OpenCASCADE's XCAF document: named solids *and* named faces.

``cascadio`` (the fallback in :mod:`lightsim.io.cad`) meshes a STEP file into one glTF mesh
per solid: the faces inside a solid lose their identity, and IGES parts lose their names.
With OpenCASCADE's Python binding (``cadquery-ocp``, the ``cad-names`` extra) the file is
read into an XCAF document instead (``STEPCAFControl_Reader`` / ``IGESCAFControl_Reader``
with names on), which keeps the CAD tree:

* every simple shape of the tree (a product: a solid, a shell, a face or a compound of
  them) becomes one part, named by its product name (``TDataStd_Name``), or by its
  instance name, or ``part-<n>``; assembly placements are applied;
* every face of a part has a name: its own CAD name when the file gives one (STEP
  ``ADVANCED_FACE('name', …)`` read as an XCAF sub-shape; IGES entity names through the
  transfer reader), else ``face-<k>``, k counting the part's distinct faces from 1 in
  OpenCASCADE's exploration order (``TopExp.MapShapes``). A material map targets one face
  as ``"<part>/<face>"`` (``"reflector/face-3"``, ``"reflector/hot-spot"``); see
  :func:`lightsim.materialmap.split_cad_faces`;
* tessellation by ``BRepMesh_IncrementalMesh`` with the linear tolerance (mm, converted to
  the document unit) and the angular tolerance (deg);
* vertex normals from the exact surface: ``BRepLProp_SLProps`` at each mesh node's (u, v)
  on ``BRepAdaptor_Surface``, flipped on reversed faces (whose triangles are re-wound);
  where the surface normal is undefined (a cone apex, a sphere pole) the node takes the
  area-weighted mean of its facets' normals.

Units: OpenCASCADE converts the file to the session unit (``xstep.cascade.unit``,
millimetres by default); lightsim scales to metres from that.

=================  =====  =======  =====================================================
parameter          unit   default  meaning
=================  =====  =======  =====================================================
``linear_tol``     mm     0.01     largest facet-to-surface distance (from ``Tessellation``)
``angular_tol``    deg    2        largest angle between neighbouring facet normals
=================  =====  =======  =====================================================
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.gltf import GltfPrimitive

FACE_PREFIX = "face-"
FACE_SEP = "/"
# OpenCASCADE session length units (xstep.cascade.unit) → metres
_SESSION_UNITS_M = {"MM": 1e-3, "M": 1.0, "CM": 1e-2, "KM": 1e3, "IN": 0.0254,
                    "FT": 0.3048, "MI": 1609.344, "UM": 1e-6, "MIL": 0.0254e-3,
                    "UIN": 0.0254e-6}


@dataclass(frozen=True)
class FaceLabels:
    """Which CAD face each triangle of a part came from.

    Attributes
    ----------
    names : tuple of str
        Face names within the part (CAD name or ``face-<k>``), index = face number − 1.
    triangle_face : (m,) int32 array
        Per triangle, the index into ``names``.
    """

    names: tuple[str, ...]
    triangle_face: np.ndarray


def have_ocp() -> bool:
    """True when OpenCASCADE's Python binding (``cadquery-ocp``) can be imported."""
    try:
        import OCP.STEPCAFControl
        import OCP.XCAFDoc  # noqa: F401
    except ImportError:
        return False
    return True


def _quiet() -> None:
    # OpenCASCADE prints transfer statistics on stdout: keep the command line clean
    from OCP.Message import Message, Message_PrinterOStream

    Message.DefaultMessenger_s().RemovePrinters(Message_PrinterOStream.get_type_descriptor_s())


def _label_sequence():
    try:
        from OCP.TDF import TDF_LabelSequence  # OCP 7.x
    except ImportError:
        from OCP.OCP.collections import Sequence_TDF_Label as TDF_LabelSequence  # OCP 8
    return TDF_LabelSequence()


def _labels(seq) -> list:
    return [seq.Value(i) for i in range(1, seq.Length() + 1)]


def _name(label) -> str | None:
    from OCP.TDataStd import TDataStd_Name

    attr = TDataStd_Name()
    if label.FindAttribute(TDataStd_Name.GetID_s(), attr):
        s = attr.Get().ToExtString().strip()
        return s or None
    return None


def _read_document(path: Path, kind: str):
    """(XCAF document, reader) of a STEP or IGES file, names on."""
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.IGESCAFControl import IGESCAFControl_Reader
    from OCP.Interface import Interface_Static
    from OCP.STEPCAFControl import STEPCAFControl_Controller, STEPCAFControl_Reader
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDocStd import TDocStd_Document

    _quiet()
    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    if kind == "step":
        STEPCAFControl_Controller.Init_s()
        # face names (ADVANCED_FACE('name', …)) become named XCAF sub-shapes
        Interface_Static.SetIVal_s("read.stepcaf.subshapes.name", 1)
        reader = STEPCAFControl_Reader()
    else:
        reader = IGESCAFControl_Reader()
    reader.SetNameMode(True)
    try:
        ok = reader.ReadFile(str(path)) == IFSelect_RetDone and reader.Transfer(doc)
    except Exception as exc:  # OpenCASCADE raises Standard_Failure subclasses
        raise InputError(f"{path}: OpenCASCADE could not read this {kind.upper()} file "
                         f"({exc.__class__.__name__})") from None
    if not ok:
        raise InputError(f"{path}: OpenCASCADE could not read this {kind.upper()} file")
    return doc, reader


def _session_unit_m() -> float:
    from OCP.Interface import Interface_Static

    unit = (Interface_Static.CVal_s("xstep.cascade.unit") or "MM").upper()
    if unit not in _SESSION_UNITS_M:
        raise InputError(f"OpenCASCADE session unit {unit!r} is not supported")
    return _SESSION_UNITS_M[unit]


def _products(doc) -> list[tuple[str | None, Any, Any, Any]]:
    """(name, shape, label, location) of every simple shape in the XCAF tree."""
    from OCP.TDF import TDF_Label
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFDoc import XCAFDoc_DocumentTool, XCAFDoc_ShapeTool

    tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    out: list[tuple[str | None, Any, Any, Any]] = []

    def walk(label, loc, inst_name: str | None, depth: int) -> None:
        if depth > 64:
            raise InputError("CAD assembly nested more than 64 levels deep")
        if XCAFDoc_ShapeTool.IsAssembly_s(label):
            comps = _label_sequence()
            XCAFDoc_ShapeTool.GetComponents_s(label, comps, False)
            for c in _labels(comps):
                ref = TDF_Label()
                if XCAFDoc_ShapeTool.GetReferredShape_s(c, ref):
                    walk(ref, loc.Multiplied(XCAFDoc_ShapeTool.GetLocation_s(c)),
                         _name(c), depth + 1)
            return
        shape = XCAFDoc_ShapeTool.GetShape_s(label)
        if not shape.IsNull():
            out.append((_name(label) or inst_name, shape, label, loc))

    free = _label_sequence()
    tool.GetFreeShapes(free)
    for label in _labels(free):
        walk(label, TopLoc_Location(), None, 0)
    return out


def _face_map(shape):
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp
    try:
        from OCP.TopTools import TopTools_IndexedMapOfShape  # OCP 7.x
    except ImportError:  # OCP 8
        from OCP.OCP.collections import (
            IndexedMap_TopoDS_Shape_TopTools_ShapeMapHasher as TopTools_IndexedMapOfShape,
        )

    fmap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_FACE, fmap)
    return fmap


def _face_names(label, fmap, reader, kind: str) -> dict[int, str]:
    """Face index (1-based, in ``fmap``) → CAD name, for the faces the file names."""
    from OCP.XCAFDoc import XCAFDoc_ShapeTool

    names: dict[int, str] = {}
    subs = _label_sequence()
    if XCAFDoc_ShapeTool.GetSubShapes_s(label, subs):
        for sub in _labels(subs):
            nm = _name(sub)
            if nm is None:
                continue
            sub_map = _face_map(XCAFDoc_ShapeTool.GetShape_s(sub))
            for j in range(1, sub_map.Extent() + 1):
                k = fmap.FindIndex(sub_map.FindKey(j))
                if k > 0:
                    names.setdefault(k, nm)
    if kind == "iges":  # IGESCAFControl names only the roots: ask the transfer reader
        tr = reader.WS().TransferReader()
        for k in range(1, fmap.Extent() + 1):
            if k in names:
                continue
            ent = tr.EntityFromShapeResult(fmap.FindKey(k), 1)
            try:
                if ent is not None and ent.HasName():
                    nm = ent.NameValue().ToCString().strip()
                    if nm:
                        names[k] = nm
            except AttributeError:  # not an IGES entity
                continue
    return names


def _unique_face_names(n: int, cad: dict[int, str]) -> tuple[str, ...]:
    """Names of faces 1..n: CAD names (made unique with ``#k``) or ``face-<k>``."""
    out, seen = [], set()
    for k in range(1, n + 1):
        base = cad.get(k, f"{FACE_PREFIX}{k}").replace(FACE_SEP, "_")
        nm, j = base, 1
        while nm in seen:
            nm, j = f"{base}#{j}", j + 1
        seen.add(nm)
        out.append(nm)
    return tuple(out)


def _mesh_face(face, loc, scale: float):
    # ``loc`` is the assembly placement; the face's own location (``floc``) is applied to
    # its mesh nodes here and by BRepAdaptor_Surface to the surface normals
    """(vertices m, triangles, normals) of one meshed face, or None if it has no mesh."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.BRepLProp import BRepLProp_SLProps
    from OCP.TopAbs import TopAbs_REVERSED
    from OCP.TopLoc import TopLoc_Location

    floc = TopLoc_Location()
    tri = BRep_Tool.Triangulation_s(face, floc)
    if tri is None or tri.NbTriangles() == 0:
        return None
    trsf = loc.Multiplied(floc).Transformation()
    placement = loc.Transformation()
    nn, nt = tri.NbNodes(), tri.NbTriangles()
    verts = np.empty((nn, 3))
    for i in range(nn):
        p = tri.Node(i + 1).Transformed(trsf)
        verts[i] = (p.X(), p.Y(), p.Z())
    faces = np.empty((nt, 3), dtype=np.int64)
    for t in range(nt):
        faces[t] = tri.Triangle(t + 1).Get()
    faces -= 1
    rev = face.Orientation() == TopAbs_REVERSED
    if rev:
        faces = faces[:, [0, 2, 1]]
    normals = np.full((nn, 3), np.nan)
    if tri.HasUVNodes():
        props = BRepLProp_SLProps(BRepAdaptor_Surface(face), 1, 1e-9)
        sign = -1.0 if rev else 1.0
        for i in range(nn):
            u, v = tri.UVNode(i + 1).Coord()
            props.SetParameters(u, v)
            if props.IsNormalDefined():
                d = props.Normal().Transformed(placement)
                normals[i] = (sign * d.X(), sign * d.Y(), sign * d.Z())
    bad = ~np.isfinite(normals).all(axis=1)
    if bad.any():  # singular points of the surface: mean of the facet normals there
        tv = verts[faces]
        fn = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
        acc = np.zeros((nn, 3))
        for c in range(3):
            np.add.at(acc, faces[:, c], fn)
        ln = np.linalg.norm(acc, axis=1, keepdims=True)
        fallback = np.divide(acc, ln, out=np.zeros_like(acc), where=ln > 0)
        normals[bad] = fallback[bad]
    return verts * scale, faces, normals


def read_xcaf(path: str | os.PathLike, tess: Any) -> list:
    """Parts of a STEP/IGES file with CAD names and per-triangle face labels.

    Parameters
    ----------
    path : path-like
        ``.step``/``.stp`` or ``.iges``/``.igs`` file.
    tess : lightsim.io.cad.Tessellation
        Mesher tolerances (mm, deg).

    Returns
    -------
    list of lightsim.io.gltf.GltfPrimitive
        One per simple shape of the CAD tree, vertices in metres, exact-surface vertex
        normals, ``extras["cad_faces"]`` a :class:`FaceLabels`.
    """
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.TopoDS import TopoDS

    to_face = getattr(TopoDS, "Face_s", None) or TopoDS.Face  # OCP 7.x / 8

    p = Path(path)
    kind = "step" if p.suffix.lower() in (".step", ".stp") else "iges"
    if kind == "step" and b"ISO-10303-21" not in p.read_bytes()[:200]:
        raise InputError(f"{p}: not a STEP file (no ISO-10303-21 header)")
    doc, reader = _read_document(p, kind)
    scale = _session_unit_m()
    lin = tess.linear_tol_mm * 1e-3 / scale  # the mesher works in the session unit
    ang = math.radians(tess.angular_tol_deg)
    parts = []
    for n, (name, shape, label, loc) in enumerate(_products(doc)):
        fmap = _face_map(shape)
        if fmap.Extent() == 0:
            continue
        BRepMesh_IncrementalMesh(shape, lin, False, ang, False)
        names = _unique_face_names(fmap.Extent(), _face_names(label, fmap, reader, kind))
        vs, fs, ns, labels, base = [], [], [], [], 0
        for k in range(1, fmap.Extent() + 1):
            mesh = _mesh_face(to_face(fmap.FindKey(k)), loc, scale)
            if mesh is None:
                continue
            v, f, nrm = mesh
            vs.append(v)
            fs.append(f + base)
            ns.append(nrm)
            labels.append(np.full(len(f), k - 1, dtype=np.int32))
            base += len(v)
        if not fs:
            continue
        parts.append(GltfPrimitive(
            name or f"part-{n + 1}", np.concatenate(vs), np.concatenate(fs),
            np.concatenate(ns), {},
            {"cad_faces": FaceLabels(names, np.concatenate(labels))}))
    if not parts:
        raise InputError(f"{p}: no surfaces in this CAD file")
    return parts
