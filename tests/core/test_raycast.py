"""The embree scene built through ctypes (lightsim.raycast.embree_scene) is the mesh
embreex's own TriangleMesh builds: the same hits, bit for bit, on rays we did not aim."""

from __future__ import annotations

import numpy as np
import trimesh
from embreex import rtcore as rtc
from embreex import rtcore_scene as rtcs

from lightsim.raycast import RayCaster, embree_handles, embree_scene


def _rays(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    o = (rng.random((n, 3)) * 4 - 2).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return o, d.astype(np.float32)


def _compare(tri: np.ndarray, seed: int = 0) -> float:
    o, d = _rays(20_000, seed)
    fast = embree_scene(tri, fast=True).run(o, d, output=1)
    slow = embree_scene(tri, fast=False).run(o, d, output=1)
    for key in ("primID", "geomID", "tfar", "u", "v"):
        np.testing.assert_array_equal(fast[key], slow[key], err_msg=key)
    return float((slow["primID"] >= 0).mean())


def test_fast_path_is_taken_with_the_installed_embreex():
    device = rtc.EmbreeDevice()
    handles = embree_handles(rtcs.EmbreeScene(device), device)
    assert handles is not None and all(handles), (
        "embreex's EmbreeScene layout changed: lightsim falls back to TriangleMesh "
        "(correct, but ~2 µs per triangle slower)")


def test_same_hits_as_embreex_triangle_mesh():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    tri = np.ascontiguousarray(sphere.triangles, dtype=np.float32)
    hit = _compare(tri)
    assert 0.1 < hit < 0.5  # rays start inside (all hit) and outside (some hit)


def test_degenerate_and_extreme_triangles():
    rng = np.random.default_rng(3)
    tri = (rng.random((500, 3, 3)) * 2 - 1).astype(np.float32)
    tri[:50, 1] = tri[:50, 0]            # zero-area triangles
    tri[50:100] *= np.float32(1e-30)     # tiny
    tri[100:150] *= np.float32(1e30)     # huge
    _compare(tri, seed=1)


def test_raycaster_uses_it_and_still_hits():
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    caster = RayCaster(np.asarray(box.triangles), threads=1)
    prim, t, _, _ = caster.intersect(np.array([[0.0, 0.0, -2.0]]), np.array([[0.0, 0.0, 1.0]]))
    assert prim[0] >= 0 and abs(float(t[0]) - 1.5) < 1e-6
    caster.close()
