"""Region breakdowns of --provenance: a box of the screen split by path class, exact on
a two-facet scene, adding up, and bad boxes refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart
from lightsim.provenance import (
    PATH_LENGTH,
    PathElements,
    RegionRaster,
    region_cells,
    region_store,
    region_values,
    share_table,
)
from lightsim.scene import load_scene
from lightsim.wall import wall_m_from_deg

from support import write_point_lamp

PHI = 1000.0  # lm, the point lamp's flux


def _square(centre, u, v, half):
    c, u, v = (np.asarray(x, float) for x in (centre, u, v))
    verts = np.array([c - half * u - half * v, c + half * u - half * v,
                      c + half * u + half * v, c - half * u + half * v])
    return verts, np.array([[0, 1, 2], [0, 2, 3]])


def _facet_mirror(x: float):
    """A 45° mirror at (x, 0, 0) sending light from the origin towards +z (the wall):
    the origin's image sits at (x, 0, −|x|)."""
    s = math.copysign(1.0, x)
    return _square((x, 0.0, 0.0), np.array([s, 0.0, 1.0]) / math.sqrt(2), (0.0, 1.0, 0.0),
                   0.012)


def _omega_rect(point, h0, h1, v0, v1, D) -> float:
    """Solid angle (sr) of the wall rectangle [h0, h1] × [v0, v1] (m, wall at z = D,
    h along −x as the conventions' wall) seen from ``point``."""
    d = D - point[2]
    xs = (h0 + point[0], h1 + point[0])  # h = −x: the image at +x sits at h = −x
    ys = (v0 - point[1], v1 - point[1])

    def corner(x, y):
        return math.atan(x * y / (d * math.sqrt(d * d + x * x + y * y)))

    return (corner(xs[1], ys[1]) - corner(xs[0], ys[1]) - corner(xs[1], ys[0])
            + corner(xs[0], ys[0]))


@pytest.fixture(scope="module")
def facet_store(tmp_path_factory):
    v0, f0 = _facet_mirror(0.03)
    v1, f1 = _facet_mirror(-0.05)
    mirror = GltfPart("reflector", np.vstack([v0, v1]), np.vstack([f0, f1 + len(v0)]), None,
                      GltfMaterial("m", base_color=(0.9, 0.9, 0.9), metallic=1.0),
                      extras={"lightsim": {"facets": [{"name": "a"}, {"name": "b"}]}})
    scene = load_scene(write_point_lamp(tmp_path_factory.mktemp("f") / "facets.glb", mirror))
    cfg = RunConfig(seed=3, frame_photons=400_000, estimator="bin", spt=False,
                    apertures=((0.0, 0.0),), aperture_deg=2.0, path_length=PATH_LENGTH)
    with Session(scene, cfg) as s:
        s.run(photons=800_000)
        stats = s.backend.stats()
        sets = sorted(stats)
        emitted = np.array([stats[q]["emitted"] for q in sets], float)
        per_set = s.backend.paths()
        frame = s.scene.wall
    store = region_store({q: per_set[q] for q in sets}, emitted,
                         PathElements.from_scene(scene), RegionRaster.of(frame))
    return store, frame


def test_a_box_gives_each_facet_its_geometric_share(facet_store):
    """Mean illuminance over a box: the direct light I0·Ω/A from the source, each facet
    0.9·I0·Ω/A from its mirror image (Ω the box's solid angle from that point, A its area);
    the classes add up to the box's total."""
    store, frame = facet_store
    labels, values, covered = region_values(store, (-4.0, 4.0, -2.0, 2.0))
    h0, h1, v0, v1 = covered
    assert h0 <= -3.5 and h1 >= 3.5 and v0 <= -1.5 and v1 >= 1.5
    D = frame.distance_m
    hm = [float(wall_m_from_deg(x, D)) for x in (h0, h1)]
    vm = [float(wall_m_from_deg(x, D)) for x in (v0, v1)]
    area = (hm[1] - hm[0]) * (vm[1] - vm[0])
    i0 = PHI / (4 * math.pi)
    exact = {"filament (direct)": i0 * _omega_rect((0, 0, 0), *hm, *vm, D) / area,
             "filament → reflector facet 0":
                 0.9 * i0 * _omega_rect((0.03, 0, -0.03), *hm, *vm, D) / area,
             "filament → reflector facet 1":
                 0.9 * i0 * _omega_rect((-0.05, 0, -0.05), *hm, *vm, D) / area}
    rows = {r["class"]: r for r in share_table(labels, values, 0, min_share=0.0, top=20,
                                               unit="lx")}
    assert set(exact) <= set(rows), rows.keys()
    for name, want in exact.items():
        lo, hi = rows[name]["interval_lx"]
        assert lo <= want <= hi, (name, rows[name], want)
    share = exact["filament → reflector facet 0"] / sum(exact.values())
    assert rows["filament → reflector facet 0"]["share"] == pytest.approx(share, rel=0.05)
    assert sum(r["value_lx"] for r in rows.values()) == pytest.approx(
        values[:, :, 0].sum(axis=1).mean(), rel=1e-12)


