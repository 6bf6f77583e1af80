"""Scene: load meshes, map materials, validate input, flatten to one triangle soup.

A scene is a list of named parts (one per glTF node primitive or trimesh geometry). Each
part has a role — ``surface`` (traced: diffuse, mirror or dielectric), ``emitter``
(photon source, not traced), ``wall`` (the measurement wall: a diffuse detector that
records photons and ends them) — and a material. The tracer sees the flattened soup of
all surface and wall triangles. :func:`load_scene` takes its parameters as one
:class:`SceneSettings`:

=====================  =====  =========  ================================================
parameter              unit   default    meaning
=====================  =====  =========  ================================================
``flux``               lm     from file  luminous flux of the emitters (total; overrides
                                         ``extras.lightsim.flux_lm``)
``emission``           –      from file  ``isotropic`` or ``lambertian`` (overrides)
``wall_distance``      m      25         distance of the added wall (plane z = D)
``wall_size``          m      30 × 12    width × height of the added wall, centred on H-V
``wall_albedo``        –      0.8        albedo of the added wall (camera views only)
``part_materials``     –      none       per part: ``mirror[:R]``, ``glass[:n]``,
                                         ``diffuse[:ρ]``, ``wall``, ``ignore``
``rayfile``            –      none       TM-25 / Zemax ray file that replaces the file's
                                         emitters (``rayfile_at`` m, ``rayfile_axis``)
``materials``          –      none       material map (TOML): name pattern → optics
                                         (:mod:`lightsim.materialmap`)
``tessellation``       mm/°   0.01/2     STEP/IGES mesher tolerances (:mod:`lightsim.io.cad`)
=====================  =====  =========  ================================================

Input problems raise :class:`~lightsim.errors.InputError` with one line: missing file,
not a mesh, truncated GLB, NaN/inf vertices, no emitter, zero or negative flux, a wall
that is not planar. Zero-area triangles are dropped with a warning. A wall modelled as a
closed thin solid (a slab, as CAD exports one) is reduced to its lamp-facing face, with a
warning (:func:`solid_wall_face`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.emitters.goniometric import GoniometricEmitter
from lightsim.emitters.rayfile import RaySource
from lightsim.emitters.registry import filament_factory, photometric_reader
from lightsim.errors import InputError
from lightsim.io.cad import read_cad
from lightsim.io.closed_mesh import closed_mesh  # numpy: no trimesh import
from lightsim.io.gltf import read_gltf
from lightsim.materialmap import read_material_map, split_cad_faces
from lightsim.materials import (
    DIELECTRIC,
    DIFFUSE,
    MIRROR,
    Material,
    MaterialTable,
    material_from_gltf,
)
from lightsim.wall import WallFrame  # the measuring wall's frame (re-exported here)

log = logging.getLogger("lightsim.scene")

SURFACE, EMITTER, WALL = "surface", "emitter", "wall"
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".stl", ".ply", ".off", ".step", ".stp", ".iges",
                 ".igs")
PHOTOMETRIC_SUFFIXES = (".ies", ".ldt")


@dataclass
class Part:
    """A named triangle mesh in world space with one material.

    Attributes
    ----------
    name : str
    role : str
        ``surface``, ``emitter`` or ``wall``.
    vertices : (n, 3) float64
        World positions (m).
    faces : (m, 3) int64
    normals : (n, 3) float64 or None
        Unit vertex normals used as shading normals on specular surfaces.
    material : Material
    flux_lm : float
        Luminous flux (lm), emitters only.
    emission : str
        ``isotropic``, ``lambertian`` or ``collimated`` (every photon leaves along the face
        normal: a distant source such as the sun), emitters only.
    """

    name: str
    role: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    material: Material
    flux_lm: float = 0.0
    emission: str = "isotropic"
    extras: dict[str, Any] = field(default_factory=dict)
    distribution: Any = None  # what a point source came from (IES/LDT grid, ray file)
    emitter: Any = None  # core emitter (lightsim.emitters) that samples a point source

    @property
    def triangles(self) -> np.ndarray:
        """(m, 3, 3) float64 corner positions (m)."""
        return self.vertices[self.faces]

    def transformed(self, matrix: np.ndarray) -> Part:
        """A copy moved by the 4×4 ``matrix`` (normals by its inverse transpose)."""
        lin, t = matrix[:3, :3], matrix[:3, 3]
        verts = self.vertices @ lin.T + t
        normals = None
        if self.normals is not None:
            nm = self.normals @ np.linalg.inv(lin)
            normals = nm / np.maximum(np.linalg.norm(nm, axis=1, keepdims=True), 1e-300)
        faces = self.faces[:, ::-1].copy() if np.linalg.det(lin) < 0 else self.faces
        return replace(self, vertices=verts, normals=normals, faces=faces)


@dataclass
class Scene:
    """All parts of a scene plus the derived, flattened arrays the tracer reads."""

    parts: list[Part]
    wall: WallFrame | None
    source: str = ""
    warnings: list[str] = field(default_factory=list)
    channels: int | None = None  # force 1 or 3; None: decided from the materials

    def __getstate__(self) -> dict[str, Any]:
        """Pickle only the parts, not the derived arrays (Ray ships scenes; they are
        recomputed on first use)."""
        keep = ("parts", "wall", "source", "warnings", "channels")
        return {k: v for k, v in self.__dict__.items() if k in keep}

    # -- derived data (recomputed when a part changes: see `replace_part`) --------------
    @cached_property
    def surfaces(self) -> list[Part]:
        """Parts the tracer sees: surfaces and the wall (emitters do not occlude)."""
        return [p for p in self.parts if p.role in (SURFACE, WALL)]

    @property
    def emitters(self) -> list[Part]:
        return [p for p in self.parts if p.role == EMITTER]

    @cached_property
    def materials(self) -> MaterialTable:
        return MaterialTable.build([p.material for p in self.surfaces], self.channels)

    @cached_property
    def triangles(self) -> np.ndarray:
        """(T, 3, 3) float64 corners of all traced triangles (m)."""
        if not self.surfaces:
            return np.zeros((0, 3, 3))
        return np.concatenate([p.triangles for p in self.surfaces])

    @cached_property
    def tri_part(self) -> np.ndarray:
        """(T,) int32 index into :attr:`surfaces` (and the material table)."""
        return np.concatenate([np.full(len(p.faces), i, np.int32)
                               for i, p in enumerate(self.surfaces)] or [np.zeros(0, np.int32)])

    @cached_property
    def tri_is_wall(self) -> np.ndarray:
        roles = np.array([p.role == WALL for p in self.surfaces], dtype=np.bool_)
        return roles[self.tri_part] if len(roles) else np.zeros(0, np.bool_)

    @cached_property
    def face_normals(self) -> np.ndarray:
        """(T, 3) float64 unit geometric normals (counter-clockwise = front)."""
        tri = self.triangles
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    @cached_property
    def corner_normals(self) -> np.ndarray:
        """(T, 3, 3) float64 shading normals per corner (face normal where none given)."""
        out = []
        for p, fn in zip(self.surfaces, np.split(self.face_normals,
                                                 np.cumsum([len(p.faces) for p in
                                                            self.surfaces])[:-1])):
            if p.normals is not None and p.material.kind != DIFFUSE:
                cn = p.normals[p.faces]
                # a corner normal on the back of its face is a broken export: use the face
                bad = np.einsum("tcj,tj->tc", cn, fn) <= 0.0
                cn = np.where(bad[..., None], fn[:, None, :], cn)
            else:
                cn = np.repeat(fn[:, None, :], 3, axis=1)
            out.append(cn)
        return np.concatenate(out) if out else np.zeros((0, 3, 3))

    @cached_property
    def scale(self) -> float:
        """Size of the luminaire (bounding-box diagonal of non-wall parts, m)."""
        pts = [p.vertices for p in self.parts if p.role != WALL]
        if not pts:
            return 1.0
        allp = np.concatenate(pts)
        return float(max(np.linalg.norm(np.ptp(allp, axis=0)), 1e-9))

    @cached_property
    def extent(self) -> float:
        """Largest absolute coordinate of any part (m); sets float32 offset scales."""
        return float(max((np.abs(p.vertices).max() for p in self.parts if len(p.vertices)),
                         default=1.0))

    @property
    def total_flux(self) -> float:
        return float(sum(p.flux_lm for p in self.emitters))

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    def replace_part(self, name: str, **changes: Any) -> Scene:
        """A new scene with part ``name`` changed (e.g. ``material=…``, moved vertices)."""
        if not any(p.name == name for p in self.parts):
            raise InputError(f"no part named '{name}' (parts: {', '.join(self.part_names)})")
        parts = [replace(p, **changes) if p.name == name else p for p in self.parts]
        return Scene(parts, self.wall, self.source, list(self.warnings), self.channels)

    def transform_part(self, name: str, matrix: np.ndarray) -> Scene:
        """A new scene with part ``name`` moved by the 4×4 ``matrix``."""
        # compare names, not parts: Part equality compares numpy arrays (ambiguous)
        if not any(p.name == name for p in self.parts):
            raise InputError(f"no part named '{name}'")
        parts = [p.transformed(matrix) if p.name == name else p for p in self.parts]
        return Scene(parts, self.wall, self.source, list(self.warnings), self.channels)

    def with_wall_transform(self, matrix: np.ndarray) -> Scene:
        """A new scene with the wall part *and* its pixel frame moved by the 4×4 ``matrix``.

        Aiming the lamp by a rotation R about the origin is the same, in the lamp's frame,
        as moving the wall by R⁻¹: ``scene.with_wall_transform(np.linalg.inv(R))`` gives
        the lux map of the aimed lamp (bit for bit up to float rounding of the hit points)
        without touching the lamp's triangles, so a :class:`~lightsim.tracer.PhotonTracer`
        given the old tracer's ``caster`` keeps its embree scene (the wall is intersected
        exactly outside it, :meth:`~lightsim.raycast.RayCaster.with_wall`; a wall of more
        than ``WALL_MAX_TRIANGLES`` triangles lives in embree and needs a new caster —
        the session's ``("wall", M)`` change rebuilds it then). The H-V point
        stays at the same wall coordinates (it belongs to the wall's grid, as when the lamp
        is turned); the lamp → wall distance follows the moved plane.

        Raises
        ------
        InputError
            If the scene has no wall or ``matrix`` is not a finite invertible 4×4.
        """
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise InputError("wall transform: needs a finite 4x4 matrix")
        lin, t = m[:3, :3], m[:3, 3]
        if not abs(np.linalg.det(lin)) > 1e-12:
            raise InputError("wall transform: the matrix is singular")
        walls = [p for p in self.parts if p.role == WALL]
        if not walls or self.wall is None:
            raise InputError("wall transform: the scene has no wall")
        parts = [p.transformed(m) if p.role == WALL else p for p in self.parts]
        w = self.wall

        def unit(x: np.ndarray) -> np.ndarray:
            y = lin @ np.asarray(x, dtype=np.float64)
            return y / np.linalg.norm(y)

        # an in-plane scale stretches the wall's metres too (the wall-distance control)
        sh = float(np.linalg.norm(lin @ np.asarray(w.h_axis, float)))
        sv = float(np.linalg.norm(lin @ np.asarray(w.v_axis, float)))
        centre = lin @ np.asarray(w.centre, dtype=np.float64) + t
        normal = np.linalg.inv(lin).T @ np.asarray(w.normal, dtype=np.float64)
        normal /= np.linalg.norm(normal)
        rigid = not np.any(t) and np.allclose(lin.T @ lin, np.eye(3), rtol=0, atol=1e-12)
        distance = w.distance_m if rigid else float(abs(normal @ centre))
        frame = replace(w, centre=centre, h_axis=unit(w.h_axis), v_axis=unit(w.v_axis),
                        normal=normal, distance_m=distance,
                        h_range_m=(w.h_range_m[0] * sh, w.h_range_m[1] * sh),
                        v_range_m=(w.v_range_m[0] * sv, w.v_range_m[1] * sv),
                        hv_offset=(w.hv_offset_m[0] * sh, w.hv_offset_m[1] * sv))
        out = Scene(parts, frame, self.source, list(self.warnings), self.channels)
        # what does not depend on the wall's place carries over (no pass over the lamp)
        for key in ("scale", "tri_part", "tri_is_wall", "materials"):
            if key in self.__dict__:
                out.__dict__[key] = self.__dict__[key]
        return out

    @property
    def wall_triangles(self) -> np.ndarray:
        """(W, 3, 3) float64 corners of the wall's triangles, in soup order (the rows
        where :attr:`tri_is_wall` is true), without building the whole soup."""
        walls = [p.triangles for p in self.surfaces if p.role == WALL]
        return np.concatenate(walls) if walls else np.zeros((0, 3, 3))

    @property
    def part_names(self) -> list[str]:
        return [p.name for p in self.parts]

    def describe(self) -> list[str]:
        """One line per part: role, triangles, material."""
        lines = []
        for p in self.parts:
            what = (f"emitter {p.flux_lm:g} lm {p.emission}" if p.role == EMITTER
                    else "wall (detector)" if p.role == WALL else p.material.describe())
            lines.append(f"{p.name}: {len(p.faces)} triangles, {what}")
        return lines


# ------------------------------------------------------------------------------------------
# Loading
# ------------------------------------------------------------------------------------------

def _parse_part_material(name: str, spec: str) -> tuple[str, Material | None]:
    """``mirror[:R]``, ``glass[:n]``, ``diffuse[:ρ]``, ``wall``, ``ignore`` → role, material."""
    kind, _, arg = spec.partition(":")
    kind = kind.strip().lower()
    try:
        value = float(arg) if arg else None
    except ValueError:
        raise InputError(f"part material '{name}={spec}': '{arg}' is not a number") from None
    if kind == "mirror":
        return SURFACE, Material(name, MIRROR, np.full(3, 0.88 if value is None else value))
    if kind in ("glass", "dielectric"):
        return SURFACE, Material(name, DIELECTRIC, np.ones(3), 1.5 if value is None else value)
    if kind == "diffuse":
        return SURFACE, Material(name, DIFFUSE, np.full(3, 0.5 if value is None else value))
    if kind == "wall":
        return WALL, Material(name, DIFFUSE, np.full(3, 0.8 if value is None else value))
    if kind == "ignore":
        return "ignore", None
    raise InputError(f"part material '{name}={spec}': kind must be mirror, glass, diffuse, "
                     "wall or ignore")


def _read_parts(path: Path, tessellation: Any = None, warnings: list[str] | None = None
                ) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray | None, dict, dict]]:
    """(name, vertices, faces, normals, material json, extras) for each mesh in ``path``;
    what the reader repaired is appended to ``warnings``."""
    if path.suffix.lower() in (".step", ".stp", ".iges", ".igs"):
        return [(p.name, p.vertices, p.faces, p.normals, p.material, p.extras)
                for p in read_cad(path, tessellation)]
    if path.suffix.lower() in (".glb", ".gltf"):
        return [(p.name, p.vertices, p.faces, p.normals, p.material, p.extras)
                for p in read_gltf(path, warnings)]
    # other mesh formats: trimesh, imported here only, since it imports scipy.linalg
    # (seconds at start-up) that a glTF or STEP run never needs
    import trimesh

    try:
        loaded = trimesh.load(str(path), force="scene", process=False)
    except Exception as exc:  # trimesh raises many exception types for bad files
        raise InputError(f"{path}: cannot read mesh ({exc.__class__.__name__}: {exc})") from None
    out = []
    for node in loaded.graph.nodes_geometry:
        transform, geom_name = loaded.graph[node]
        geom = loaded.geometry[geom_name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        verts = np.asarray(geom.vertices, dtype=np.float64) @ transform[:3, :3].T \
            + transform[:3, 3]
        faces = np.asarray(geom.faces, dtype=np.int64)
        if np.linalg.det(transform[:3, :3]) < 0:
            faces = faces[:, ::-1].copy()
        out.append((str(node), verts, faces, None, {}, {}))
    return out


def _plane_frame(part: Part, resolution: tuple[int, int]) -> WallFrame:
    """Fit the wall plane and build its frame (normal towards the origin)."""
    pts = part.vertices[np.unique(part.faces)]
    centroid = pts.mean(axis=0)
    _, s, vt = np.linalg.svd(pts - centroid, full_matrices=False)
    normal = vt[2]
    size = max(float(s[0]), 1e-12)
    dev = np.abs((pts - centroid) @ normal).max()
    if dev > 1e-6 * max(float(np.ptp(pts, axis=0).max()), 1e-9) + 1e-9:
        raise InputError(f"wall '{part.name}' is not planar (vertices {dev:.3g} m off its plane)")
    if normal @ centroid > 0:  # face the lamp at the origin
        normal = -normal
    distance = float(abs(normal @ centroid))
    if distance < 1e-9 * size:
        raise InputError(f"wall '{part.name}' passes through the lamp reference point (origin)")
    centre = (normal @ centroid) * normal
    v_axis = np.array([0.0, 1.0, 0.0]) - normal[1] * normal
    if np.linalg.norm(v_axis) < 1e-6:  # a floor or ceiling: V along world +Z
        v_axis = np.array([0.0, 0.0, 1.0]) - normal[2] * normal
    v_axis /= np.linalg.norm(v_axis)
    h_axis = np.cross(v_axis, normal)
    d = pts - centre
    h, v = d @ h_axis, d @ v_axis
    return WallFrame(centre, h_axis, v_axis, normal, (float(h.min()), float(h.max())),
                     (float(v.min()), float(v.max())), distance, resolution)


SOLID_WALL_MAX_THICKNESS = 0.05  # thickness / in-plane size below which a solid is "thin"
FACE_COS_TOL = 1e-6               # 1 − cos of the angle a front-face triangle may tilt


def solid_wall_face(part: Part) -> tuple[Part, str] | None:
    """The lamp-facing face of a closed thin solid wall, or None if ``part`` is not one.

    A CAD wall is often a slab (e.g. 1 mm thick): closed, with a front face towards the
    lamp, a back face and rims. The detector is the front face — the triangles whose
    outward normal points at the lamp reference point (origin) and lie in the plane
    nearest to it. Returns the reduced part and a one-line description, or None when the
    part is open, not thin, or has no planar front face (then it stays "not planar").
    """
    if len(part.faces) < 4:
        return None
    mesh = closed_mesh(part.vertices, part.faces)
    if not mesh.watertight:
        return None
    pts = part.vertices[np.unique(part.faces)]
    centroid = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centroid, full_matrices=False)
    normal = vt[2]
    if normal @ centroid > 0:
        normal = -normal  # towards the lamp at the origin
    off = (pts - centroid) @ normal
    thickness = float(np.ptp(off))
    size = float(np.ptp((pts - centroid) @ vt[1]))
    if not (size > 0 and thickness <= SOLID_WALL_MAX_THICKNESS * size):
        return None
    tri = part.vertices[part.faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    # a solid with inward winding (negative volume) has its front face pointing away
    outward = 1.0 if mesh.volume >= 0 else -1.0
    facing = outward * (fn @ normal) > 1.0 - FACE_COS_TOL
    if not np.any(facing):
        return None
    height = tri.mean(axis=1) @ normal  # larger: nearer the lamp
    front = facing & (height >= height[facing].max() - 0.25 * thickness)
    faces = part.faces[front]
    if outward < 0:
        faces = faces[:, ::-1].copy()
    reduced = replace(part, faces=faces)
    note = (f"wall '{part.name}' is a closed solid {thickness * 1e3:.3g} mm thick: its "
            f"lamp-facing face ({int(front.sum())} of {len(part.faces)} triangles) is the "
            "detector")
    return reduced, note


def make_wall(distance: float, size: tuple[float, float], albedo: float = 0.8,
              resolution: tuple[int, int] = (640, 256)) -> tuple[Part, WallFrame]:
    """A rectangular diffuse wall at z = ``distance`` facing the lamp, centred on H-V."""
    if not (math.isfinite(distance) and distance > 0):
        raise InputError(f"wall distance must be a positive number of metres, got {distance}")
    w, h = size
    if not (w > 0 and h > 0 and math.isfinite(w) and math.isfinite(h)):
        raise InputError(f"wall size must be positive, got {w}x{h} m")
    # H is world −X (a driver's right), V is +Y; normal −Z towards the lamp.
    x0, x1, y0, y1 = -w / 2, w / 2, -h / 2, h / 2
    verts = np.array([[x0, y0, distance], [x1, y0, distance], [x1, y1, distance],
                      [x0, y1, distance]])
    faces = np.array([[0, 2, 1], [0, 3, 2]])  # clockwise seen from the lamp → normal −Z
    part = Part("wall", WALL, verts, faces, None, Material("wall", DIFFUSE, np.full(3, albedo)))
    frame = WallFrame(np.array([0.0, 0.0, distance]), np.array([-1.0, 0.0, 0.0]),
                      np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0]),
                      (-w / 2, w / 2), (-h / 2, h / 2), distance, resolution)
    return part, frame


def _check_dielectric(part: Part, warnings: list[str]) -> Part:
    """Flip a closed dielectric with inward normals; warn about open ones."""

    mesh = closed_mesh(part.vertices, part.faces)
    if not mesh.watertight:
        warnings.append(f"dielectric '{part.name}' is not closed: inside/outside follow the "
                        "triangle winding")
        return part
    if mesh.volume < 0:
        warnings.append(f"dielectric '{part.name}' has inverted normals (negative volume): "
                        "flipped")
        normals = None if part.normals is None else -part.normals
        return replace(part, faces=part.faces[:, ::-1].copy(), normals=normals)
    return part


@dataclass(frozen=True)
class SceneSettings:
    """How a file becomes a scene: the parameters of the module's table (units there).

    Every field has the default the table gives; ``load_scene(path)`` reads the file as it
    is, with a 30 m × 12 m wall at 25 m added when the file has none.
    """

    flux: float | None = None
    emission: str | None = None
    filament: str | None = None
    filament_at: tuple[float, float, float] | None = None
    filament_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    wall_distance: float = 25.0
    wall_size: tuple[float, float] = (30.0, 12.0)
    wall_albedo: float = 0.8
    resolution: tuple[int, int] = (640, 256)
    part_materials: dict[str, str] | None = None
    channels: int | None = None
    lamp_set: int | None = None
    rayfile: str | None = None
    rayfile_at: tuple[float, float, float] | None = None
    rayfile_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    materials: str | Path | None = None
    tessellation: Any = None

    def added_wall(self) -> tuple[Part, WallFrame]:
        """The wall :func:`make_wall` adds for a file without one."""
        return make_wall(self.wall_distance, self.wall_size, self.wall_albedo, self.resolution)


EMISSIONS = ("isotropic", "lambertian", "collimated")


def load_scene(path: str | Path, settings: SceneSettings | None = None) -> Scene:
    """Load a luminaire (GLB, glTF, OBJ, STL, PLY, STEP, IGES; an IES/LDT file; a TM-25 ray
    file) into a validated :class:`Scene`.

    An IES/LDT file becomes a goniometric point source (``settings.lamp_set``: the EULUMDAT
    lamp set to use, 1-based; the reader's warnings become scene warnings); a ray file alone
    becomes an LED at the origin. A mesh file's parts get their roles and materials
    (:func:`mesh_parts`), then the emitters (:func:`add_emitters`) and the wall
    (:func:`add_wall`; one is added at ``settings.wall_distance`` when the file has none).
    """
    s = SceneSettings() if settings is None else settings
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if not path.is_file():
        raise InputError(f"{path}: not a file")
    if path.suffix.lower() in PHOTOMETRIC_SUFFIXES:
        return _photometric_scene(path, s)
    if s.lamp_set is not None:
        raise InputError("--lamp-set applies to EULUMDAT (.ldt) files only")
    if path.suffix.lower() == ".tm25ray":
        return _rayfile_scene(path, s)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(f"{path}: not a mesh or photometric file (expected one of "
                         f"{', '.join(MESH_SUFFIXES + PHOTOMETRIC_SUFFIXES)})")
    if s.flux is not None and not (math.isfinite(s.flux) and s.flux > 0):
        raise InputError(f"flux must be a positive number of lumens, got {s.flux}")
    if s.emission is not None and s.emission not in EMISSIONS:
        raise InputError(f"emission must be isotropic, lambertian or collimated, "
                         f"got '{s.emission}'")
    warnings: list[str] = []
    parts = mesh_parts(path, s, warnings)
    parts = add_emitters(path, parts, s, warnings)
    parts, frame = add_wall(path, parts, s, warnings)
    if not any(p.role == SURFACE for p in parts):
        warnings.append("the scene has no surfaces besides the wall: light goes straight to it")
    scene = Scene(parts, frame, str(path), warnings, s.channels)
    for w in warnings:  # the CLI prints scene.warnings itself
        log.debug(w)
    return scene


def _photometric_scene(path: Path, s: SceneSettings) -> Scene:
    """An IES/LDT file: its goniometric point source at the origin and the added wall."""
    if s.filament is not None:
        raise InputError("an IES/LDT file is its own light source: --filament makes no sense")
    source = goniometric_source(path, s.flux, lamp_set=s.lamp_set)
    wall_part, frame = s.added_wall()
    return Scene([source, wall_part], frame, str(path), list(source.distribution.warnings),
                 s.channels)


def _rayfile_scene(path: Path, s: SceneSettings) -> Scene:
    """A ray file alone: the LED at the origin in front of the added wall."""
    if s.filament is not None or s.rayfile is not None:
        raise InputError("a ray file is its own light source: --filament/--rayfile make "
                         "no sense")
    source = ray_source_part(path, (0.0, 0.0, 0.0), s.rayfile_axis, s.flux)
    wall_part, frame = s.added_wall()
    return Scene([source, wall_part], frame, str(path), [], s.channels)


def mesh_parts(path: Path, s: SceneSettings, warnings: list[str]) -> list[Part]:
    """The file's parts with their roles and materials: the file's own (glTF materials,
    ``extras.lightsim``), then ``--part-material`` overrides, then the material map's rules;
    degenerate triangles dropped. What was repaired or ignored is appended to ``warnings``."""
    part_materials = dict(s.part_materials or {})
    mmap = None if s.materials is None else read_material_map(s.materials)
    raw = _read_parts(path, s.tessellation, warnings)
    raw = split_cad_faces(raw, mmap, part_materials)  # CAD faces a rule/option names
    if not raw:
        raise InputError(f"{path}: contains no triangle meshes")
    unmatched: list[str] = []
    parts: list[Part] = []
    names_seen: dict[str, int] = {}
    for name, verts, faces, normals, mat_json, extras in raw:
        # unique names: several primitives of one node become name, name#1, ...
        k = names_seen.get(name, 0)
        names_seen[name] = k + 1
        pname = name if k == 0 else f"{name}#{k}"
        if not np.all(np.isfinite(verts)):
            bad = int((~np.isfinite(verts)).any(axis=1).sum())
            raise InputError(f"{path}: part '{pname}' has {bad} vertices with NaN/inf coordinates")
        if normals is not None and not np.all(np.isfinite(normals)):
            normals = None
            warnings.append(f"part '{pname}': invalid vertex normals ignored")
        ls = (extras.get("lightsim") or {}) if isinstance(extras, dict) else {}
        material, emissive = material_from_gltf(pname, mat_json)
        role = str(ls.get("role", "")).lower() or (
            EMITTER if emissive else WALL if name.lower() == "wall" else SURFACE)
        if role not in (SURFACE, EMITTER, WALL, "ignore", "mirror", "dielectric", "diffuse"):
            raise InputError(f"part '{pname}': unknown role '{role}'")
        if role in ("mirror", "dielectric", "diffuse"):
            kind = {"mirror": MIRROR, "dielectric": DIELECTRIC, "diffuse": DIFFUSE}[role]
            material = replace(material, kind=kind)
            role = SURFACE
        explicit = False
        for key in (pname, name):
            if key in part_materials:
                role, override = _parse_part_material(pname, part_materials.pop(key))
                material = override or material
                explicit = True
                break
        if mmap is not None and not explicit:
            rule = mmap.rule_for(pname) or mmap.rule_for(name)
            if rule is None:
                unmatched.append(pname)
            else:
                role = {"emitter": EMITTER, "wall": WALL, "ignore": "ignore"}.get(
                    rule.kind, SURFACE)
                material = rule.material(pname) or material
                if rule.kind == "emitter":
                    ls = {**ls, "emission": rule.emission}
                    if rule.flux_lm is not None:
                        ls["flux_lm"] = rule.flux_lm
        if role == "ignore":
            continue
        faces = _without_degenerate(pname, verts, faces, warnings)
        if len(faces) == 0:
            warnings.append(f"part '{pname}': no triangles left, ignored")
            continue
        part = Part(pname, role, verts, faces, normals, material, extras=dict(extras))
        if role == EMITTER:
            _set_emission(part, ls, s.emission)
        if role == SURFACE and material.kind == DIELECTRIC:
            part = _check_dielectric(part, warnings)
        parts.append(part)
    if unmatched:
        warnings.append(f"material map: no rule for {', '.join(unmatched)} (file materials "
                        "kept)")
    if part_materials:
        raise InputError(f"--part-material names unknown part(s): {', '.join(part_materials)} "
                         f"(parts: {', '.join(n for n, *_ in raw)})")
    return parts


def _without_degenerate(pname: str, verts: np.ndarray, faces: np.ndarray,
                        warnings: list[str]) -> np.ndarray:
    """``faces`` without zero-area triangles (or repeated indices), with a warning."""
    tri = verts[faces] if len(faces) else np.zeros((0, 3, 3))
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    size = float(np.ptp(verts, axis=0).max()) if len(verts) else 0.0
    keep = area2 > (1e-12 * size) ** 2
    if not np.all(keep):
        warnings.append(f"part '{pname}': dropped {int((~keep).sum())} zero-area triangles")
        faces = faces[keep]
    return faces


def _set_emission(part: Part, ls: dict[str, Any], emission: str | None) -> None:
    """An emitter's angular emission and flux (lm) from ``extras.lightsim`` (``ls``), the
    emission overridden by ``emission``."""
    part.emission = str(emission or ls.get("emission", "isotropic")).lower()
    if part.emission not in EMISSIONS:
        raise InputError(f"emitter '{part.name}': emission must be isotropic, lambertian "
                         f"or collimated, got '{part.emission}'")
    f = ls.get("flux_lm")
    if f is not None:
        if isinstance(f, bool) or not isinstance(f, int | float):
            raise InputError(f"emitter '{part.name}': flux_lm {f!r} is not a number")
        if not math.isfinite(f):
            raise InputError(f"emitter '{part.name}': flux_lm must be a finite number of "
                             f"lumens, got {f}")
        part.flux_lm = float(f)


def add_emitters(path: Path, parts: list[Part], s: SceneSettings,
                 warnings: list[str]) -> list[Part]:
    """``parts`` with the light sources the settings ask for: a ray file replacing the
    file's emitters, a bulb preset's filament; every emitter's flux checked (a total
    ``settings.flux`` shared in the file's ratios)."""
    if s.rayfile is not None:
        if s.filament is not None:
            raise InputError("give either --filament or --rayfile, not both")
        for p in [p for p in parts if p.role == EMITTER]:
            warnings.append(f"emitter '{p.name}' replaced by the ray file {Path(s.rayfile).name}")
        parts = [p for p in parts if p.role != EMITTER]
        parts.append(ray_source_part(s.rayfile, s.rayfile_at or (0.0, 0.0, 0.0),
                                     s.rayfile_axis, s.flux))
    if s.filament is not None:
        parts = [*parts, _filament_part(s.filament, s.filament_at, s.filament_axis, s.flux,
                                        s.emission)]
    emitters = [p for p in parts if p.role == EMITTER]
    if not emitters:
        raise InputError(f"{path}: no emitter among its parts ({_part_names(parts)}); give "
                         "one kind = \"emitter\" in a material map (--materials), or a bulb "
                         "with --filament BULB --filament-at X,Y,Z (`lightsim luminaire parts "
                         f"{path.name}` lists the part and face names)")
    if s.flux is not None and s.filament is None and s.rayfile is None:
        own = [p.flux_lm for p in emitters]
        total = sum(f for f in own if f > 0)
        for p in emitters:  # the total is set; shares keep the file's ratios where known
            p.flux_lm = s.flux * (p.flux_lm / total if total > 0 else 1.0 / len(emitters))
    for p in emitters:
        if p.flux_lm == 0.0 and s.flux is None:
            raise InputError(f"emitter '{p.name}' has no luminous flux: set extras "
                             "{\"lightsim\": {\"flux_lm\": …}} in the file or give --flux")
        if not (math.isfinite(p.flux_lm) and p.flux_lm > 0):
            raise InputError(f"emitter '{p.name}': flux must be positive, got {p.flux_lm} lm")
    return parts


def _part_names(parts: list[Part], most: int = 12) -> str:
    """The parts' names, comma-separated, at most ``most`` of them (one error line)."""
    names = [p.name for p in parts]
    if not names:
        return "none left"
    more = f", … {len(names) - most} more" if len(names) > most else ""
    return ", ".join(names[:most]) + more


def add_wall(path: Path, parts: list[Part], s: SceneSettings, warnings: list[str]
             ) -> tuple[list[Part], WallFrame]:
    """``parts`` with exactly one wall (the file's, a solid one reduced to its lamp-facing
    face, or the added one) and the wall's frame."""
    walls = [p for p in parts if p.role == WALL]
    if len(walls) > 1:
        raise InputError(f"{path}: more than one wall ({', '.join(p.name for p in walls)})")
    if not walls:
        wall_part, frame = s.added_wall()
        return [*parts, wall_part], frame
    solid = solid_wall_face(walls[0])
    if solid is not None:
        parts = [solid[0] if p is walls[0] else p for p in parts]
        warnings.append(solid[1])
        walls = [solid[0]]
    return parts, _plane_frame(walls[0], s.resolution)


def goniometric_source(path: str | Path, flux: float | None = None,
                       position: tuple[float, float, float] = (0.0, 0.0, 0.0),
                       lamp_set: int | None = None) -> Part:
    """A point source with the intensity distribution of an IES or EULUMDAT file.

    Photons leave ``position`` (m) in directions drawn from the file's interpolated
    intensity (IES Types A, B, C or EULUMDAT; lamp axes +Z ahead, +Y up); the flux is the
    interpolant's integral, or ``flux`` (lm) with the distribution's shape kept.
    """
    if flux is not None and not (math.isfinite(flux) and flux > 0):
        raise InputError(f"flux must be a positive number of lumens, got {flux}")
    grid = photometric_reader(Path(path).suffix)(path, lamp_set=lamp_set)
    total = float(grid.total_flux())
    if not total > 0:
        raise InputError(f"{path}: the intensity distribution emits no flux")
    if flux is not None:
        grid = grid.scaled(flux / total)
        total = float(flux)
    # a tiny tetrahedron stands for the point in size and bookkeeping; it is never traced
    p = np.asarray(position, dtype=np.float64)
    verts = p + 1e-6 * np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1.0]])
    faces = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    return Part(Path(path).stem, EMITTER, verts, faces, None, Material("source", DIFFUSE),
                flux_lm=total, emission="goniometric", distribution=grid,
                emitter=GoniometricEmitter(p, grid.table, total, Path(path).name))


