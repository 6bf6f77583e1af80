"""A headlamp as CAD (STEP/IGES B-rep) with exact surfaces, built with OpenCASCADE (OCP).

The test and example source for :mod:`lightsim.io.cad`: a paraboloid reflector as an
exact surface of revolution of a parabola (no facets), a flat cover lens, a spherical
quartz bulb shell and an axial filament cylinder at the focus — each a named part of the
CAD tree, in millimetres as CAD files are. Needs ``cadquery-ocp`` (the ``cad`` extra).

The material map written beside it (:func:`example_material_map`) gives the optics:
mirror 0.88, polycarbonate 1.59, quartz 1.46, filament 1000 lm isotropic.

================  =====  =======  ===================================================
parameter         unit   default  meaning
================  =====  =======  ===================================================
``focal_mm``      mm     25       paraboloid focal length f (vertex at the origin, +Z)
``rim_mm``        mm     80       rim radius (aperture / 2)
``hole_mm``       mm     10       radius of the bulb hole at the vertex
``lens``          –      True     add the cover lens and bulb glass
================  =====  =======  ===================================================
"""

from __future__ import annotations

import os
from pathlib import Path

from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path, write_text


def _ocp():
    try:
        from OCP.Message import Message, Message_PrinterOStream
    except ImportError:
        raise InputError("building CAD needs OpenCASCADE's Python binding: pip install "
                         "'lightsim[cad]' (cadquery-ocp)") from None
    # OpenCASCADE prints transfer statistics on stdout: keep the command line clean
    Message.DefaultMessenger_s().RemovePrinters(Message_PrinterOStream.get_type_descriptor_s())


def paraboloid_face(focal_mm: float = 25.0, rim_mm: float = 80.0, hole_mm: float = 10.0):
    """The exact paraboloid z = r² / (4f) for hole ≤ r ≤ rim as an OCP face."""
    _ocp()
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace
    from OCP.Geom import Geom_Parabola, Geom_SurfaceOfRevolution, Geom_TrimmedCurve
    from OCP.gp import gp_Ax1, gp_Ax2, gp_Dir, gp_Pnt

    if not 0 < hole_mm < rim_mm:
        raise InputError(f"need 0 < hole < rim, got {hole_mm} and {rim_mm} mm")
    # parabola in the plane normal to Y with its axis along +Z: P(u) = (u, 0, u²/4f)
    par = Geom_Parabola(gp_Ax2(gp_Pnt(0, 0, 0), gp_Dir(0, 1, 0), gp_Dir(0, 0, 1)), focal_mm)
    arc = Geom_TrimmedCurve(par, hole_mm, rim_mm)
    surf = Geom_SurfaceOfRevolution(arc, gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(0, 0, 1)))
    return BRepBuilderAPI_MakeFace(surf, 1e-7).Face()


def headlamp_shapes(focal_mm: float = 25.0, rim_mm: float = 80.0, hole_mm: float = 10.0,
                    lens: bool = True) -> list[tuple[str, object]]:
    """(name, OCP shape) of the example lamp's parts, in mm."""
    _ocp()
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Cut
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeCylinder, BRepPrimAPI_MakeSphere
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt

    f = focal_mm
    parts: list[tuple[str, object]] = [("reflector", paraboloid_face(f, rim_mm, hole_mm))]
    # axial filament: Ø 1.4 mm × 5 mm, centred on the focus
    parts.append(("filament", BRepPrimAPI_MakeCylinder(
        gp_Ax2(gp_Pnt(0, 0, f - 2.5), gp_Dir(0, 0, 1)), 0.7, 5.0).Shape()))
    if lens:
        outer = BRepPrimAPI_MakeSphere(gp_Pnt(0, 0, f), 6.0).Shape()
        inner = BRepPrimAPI_MakeSphere(gp_Pnt(0, 0, f), 5.3).Shape()
        parts.append(("bulb", BRepAlgoAPI_Cut(outer, inner).Shape()))
        z_lens = rim_mm * rim_mm / (4 * f) + 6.0
        parts.append(("lens", BRepPrimAPI_MakeCylinder(
            gp_Ax2(gp_Pnt(0, 0, z_lens), gp_Dir(0, 0, 1)), rim_mm + 5.0, 3.0).Shape()))
    return parts


def write_cad(path: str | os.PathLike, parts: list[tuple[str, object]]) -> Path:
    """Write named shapes as STEP (``.step``/``.stp``) or IGES (``.iges``/``.igs``)."""
    _ocp()
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.IGESCAFControl import IGESCAFControl_Writer
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    p = Path(path)
    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    for name, shape in parts:
        TDataStd_Name.Set_s(tool.AddShape(shape, False), TCollection_ExtendedString(name))
    suffix = p.suffix.lower()
    with atomic_path(p) as tmp:
        if suffix in (".step", ".stp"):
            w = STEPCAFControl_Writer()
            w.SetNameMode(True)
            w.Transfer(doc, STEPControl_AsIs)
            ok = w.Write(str(tmp)) == IFSelect_RetDone
        elif suffix in (".iges", ".igs"):
            w = IGESCAFControl_Writer()
            w.SetNameMode(True)
            w.Transfer(doc)
            ok = bool(w.Write(str(tmp)))
        else:
            raise InputError(f"{p}: CAD file name must end in .step, .stp, .iges or .igs")
        if not ok:
            raise InputError(f"{p}: OpenCASCADE could not write the file")
    return p


def example_material_map(flux_lm: float = 1000.0) -> str:
    """The material map (TOML text) of :func:`headlamp_shapes`'s parts."""
    return f'''# lightsim material map for the example CAD headlamp (luminaires/cad_example.py)
schema = "lightsim-materials-1"

[[rule]]
match = "reflector*"
kind = "mirror"
reflectance = 0.88

[[rule]]
match = "filament*"
kind = "emitter"
flux_lm = {flux_lm:g}
emission = "isotropic"

[[rule]]
match = "bulb*"
kind = "glass"
ior = 1.46

[[rule]]
match = "lens*"
kind = "glass"
ior = 1.59
'''


def write_example(path: str | os.PathLike, focal_mm: float = 25.0, rim_mm: float = 80.0,
                  flux_lm: float = 1000.0) -> Path:
    """Write the example headlamp (:func:`headlamp_shapes`) as CAD to ``path`` (STEP or
    IGES by suffix, mm) and its material map (:func:`example_material_map`) beside it as
    ``<path>.toml``; returns the material map's path."""
    p = Path(path)
    write_cad(p, headlamp_shapes(focal_mm, rim_mm))
    mmap = p.with_suffix(".toml")
    write_text(mmap, example_material_map(flux_lm))
    return mmap
