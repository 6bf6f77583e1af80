"""The paper's scenes, built by code: RING, EGG, GLASS (and the shipped HEADLIGHT).

Günther et al. use them for their Tables 1–7: a metal ring on a plane lit by a small area
light (direct and multiply reflected caustics), a glass egg on a plane, and a cognac glass
with coloured liquid. The detector of the first three is the floor (photons landing on it
are recorded); its frame has H along +X and V along −Z, seen from above.

=============  ======  ========  ===========================================================
scene          unit    size      contents
=============  ======  ========  ===========================================================
``ring``       m       4 × 4     mirror ring R = 0.5, height 0.25 (R 0.9) + 0.05 m disk light
``egg``        m       4 × 4     glass ellipsoid (n = 1.5) 0.6 × 0.8 × 0.6 + disk light
``glass``      m       2 × 2     glass tumbler (n = 1.5) with amber liquid (n = 1.33,
                                 coloured attenuation) + disk light → RGB plan
``headlight``  m       wall 25   ``luminaires/examples/headlight.glb``
=============  ======  ========  ===========================================================
"""

from __future__ import annotations

import numpy as np
import trimesh

from lightsim.errors import InputError
from lightsim.luminaires.headlight import example_headlight
from lightsim.materials import DIELECTRIC, Material
from lightsim.scene import SURFACE, Part, Scene, SceneSettings, WallFrame, load_scene
from lightsim.validation.scenes import primitives as prim

SCENES = ("ring", "egg", "glass", "headlight")


def floor_frame(size: float, resolution: tuple[int, int], height: float) -> WallFrame:
    """Detector frame of a square floor at y = 0 seen from above (H = +X, V = −Z)."""
    h = size / 2
    return WallFrame(np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0]),
                     np.array([0.0, 1.0, 0.0]), (-h, h), (-h, h), height, resolution)


def _floor(size: float) -> Part:
    return prim.floor(size, albedo=0.8, name="floor", as_wall=True)


def _light(position, target, flux: float = 100.0, radius: float = 0.05) -> Part:
    p, t = np.asarray(position, float), np.asarray(target, float)
    return prim.disk_source(flux, radius, centre=p, normal=t - p, name="light")


def ring(resolution: tuple[int, int] = (256, 256)) -> Scene:
    """RING: a mirror ring on the floor, lit from the side by a small area light."""
    parts = [_light((-1.4, 1.0, 0.0), (0.0, 0.1, 0.0)),
             prim.cylinder_ring(0.5, 0.25, 0.01, 0.9, segments=192),
             _floor(4.0)]
    return Scene(parts, floor_frame(2.0, resolution, 1.0))


def egg(resolution: tuple[int, int] = (256, 256)) -> Scene:
    """EGG: a glass ellipsoid resting on the floor under a small area light."""
    m = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    verts = np.asarray(m.vertices) * np.array([0.3, 0.4, 0.3]) + np.array([0.0, 0.4005, 0.0])
    normals = np.asarray(m.vertices) / np.array([0.3, 0.4, 0.3])  # ∇ of the ellipsoid
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    glass = Part("egg", SURFACE, verts, np.asarray(m.faces, np.int64), normals,
                 Material("glass", DIELECTRIC, np.ones(3), 1.5))
    parts = [_light((-0.8, 2.0, 0.3), (0.0, 0.4, 0.0)), glass, _floor(4.0)]
    return Scene(parts, floor_frame(2.0, resolution, 2.0))


def _revolve_y(profile: np.ndarray, sections: int) -> trimesh.Trimesh:
    """Revolve an (r, y) profile about the +Y axis (counter-clockwise → outward)."""
    m = trimesh.creation.revolve(profile, sections=sections)
    # trimesh revolves about Z: map (x, y, z) → (x, z, −y) so that the axis becomes +Y
    rot = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=float)
    m.apply_transform(rot)
    return m


def glass(resolution: tuple[int, int] = (256, 256)) -> Scene:
    """GLASS: a thick-walled glass tumbler holding amber liquid, lit from the side."""
    r_out, r_in, base, height, liquid = 0.12, 0.11, 0.02, 0.30, 0.18
    # closed (r, y) profile of the glass wall, counter-clockwise
    shell = np.array([[0.0, 0.0], [r_out, 0.0], [r_out, height], [r_in, height],
                      [r_in, base], [0.0, base]])
    g = _revolve_y(shell, 96)
    gap = 2e-4  # a thin air gap keeps glass and liquid separate interfaces
    fluid = np.array([[0.0, base + gap], [r_in - gap, base + gap], [r_in - gap, liquid],
                      [0.0, liquid]])
    f = _revolve_y(fluid, 96)
    amber = Material("cognac", DIELECTRIC, np.ones(3), 1.33,
                     -np.log(np.array([0.85, 0.45, 0.12])) / 0.1)
    parts = [
        _light((-1.2, 0.9, 0.2), (0.0, 0.12, 0.0), radius=0.04),
        Part("glass", SURFACE, np.asarray(g.vertices, float), np.asarray(g.faces, np.int64),
             np.asarray(g.vertex_normals, float), Material("glass", DIELECTRIC, np.ones(3), 1.5)),
        Part("liquid", SURFACE, np.asarray(f.vertices, float), np.asarray(f.faces, np.int64),
             np.asarray(f.vertex_normals, float), amber),
        _floor(3.0),
    ]
    return Scene(parts, floor_frame(1.2, resolution, 0.9))


def headlight(resolution: tuple[int, int] = (640, 256)) -> Scene:
    """The shipped example headlight with the default 25 m wall."""
    return load_scene(example_headlight(), SceneSettings(resolution=resolution))


def build(name: str, resolution: tuple[int, int] | None = None) -> Scene:
    """Scene by name (``ring``, ``egg``, ``glass``, ``headlight``)."""
    builders = {"ring": ring, "egg": egg, "glass": glass, "headlight": headlight}
    if name not in builders:
        raise InputError(f"unknown scene '{name}' (choose from {', '.join(SCENES)})")
    return builders[name]() if resolution is None else builders[name](resolution)