def ray_source_part(path: str | Path, at: tuple[float, float, float] = (0.0, 0.0, 0.0),
                    axis: tuple[float, float, float] = (0.0, 0.0, 1.0),
                    flux: float | None = None) -> Part:
    """An emitter part that draws its photons from a TM-25 or Zemax ray file.

    The file's origin is placed at ``at`` (m) and its +Z turned to ``axis``; the flux is
    the file's luminous flux or ``flux`` (lm). See :mod:`lightsim.emitters.rayfile`.
    """
    src = RaySource(path, at, axis, flux)
    # a tiny tetrahedron stands for the source in size and bookkeeping; never traced
    p = src.position
    verts = p + 1e-6 * np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1.0]])
    faces = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    return Part(f"rayfile-{Path(path).stem}", EMITTER, verts, faces, None,
                Material("source", DIFFUSE), flux_lm=src.flux_lm, emission="rayfile",
                distribution=src, emitter=src)


def _filament_part(bulb: str, at: tuple[float, float, float] | None,
                   axis: tuple[float, float, float], flux: float | None,
                   emission: str | None) -> Part:
    """An emitter part built from a bulb preset for meshes without their own emitter (the
    bulb catalogue is registered by ``lightsim.luminaires``: :mod:`lightsim.emitters.registry`)."""
    if at is None:
        raise InputError("--filament needs --filament-at X,Y,Z (m)")
    make = filament_factory()
    axis_v = np.asarray(axis, dtype=np.float64)
    if not np.all(np.isfinite(axis_v)) or np.linalg.norm(axis_v) == 0:
        raise InputError(f"--filament-axis must be a non-zero vector, got {axis}")
    verts, faces, bulb_flux, name = make(bulb, np.asarray(at, float),
                                         axis_v / np.linalg.norm(axis_v))
    return Part(f"filament-{name}", EMITTER, verts, faces, None, Material("filament", DIFFUSE),
                flux_lm=float(flux if flux is not None else bulb_flux),
                emission=emission or "isotropic")
