"""When the screen geometry does not constrain the aim, the aim is refused with a reason;
marker searches report the ids found and missing."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lightsim.validation.photo_aim import (
    COLLINEAR_DEG,
    FAR_FROM_CUTOFF_DEG,
    aim_geometry_problem,
    marker_search,
)
from lightsim.validation.screen_target import DEFAULT_LAYOUT
from lightsim.validation.synthetic_photo import MARKER_MIN_PX, marker_scale, wall_frame
from lightsim.wall import WallFrame

CENTRES = {i: (h, v) for i, h, v in DEFAULT_LAYOUT.markers}


def _markers(ids, v_shift=0.0):
    """Geometry-like record of markers ``ids`` (four corners each, 1.5° square)."""
    corners = []
    for i in ids:
        h, v = CENTRES[i]
        corners += [(h + dx, v + v_shift + dy) for dx, dy in
                    ((-0.75, 0.75), (0.75, 0.75), (0.75, -0.75), (-0.75, -0.75))]
    return SimpleNamespace(source="markers", screen_deg=np.array(corners),
                           details={"marker_ids": sorted(ids)})


def test_marker_search_names_found_and_missing():
    m = marker_search([9, 8], list(range(10)))
    assert m["found"] == [8, 9] and m["missing"] == list(range(8)) and m["of"] == 10
    assert m["text"] == "markers: 2 of 10 found (ids 8, 9); missing 0, 1, 2, 3, 4, 5, 6, 7"
    assert marker_search([], [0, 1])["text"] == "markers: 0 of 2 found; missing 0, 1"
    assert marker_search([0, 1], [0, 1])["text"] == "markers: 2 of 2 found (ids 0, 1)"


@pytest.mark.parametrize("ids, cut_v, fragment", [
    ([8, 9], -0.5, "only 2 marker(s) (ids 8, 9); at least 4"),
    ([5, 6, 7], -0.5, "only 3 marker(s)"),
    ([5, 6, 7, 8, 9], -0.5, "lie nearly on one line"),
    ([0, 1, 3, 4], -0.5, "lie nearly on one line"),
])
def test_weak_geometry_is_refused_with_its_reason(ids, cut_v, fragment):
    problem = aim_geometry_problem(_markers(ids), cut_v)
    assert problem is not None and fragment in problem and "\n" not in problem


def test_markers_far_from_the_cutoff_are_refused():
    far = _markers([0, 1, 5, 6], v_shift=12.0)    # rows at 14.5° and 7.5° up
    problem = aim_geometry_problem(far, -0.5)
    assert problem is not None and f"more than {FAR_FROM_CUTOFF_DEG:g}°" in problem
    assert aim_geometry_problem(far, None) is None  # no cut-off: not checked


def test_two_rows_around_the_cutoff_constrain_the_aim():
    assert aim_geometry_problem(_markers([0, 4, 5, 9]), -0.5) is None
    assert aim_geometry_problem(_markers([2, 6, 7, 8]), -0.5) is None
    # control points count one by one
    pts = SimpleNamespace(source="points", details={},
                          screen_deg=np.array([(-8, 2.5), (8, 2.5), (-8, -4.5)]))
    assert "only 3 control point(s)" in aim_geometry_problem(pts, -0.5)
    line = SimpleNamespace(source="points", details={}, screen_deg=np.array(
        [(-8, 1.0), (-4, 1.0 + COLLINEAR_DEG / 4), (4, 1.0), (8, 1.0)]))
    assert "one line" in aim_geometry_problem(line, -0.5)


@pytest.mark.parametrize("width, expected", [(320, 6.0), (640, 3.0), (1280, 2.0),
                                             (160, 12.0)])
def test_marker_scale_makes_markers_big_enough(width, expected):
    frame = wall_frame((width, width * 2 // 5))
    scale = marker_scale(frame)
    assert scale == expected
    h = WallFrame.from_any(frame).h_deg()
    px_per_deg = (len(h) - 1) / np.ptp(h)
    assert scale * DEFAULT_LAYOUT.size_deg * px_per_deg >= MARKER_MIN_PX
    assert (scale - 1) * DEFAULT_LAYOUT.size_deg * px_per_deg < MARKER_MIN_PX or scale == 1
