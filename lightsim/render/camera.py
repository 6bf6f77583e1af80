"""Views: the orthographic wall detector and a pinhole camera traced with embree.

The **wall detector** is the measurement screen: W×H pixels over the wall's H/V extent,
each the illuminance E (lx) at the pixel centre (see :class:`lightsim.wall.WallFrame`).

The **pinhole camera** sees what a photograph of the scene sees. Eye rays are cast with
embree; at a diffuse surface the pixel is its luminance L = ρ E / π (cd/m²), with E from
the photon map (only photons whose surface normal agrees are counted). Mirrors and glass
are followed for up to ``max_specular`` bounces: a mirror multiplies by its reflectance,
glass follows the refracted ray with weight 1 − F (the reflected image in glass is left
out, except under total internal reflection, where the ray reflects). Emitters are not
part of the traced geometry, so a camera does not see the filament itself.

=================  ======  ==========  ==============================================
parameter          unit    default     meaning
=================  ======  ==========  ==============================================
``position``       m       required    eye point
``look_at``        m       required    point at the image centre
``up``             –       (0, 1, 0)   world up direction
``fov_deg``        deg     40          vertical field of view
``resolution``     px      640 × 480   image width × height (row 0 = top)
``max_specular``   –       4           mirror/glass bounces followed per eye ray
=================  ======  ==========  ==============================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lightsim.errors import InputError
from lightsim.materials import DIELECTRIC, DIFFUSE, MIRROR, fresnel_dielectric


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera (see the module docstring for the parameters)."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_deg: float = 40.0
    resolution: tuple[int, int] = (640, 480)
    max_specular: int = 4

    def __post_init__(self) -> None:
        p, t = np.asarray(self.position, float), np.asarray(self.look_at, float)
        if p.shape != (3,) or t.shape != (3,) or not np.all(np.isfinite(p)) \
                or not np.all(np.isfinite(t)):
            raise InputError("camera position and look-at must be finite X,Y,Z points (m)")
        if np.linalg.norm(t - p) == 0:
            raise InputError("camera look-at point equals its position")
        if not 0.1 <= self.fov_deg <= 170:
            raise InputError(f"camera field of view must be 0.1–170°, got {self.fov_deg}")
        w, h = self.resolution
        if w < 1 or h < 1:
            raise InputError(f"camera resolution must be at least 1x1, got {w}x{h}")
        f = (t - p) / np.linalg.norm(t - p)
        if np.linalg.norm(np.cross(f, np.asarray(self.up, float))) < 1e-9:
            raise InputError("camera up vector is parallel to the viewing direction")

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) unit vectors."""
        p, t = np.asarray(self.position, float), np.asarray(self.look_at, float)
        f = (t - p) / np.linalg.norm(t - p)
        r = np.cross(f, np.asarray(self.up, float))
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        return r, u, f

    def rays(self, rows: np.ndarray | None = None, cols: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """Eye rays through pixel centres: origins and unit directions, (n, 3) each.

        ``rows``/``cols`` select a sub-grid (an interleave set); default all pixels, in
        row-major order.
        """
        w, h = self.resolution
        rows = np.arange(h) if rows is None else np.asarray(rows)
        cols = np.arange(w) if cols is None else np.asarray(cols)
        r, u, f = self.basis()
        half_h = math.tan(math.radians(self.fov_deg) / 2)
        half_w = half_h * w / h
        x = (2 * (cols + 0.5) / w - 1) * half_w
        y = (1 - 2 * (rows + 0.5) / h) * half_h
        xx, yy = np.meshgrid(x, y)
        d = f + xx[..., None] * r + yy[..., None] * u
        d = d.reshape(-1, 3)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        o = np.broadcast_to(np.asarray(self.position, float), d.shape).copy()
        return o, d

    def to_dict(self) -> dict:
        return {"position": list(self.position), "look_at": list(self.look_at),
                "up": list(self.up), "fov_deg": self.fov_deg,
                "resolution": list(self.resolution)}


def eye_hits(scene, caster, origins: np.ndarray, directions: np.ndarray,
             max_specular: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Follow eye rays to the diffuse surface each one sees.

    Returns
    -------
    points : (n, 3) float64
        Diffuse hit points (m); undefined where ``weight`` is 0.
    normals : (n, 3) float64
        Geometric normals facing the eye ray.
    weight : (n, C) float64
        Path weight × albedo / π: the pixel luminance is weight × E (cd/m² per lx).
    part : (n,) int32
        Surface part index, −1 where the ray saw nothing diffuse.
    """
    n = len(origins)
    mats = scene.materials
    C = mats.channels
    points = np.zeros((n, 3))
    normals = np.zeros((n, 3))
    weight = np.zeros((n, C))
    part = np.full(n, -1, np.int32)
    o = np.asarray(origins, float).copy()
    d = np.asarray(directions, float).copy()
    w = np.ones((n, C))
    idx = np.arange(n)
    fn_all, tri_all, tri_part = scene.face_normals, scene.triangles, scene.tri_part
    for _ in range(max_specular + 1):
        if len(idx) == 0:
            break
        prim, t, bu, bv = caster.intersect(o, d)
        hit = prim >= 0
        idx, o, d, w, prim, t, bu, bv = (a[hit] for a in (idx, o, d, w, prim, t, bu, bv))
        if len(idx) == 0:
            break
        k = prim
        b1 = np.clip(bu.astype(float), 0, 1)
        b2 = np.clip(bv.astype(float), 0, 1 - b1)
        p = ((1 - b1 - b2)[:, None] * tri_all[k, 0] + b1[:, None] * tri_all[k, 1]
             + b2[:, None] * tri_all[k, 2])
        g = fn_all[k]
        cos_g = np.einsum("ij,ij->i", d, g)
        g_face = np.where((cos_g < 0)[:, None], g, -g)  # faces the incoming ray
        m = tri_part[k]
        kind = mats.kind[m]
        diffuse = kind == DIFFUSE
        sel = idx[diffuse]
        points[sel] = p[diffuse]
        normals[sel] = g_face[diffuse]
        weight[sel] = w[diffuse] * mats.value[m[diffuse]] / math.pi
        part[sel] = m[diffuse]
        spec = ~diffuse
        idx, o, d, w, p, g_face, m, kind, cos_g = (
            a[spec] for a in (idx, o, d, w, p, g_face, m, kind, cos_g))
        if len(idx) == 0:
            break
        cos_i = np.abs(cos_g)
        refl = d + 2 * cos_i[:, None] * g_face
        new_d = refl.copy()
        side = np.ones(len(idx))
        mirror = kind == MIRROR
        w[mirror] *= mats.value[m[mirror]]
        for j in np.flatnonzero(kind == DIELECTRIC):
            entering = cos_g[j] < 0
            eta_i, eta_t = (1.0, mats.ior[m[j]]) if entering else (mats.ior[m[j]], 1.0)
            F = fresnel_dielectric(cos_i[j], eta_i, eta_t)
            if F >= 1.0:
                continue  # total internal reflection: keep the reflected ray
            eta = eta_i / eta_t
            cos_t = math.sqrt(max(0.0, 1 - eta * eta * (1 - cos_i[j] ** 2)))
            new_d[j] = eta * d[j] + (eta * cos_i[j] - cos_t) * g_face[j]
            w[j] *= 1.0 - F
            side[j] = -1.0
        new_d /= np.linalg.norm(new_d, axis=1, keepdims=True)
        eps = 3.814697265625e-06 * (np.abs(p).max(axis=1) + 0.01 * scene.scale)
        o = p + (side * eps)[:, None] * g_face
        d = new_d
    return points, normals, weight, part
