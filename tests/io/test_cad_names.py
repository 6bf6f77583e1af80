"""CAD names through OpenCASCADE's XCAF document: named solids and faces of STEP and IGES
files, assembly placements, units, exact-surface normals, and material maps that target
single faces.

Every CAD file is made at test time with OpenCASCADE's own writers (cadquery-ocp): named
solids (``TDataStd_Name`` on shapes) and named faces (named XCAF sub-shapes, written to
STEP as ``ADVANCED_FACE('name', …)`` and to IGES as entity names).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from support import run_cli

pytest.importorskip("OCP", reason="the XCAF CAD reader needs cadquery-ocp (the 'cad-names' "
                                  "extra)")

from lightsim.errors import InputError
from lightsim.io.cad import Tessellation, read_cad
from lightsim.io.cad_xcaf import FaceLabels
from lightsim.materialmap import read_material_map
from lightsim.materials import DIELECTRIC, DIFFUSE, MIRROR
from lightsim.partlist import list_parts
from lightsim.scene import EMITTER, SceneSettings, load_scene

COARSE = Tessellation(0.1, 10.0)
BOX_MM = (40.0, 30.0, 20.0)            # housing box, corner at the origin
NAMED = {2: "lid", 5: "window"}        # face index (OpenCASCADE order, 1-based) → CAD name


def _quiet():
    from OCP.Message import Message, Message_PrinterOStream

    Message.DefaultMessenger_s().RemovePrinters(Message_PrinterOStream.get_type_descriptor_s())


def _faces(shape):
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer

    ex, out = TopExp_Explorer(shape, TopAbs_FACE), []
    while ex.More():
        out.append(ex.Current())
        ex.Next()
    return out


def write_named_cad(path, *, unit: str = "MM", assembly: bool = False):
    """A box 'housing' with two named faces and a sphere 'filament' (mm), as STEP/IGES.

    With ``assembly`` the housing is placed twice (+0 and +100 mm in x) in an assembly
    'lamp' whose components are named 'left' and 'right'.
    """
    _quiet()
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox, BRepPrimAPI_MakeSphere
    from OCP.gp import gp_Pnt, gp_Trsf, gp_Vec
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.IGESCAFControl import IGESCAFControl_Writer
    from OCP.Interface import Interface_Static
    from OCP.STEPCAFControl import STEPCAFControl_Controller, STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    def name(label, text):
        TDataStd_Name.Set_s(label, TCollection_ExtendedString(text))

    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    box = BRepPrimAPI_MakeBox(*BOX_MM).Shape()
    sphere = BRepPrimAPI_MakeSphere(gp_Pnt(20.0, 15.0, 10.0), 2.0).Shape()
    if assembly:
        assy = tool.NewShape()
        name(assy, "lamp")
        housing = tool.AddShape(box, False)
        for comp, dx in (("left", 0.0), ("right", 100.0)):
            t = gp_Trsf()
            t.SetTranslation(gp_Vec(dx, 0.0, 0.0))
            name(tool.AddComponent(assy, housing, TopLoc_Location(t)), comp)
    else:
        housing = tool.AddShape(box, False)
    name(housing, "housing")
    for k, face in enumerate(_faces(box), start=1):
        if k in NAMED:
            name(tool.AddSubShape(housing, face), NAMED[k])
    name(tool.AddShape(sphere, False), "filament")
    tool.UpdateAssemblies()  # the assembly's compound now holds its components
    if str(path).lower().endswith((".step", ".stp")):
        STEPCAFControl_Controller.Init_s()
        Interface_Static.SetIVal_s("write.stepcaf.subshapes.name", 1)
        Interface_Static.SetCVal_s("write.step.unit", unit)
        w = STEPCAFControl_Writer()
        w.SetNameMode(True)
        w.Transfer(doc, STEPControl_AsIs)
        ok = w.Write(str(path)) == IFSelect_RetDone
        Interface_Static.SetCVal_s("write.step.unit", "MM")
    else:
        w = IGESCAFControl_Writer()
        w.SetNameMode(True)
        w.Transfer(doc)
        ok = bool(w.Write(str(path)))
    assert ok
    return path


@pytest.mark.parametrize("suffix", [".step", ".igs"])
def test_solid_and_face_names_survive(tmp_path, suffix):
    cad = write_named_cad(tmp_path / f"lamp{suffix}")
    parts = {p.name: p for p in read_cad(cad, COARSE)}
    assert set(parts) == {"housing", "filament"}           # IGES too: no iges-1, iges-2
    labels = parts["housing"].extras["cad_faces"]
    assert isinstance(labels, FaceLabels)
    assert labels.names == ("face-1", "lid", "face-3", "face-4", "window", "face-6")
    assert len(labels.triangle_face) == len(parts["housing"].faces)
    assert set(np.unique(labels.triangle_face)) == set(range(6))
    v = np.asarray(parts["housing"].vertices)
    np.testing.assert_allclose(v.min(axis=0), 0.0, atol=1e-9)
    np.testing.assert_allclose(v.max(axis=0), np.array(BOX_MM) * 1e-3, atol=1e-9)  # metres


def test_named_faces_are_the_faces_the_writer_named(tmp_path):
    """Each named face is the box side the test named, found by its plane."""
    cad = write_named_cad(tmp_path / "lamp.step")
    from OCP.BRepGProp import BRepGProp
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox
    from OCP.GProp import GProp_GProps

    box = BRepPrimAPI_MakeBox(*BOX_MM).Shape()
    housing = next(p for p in read_cad(cad, COARSE) if p.name == "housing")
    labels = housing.extras["cad_faces"]
    v = np.asarray(housing.vertices)
    for k, nm in NAMED.items():
        props = GProp_GProps()
        BRepGProp.SurfaceProperties_s(_faces(box)[k - 1], props)
        c = props.CentreOfMass()
        centre = np.array([c.X(), c.Y(), c.Z()]) * 1e-3
        tri = housing.faces[labels.triangle_face == labels.names.index(nm)]
        np.testing.assert_allclose(v[np.unique(tri)].mean(axis=0), centre, atol=1e-9)


def test_normals_are_exact_and_outward_with_consistent_winding(tmp_path):
    cad = write_named_cad(tmp_path / "lamp.step")
    parts = {p.name: p for p in read_cad(cad, COARSE)}
    sph = parts["filament"]
    v, n = np.asarray(sph.vertices), np.asarray(sph.normals)
    radial = v - np.array([0.020, 0.015, 0.010])
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", n, radial).min() > 1 - 1e-9   # the exact sphere normal
    for p in parts.values():                                     # winding agrees with normals
        tv = np.asarray(p.vertices)[p.faces]
        fn = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
        vn = np.asarray(p.normals)[p.faces].mean(axis=1)
        area2 = np.linalg.norm(fn, axis=1)
        ok = area2 > 1e-12 * area2.max()                         # poles: zero-area triangles
        assert (np.einsum("ij,ij->i", fn, vn)[ok] > 0).all()
    box = parts["housing"]
    centre = np.array(BOX_MM) * 0.5e-3
    outward = np.einsum("ij,ij->i", np.asarray(box.normals), np.asarray(box.vertices) - centre)
    assert (outward > 0).all()


def test_assembly_placements_are_applied(tmp_path):
    cad = write_named_cad(tmp_path / "assy.step", assembly=True)
    parts = read_cad(cad, COARSE)
    housings = [p for p in parts if p.name == "housing"]
    assert len(housings) == 2 and {p.name for p in parts} == {"housing", "filament"}
    xmin = sorted(float(np.asarray(p.vertices)[:, 0].min()) for p in housings)
    np.testing.assert_allclose(xmin, [0.0, 0.100], atol=1e-9)
    for p in housings:
        assert p.extras["cad_faces"].names[1] == "lid"


def test_step_in_metres_reads_in_metres(tmp_path):
    a = read_cad(write_named_cad(tmp_path / "mm.step"), COARSE)
    b = read_cad(write_named_cad(tmp_path / "m.step", unit="M"), COARSE)
    for pa, pb in zip(sorted(a, key=lambda p: p.name), sorted(b, key=lambda p: p.name),
                      strict=True):
        np.testing.assert_allclose(np.asarray(pa.vertices).max(axis=0),
                                   np.asarray(pb.vertices).max(axis=0), rtol=1e-9)


def test_cascadio_fallback_keeps_solids_without_face_names(tmp_path):
    pytest.importorskip("cascadio", reason="the fallback reader needs cascadio (the 'cad' "
                                           "extra)")
    cad = write_named_cad(tmp_path / "lamp.step")
    parts = read_cad(cad, COARSE, backend="cascadio")
    assert {p.name for p in parts} == {"housing", "filament"}
    assert all("cad_faces" not in p.extras for p in parts)
    with pytest.raises(InputError, match="backend"):
        read_cad(cad, COARSE, backend="magic")


def _map(tmp_path, body: str):
    m = tmp_path / "map.toml"
    m.write_text('schema = "lightsim-materials-1"\n' + body +
                 '[[rule]]\nmatch = "filament"\nkind = "emitter"\nflux_lm = 100\n')
    return m


def test_material_map_targets_named_and_numbered_faces(tmp_path):
    cad = write_named_cad(tmp_path / "lamp.igs")
    mmap = _map(tmp_path, '[[rule]]\nmatch = "housing/lid"\nkind = "mirror"\n'
                          '[[rule]]\nmatch = "housing/face-3"\nkind = "glass"\nior = 1.5\n'
                          '[[rule]]\nmatch = "housing*"\nkind = "diffuse"\n')
    whole = next(p for p in read_cad(cad, COARSE) if p.name == "housing")
    scene = load_scene(cad, SceneSettings(materials=mmap, tessellation=COARSE))
    by = {p.name: p for p in scene.parts}
    assert {"housing/lid", "housing/face-3", "housing", "filament"} <= set(by)
    assert by["housing/lid"].material.kind == MIRROR
    assert by["housing/face-3"].material.kind == DIELECTRIC
    assert by["housing"].material.kind == DIFFUSE and by["filament"].role == EMITTER
    assert "housing/window" not in by           # matched by "housing*" like its part
    # the split keeps every triangle once and each piece's vertices are its own
    pieces = [by[n] for n in ("housing/lid", "housing/face-3", "housing")]
    assert sum(len(p.faces) for p in pieces) == len(whole.faces)
    for p in pieces:
        assert p.faces.max() < len(p.vertices) and len(np.unique(p.faces)) == len(p.vertices)
    lid_z = np.asarray(by["housing/lid"].vertices)[:, :]
    assert np.ptp(lid_z, axis=0).min() == pytest.approx(0.0, abs=1e-12)  # one flat side


def test_part_material_option_splits_a_face(tmp_path):
    cad = write_named_cad(tmp_path / "lamp.step")
    mmap = _map(tmp_path, '[[rule]]\nmatch = "housing*"\nkind = "diffuse"\n')
    scene = load_scene(cad, SceneSettings(materials=mmap, tessellation=COARSE,
                       part_materials={"housing/window": "mirror"}))
    by = {p.name: p for p in scene.parts}
    assert by["housing/window"].material.kind == MIRROR
    assert by["housing"].material.kind == DIFFUSE
    with pytest.raises(InputError, match="unknown part"):
        load_scene(cad, SceneSettings(materials=mmap, tessellation=COARSE,
                   part_materials={"housing/face-99": "mirror"}))


def test_cli_face_rule_runs(tmp_path, capsys):
    cad = write_named_cad(tmp_path / "lamp.step")
    mmap = _map(tmp_path, '[[rule]]\nmatch = "housing/window"\nkind = "ignore"\n'
                          '[[rule]]\nmatch = "housing*"\nkind = "mirror"\n')
    code, _, err = run_cli(["simulate", str(cad), "--materials", str(mmap),
                            "--cad-linear-tol", "0.1", "--cad-angular-tol", "10",
                            "--photons", "5000", "--resolution", "32x16", "--out",
                            str(tmp_path / "o")], capsys)
    assert code in (0, None), err
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["energy_lm"]["emitted"] == pytest.approx(100.0)


def test_parts_lists_solids_and_face_addresses_a_map_can_use(tmp_path):
    cad = write_named_cad(tmp_path / "lamp.step")
    entries = {e.name: e for e in list_parts(cad, tess=COARSE)}
    assert set(entries) == {"housing", "filament"}
    housing = entries["housing"]
    assert [f.address for f in housing.faces] == [
        "housing/face-1", "housing/lid", "housing/face-3", "housing/face-4",
        "housing/window", "housing/face-6"]
    assert sum(f.triangles for f in housing.faces) == housing.triangles
    assert housing.size_mm == pytest.approx(BOX_MM, abs=1e-6)
    # every listed address is one a run accepts: naming it splits that face off
    scene = load_scene(cad, SceneSettings(
        tessellation=COARSE, part_materials={"filament": "ignore"} | {
            f.address: "mirror" for f in housing.faces[:2]},
        filament="H7", filament_at=(0.02, 0.015, 0.05)))
    assert {"housing/face-1", "housing/lid"} <= {p.name for p in scene.parts}


def test_parts_shows_the_rule_each_name_gets(tmp_path):
    cad = write_named_cad(tmp_path / "lamp.step")
    mmap = read_material_map(_map(tmp_path, '[[rule]]\nmatch = "housing/lid"\nkind = "mirror"\n'
                                            '[[rule]]\nmatch = "housing*"\nkind = "diffuse"\n'))
    entries = {e.name: e for e in list_parts(cad, mmap, COARSE)}
    assert entries["housing"].rule == 2 and entries["filament"].rule == 3
    faces = {f.address: f for f in entries["housing"].faces}
    assert faces["housing/lid"].rule == 1 and faces["housing/lid"].split
    assert faces["housing/window"].rule == 2 and not faces["housing/window"].split


def test_cli_parts_and_no_emitter_error_name_the_parts(tmp_path, capsys):
    cad = write_named_cad(tmp_path / "lamp.step")
    code, out, _ = run_cli(["luminaire", "parts", str(cad)], capsys)
    assert code in (0, None)
    assert "housing/window" in out and "filament" in out and "no part emits light" in out
    code, out, err = run_cli(["simulate", str(cad), "--part-material", "filament=diffuse",
                              "--photons", "100", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "Traceback" not in err
    line = [x for x in err.splitlines() if "no emitter" in x]
    assert len(line) == 1 and "(housing, filament)" in line[0]
    assert "luminaire parts lamp.step" in line[0]
    assert not (tmp_path / "o" / "summary.json").exists()
    code, _, err = run_cli(["luminaire", "parts", str(tmp_path / "lamp.obj")], capsys)
    assert code == 2 and "no such file" in err
