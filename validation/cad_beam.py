"""Beam error of a STEP paraboloid against its exact law, as the tessellation tightens.

The exact law: every ray from the focus of a paraboloid leaves it parallel to the axis
(``validation.scenes.analytic.paraboloid_reflected_lux`` is the illuminance that follows).
A tessellated reflector breaks it twice: facets sit off the surface, and shading normals
are interpolated between the exact vertex normals. This study writes an exact paraboloid
(OpenCASCADE surface of revolution of a parabola) to STEP, imports it through
:mod:`lightsim.io.cad` at a series of tolerances, traces rays from the focus with
lightsim's tracer (embree + the mirror kernel) and measures the angle of every reflected
ray to the axis: the beam error. At 25 m an error δ moves light by 25 m · δ.

Run: ``python -m lightsim.validation.cad_beam`` (needs the ``cad`` extra).

==============  =====  ==========  =================================================
parameter       unit   default     meaning
==============  =====  ==========  =================================================
``focal_mm``    mm     25          focal length (the shipped headlight's)
``rim_mm``      mm     80          rim radius
``hole_mm``     mm     10          bulb hole radius
``rays``        –      200 000     rays from the focus onto the reflector
``tolerances``  mm/°   see TOLS    (linear, angular) pairs of the study
==============  =====  ==========  =================================================
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from lightsim.io.cad import Tessellation, read_cad
from lightsim.luminaires.cad_example import paraboloid_face, write_cad
from lightsim.materials import MIRROR, Material
from lightsim.scene import Part, Scene, SceneSettings, load_scene
from lightsim.tracer import PhotonTracer

TOLS = ((0.5, 20.0), (0.1, 10.0), (0.03, 5.0), (0.01, 2.0), (0.003, 1.0))


@dataclass
class BeamError:
    """Reflected-ray angle to the axis for one tessellation (mrad)."""

    linear_tol_mm: float
    angular_tol_deg: float
    triangles: int
    rms_mrad: float
    p95_mrad: float
    max_mrad: float
    normal_err_mrad: float  # largest vertex-normal angle to the exact surface normal

    @property
    def shift_25m_mm(self) -> float:
        """RMS displacement of the light on a screen 25 m away (mm)."""
        return 25.0 * self.rms_mrad


def write_paraboloid_step(path: Path, focal_mm: float, rim_mm: float, hole_mm: float) -> Path:
    return write_cad(path, [("reflector", paraboloid_face(focal_mm, rim_mm, hole_mm))])


def beam_error(step: Path, focal_mm: float, rim_mm: float, hole_mm: float,
               linear_tol_mm: float, angular_tol_deg: float, rays: int = 200_000,
               seed: int = 1, backend: str = "auto") -> BeamError:
    """Trace ``rays`` rays from the focus off the imported reflector; see the module.

    ``backend`` is the CAD reader of :func:`lightsim.io.cad.read_cad` ("auto", "xcaf",
    "cascadio"); "auto" goes through :func:`lightsim.scene.load_scene` as a user's file.
    """
    tess = Tessellation(linear_tol_mm, angular_tol_deg)
    if backend == "auto":
        scene = load_scene(step, SceneSettings(part_materials={"reflector": "mirror:1.0"},
                           filament="H7", filament_at=(0.0, 0.0, focal_mm * 1e-3),
                           tessellation=tess))
        refl = next(p for p in scene.parts if p.name == "reflector")
    else:
        prim = next(p for p in read_cad(step, tess, backend=backend) if p.name == "reflector")
        refl = SimpleNamespace(vertices=np.asarray(prim.vertices, dtype=np.float64),
                               faces=np.asarray(prim.faces), normals=np.asarray(
                                   prim.normals, dtype=np.float64))
    f = focal_mm * 1e-3
    # vertex normals against the exact paraboloid normal (−x/2f, −y/2f, 1)
    v = refl.vertices
    exact_n = np.column_stack([-v[:, 0] / (2 * f), -v[:, 1] / (2 * f), np.ones(len(v))])
    exact_n /= np.linalg.norm(exact_n, axis=1, keepdims=True)
    cosn = np.abs(np.einsum("ij,ij->i", refl.normals, exact_n))
    normal_err = float(np.arccos(np.clip(cosn, -1, 1)).max() * 1e3)
    lamp = Scene([Part("reflector", "surface", refl.vertices, refl.faces, refl.normals,
                       Material("reflector", MIRROR, np.ones(3)))], None, channels=1)
    # directions from the focus onto the ring hole < r < rim: ψ from −Z, r = 2f tan(ψ/2)
    rng = np.random.default_rng(seed)
    c_lo = math.cos(2 * math.atan(hole_mm / (2 * focal_mm)))
    c_hi = math.cos(2 * math.atan(rim_mm / (2 * focal_mm)))
    cz = rng.uniform(c_hi, c_lo, rays)  # cos ψ, uniform = isotropic in solid angle
    phi = rng.uniform(0.0, 2 * math.pi, rays)
    s = np.sqrt(1.0 - cz * cz)
    dirs = np.column_stack([s * np.cos(phi), s * np.sin(phi), -cz])
    origins = np.tile([0.0, 0.0, f], (rays, 1))
    tracer = PhotonTracer(lamp, max_depth=4)
    res = tracer.trace(origins, dirs, np.ones((rays, 1)), np.arange(rays, dtype=np.uint64),
                       record_escaped=True)
    tracer.caster.close()
    out = res.escaped_dir
    ang = np.arccos(np.clip(out[:, 2], -1.0, 1.0)) * 1e3
    return BeamError(linear_tol_mm, angular_tol_deg, len(refl.faces),
                     float(np.sqrt(np.mean(ang**2))), float(np.percentile(ang, 95)),
                     float(ang.max()), normal_err)


def study(focal_mm: float = 25.0, rim_mm: float = 80.0, hole_mm: float = 10.0,
          tolerances=TOLS, rays: int = 200_000, backend: str = "auto") -> list[BeamError]:
    with tempfile.TemporaryDirectory() as tmp:
        step = write_paraboloid_step(Path(tmp) / "paraboloid.step", focal_mm, rim_mm,
                                     hole_mm)
        return [beam_error(step, focal_mm, rim_mm, hole_mm, lin, ang, rays, backend=backend)
                for lin, ang in tolerances]


def format_table(rows: list[BeamError]) -> str:
    head = ("| linear tol (mm) | angular tol (°) | triangles | rms (mrad) | 95 % (mrad) | "
            "max (mrad) | rms shift at 25 m (mm) | vertex normal error (mrad) |")
    lines = [head, "|" + "---|" * 8]
    for r in rows:
        lines.append(f"| {r.linear_tol_mm:g} | {r.angular_tol_deg:g} | {r.triangles:,} | "
                     f"{r.rms_mrad:.3f} | {r.p95_mrad:.3f} | {r.max_mrad:.3f} | "
                     f"{r.shift_25m_mm:.1f} | {r.normal_err_mrad:.4f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    import sys

    for b in sys.argv[1:] or ["auto"]:
        print(f"CAD reader: {b}")
        print(format_table(study(backend=b)))
