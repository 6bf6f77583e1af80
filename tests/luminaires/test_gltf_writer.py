"""GLB writer: round trip through pygltflib and trimesh, materials, extensions, extras, errors."""

from __future__ import annotations

import json

import numpy as np
import pygltflib
import pytest
import trimesh

from lightsim.errors import InputError
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, glb_bytes, write_glb


def _accessor(gltf: pygltflib.GLTF2, index: int, dtype: str, width: int) -> np.ndarray:
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    data = np.frombuffer(
        gltf.binary_blob(), dtype=dtype, count=acc.count * width,
        offset=view.byteOffset + (acc.byteOffset or 0),
    )  # fmt: skip
    return data.reshape(acc.count, width) if width > 1 else data


def _parts() -> list[GltfPart]:
    rng = np.random.default_rng(3)
    box = trimesh.creation.box(extents=(0.02, 0.01, 0.03))
    # irregular float64 positions: the file must hold exactly their float32 rounding
    box_v = box.vertices + rng.normal(scale=1e-4, size=box.vertices.shape)
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    glass = GltfMaterial(
        "glass", base_color=(1.0, 1.0, 1.0), transmission=1.0, ior=1.5,
        attenuation_distance=0.1, attenuation_color=(0.9, 0.8, 0.7), thickness=0.01,
    )  # fmt: skip
    mirror = GltfMaterial("mirror", base_color=(0.88, 0.88, 0.88), metallic=1.0, roughness=0.0)
    emitter = GltfMaterial("lamp", emissive=(1.0, 1.0, 1.0))
    return [
        GltfPart("ball", sphere.vertices, sphere.faces, sphere.vertex_normals, glass,
                 extras={"lightsim": {"role": "dielectric"}}, translation=(0.0, 0.1, 0.0)),
        GltfPart("box", box_v, box.faces, None, mirror),
        GltfPart("lamp", box.vertices * 0.1, box.faces, None, emitter,
                 extras={"lightsim": {"flux_lm": np.float64(1000.0), "emission": "isotropic"}}),
    ]  # fmt: skip


def test_round_trip_pygltflib_bit_exact(tmp_path):
    parts = _parts()
    path = tmp_path / "scene.glb"
    size = write_glb(path, parts, asset_extras={"lightsim": {"units": "m"}})
    assert size == path.stat().st_size
    gltf = pygltflib.GLTF2().load(str(path))
    assert gltf.asset.version == "2.0"
    assert gltf.asset.extras == {"lightsim": {"units": "m"}}
    assert [n.name for n in gltf.nodes] == ["ball", "box", "lamp"]
    assert gltf.scenes[gltf.scene].nodes == [0, 1, 2]
    assert sorted(gltf.extensionsUsed) == [
        "KHR_materials_ior", "KHR_materials_transmission", "KHR_materials_volume"
    ]  # fmt: skip
    for node, part in zip(gltf.nodes, parts):
        prim = gltf.meshes[node.mesh].primitives[0]
        assert prim.mode == 4
        pos = _accessor(gltf, prim.attributes.POSITION, "<f4", 3)
        np.testing.assert_array_equal(pos, np.asarray(part.vertices, dtype=np.float32))
        acc = gltf.accessors[prim.attributes.POSITION]
        np.testing.assert_array_equal(acc.min, pos.min(axis=0))
        np.testing.assert_array_equal(acc.max, pos.max(axis=0))
        idx_acc = gltf.accessors[prim.indices]
        assert idx_acc.componentType == pygltflib.UNSIGNED_INT
        np.testing.assert_array_equal(
            _accessor(gltf, prim.indices, "<u4", 1).reshape(-1, 3), part.faces
        )
        if part.normals is None:
            assert prim.attributes.NORMAL is None
        else:
            nrm = _accessor(gltf, prim.attributes.NORMAL, "<f4", 3)
            np.testing.assert_array_equal(nrm, np.asarray(part.normals, dtype=np.float32))
    assert gltf.nodes[0].translation == [0.0, 0.1, 0.0]
    assert gltf.nodes[2].extras == {"lightsim": {"flux_lm": 1000.0, "emission": "isotropic"}}


