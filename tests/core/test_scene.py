"""Scene loading: glTF conventions, validation, and the one-line errors of bad input."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import trimesh

from lightsim.errors import InputError
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb
from lightsim.materials import DIELECTRIC, DIFFUSE, MIRROR
from lightsim.scene import EMITTER, WALL, SceneSettings, load_scene
from lightsim.validation.fuzz import pack_glb, small_scene_glb, split_glb, to_gltf_text

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
    scene = load_scene(_lamp(tmp_path),
                       SceneSettings(flux=900.0, wall_distance=20.0, wall_size=(8, 4)))
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
    scene = load_scene(path, SceneSettings(filament="H7", filament_at=(0, 0, 0.0),
                       part_materials={"reflector.stl": "mirror:0.9"}))
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
        load_scene(path, SceneSettings(filament="H99", filament_at=(0, 0, 0)))
    with pytest.raises(InputError, match="wall distance"):
        load_scene(_lamp(tmp_path), SceneSettings(wall_distance=-3))
    bent = GltfPart("wall", np.array([[-5, -2, 10], [5, -2, 10], [5, 2, 11], [-5, 2, 10.0]]),
                    np.array([[0, 2, 1], [0, 3, 2]]), None, GREY)
    with pytest.raises(InputError, match="not planar"):
        load_scene(_lamp(tmp_path, [bent], filename="bent.glb"))


# -- glTF validation: every field the loader reads, one line naming the element ----------

def _edited_glb(tmp_path, edit, suffix=".glb"):
    """The fuzz seed scene (filament, lens, reflector) with one JSON edit applied."""
    doc, blob = split_glb(small_scene_glb())
    edit(doc)
    path = tmp_path / f"edited{suffix}"
    path.write_bytes(pack_glb(doc, blob) if suffix == ".glb" else to_gltf_text(doc, blob))
    return path


def _node(doc, name):
    return next(n for n in doc["nodes"] if n.get("name") == name)


NAN = float("nan")
INF = float("inf")


@pytest.mark.parametrize("edit,match", [
    (lambda d: _node(d, "lens").update(scale=[0.0, 0.0, 0.0]), "node 1 'lens'.*singular"),
    (lambda d: _node(d, "lens").update(scale=[1.0, 0.0, 1.0]), "singular"),
    (lambda d: _node(d, "lens").update(scale=[1e30] * 3), "'lens'.*reach 1.05e\\+29 m"),
    (lambda d: _node(d, "lens").update(scale=[1e-30] * 3), "'lens'.*shrinks the mesh"),
    (lambda d: _node(d, "lens").update(translation=[1e30, 0, 0]), "'lens'.*from the origin"),
    (lambda d: _node(d, "lens").update(matrix=[NAN] * 16), "'lens': matrix must be finite"),
    (lambda d: _node(d, "lens").update(matrix=[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1]),
     "'lens'.*singular"),
    (lambda d: _node(d, "lens").update(rotation=[0, 0, 0, 0]), "not a unit quaternion"),
    (lambda d: _node(d, "lens").update(scale=["a", 1, 1]), "scale must hold numbers"),
    (lambda d: _node(d, "lens").update(children=[1]), "reached twice"),
    (lambda d: _node(d, "lens").update(mesh=99), "mesh 99 does not exist"),
    (lambda d: _node(d, "lens").update(name=123), "name must be a string"),
    (lambda d: d["materials"][0].update(emissiveFactor="red"), "material 0 'filament': "
     "emissiveFactor must be a list of 3 numbers"),
    (lambda d: d["materials"][0].update(emissiveFactor=[INF, 1, 1]), "emissiveFactor must be "
     "finite"),
    (lambda d: d["materials"][0].update(emissiveFactor=[-1, -1, -1]), "emissiveFactor must lie"),
    (lambda d: d["materials"][2]["pbrMetallicRoughness"].update(baseColorFactor=[2, 1, 1, 1]),
     "'chrome': baseColorFactor must lie in \\[0, 1\\]"),
    (lambda d: d["materials"][2]["pbrMetallicRoughness"].update(metallicFactor="shiny"),
     "metallicFactor must be a number"),
    (lambda d: d["materials"][1]["extensions"]["KHR_materials_transmission"].update(
        transmissionFactor=""), "'glass': transmissionFactor must be a number"),
    (lambda d: d["materials"][1]["extensions"]["KHR_materials_ior"].update(ior=NAN),
     "ior must be finite"),
    (lambda d: d["materials"][1]["extensions"]["KHR_materials_volume"].update(
        attenuationDistance=0.0), "attenuationDistance must lie in \\(0"),
    (lambda d: d["accessors"][0].update(componentType=5123), "accessor 0 \\(POSITION of mesh "
     "0 'filament' primitive 0\\): componentType UNSIGNED_SHORT is not FLOAT"),
    (lambda d: d["accessors"][1].update(componentType=5120), "accessor 1 \\(indices.*unsigned"),
    (lambda d: d["accessors"][1].update(componentType=1234), "componentType must be one of"),
    (lambda d: d["accessors"][0].update(count=43), "accessor 0: 43 × VEC3 FLOAT needs 516 "
     "bytes of bufferView 0, which has 504"),
    (lambda d: d["accessors"][0].update(count=2**31), "count must be an integer"),
    (lambda d: d["accessors"][0].update(byteOffset=2), "misaligned"),
    (lambda d: d["bufferViews"][2].update(byteOffset=1466), "accessor 2: starts at byte 1466"),
    (lambda d: d["bufferViews"][0].update(byteStride=300), "byteStride must be 4…252"),
    (lambda d: d["bufferViews"][6].update(byteLength=10**6), "bufferView 6: bytes .* run past"),
    (lambda d: d["accessors"][0].pop("bufferView"), "has no bufferView"),
    (lambda d: d["accessors"][0].update(sparse={}), "sparse accessors are not supported"),
    (lambda d: d["meshes"][0]["primitives"][0].update(mode=99), "mode must be 0…6"),
    (lambda d: d["meshes"][0]["primitives"][0].update(material=42), "material 42 does not"),
    (lambda d: d["meshes"][0]["primitives"][0]["attributes"].pop("POSITION"),
     "has no POSITION"),
    (lambda d: d.update(scene=5), "the default scene: scene 5 does not exist"),
    (lambda d: d["buffers"][0].update(byteLength=10**12), "buffer 0 is truncated"),
    (lambda d: _node(d, "filament")["extras"]["lightsim"].update(flux_lm="abc"),
     "flux_lm 'abc' is not a number"),
    (lambda d: _node(d, "filament")["extras"]["lightsim"].update(flux_lm=INF),
     "flux_lm must be a finite"),
    (lambda d: _node(d, "filament").update(extras="x"), "extras must be a JSON object"),
])
def test_gltf_fields_are_validated_with_one_line(tmp_path, edit, match):
    path = _edited_glb(tmp_path, edit)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy RuntimeWarning on the way
        with pytest.raises(InputError, match=match) as err:
            load_scene(path)
    assert "\n" not in str(err.value)


def test_gltf_data_uri_is_validated(tmp_path):
    def corrupt(d):
        d["buffers"][0]["uri"] = "data:application/octet-stream;base64,@@@"

    doc, blob = split_glb(small_scene_glb())
    corrupt(doc)
    path = tmp_path / "x.gltf"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="corrupt base64"):
        load_scene(path)
    assert pack_glb(doc, blob)[:4] == b"glTF"


@pytest.mark.parametrize("edit,warning", [
    (lambda d: d.update(scenes=[]), "'scenes' is empty: every root node is loaded"),
    (lambda d: _node(d, "lens").update(scale=[-1.0, 1.0, 1.0]), "'lens': mirroring transform"),
    (lambda d: _node(d, "lens").update(rotation=[0, 0, 0, 1.01]), "normalised"),
    (lambda d: d["meshes"][2]["primitives"][0].update(mode=0), "POINTS primitive skipped"),
])
def test_gltf_repairs_are_warnings(tmp_path, edit, warning):
    path = _edited_glb(tmp_path, edit, suffix=".gltf")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = load_scene(path)
    assert any(warning in w for w in scene.warnings), scene.warnings
    assert scene.total_flux == pytest.approx(1000.0)


def test_gltf_mirroring_transform_keeps_outward_winding(tmp_path):
    plain = load_scene(_edited_glb(tmp_path, lambda d: None))
    mirrored = load_scene(_edited_glb(
        tmp_path, lambda d: _node(d, "lens").update(scale=[-1.0, 1.0, 1.0])))
    a = next(p for p in plain.parts if p.name == "lens")
    b = next(p for p in mirrored.parts if p.name == "lens")

    def normals(p):
        t = p.triangles
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        return n / np.linalg.norm(n, axis=1, keepdims=True), t.mean(axis=1)

    na, ca = normals(a)
    nb, cb = normals(b)
    # a box mirrored in x is the same box: outward normals stay outward
    assert np.all(np.einsum("ij,ij->i", na, ca - ca.mean(axis=0)) > 0)
    assert np.all(np.einsum("ij,ij->i", nb, cb - cb.mean(axis=0)) > 0)
