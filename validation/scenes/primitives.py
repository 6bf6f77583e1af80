"""Building blocks of the analytic and paper scenes, as in-memory :class:`Part` objects.

Every function returns plain parts in metres (glTF axes: +Y up, light along +Z); the
scenes in :mod:`lightsim.validation.scenes` combine them. Shapes that act as optics carry
exact analytic vertex normals so the tracer's interpolated shading normals are accurate.
"""

from __future__ import annotations

import numpy as np
import trimesh

from lightsim.materials import DIELECTRIC, DIFFUSE, MIRROR, Material
from lightsim.scene import EMITTER, SURFACE, WALL, Part


def point_source(flux_lm: float, radius: float = 1e-4, centre=(0.0, 0.0, 0.0),
                 emission: str = "isotropic", name: str = "source") -> Part:
    """A tiny sphere emitting ``flux_lm`` lumens (an isotropic point source for
    ``radius`` ≪ distances)."""
    ico = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    verts = np.asarray(ico.vertices) + np.asarray(centre, dtype=np.float64)
    return Part(name, EMITTER, verts, np.asarray(ico.faces, np.int64), None,
                Material(name, DIFFUSE), flux_lm=float(flux_lm), emission=emission)


def disk_source(flux_lm: float, radius: float, centre=(0.0, 0.0, 0.0),
                normal=(0.0, 0.0, 1.0), segments: int = 32, name: str = "source") -> Part:
    """A flat disk emitting ``flux_lm`` lumens on its front side (Lambertian)."""
    ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(segments)], axis=1)
    verts = np.vstack([[0.0, 0.0, 0.0], ring])
    faces = np.array([[0, 1 + i, 1 + (i + 1) % segments] for i in range(segments)])
    verts = _orient(verts, np.asarray(normal, float)) + np.asarray(centre, float)
    return Part(name, EMITTER, verts, faces, None, Material(name, DIFFUSE), flux_lm=float(flux_lm),
                emission="lambertian")