def test_materials_and_extensions(tmp_path):
    path = tmp_path / "scene.glb"
    write_glb(path, _parts())
    gltf = pygltflib.GLTF2().load(str(path))
    mats = {m.name: m for m in gltf.materials}
    glass = mats["glass"]
    assert glass.extensions["KHR_materials_transmission"] == {"transmissionFactor": 1.0}
    assert glass.extensions["KHR_materials_ior"] == {"ior": 1.5}
    volume = glass.extensions["KHR_materials_volume"]
    assert volume["attenuationDistance"] == 0.1
    assert volume["attenuationColor"] == [0.9, 0.8, 0.7]
    assert volume["thicknessFactor"] == 0.01
    mirror = mats["mirror"]
    assert mirror.pbrMetallicRoughness.metallicFactor == 1.0
    assert mirror.pbrMetallicRoughness.baseColorFactor == [0.88, 0.88, 0.88, 1.0]
    assert not mirror.extensions
    assert mats["lamp"].emissiveFactor == [1.0, 1.0, 1.0]
    # valid JSON chunk, little-endian GLB header
    data = path.read_bytes()
    assert data[:4] == b"glTF" and int.from_bytes(data[8:12], "little") == len(data)
    json.loads(data[20 : 20 + int.from_bytes(data[12:16], "little")])


def test_round_trip_trimesh(tmp_path):
    parts = _parts()
    path = tmp_path / "scene.glb"
    write_glb(path, parts)
    scene = trimesh.load(path, process=False)
    assert set(scene.geometry) == {"ball", "box", "lamp"}
    for part in parts:
        mesh = scene.geometry[part.name]
        np.testing.assert_array_equal(mesh.vertices, np.asarray(part.vertices, np.float32))
        np.testing.assert_array_equal(mesh.faces, part.faces)
        if part.normals is not None:
            np.testing.assert_array_equal(
                mesh.vertex_normals, np.asarray(part.normals, np.float32)
            )
    # node transform survives
    transform, name = scene.graph["ball"]
    assert name == "ball"
    np.testing.assert_allclose(transform[:3, 3], [0.0, 0.1, 0.0])
    ball = scene.geometry["ball"]
    assert ball.is_watertight and ball.volume > 0


def test_deterministic_bytes():
    assert glb_bytes(_parts()) == glb_bytes(_parts())


def test_shared_materials_written_once(tmp_path):
    mat = GltfMaterial("grey")
    box = trimesh.creation.box()
    parts = [GltfPart(n, box.vertices, box.faces, None, mat) for n in ("a", "b")]
    path = tmp_path / "s.glb"
    write_glb(path, parts)
    gltf = pygltflib.GLTF2().load(str(path))
    assert len(gltf.materials) == 1
    assert not gltf.extensionsUsed


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"vertices": np.full((8, 3), np.nan)}, "NaN"),
        ({"vertices": np.zeros((8, 2))}, "shape"),
        ({"faces": np.array([[0, 1, 99]])}, "out of range"),
        ({"faces": np.array([[0.0, 1.0, 2.0]])}, "integer"),
        ({"normals": np.ones((8, 3))}, "unit"),
        ({"normals": np.ones((3, 3))}, "differs"),
        ({"material": GltfMaterial("m", metallic=2.0)}, "metallic"),
        ({"material": GltfMaterial("m", ior=0.5)}, "ior"),
        ({"material": GltfMaterial("m", base_color=(1.0, 2.0, 0.0))}, "base_color"),
        ({"material": GltfMaterial("m", attenuation_distance=0.0)}, "attenuation"),
        ({"extras": {"x": float("inf")}}, "non-finite"),
        ({"extras": {"x": object()}}, "not JSON"),
        ({"rotation": (0.0, 0.0, 0.0, 2.0)}, "quaternion"),
        ({"name": ""}, "name"),
    ],
)
def test_bad_parts_raise_input_error(change, message):
    box = trimesh.creation.box()
    fields = {"name": "p", "vertices": box.vertices, "faces": box.faces, "normals": None,
              "material": GltfMaterial("m")}  # fmt: skip
    fields.update(change)
    with pytest.raises(InputError, match=message):
        glb_bytes([GltfPart(**fields)])


def test_duplicate_names_and_empty_list():
    box = trimesh.creation.box()
    part = GltfPart("p", box.vertices, box.faces, None, GltfMaterial("m"))
    with pytest.raises(InputError, match="unique"):
        glb_bytes([part, part])
    with pytest.raises(InputError, match="without parts"):
        glb_bytes([])
