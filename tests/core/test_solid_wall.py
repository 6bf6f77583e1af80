"""A wall modelled as a closed thin solid (a CAD slab) uses its lamp-facing face."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb
from lightsim.render.frame import luminous
from lightsim.scene import WALL, SceneSettings, load_scene

EMIT = GltfMaterial("filament", emissive=(1.0, 1.0, 1.0))
GREY = GltfMaterial("paint", base_color=(0.8, 0.8, 0.8))


def _source():
    m = trimesh.creation.icosphere(subdivisions=1, radius=0.002)
    return GltfPart("filament", np.asarray(m.vertices), np.asarray(m.faces), None, EMIT,
                    extras={"lightsim": {"flux_lm": 1000.0}})


def _slab_wall(z0: float, thickness: float, inverted: bool = False):
    m = trimesh.creation.box(extents=(4.0, 2.0, thickness))
    v = np.asarray(m.vertices) + (0.0, 0.0, z0 + thickness / 2)
    f = np.asarray(m.faces)
    return GltfPart("wall", v, f[:, ::-1] if inverted else f, None, GREY)


def _plane_wall(z0: float):
    v = np.array([[-2, -1, z0], [2, -1, z0], [2, 1, z0], [-2, 1, z0]], float)
    return GltfPart("wall", v, np.array([[0, 2, 1], [0, 3, 2]]), None, GREY)


@pytest.mark.parametrize("inverted", [False, True])
def test_slab_wall_becomes_its_front_face(tmp_path, inverted):
    path = tmp_path / "slab.glb"
    write_glb(path, [_source(), _slab_wall(2.0, 0.001, inverted)])
    scene = load_scene(path, SceneSettings(resolution=(40, 20)))
    wall = next(p for p in scene.parts if p.role == WALL)
    tri = wall.vertices[wall.faces]
    # only the two front triangles remain, in the plane z = 2, facing the lamp (−Z)
    assert len(wall.faces) == 2
    np.testing.assert_allclose(tri[..., 2], 2.0, atol=1e-12)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(n[:, 2] < 0)
    assert scene.wall.distance_m == pytest.approx(2.0)
    notes = [w for w in scene.warnings if "closed solid" in w]
    assert len(notes) == 1 and "1 mm thick" in notes[0] and "\n" not in notes[0]


def test_thick_or_open_bent_walls_are_still_refused(tmp_path):
    path = tmp_path / "thick.glb"
    write_glb(path, [_source(), _slab_wall(2.0, 0.5)])  # 0.5 m of 2 m: not a thin wall
    with pytest.raises(InputError, match="not planar"):
        load_scene(path)


def test_solid_wall_lux_matches_planar_wall(tmp_path):
    """Same lamp, same photons: a 1 mm slab wall and a plane at its front face agree."""
    lux = []
    for name, wall in (("plane", _plane_wall(2.0)), ("slab", _slab_wall(2.0, 0.001))):
        path = tmp_path / f"{name}.glb"
        write_glb(path, [_source(), wall])
        scene = load_scene(path, SceneSettings(resolution=(32, 16)))
        with Session(scene, RunConfig(frame_photons=32_000, interleave=2)) as s:
            lux.append(luminous(s.run(photons=32_000).lux))
    plane, slab = lux
    assert plane.max() > 0
    # the same photons reach the same plane (the slab's triangles split the face along
    # the other diagonal, which moves a few kNN neighbours): well within 1 %
    assert abs(slab.sum() / plane.sum() - 1.0) < 1e-3
    assert np.abs(slab - plane).mean() / plane.mean() < 0.01
