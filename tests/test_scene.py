"""Scene loading: glTF conventions, validation, and the one-line errors of bad input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lightsim.errors import InputError
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb
from lightsim.materials import DIELECTRIC, DIFFUSE, MIRROR
from lightsim.scene import EMITTER, WALL, load_scene

EMIT = GltfMaterial("filament", emissive=(1.0, 0.9, 0.8))
MIRROR_M = GltfMaterial("alu", base_color=(0.88, 0.88, 0.88), metallic=1.0)
GLASS = GltfMaterial("pc", transmission=1.0, ior=1.59)
TINTED = GltfMaterial("tint", transmission=1.0, ior=1.5, attenuation_distance=0.01,
                      attenuation_color=(0.5, 0.8, 0.9))
GREY = GltfMaterial("housing", base_color=(0.2, 0.2, 0.2))


def _box_part(name, material, centre=(0, 0, 0), size=0.01, extras=None, normals=False):
    m = trimesh.creation.box(extents=(size, size, size))
    v = np.asarray(m.vertices) + centre
    n = np.asarray(m.vertex_normals) if normals else None
    return GltfPart(name, v, np.asarray(m.faces), n, material, extras=extras)


def _lamp(tmp_path, extra_parts=(), flux=1200.0, filename="lamp.glb"):
    parts = [_box_part("filament", EMIT, extras={"lightsim": {"flux_lm": flux}}, size=0.002),
             _box_part("reflector", MIRROR_M, (0, 0, -0.03)),
             _box_part("lens", GLASS, (0, 0, 0.05)),
             *extra_parts]
    path = tmp_path / filename
    write_glb(path, parts)
    return path


def test_glb_conventions_are_read(tmp_path):
    wall = GltfPart("wall", np.array([[-5, -2, 10], [5, -2, 10], [5, 2, 10], [-5, 2, 10.0]]),
                    np.array([[0, 2, 1], [0, 3, 2]]), None, GREY)
    path = _lamp(tmp_path, [_box_part("filter", TINTED, (0, 0, 0.1)), wall])
    scene = load_scene(path)
    roles = {p.name: p.role for p in scene.parts}
    assert roles == {"filament": EMITTER, "reflector": "surface", "lens": "surface",
                     "filter": "surface", "wall": WALL}
    mats = {p.name: p.material for p in scene.parts}
    assert mats["reflector"].kind == MIRROR
    np.testing.assert_allclose(mats["reflector"].rgb, 0.88, rtol=1e-6)
    assert mats["lens"].kind == DIELECTRIC and mats["lens"].ior == pytest.approx(1.59)
    np.testing.assert_allclose(mats["filter"].sigma,
                               -np.log([0.5, 0.8, 0.9]) / 0.01, rtol=1e-6)
    assert mats["wall"].kind == DIFFUSE
    assert scene.total_flux == pytest.approx(1200.0)
    # the wall frame: plane z = 10 facing the lamp, H = −X, V = +Y
    f = scene.wall
    assert f.distance_m == pytest.approx(10.0)
    np.testing.assert_allclose(f.normal, [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(f.h_axis, [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(f.v_axis, [0, 1, 0], atol=1e-12)
    assert f.h_range_m == pytest.approx((-5, 5)) and f.v_range_m == pytest.approx((-2, 2))
    # coloured attenuation → the plan will need RGB
    assert scene.materials.coloured


def test_default_wall_and_flux_override(tmp_path):
    scene = load_scene(_lamp(tmp_path), flux=900.0, wall_distance=20.0, wall_size=(8, 4))
    assert scene.wall.distance_m == 20.0
    assert scene.total_flux == pytest.approx(900.0)
    wall = next(p for p in scene.parts if p.role == WALL)
    # the added wall's normal faces the lamp (−Z)
    tri = wall.vertices[wall.faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(n[:, 2] < 0)


def test_inverted_glass_is_flipped_and_open_glass_warned(tmp_path):
    m = trimesh.creation.icosphere(2, radius=0.01)
    inverted = GltfPart("bulb", np.asarray(m.vertices) + (0, 0, 0.02),
                        np.asarray(m.faces)[:, ::-1], None, GLASS)
    open_faces = np.asarray(m.faces)[: len(m.faces) // 2]
    open_lens = GltfPart("lens2", np.asarray(m.vertices) + (0, 0, 0.08), open_faces, None, GLASS)
    scene = load_scene(_lamp(tmp_path, [inverted, open_lens]))
    assert any("inverted normals" in w and "bulb" in w for w in scene.warnings)
    assert any("not closed" in w and "lens2" in w for w in scene.warnings)
    bulb = next(p for p in scene.parts if p.name == "bulb")
    assert trimesh.Trimesh(bulb.vertices, bulb.faces).volume > 0


def test_zero_area_triangles_dropped_with_warning(tmp_path):
    v = np.array([[0, 0, 0.1], [0.01, 0, 0.1], [0, 0.01, 0.1], [0.02, 0, 0.1]])
    f = np.array([[0, 1, 2], [0, 1, 3], [1, 1, 2]])  # the last two are degenerate
    part = GltfPart("plate", v, f, None, GREY)
    scene = load_scene(_lamp(tmp_path, [part]))
    plate = next(p for p in scene.parts if p.name == "plate")
    assert len(plate.faces) == 1
    assert any("dropped 2 zero-area" in w for w in scene.warnings)


def test_stl_without_emitter_takes_a_filament(tmp_path):
    path = tmp_path / "reflector.stl"
    trimesh.creation.icosphere(1, radius=0.05).export(path)
    with pytest.raises(InputError, match="no emitter"):
        load_scene(path)
    scene = load_scene(path, filament="H7", filament_at=(0, 0, 0.0),
                       part_materials={"reflector.stl": "mirror:0.9"})
    em = scene.emitters
    assert len(em) == 1 and em[0].flux_lm > 0
    refl = next(p for p in scene.parts if p.role == "surface")
    assert refl.material.kind == MIRROR and refl.material.rgb[0] == pytest.approx(0.9)


@pytest.mark.parametrize("case,match", [
    ("missing", "no such file"),
    ("notmesh", "not a mesh or photometric file"),
    ("truncated", "truncated"),
    ("garbage", "not a glTF file"),
    ("nan", "NaN/inf"),
    ("noflux", "no luminous flux"),
    ("negflux", "flux must be positive"),
])
def test_bad_input_is_one_clear_error(tmp_path, case, match):
    path = _lamp(tmp_path)
    if case == "missing":
        path = tmp_path / "nope.glb"
    elif case == "notmesh":
        path = tmp_path / "notes.txt"
        path.write_text("hello")
    elif case == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif case == "garbage":
        path = tmp_path / "x.gltf"
        path.write_bytes(b"\x00\x01garbage")
    elif case == "nan":
        # our writer refuses NaN, so patch one vertex of a written file
        bad = _box_part("bad", GREY)
        bad.vertices[0, 0] = 123.25
        path = _lamp(tmp_path, [bad], filename="nan.glb")
        data = path.read_bytes()
        marker = np.float32(123.25).tobytes()
        assert data.count(marker) == 1
        path.write_bytes(data.replace(marker, np.float32(np.nan).tobytes()))
    elif case == "noflux":
        path = tmp_path / "noflux.glb"
        write_glb(path, [_box_part("filament", EMIT, size=0.002)])
    elif case == "negflux":
        path = _lamp(tmp_path, flux=-5.0, filename="neg.glb")
    with pytest.raises(InputError, match=match) as err:
        load_scene(path)
    assert "\n" not in str(err.value)


def test_unknown_bulb_and_bad_wall(tmp_path):
    path = tmp_path / "r.stl"
    trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(path)
    with pytest.raises(InputError):
        load_scene(path, filament="H99", filament_at=(0, 0, 0))
    with pytest.raises(InputError, match="wall distance"):
        load_scene(_lamp(tmp_path), wall_distance=-3)
    bent = GltfPart("wall", np.array([[-5, -2, 10], [5, -2, 10], [5, 2, 11], [-5, 2, 10.0]]),
                    np.array([[0, 2, 1], [0, 3, 2]]), None, GREY)
    with pytest.raises(InputError, match="not planar"):
        load_scene(_lamp(tmp_path, [bent], filename="bent.glb"))
