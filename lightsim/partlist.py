"""The parts and faces of a lamp file, by the names a material map can use.

A STEP or IGES lamp arrives without optics; a material map (:mod:`lightsim.materialmap`)
gives them by name. This module lists those names: every part (solid, shell or glTF
node, with the ``#k`` suffix a scene gives repeated names) and, for CAD parts read
through OpenCASCADE's XCAF document, every face's address ``"<part>/<face>"``. With a
material map it also says which rule each part and face gets, and which faces a rule
splits off into parts of their own (as :func:`lightsim.materialmap.split_cad_faces`
does when a scene is loaded).

===============  =====  ====================================================
field            unit   meaning
===============  =====  ====================================================
``triangles``    –      triangles after tessellation (CAD) or in the file
``size_mm``      mm     axis-aligned extent of the part (x, y, z)
``rule``         –      1-based number of the map rule that decides, or None
``emissive``     –      the file itself marks the part as an emitter (glTF)
===============  =====  ====================================================
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lightsim.errors import InputError
from lightsim.io.cad import CAD_SUFFIXES, Tessellation, read_cad
from lightsim.io.gltf import read_gltf
from lightsim.materialmap import MaterialMap

LISTABLE_SUFFIXES = CAD_SUFFIXES + (".glb", ".gltf")


@dataclass(frozen=True)
class FaceEntry:
    """One CAD face: its address, triangle count and the map rule matching it.

    ``split`` is True when that rule differs from the part's, so the face becomes a part
    of its own in a run."""

    address: str
    triangles: int
    rule: int | None = None
    split: bool = False


@dataclass(frozen=True)
class PartEntry:
    """One part of a lamp file (see the module docstring for the fields)."""

    name: str
    triangles: int
    size_mm: tuple[float, float, float]
    faces: tuple[FaceEntry, ...]
    rule: int | None = None
    emissive: bool = False


def list_parts(path: str | os.PathLike, mmap: MaterialMap | None = None,
               tess: Tessellation | None = None) -> list[PartEntry]:
    """The parts (and CAD faces) of a STEP, IGES or glTF lamp file.

    Parameters
    ----------
    path : path-like
        ``.step``/``.stp``/``.iges``/``.igs``/``.glb``/``.gltf`` file.
    mmap : MaterialMap, optional
        When given, each part's and face's deciding rule is filled in.
    tess : Tessellation, optional
        CAD mesher tolerances (mm, deg).

    Returns
    -------
    list of PartEntry
        In file order; names as a run names them (a repeated name becomes ``name#1``…).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such file")
    suffix = p.suffix.lower()
    if suffix not in LISTABLE_SUFFIXES:
        raise InputError(f"{p}: parts are listed for STEP, IGES and glTF files (got "
                         f"'{suffix or 'no suffix'}')")
    prims = read_cad(p, tess) if suffix in CAD_SUFFIXES else read_gltf(p)
    seen: dict[str, int] = {}
    out = []
    for prim in prims:
        k = seen.get(prim.name, 0)
        seen[prim.name] = k + 1
        pname = prim.name if k == 0 else f"{prim.name}#{k}"
        verts = np.asarray(prim.vertices, dtype=np.float64)
        size = tuple(float(x) * 1e3 for x in np.ptp(verts, axis=0)) if len(verts) else \
            (0.0, 0.0, 0.0)
        rule = None if mmap is None else (mmap.rule_number(pname) or
                                          mmap.rule_number(prim.name))
        labels = prim.extras.get("cad_faces") if isinstance(prim.extras, dict) else None
        faces: list[FaceEntry] = []
        if labels is not None:
            counts = np.bincount(np.asarray(labels.triangle_face, dtype=np.int64),
                                 minlength=len(labels.names))
            for i, face in enumerate(labels.names):
                addr = f"{prim.name}/{face}"
                frule = None if mmap is None else mmap.rule_number(addr)
                faces.append(FaceEntry(addr, int(counts[i]), frule,
                                       frule is not None and frule != rule))
        out.append(PartEntry(pname, len(prim.faces), size,  # type: ignore[arg-type]
                             tuple(faces), rule, _emissive(prim.material)))
    return out


def _emissive(material: dict) -> bool:
    """True when a glTF material emits (a non-zero ``emissiveFactor``)."""
    factor = material.get("emissiveFactor") if isinstance(material, dict) else None
    return bool(factor) and any(float(x) > 0 for x in factor)
