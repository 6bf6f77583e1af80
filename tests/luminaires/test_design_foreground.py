"""The design's foreground (cup-edge facets spread sideways, foreground slivers, the road
term), its whole-lamp aim step and the capped traffic-side cut-off."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.luminaires.design_lamp import (
    FG_LIT_MIN,
    FOREGROUND_AIMS,
    LIT_MIN,
    RISE_CAP_DEG,
    SIGN_AIMS,
    Layout,
    cutoff_line,
    facet_images,
    facets_for,
    hole_diameter,
    shift_all,
    start_vector,
)
from lightsim.luminaires.design_terms import (
    foreground_points,
    foreground_term,
    reach_points,
    reach_ratio,
)
from lightsim.luminaires.facet_model import movable_facets
from lightsim.render.road import road_illuminance_from

LAY = Layout(rings=3, sectors=16, sign_share=0.03)


def test_foreground_points_ask_for_exactly_one_lux_on_the_road():
    h, v, need = foreground_points(4.0)
    assert len(h) == 6 and np.all(need > 1000)
    # the road module (its own geometry) turns that intensity into 1 lx at the points
    for hk, vk, ik in zip(h, v, need):
        road = road_illuminance_from(lambda hh, vv, ik=ik: np.full(np.shape(hh), ik),
                                     0.65, (-8.0, 8.0), (0.0, 20.0), 0.5)
        x = 10.0 * math.tan(math.radians(hk)) if vk < -3 else 15.0 * math.tan(math.radians(hk))
        z = 10.0 if vk < -3 else 15.0
        j = int(np.argmin(np.abs(road.x_m - x)))
        i = int(np.argmin(np.abs(road.z_m - z)))
        assert abs(road.x_m[j] - x) < 1e-6 and abs(road.z_m[i] - z) < 1e-6
        assert road.lux[i, j] == pytest.approx(1.0, rel=1e-9)
    # a lamp twice as bright as asked has a margin of ln 2; a dark one is short
    t = foreground_term(lambda hh, vv: 2 * foreground_points(4.0)[2], 4.0, 0.0)
    assert t.margin == pytest.approx(math.log(2.0)) and t.penalty == 0
    dark = foreground_term(lambda hh, vv: np.zeros(6), 4.0, 0.1)
    assert dark.margin < -5 and dark.penalty > 25


def test_reach_ratio_is_one_exactly_at_the_road_modules_reach():
    # a beam with a Gaussian hot spot 1.4° down and 2° right: scaled so that its ratio at
    # 27 m is 1, the road module (its own geometry, 0.5 m grid) finds 1 lx at 27 m and
    # not farther; scaled 1.1× it reaches ≥ 27 m, 0.9× short of it
    def beam(h, v):
        return 3.0e4 * np.exp(-((np.asarray(h) - 2.0) ** 2 + (np.asarray(v) + 1.4) ** 2) / 2)

    q = reach_ratio(beam, 27.0)
    assert 0.1 < q < 10
    h, v, need = reach_points(27.0)
    assert np.all(np.diff(h) > 0) and np.allclose(v, v[0]) and np.all(need > 27.0 ** 3 / 0.65)
    for f, far_enough in ((1.0 / q * 1.02, True), (1.0 / q * 0.9, False)):
        road = road_illuminance_from(lambda hh, vv, f=f: f * beam(hh, vv), 0.65,
                                     (-15.0, 15.0), (0.0, 60.0), 0.25)
        assert (road.reach_m(1.0) >= 27.0) is far_enough
        assert reach_ratio(lambda hh, vv, f=f: f * beam(hh, vv), 27.0) == pytest.approx(f * q)
    # continuous: a 1 % brighter beam has a 1 % larger ratio (the contour would not move)
    assert reach_ratio(lambda hh, vv: 1.01 * beam(hh, vv), 27.0) == pytest.approx(1.01 * q)
    assert reach_ratio(lambda hh, vv: np.zeros(np.shape(hh)), 27.0) < 1e-6
    assert reach_ratio(lambda hh, vv: np.full(np.shape(hh), np.nan), 27.0) < 1e-6


def test_cup_edge_facets_spread_sideways_and_become_movable():
    hole = hole_diameter(LAY)
    x = start_vector(LAY)
    plain = facets_for(x, LAY, hole)
    lay = replace(LAY, shaded_spread_deg=20.0, shaded_drop_deg=2.0)
    spread = facets_for(x, lay, hole)
    n = LAY.rings * LAY.sectors
    images = facet_images(plain[:n], LAY, hole)
    edge = [k for k, im in enumerate(images) if FG_LIT_MIN <= im.lit_fraction < LIT_MIN]
    assert edge
    for k in range(n):
        a, b = plain[k], spread[k]
        if k in edge:
            c = math.cos(0.5 * (a.phi0_rad + a.phi1_rad))
            assert b.h_deg == pytest.approx(np.clip(a.h_deg + 20.0 * c, -40, 40))
            assert b.v_deg == pytest.approx(LAY.cutoff_v_deg - 2.0)
        else:
            assert b == a
    assert set(edge) <= set(movable_facets(spread, lay, hole))
    assert not set(edge) & set(movable_facets(plain, LAY, hole))
    with pytest.raises(InputError):
        replace(LAY, shaded_spread_deg=-1.0).check()


def test_foreground_slivers_keep_the_second_ring_tiled_and_sit_on_their_aims():
    hole = hole_diameter(LAY)
    x = start_vector(LAY)
    lay = replace(LAY, foreground_share=0.2)
    base = facets_for(x, LAY, hole)
    facets = facets_for(x, lay, hole)
    n = LAY.rings * LAY.sectors
    ns = len(SIGN_AIMS)
    assert len(facets) == n + ns + len(FOREGROUND_AIMS)
    assert facets[n:n + ns] == base[n:n + ns]  # the overhead-sign slivers are untouched
    fg = facets[n + ns:]
    ring1 = sorted((f.phi0_rad, f.phi1_rad) for f in facets[LAY.sectors:2 * LAY.sectors] + fg)
    assert ring1[0][0] == pytest.approx(0.0) and ring1[-1][1] == pytest.approx(2 * math.pi)
    assert all(a[1] == pytest.approx(b[0]) for a, b in itertools.pairwise(ring1))
    for fc, img, (h, v, _w) in zip(fg, facet_images(fg, lay, hole), FOREGROUND_AIMS):
        assert abs(np.median(img.dh + fc.h_deg) - h) < 0.3
        assert abs(np.median(img.dv + fc.v_deg) - v) < 0.3
    with pytest.raises(InputError):
        replace(LAY, foreground_share=0.95).check()


def test_aim_step_moves_every_facet_by_the_same_angle():
    hole = hole_diameter(LAY)
    x = start_vector(LAY)
    lay = replace(LAY, facet_shifts_deg=((3, 0.2, -0.1),))
    a = facets_for(x, lay, hole)
    b = facets_for(x, shift_all(lay, len(a), -0.14), hole)
    assert [f.h_deg for f in b] == pytest.approx([f.h_deg for f in a])
    assert [f.v_deg for f in b] == pytest.approx([f.v_deg - 0.14 for f in a])


def test_traffic_side_cutoff_rises_fifteen_degrees_then_stays_capped():
    h = np.array([-20.0, 0.0, 1.0, 3.0, 30.0])
    c = cutoff_line(h, -0.57)
    assert c[0] == c[1] == c[2] == pytest.approx(-0.57)
    assert c[3] == pytest.approx(-0.57 + 2.0 * math.tan(math.radians(15.0)))
    assert c[4] == pytest.approx(-0.57 + RISE_CAP_DEG)
    assert cutoff_line(-h, -0.57, "left") == pytest.approx(c)
