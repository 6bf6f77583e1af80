"""Aiming without an embree rebuild: the wall is intersected exactly outside embree and
moving it (the lamp aimed the opposite way) keeps the lamp's embree scene."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb
from lightsim.raycast import RayCaster
from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.scene import Scene, SceneSettings, load_scene
from lightsim.tracer import Geometry, PhotonTracer
from lightsim.validation.bench.tracer_aim import aim_rotation as aim
from lightsim.validation.bench.tracer_aim import rotated_lamp
from lightsim.validation.scenes.analytic import paraboloid_case


def emitted(tracer: PhotonTracer, n: int, seed: int = 3):
    idx = np.arange(n, dtype=np.int64)
    o, d = tracer.emitters.sample(halton_points(idx, digit_permutations(seed, 0, None)))
    power = np.full((n, tracer.channels), tracer.emitters.flux_lm)
    return o, d, power, photon_keys(seed, 0, 0, idx)


def wall_map(res, frame, bins=(48, 48)) -> np.ndarray:
    h, v = frame.to_hv(res.records.position.astype(np.float64))
    im, _, _ = np.histogram2d(h, v, bins=bins, range=[frame.h_range_m, frame.v_range_m],
                              weights=res.records.power[:, 0].astype(np.float64))
    return im


def compare_aim(scene: Scene, m: np.ndarray, n: int = 40_000):
    """Trace the same rays through the rotated lamp (rebuilt) and through the base lamp
    with the wall moved by m⁻¹ (embree scene reused): returns both results and scenes."""
    base = PhotonTracer(scene, threads=1)
    moved = scene.with_wall_transform(np.linalg.inv(m))
    t_new = PhotonTracer(moved, threads=1, caster=base.caster)
    assert t_new.caster.lamp_scene is base.caster.lamp_scene  # the lamp's BVH was not rebuilt
    fresh = Geometry.from_scene(moved)  # the lamp's rows were reused, the wall's replaced
    assert t_new.geometry is not fresh and all(
        np.array_equal(a, b) for a, b in zip(t_new.geometry[:6], fresh[:6]))
    np.testing.assert_array_equal(t_new.geometry.wall_tri, moved.wall_triangles)
    old = rotated_lamp(scene, m)
    t_old = PhotonTracer(old, threads=1)
    o, d, power, keys = emitted(base, n)
    lin = m[:3, :3]
    ra = t_old.trace(o @ lin.T + m[:3, 3], d @ lin.T, power, keys)
    rb = t_new.trace(o, d, power, keys)
    for t in (base, t_new, t_old):
        t.close()
    return ra, rb, old, moved


def test_exact_wall_matches_embree_hits():
    scene = paraboloid_case(resolution=(32, 32)).scene
    tri = scene.triangles
    rng = np.random.default_rng(1)
    o = rng.normal(scale=0.05, size=(20_000, 3))
    d = rng.normal(size=(20_000, 3)) + (0.0, 0.0, 1.0)  # half towards the wall
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ref = RayCaster(tri, threads=1)
    exact = RayCaster(tri, threads=1, wall=scene.tri_is_wall)
    assert exact.exact_wall and exact.n_lamp == len(tri) - 2
    p0, t0, u0, v0 = ref.intersect(o, d)
    p1, t1, u1, v1 = exact.intersect(o, d)
    wall = scene.tri_is_wall[np.maximum(p0, 0)] & (p0 >= 0)
    assert wall.sum() > 1000 and (~wall & (p0 >= 0)).sum() > 1000
    same = p0 == p1
    assert same.mean() > 0.9999  # a ray through the wall's diagonal may pick either half
    hit = same & (p0 >= 0)
    np.testing.assert_allclose(t1[hit], t0[hit], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(u1[hit & wall], u0[hit & wall], atol=1e-4)
    np.testing.assert_allclose(v1[hit & wall], v0[hit & wall], atol=1e-4)
    # a caster with the wall moved equals one rebuilt with it there
    m = aim(4.0, -3.0)
    moved = scene.with_wall_transform(m)
    p2, t2, *_ = exact.with_wall(moved.triangles[moved.tri_is_wall]).intersect(o, d)
    p3, t3, *_ = RayCaster(moved.triangles, threads=1, wall=moved.tri_is_wall).intersect(o, d)
    assert np.array_equal(p2, p3) and np.array_equal(t2, t3)
    with pytest.raises(ValueError, match="triangles"):
        exact.with_wall(moved.triangles[:3])
    for c in (ref, exact):
        c.close()


def test_wall_first_in_the_soup_keeps_soup_indices():
    """A wall that is not the last part: embree's ids are mapped back to the soup."""
    case = paraboloid_case(resolution=(16, 16))
    src, mirror, wall = case.scene.parts
    scene = Scene([wall, src, mirror], case.scene.wall, channels=1)
    rng = np.random.default_rng(2)
    o = rng.normal(scale=0.01, size=(20_000, 3)) + (0, 0, 0.1)
    d = rng.normal(size=(20_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    p0, t0, *_ = RayCaster(scene.triangles, threads=1).intersect(o, d)
    p1, t1, *_ = RayCaster(scene.triangles, threads=1, wall=scene.tri_is_wall).intersect(o, d)
    assert (p0 == p1).mean() > 0.9999 and (p0 >= 2).sum() > 1000
    same = (p0 == p1) & (p0 >= 0)
    np.testing.assert_allclose(t1[same], t0[same], rtol=1e-5, atol=1e-6)
    assert ((p1 == 0) | (p1 == 1)).sum() > 100  # the wall's own soup indices


def test_aim_by_moving_the_wall_gives_the_aimed_lamps_map():
    scene = paraboloid_case(resolution=(48, 48)).scene
    m = aim(3.0, -2.0)
    ra, rb, old, moved = compare_aim(scene, m)
    # the same photons reach the wall, at the same wall coordinates to float rounding
    assert abs(len(ra.records) - len(rb.records)) <= 2e-4 * len(ra.records)
    sa, sb = ra.records.source, rb.records.source
    common, ia, ib = np.intersect1d(sa, sb, return_indices=True)
    assert len(common) >= (1 - 2e-4) * len(sa)
    ha, va = old.wall.to_hv(ra.records.position[ia].astype(np.float64))
    hb, vb = moved.wall.to_hv(rb.records.position[ib].astype(np.float64))
    assert np.quantile(np.hypot(ha - hb, va - vb), 0.999) < 1e-5  # m, on a 0.5 m wall
    np.testing.assert_allclose(ra.records.power[ia], rb.records.power[ib], rtol=1e-6)
    a, b = wall_map(ra, old.wall), wall_map(rb, moved.wall)
    assert np.abs(a - b).sum() <= 2e-3 * a.sum()
    np.testing.assert_allclose(ra.ledger.sum(axis=0), rb.ledger.sum(axis=0), rtol=2e-4,
                               atol=1e-6 * ra.ledger.sum())
    # and the aim is real: the unmoved wall sees a different pattern
    base = PhotonTracer(scene, threads=1)
    o, d, power, keys = emitted(base, 40_000)
    r0 = base.trace(o, d, power, keys)
    base.close()
    assert np.abs(wall_map(r0, scene.wall) - a).sum() > 0.2 * a.sum()


def test_moved_wall_frame_keeps_pixels_and_hv_point():
    scene = paraboloid_case(resolution=(32, 16)).scene
    m = aim(10.0, 5.0)
    moved = scene.with_wall_transform(m)
    w0, w1 = scene.wall, moved.wall
    assert w1.distance_m == w0.distance_m and w1.hv_offset_m == w0.hv_offset_m
    h = np.array([-0.2, 0.0, 0.13])
    v = np.array([0.1, -0.05, 0.0])
    np.testing.assert_allclose(w1.to_world(h, v), w0.to_world(h, v) @ m[:3, :3].T,
                               atol=1e-12)
    np.testing.assert_allclose(w1.to_hv(w0.to_world(h, v) @ m[:3, :3].T), (h, v), atol=1e-12)
    # a scale about the origin (the wall-distance control) scales distance and metres
    s = np.diag([2.0, 2.0, 2.0, 1.0])
    far = scene.with_wall_transform(s).wall
    assert far.distance_m == pytest.approx(2 * w0.distance_m)
    assert far.h_range_m == pytest.approx(tuple(2 * x for x in w0.h_range_m))
    assert far.degrees(0.1, 0.0)[0] == pytest.approx(w0.degrees(0.05, 0.0)[0])
    with pytest.raises(InputError, match="4x4"):
        scene.with_wall_transform(np.full((4, 4), np.nan))
    with pytest.raises(InputError, match="singular"):
        scene.with_wall_transform(np.zeros((4, 4)))


def test_solid_wall_aim(tmp_path):
    """A slab wall (a closed solid reduced to its front face) moves without a rebuild
    too."""
    emit = GltfMaterial("filament", emissive=(1.0, 1.0, 1.0))
    grey = GltfMaterial("paint", base_color=(0.8, 0.8, 0.8))
    chrome = GltfMaterial("chrome", base_color=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.0)
    src = trimesh.creation.icosphere(subdivisions=1, radius=0.002)
    cup = trimesh.creation.cylinder(radius=0.05, height=0.06, sections=24)
    cup_v = np.asarray(cup.vertices) + (0, 0, -0.035)
    slab = trimesh.creation.box(extents=(4.0, 2.0, 0.001))
    write_glb(tmp_path / "lamp.glb", [
        GltfPart("filament", np.asarray(src.vertices), np.asarray(src.faces), None, emit,
                 extras={"lightsim": {"flux_lm": 1000.0}}),
        GltfPart("cup", cup_v, np.asarray(cup.faces), None, chrome),
        GltfPart("wall", np.asarray(slab.vertices) + (0, 0, 2.0005), np.asarray(slab.faces),
                 None, grey)])
    scene = load_scene(tmp_path / "lamp.glb", SceneSettings(resolution=(32, 16)))
    assert any("closed solid" in w for w in scene.warnings)
    m = aim(-6.0, 4.0)
    ra, rb, old, moved = compare_aim(scene, m, n=20_000)
    assert len(ra.records) > 1000
    common, ia, ib = np.intersect1d(ra.records.source, rb.records.source,
                                    return_indices=True)
    assert len(common) >= (1 - 1e-3) * len(ra.records)
    ha, va = old.wall.to_hv(ra.records.position[ia].astype(np.float64))
    hb, vb = moved.wall.to_hv(rb.records.position[ib].astype(np.float64))
    assert np.quantile(np.hypot(ha - hb, va - vb), 0.99) < 1e-4


def test_session_wall_transform_keeps_embree_and_matches_a_fresh_session():
    scene = paraboloid_case(resolution=(24, 24)).scene
    m = np.linalg.inv(aim(2.0, 1.0))
    cfg = RunConfig(frame_photons=20_000, interleave=1, seed=5)
    with Session(scene, cfg) as s:
        s.frame()
        caster = s.backend.clients[0].tracer.caster
        s.update(wall_transform=m)
        assert s.backend.clients[0].tracer.caster.lamp_scene is caster.lamp_scene
        a = s.frame()
    with Session(scene.with_wall_transform(m), cfg) as s2:
        b = s2.frame()
    assert np.array_equal(a.lux, b.lux)


def test_finely_meshed_wall_stays_in_embree_and_still_moves():
    """A wall of more than WALL_MAX_TRIANGLES triangles is cast by embree; moving it
    rebuilds the embree scene and gives the same map as a fresh session."""
    case = paraboloid_case(resolution=(24, 24))
    src, mirror, wall = case.scene.parts
    n = 9  # 9 × 9 quads = 162 triangles
    xs = np.linspace(-0.25, 0.25, n + 1)
    vx, vy = np.meshgrid(xs, xs, indexing="ij")
    verts = np.stack([vx.ravel(), vy.ravel(), np.full(vx.size, 0.6)], axis=1)
    faces = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = i * (n + 1) + j, (i + 1) * (n + 1) + j, (i + 1) * (n + 1) + j + 1, \
                i * (n + 1) + j + 1
            faces += [[a, c, b], [a, d, c]]
    fine = Scene([src, mirror, replace(wall, vertices=verts, faces=np.array(faces))],
                 case.scene.wall, channels=1)
    assert fine.tri_is_wall.sum() > 64
    t = PhotonTracer(fine, threads=1)
    assert not t.caster.exact_wall
    t.close()
    m = np.linalg.inv(aim(2.0, 1.0))
    cfg = RunConfig(frame_photons=20_000, interleave=1, seed=5)
    with Session(fine, cfg) as s:
        s.frame()
        s.update(wall_transform=m)
        a = s.frame()
    with Session(fine.with_wall_transform(m), cfg) as s2:
        b = s2.frame()
    assert np.array_equal(a.lux, b.lux) and a.lux.sum() > 0
