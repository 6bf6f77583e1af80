"""The core wall frame (lightsim.wall): pixels ↔ wall metres ↔ H/V degrees, lux ↔ cd."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.io.png import wall_angles
from lightsim.scene import make_wall
from lightsim.wall import WallFrame, candela_from_lux, lux_from_candela, wall_m_from_deg


def tilted_frame(yaw_deg: float = 20.0, distance: float = 10.0) -> WallFrame:
    """A wall turned by ``yaw_deg`` about the vertical; centre = the foot of the lamp on it
    (as lightsim.scene builds frames of walls read from a file)."""
    a = math.radians(yaw_deg)
    normal = np.array([math.sin(a), 0.0, -math.cos(a)])
    centre = distance * -normal  # foot of the origin on the plane n·x = −distance
    v_axis = np.array([0.0, 1.0, 0.0])
    h_axis = np.cross(v_axis, normal)
    return WallFrame(centre, h_axis, v_axis, normal, (-8.0, 8.0), (-2.0, 2.0), distance,
                     (128, 32))  # pixels of 1/8 m: edges exact in binary


def test_default_wall_is_centred_on_hv():
    _, wf = make_wall(25.0, (30.0, 12.0), resolution=(640, 256))
    assert wf.hv_offset_m == (0.0, 0.0)
    h, v = wf.pixel_centres()
    assert np.array_equal(wf.h_m(), h) and np.array_equal(wf.v_m(), v)
    # 1 lx at H-V, 25 m: 625 cd; the Inverse-square-cosine law off-axis
    assert candela_from_lux(1.0, 0.0, 0.0, 25.0) == pytest.approx(625.0)
    r = math.sqrt(25.0**2 + 3.0**2 + 4.0**2)
    assert lux_from_candela(1000.0, 3.0, 4.0, 25.0) == pytest.approx(1000.0 * 25.0 / r**3)
    # H is world −X: the direction 10° right of H-V
    d = wf.directions(10.0, 0.0)
    assert d[0] < 0 and math.degrees(math.atan2(-d[0], d[2])) == pytest.approx(10.0)
    assert np.allclose(wf.directions(0.0, 0.0), [0.0, 0.0, 1.0])


def test_hv_point_of_a_tilted_wall_is_on_the_lamp_axis():
    wf = tilted_frame()
    off = wf.hv_offset_m
    assert abs(off[0]) > 1.0  # the foot of the lamp is not where +Z meets the wall
    hv_world = wf.to_world(off[0], off[1])
    assert np.allclose(hv_world[:2], 0.0, atol=1e-12) and hv_world[2] > 0
    # angle 0 is H-V in every mapping: pixel_of, degrees, edges
    row, col = wf.pixel_of(0.0, 0.0)
    h_c, v_c = wf.cell_centres(row, col)
    assert np.allclose([h_c, v_c], off)
    hd, vd = wf.degrees(off[0], off[1])
    assert hd == pytest.approx(0.0, abs=1e-12) and vd == pytest.approx(0.0, abs=1e-12)
    he, ve = wall_angles(wf.to_dict(), wf.width, wf.height)  # the PNG axes
    assert np.allclose(he, wf.degrees(np.linspace(-8, 8, 129), 0.0)[0])
    assert he[0] < 0 < he[-1] and np.all(np.diff(he) > 0) and np.all(np.diff(ve) < 0)
    # the same frame through its JSON description
    again = WallFrame.from_any(wf.to_dict())
    assert again == wf and again != wf.with_resolution(64, 16)
    assert again.hv_offset_m == pytest.approx(off)
    assert np.allclose(again.h_deg(), wf.h_deg())


def test_pixel_index_and_cell_centres_round_trip():
    wf = tilted_frame()
    rows, cols = np.meshgrid(np.arange(wf.height), np.arange(wf.width), indexing="ij")
    h, v = wf.cell_centres(rows, cols)
    r, c = wf.pixel_index(h, v)
    assert np.array_equal(r, rows) and np.array_equal(c, cols)
    # half-open cells: the left/top edge belongs to the pixel, the right edge does not
    dh, dv = wf.pixel_size_m
    r, c = wf.pixel_index(np.array([-8.0, -8.0 + dh, 8.0]), np.array([2.0, 2.0 - dv, -2.0]))
    assert c.tolist() == [0, 1, wf.width] and r.tolist() == [0, 1, wf.height]
    assert wf.inside(r, c).tolist() == [True, True, False]
    r, c = wf.pixel_index(np.array([-1e9, 1e9]), np.array([1e9, -1e9]), clip=True)
    assert c.tolist() == [0, wf.width - 1] and r.tolist() == [0, wf.height - 1]
    pts = wf.to_world(h, v)
    hh, vv = wf.to_hv(pts.reshape(-1, 3))
    assert np.allclose(hh, h.ravel()) and np.allclose(vv, v.ravel())


def test_sample_reads_intensity_back_on_a_tilted_wall():
    wf = tilted_frame(yaw_deg=5.0, distance=25.0)
    hm, vm = np.meshgrid(wf.h_m(), wf.v_m())
    intensity = 2000.0 + 100.0 * hm - 30.0 * vm
    lux = wf.lux_at(intensity, hm, vm)
    h = np.array([0.0, -3.0, 4.0])
    v = np.array([0.0, 1.0, -2.0])
    want = 2000.0 + 100.0 * wall_m_from_deg(h, 25.0) - 30.0 * wall_m_from_deg(v, 25.0)
    assert np.allclose(wf.sample(lux, h, v), want, rtol=1e-9)
    assert np.isnan(wf.sample(lux, 60.0, 0.0))


def test_from_any_checks_and_floor_walls():
    with pytest.raises(InputError, match="resolution"):
        WallFrame.from_any({"distance_m": 25, "h_range_m": [-1, 1], "v_range_m": [-1, 1]})
    with pytest.raises(InputError, match="h_range_m"):
        WallFrame.from_any({"distance_m": 25, "h_range_m": [1, -1], "v_range_m": [-1, 1],
                            "resolution": [4, 4]})
    # a floor (parallel to the lamp axis) has no H-V point: angles from its centre
    floor = WallFrame(np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0]),
                      np.array([0.0, 1.0, 0.0]), (-1.0, 1.0), (-1.0, 1.0), 0.5, (8, 8))
    assert floor.hv_offset_m == (0.0, 0.0)
    assert WallFrame.from_any(floor.to_dict()).hv_offset_m == (0.0, 0.0)
    # a bare image description is the conventions' wall
    bare = WallFrame.from_any({"distance_m": 25, "h_range_m": [-1, 1], "v_range_m": [-1, 1],
                               "resolution": [4, 2]})
    assert np.allclose(bare.to_world(0.0, 0.0), [0.0, 0.0, 25.0])
    assert bare.with_resolution(8, 4).pixel_size_m == (0.25, 0.5)