def _orient(verts: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Rotate geometry built around +Z so that +Z becomes ``normal``."""
    n = normal / np.linalg.norm(normal)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, n)
    c = float(z @ n)
    if np.linalg.norm(v) < 1e-12:
        return verts if c > 0 else verts * np.array([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    r = np.eye(3) + vx + vx @ vx / (1 + c)
    return verts @ r.T


def paraboloid(focal_length: float, rim_radius: float, reflectance: float = 1.0,
               hole_radius: float = 0.0, radial: int = 96, azimuthal: int = 512,
               name: str = "reflector") -> Part:
    """Paraboloid mirror z = r²/(4f), vertex at the origin, focus (0, 0, f), opening +Z.

    Normals are the exact analytic ones pointing to the inside (towards the focus), and
    the winding makes the inside the front face. Rings are spaced evenly in r.
    """
    f = float(focal_length)
    r = np.linspace(max(hole_radius, 0.0), rim_radius, radial + 1)
    if hole_radius <= 0:
        r = r[1:]
    phi = np.linspace(0, 2 * np.pi, azimuthal, endpoint=False)
    R, P = np.meshgrid(r, phi, indexing="ij")
    x, y, z = R * np.cos(P), R * np.sin(P), R**2 / (4 * f)
    verts = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    nrm = np.stack([-x / (2 * f), -y / (2 * f), np.ones_like(x)], axis=-1).reshape(-1, 3)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    nr, na = len(r), azimuthal
    faces = []
    for i in range(nr - 1):
        for j in range(na):
            a, b = i * na + j, i * na + (j + 1) % na
            c, d = (i + 1) * na + j, (i + 1) * na + (j + 1) % na
            faces += [[a, c, b], [b, c, d]]
    if hole_radius <= 0:  # close the apex with a fan
        verts = np.vstack([verts, [0.0, 0.0, 0.0]])
        nrm = np.vstack([nrm, [0.0, 0.0, 1.0]])
        apex = len(verts) - 1
        faces += [[apex, j, (j + 1) % na] for j in range(na)]
    faces = np.asarray(faces, np.int64)
    # make the counter-clockwise front face the inside (towards +Z at the apex)
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if np.mean(np.einsum("ij,ij->i", fn, nrm[faces[:, 0]])) < 0:
        faces = faces[:, ::-1].copy()
    return Part(name, SURFACE, verts, faces, nrm,
                Material(name, MIRROR, np.full(3, reflectance)))


def box(lo, hi, material: Material, name: str) -> Part:
    """An axis-aligned closed box with outward normals (flat)."""
    m = trimesh.creation.box(bounds=np.array([lo, hi], dtype=np.float64))
    return Part(name, SURFACE, np.asarray(m.vertices, np.float64),
                np.asarray(m.faces, np.int64), None, material)


def slab(thickness: float, size: float, z0: float, ior: float = 1.5, sigma: float = 0.0,
         name: str = "slab") -> Part:
    """A square glass plate of ``thickness`` (m) with faces at z0 and z0 + thickness."""
    h = size / 2
    return box((-h, -h, z0), (h, h, z0 + thickness),
               Material(name, DIELECTRIC, np.ones(3), ior, np.full(3, sigma)), name)


def mirror_plane(size: float, centre, normal, reflectance: float, name: str = "mirror") -> Part:
    """A square one-triangle-pair mirror of side ``size`` facing ``normal``."""
    h = size / 2
    verts = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], dtype=np.float64)
    verts = _orient(verts, np.asarray(normal, float)) + np.asarray(centre, float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return Part(name, SURFACE, verts, faces, None, Material(name, MIRROR, np.full(3, reflectance)))


def cylinder_ring(radius: float, height: float, thickness: float, reflectance: float,
                  segments: int = 256, name: str = "ring") -> Part:
    """A thin-walled metal ring (open cylinder) standing on the plane y = 0, axis +Y.

    The inner and outer faces are mirrors with smooth analytic normals (inner ones point
    to the axis), and the rims close the wall.
    """
    ang = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    c, s = np.cos(ang), np.sin(ang)
    ri, ro = radius, radius + thickness
    verts, nrm, faces = [], [], []

    def add_band(r, sign):
        base = len(verts)
        for yy in (0.0, height):
            for k in range(segments):
                verts.append([r * c[k], yy, r * s[k]])
                nrm.append([sign * c[k], 0.0, sign * s[k]])
        for k in range(segments):
            a, b = base + k, base + (k + 1) % segments
            cc, d = a + segments, b + segments
            faces.extend([[a, cc, b], [b, cc, d]] if sign > 0 else [[a, b, cc], [b, d, cc]])

    add_band(ro, 1.0)
    add_band(ri, -1.0)
    for yy, up in ((0.0, -1.0), (height, 1.0)):
        base = len(verts)
        for k in range(segments):
            verts.append([ri * c[k], yy, ri * s[k]])
            nrm.append([0.0, up, 0.0])
        for k in range(segments):
            verts.append([ro * c[k], yy, ro * s[k]])
            nrm.append([0.0, up, 0.0])
        for k in range(segments):
            a, b = base + k, base + (k + 1) % segments
            cc, d = a + segments, b + segments
            faces.extend([[a, b, cc], [b, d, cc]] if up > 0 else [[a, cc, b], [b, cc, d]])
    verts = np.asarray(verts, np.float64)
    faces = np.asarray(faces, np.int64)
    nrm = np.asarray(nrm, np.float64)
    # fix the winding against the normals (front face = normal side)
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", fn, nrm[faces].mean(axis=1)) < 0
    faces[flip] = faces[flip][:, ::-1]
    return Part(name, SURFACE, verts, faces, nrm, Material(name, MIRROR, np.full(3, reflectance)))


def floor(size: float, y: float = 0.0, albedo: float = 0.8, name: str = "floor",
          as_wall: bool = False) -> Part:
    """A square horizontal plane at height ``y`` facing +Y (optionally the detector)."""
    h = size / 2
    verts = np.array([[-h, y, -h], [h, y, -h], [h, y, h], [-h, y, h]], dtype=np.float64)
    faces = np.array([[0, 2, 1], [0, 3, 2]])  # counter-clockwise seen from +Y
    return Part(name, WALL if as_wall else SURFACE, verts, faces, None,
                Material(name, DIFFUSE, np.full(3, albedo)))