def test_the_whole_raster_and_split_boxes_sum_their_cells(facet_store):
    store, _ = facet_store
    he, ve = store["h_edges_deg"], store["v_edges_deg"]
    _, values, covered = region_values(store, (he[0], he[-1], ve[-1], ve[0]))
    assert covered == pytest.approx((he[0], he[-1], ve[-1], ve[0]))
    flux = values[:, :, 0].sum(axis=1) * store["area_m2"].sum()  # lm per set
    per_set = np.bincount(store["set"], store["flux"], len(store["emitted"]))
    np.testing.assert_allclose(flux, per_set, rtol=1e-12)
    # a box of two halves: the halves' flux adds up to the whole box's
    mid = float(0.5 * (he[0] + he[-1]))
    cells_l, _ = region_cells(store, (he[0], mid - 1e-9, -3, 3))
    cells_r, _ = region_cells(store, (mid + 1e-9, he[-1], -3, 3))
    cells_a, _ = region_cells(store, (he[0], he[-1], -3, 3))
    assert sorted(np.concatenate([cells_l, cells_r]).tolist()) == sorted(cells_a.tolist())


@pytest.mark.parametrize("box", [(1.0, 0.0, -1.0, 1.0), (0.0, 1.0, 2.0, 2.0),
                                 (float("nan"), 1.0, 0.0, 1.0), (80.0, 85.0, 0.0, 1.0),
                                 (0.0, 0.01, 0.0, 0.01)])
def test_bad_boxes_are_refused(facet_store, box):
    store, _ = facet_store
    with pytest.raises(InputError, match="region box"):
        region_cells(store, box)


def test_raster_cells_edges_and_empty_input():
    """Partial cells at the image's edge, points off the image, empty frames, huge and
    tiny coordinates: the raster and the counter take them."""
    from lightsim.provenance import PathCounter, unique_rows
    from lightsim.wall import WallFrame

    frame = WallFrame.from_any({"distance_m": 25.0, "h_range_m": [-10.0, 10.0],
                                 "v_range_m": [-3.0, 2.0], "resolution": [101, 23]})
    raster = RegionRaster.of(frame, 0.5)
    nr, nc = raster.shape
    g = raster.geometry()
    assert g["h_edges_deg"].shape == (nc + 1,) and g["v_edges_deg"].shape == (nr + 1,)
    assert g["area_m2"].sum() == pytest.approx(20.0 * 5.0)  # partial cells included
    cells = raster.cell(np.array([0.0, 1e30, -1e30, 9.999, 1e-30, np.nan]),
                        np.array([0.0, 0.0, 0.0, -2.999, 1e-30, 0.0]))
    assert cells[0] >= 0 and cells[1] == -1 and cells[2] == -1 and cells[5] == -1
    assert cells[3] == nr * nc - 1 and cells[4] == cells[0]
    assert RegionRaster.of(frame, 1e-30).factor == (1, 1)
    assert RegionRaster.of(frame, 1e30).shape == (1, 1)
    counter = PathCounter(3)
    counter.add_cells(np.zeros((0, PATH_LENGTH + 3), np.int32), np.zeros(0, np.int64),
                      np.zeros((0, 3)))
    rows = np.full((3, PATH_LENGTH + 3), -1, np.int32)
    rows[:, 0] = 0
    counter.add_cells(rows, np.array([-1, 4, 4]), np.ones((3, 3)))
    out = counter.export()
    assert out["cell"].tolist() == [4] and len(out["cell_signatures"]) == 1
    assert out["signatures"] == []  # the apertures' numbering is untouched
    for r in (np.zeros((0, 4), np.int32), np.array([[3, -1]], np.int32),
              np.random.default_rng(2).integers(-1, 900, (4000, 10)).astype(np.int32)):
        u, i = unique_rows(r)
        uu, ii = np.unique(r, axis=0, return_inverse=True)
        assert np.array_equal(u, uu) and np.array_equal(i, ii.reshape(-1))
