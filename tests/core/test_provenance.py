"""Path signatures (--provenance): exact shares on scenes built to know them, the parts
adding up, and runs without signatures unchanged."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lightsim.engine.apertures import layout_from_config
from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart
from lightsim.provenance import (
    PATH_LENGTH,
    PathElements,
    class_label,
    class_values,
    element_table,
    emitter_index,
    share_table,
)
from lightsim.scene import load_scene
from lightsim.tracer import EV_REFLECT, EV_REFRACT, EV_TIR, PhotonTracer

from support import write_point_lamp

APERTURE_DEG = 9.0  # a wide aperture: many photons per class in a short test
PHI = 1000.0  # lm, the point lamp's flux


def _square(centre, u, v, half):
    """Two triangles of the square centre ± half·u ± half·v (m)."""
    c, u, v = (np.asarray(x, float) for x in (centre, u, v))
    verts = np.array([c - half * u - half * v, c + half * u - half * v,
                      c + half * u + half * v, c - half * u + half * v])
    return verts, np.array([[0, 1, 2], [0, 2, 3]])


def _facet_mirror(x: float) -> tuple[np.ndarray, np.ndarray]:
    """A flat mirror at (x, 0, 0) turned 45° so that light from the origin travelling
    along ±x leaves along +z (towards the wall): the origin's mirror image sits at
    (x, 0, −|x|) and shines along +z through the mirror."""
    s = math.copysign(1.0, x)
    u = np.array([s, 0.0, 1.0]) / math.sqrt(2)
    return _square((x, 0.0, 0.0), u, (0.0, 1.0, 0.0), 0.012)


def _run(scene, photons: int, seed: int = 1):
    cfg = RunConfig(seed=seed, frame_photons=400_000, estimator="bin", spt=False,
                    apertures=((0.0, 0.0),), aperture_deg=APERTURE_DEG,
                    path_length=PATH_LENGTH)
    with Session(scene, cfg) as s:
        s.run(photons=photons)
        stats = s.backend.stats()
        sets = sorted(stats)
        emitted = np.array([stats[q]["emitted"] for q in sets], float)
        per_set = s.backend.paths()
        counts = s.backend.apertures()
        layout = layout_from_config(s.config, s.scene.wall.distance_m)
    el = PathElements.from_scene(scene)
    labels, values = class_values({q: per_set[q] for q in sets}, emitted, layout, el, 0.0,
                                  [[0]])
    omega = layout.solid_angles()[0]
    total = np.array([counts[q][0, 0] for q in sets]) / emitted / omega  # cd per set
    return labels, values, total, layout


def _omega_from(point, layout) -> float:
    """Solid angle (sr) of the aperture's wall rectangle seen from ``point`` (a mirror
    image of the source), by the corner formula about that point (wall at z = D)."""
    D = layout.distance_m
    a = math.radians(0.5 * layout.size_deg)
    x0, x1 = -D * math.tan(a) - point[0], D * math.tan(a) - point[0]
    y0, y1 = -D * math.tan(a) - point[1], D * math.tan(a) - point[1]
    d = D - point[2]

    def corner(x, y):
        return math.atan(x * y / (d * math.sqrt(d * d + x * x + y * y)))

    return corner(x1, y1) - corner(x0, y1) - corner(x1, y0) + corner(x0, y0)


def _within(row, exact):
    lo, hi = row["interval_cd"]
    assert lo <= exact <= hi, (row, exact)


def test_two_facet_scene_gives_each_facet_its_geometric_share(tmp_path):
    """Direct light and two mirror facets (R = 0.9) light the H-V aperture: each facet
    is a point image of the source shining R·Φ/4π through the aperture's rectangle as
    seen from the image, the direct light Φ/4π; the classes split the aperture exactly."""
    v0, f0 = _facet_mirror(0.03)
    v1, f1 = _facet_mirror(-0.05)
    verts = np.vstack([v0, v1])
    faces = np.vstack([f0, f1 + len(v0)])
    mirror = GltfPart("reflector", verts, faces, None,
                      GltfMaterial("m", base_color=(0.9, 0.9, 0.9), metallic=1.0),
                      extras={"lightsim": {"facets": [{"name": "a"}, {"name": "b"}]}})
    scene = load_scene(write_point_lamp(tmp_path / "facets.glb", mirror))
    labels, values, total, layout = _run(scene, 1_600_000)
    rows = {r["class"]: r for r in share_table(labels, values, 0, min_share=0.0, top=20)}
    i0 = PHI / (4 * math.pi)
    omega = layout.solid_angles()[0]
    exact = {
        "filament (direct)": i0,
        "filament → reflector facet 0": 0.9 * i0 * _omega_from((0.03, 0, -0.03), layout) / omega,
        "filament → reflector facet 1": 0.9 * i0 * _omega_from((-0.05, 0, -0.05), layout) / omega,
    }
    assert set(exact) <= set(rows), rows.keys()
    for name, want in exact.items():
        _within(rows[name], want)
    facets = {r["element"]: r for r in element_table(labels, values, 0, top=10)}
    assert set(facets) == {"reflector facet 0", "reflector facet 1"}
    _within(facets["reflector facet 0"], exact["filament → reflector facet 0"])
    # the parts add up to the aperture's own count, set by set
    np.testing.assert_allclose(values[:, :, 0].sum(axis=1), total, rtol=1e-9)
    other = sum(r["value_cd"] for n, r in rows.items() if n not in exact)
    assert other < 0.01 * total.mean()


def _fresnel(cos_i: float, n1: float, n2: float) -> float:
    """Unpolarised Fresnel reflectance (Born & Wolf), written out here."""
    sin_t = n1 / n2 * math.sqrt(1 - cos_i * cos_i)
    if sin_t >= 1:
        return 1.0
    cos_t = math.sqrt(1 - sin_t * sin_t)
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n1 * cos_t - n2 * cos_i) / (n1 * cos_t + n2 * cos_i)
    return 0.5 * (rs * rs + rp * rp)


def test_lens_ghost_share_follows_the_fresnel_equations(tmp_path):
    """A clear glass plate (n = 1.5, 3 mm) at 45° beside the source: its front surface
    sends R(45°)·Φ/4π towards the wall, the back surface T·R·T (the inner reflection),
    as the Fresnel equations give."""
    n = 1.5
    t = 0.003
    s2 = 1 / math.sqrt(2)
    nrm = np.array([-s2, 0.0, s2])  # the front face's normal, towards the source and wall
    u = np.array([s2, 0.0, s2])
    centre = np.array([0.05, 0.0, 0.0])
    front_v, front_f = _square(centre, u, (0, 1, 0), 0.015)
    back_v, back_f = _square(centre - t * nrm, u, (0, 1, 0), 0.015)
    back_f = back_f[:, ::-1]  # the back face points away from the plate
    # the four edge faces close the plate
    verts = np.vstack([front_v, back_v])
    faces = [front_f, back_f + 4]
    for a in range(4):
        b = (a + 1) % 4
        faces.append(np.array([[a, b + 4, b], [a, a + 4, b + 4]]))
    plate = GltfPart("lens", verts, np.vstack(faces), None,
                     GltfMaterial("g", transmission=1.0, ior=n))
    scene = load_scene(write_point_lamp(tmp_path / "plate.glb", plate))
    labels, values, total, layout = _run(scene, 3_200_000)
    rows = {r["class"]: r for r in share_table(labels, values, 0, min_share=0.0, top=20)}
    i0 = PHI / (4 * math.pi)
    omega = layout.solid_angles()[0]
    R = _fresnel(s2, 1.0, n)
    T = 1 - R
    img = (0.05, 0.0, -0.05)  # the source's image in the front face
    front = R * i0 * _omega_from(img, layout) / omega
    back = T * R * T * i0 * _omega_from((img[0] + t * s2, 0, img[2] - t * s2), layout) / omega
    _within(rows["filament → lens (Fresnel reflection)"], front)
    _within(rows["filament → lens (refracted) → lens (Fresnel reflection) → lens (refracted)"],
            back)
    _within(rows["filament (direct)"], i0)
    np.testing.assert_allclose(values[:, :, 0].sum(axis=1), total, rtol=1e-9)


def test_tracer_without_signatures_is_unchanged(tmp_path):
    """path_length 0 (every run without --provenance) and 8 give the same records, bit for
    bit; the signatures are only added."""
    scene = load_scene(write_point_lamp(tmp_path / "l.glb", GltfPart(
        "lens", *_square((0, 0, 0.05), (1, 0, 0), (0, 1, 0), 0.05), None,
        GltfMaterial("g", transmission=1.0, ior=1.5))))
    rng = np.random.default_rng(3)
    pts = rng.random((20_000, 5))
    keys = np.arange(20_000, dtype=np.uint64)
    a = PhotonTracer(scene, threads=1).trace_points(pts, keys, by_source=True)
    b = PhotonTracer(scene, threads=1, path_length=8).trace_points(pts, keys, by_source=True)
    assert a.records.path is None
    for f in ("position", "normal", "power", "part", "flags", "source"):
        np.testing.assert_array_equal(getattr(a.records, f), getattr(b.records, f))
    np.testing.assert_array_equal(a.ledger, b.ledger)
    assert b.records.path.shape == (len(b.records), 8)
    # a photon through a single glass sheet: two refractions, or a reflection first
    ev = b.records.path[b.records.path >= 0] % 4
    assert set(np.unique(ev)) <= {EV_REFLECT, EV_REFRACT, EV_TIR}
    c = PhotonTracer(scene, threads=2, path_length=8).trace_points(pts, keys, by_source=True)
    np.testing.assert_array_equal(b.records.path, c.records.path)  # threads: same paths


def test_class_labels_read_as_paths_and_emitters_follow_the_sampler(tmp_path):
    scene = load_scene(write_point_lamp(tmp_path / "p.glb"))
    el = PathElements.from_scene(scene)
    assert el.emitters == ["filament"]
    assert class_label(el, (0, -1, -1, 0)) == "filament (direct)"
    wall = el.names.index("wall") if "wall" in el.names else 0
    assert class_label(el, (0, wall * 4 + 3, -1, 1)).endswith("(diffuse) → …")
    tracer = PhotonTracer(scene, threads=1)
    u = np.random.default_rng(0).random((100, 5))
    assert np.all(emitter_index(tracer.emitters, u, el.emitter_triangles) == 0)
    assert len(emitter_index(tracer.emitters, u[:0], el.emitter_triangles)) == 0


def test_share_table_pools_rare_classes_and_survives_empty_input():
    values = np.zeros((4, 3, 1))
    values[:, 0, 0] = [10, 11, 9, 10]
    values[:, 1, 0] = [0.1, 0.0, 0.2, 0.1]
    values[:, 2, 0] = [0.0, 0.1, 0.0, 0.1]
    rows = share_table(["a", "b", "c"], values, 0, min_share=0.05)
    assert [r["class"] for r in rows] == ["a", "other"]
    assert rows[1]["classes"] == 2
    assert sum(r["value_cd"] for r in rows) == pytest.approx(values.sum(axis=1).mean())
    assert share_table([], np.zeros((4, 0, 1)), 0) == []


def test_sets_that_caught_nothing_give_empty_classes_and_spots():
    from lightsim.engine.apertures import ApertureLayout
    from lightsim.provenance import PathCounter, spot_values

    layout = ApertureLayout(np.array([0.0, 1.0]), np.array([0.0, 0.0]), 0.15, 25.0)
    empty = {0: PathCounter(1).export(), 1: None}
    labels, values = class_values(empty, np.array([100.0, 0.0]), layout,
                                  PathElements(np.zeros(0, np.int32), [], np.zeros(0)), 0.0,
                                  [[0], [0, 1]])
    assert labels == [] and values.shape == (2, 0, 2)
    tris, cd = spot_values(empty, np.array([100.0, 0.0]), layout, 0.0, [[0]])
    assert len(tris) == 0 and cd.shape == (0, 1)


def test_signature_rows_map_triangles_to_elements_and_find_the_spot():
    from lightsim.provenance import signature_rows

    el = PathElements(np.array([0, 0, 1, 1, 2], np.int32), ["reflector facet 0",
                      "reflector facet 1", "lens"], np.array([1, 1, 2]), ["filament"])
    path = np.array([[3 * 4 + EV_REFLECT, 4 * 4 + EV_REFRACT, 4 * 4 + EV_REFRACT, -1],
                     [4 * 4 + EV_REFRACT, 4 * 4 + EV_REFLECT, 4 * 4 + EV_REFRACT, -1],
                     [-1, -1, -1, -1],
                     [0 * 4 + EV_REFLECT, 1, 1, 1]], np.int32)
    events = np.array([3, 3, 0, 9], np.uint8)
    rows = signature_rows(el, path, events, np.zeros(4, np.int32))
    assert rows[0].tolist() == [0, 1 * 4 + EV_REFLECT, 2 * 4 + EV_REFRACT,
                                2 * 4 + EV_REFRACT, -1, 0, 3]
    assert rows[1, -1] == 4  # a ghost: the lens surface that reflected it
    assert rows[2, -1] == -1 and rows[3, -2] == 1 and rows[3, -1] == -1  # direct; too long
    assert class_label(el, tuple(rows[0, :-1])) == \
        "filament → reflector facet 1 → lens (refracted)"
    assert class_label(el, tuple(rows[1, :-1])) == (
        "filament → lens (refracted) → lens (Fresnel reflection) → lens (refracted)")
    assert class_label(el, tuple(rows[3, :-1])).endswith("→ …")


def test_emitter_index_names_the_led_each_photon_leaves():
    """The matrix lamp's 16 LEDs: every sampled origin lies on the LED the index names."""
    from pathlib import Path

    scene = load_scene(Path(__file__).parents[2] / "luminaires" / "examples" / "matrix.glb")
    el = PathElements.from_scene(scene)
    mix = PhotonTracer(scene, threads=1).emitters
    u = np.random.default_rng(5).random((4000, 5))
    origin, _ = mix.sample(u)
    idx = emitter_index(mix, u, el.emitter_triangles)
    parts = {p.name: p for p in scene.emitters}
    assert len(set(idx.tolist())) == 16
    for k in range(16):
        tri = parts[el.emitters[k]].triangles.reshape(-1, 3)
        o = origin[idx == k]
        assert np.all(o >= tri.min(axis=0) - 1e-9) and np.all(o <= tri.max(axis=0) + 1e-9)
