"""lightsim.io.closed_mesh against trimesh (is_watertight, volume) on closed, open,
inverted and split-vertex meshes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from lightsim.io.closed_mesh import closed_mesh


def _split(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Every triangle with its own three vertices (as glTF exports with flat normals)."""
    v = np.asarray(mesh.vertices)[np.asarray(mesh.faces)].reshape(-1, 3)
    return v, np.arange(len(v)).reshape(-1, 3)


MESHES = {
    "box": trimesh.creation.box((0.1, 0.2, 0.004)),
    "sphere": trimesh.creation.icosphere(2, radius=0.03),
    "cylinder": trimesh.creation.cylinder(0.01, 0.05, sections=24),
}


@pytest.mark.parametrize("name", sorted(MESHES))
@pytest.mark.parametrize("variant", ["plain", "inverted", "split", "open"])
def test_agrees_with_trimesh(name, variant):
    mesh = MESHES[name]
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if variant == "inverted":
        f = f[:, ::-1]
    elif variant == "split":
        v, f = _split(mesh)
    elif variant == "open":
        f = f[1:]
    ref = trimesh.Trimesh(v, f, process=True, validate=False)
    got = closed_mesh(v, f)
    assert got.watertight == ref.is_watertight
    if ref.is_watertight:
        assert got.volume == pytest.approx(ref.volume, rel=1e-9)
        assert (got.volume > 0) == (variant != "inverted")


def test_degenerate_inputs():
    assert not closed_mesh(np.zeros((0, 3)), np.zeros((0, 3), int)).watertight
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    res = closed_mesh(quad, np.array([[0, 1, 2], [0, 2, 3]]))
    assert not res.watertight and res.volume == 0.0
