"""M×M interleave sets: partition, gather/scatter, static assignment, wall coordinates."""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.errors import LightsimError
from lightsim.render.interleave import InterleavePattern

SIZES = [(7, 5), (13, 11), (1, 1), (2, 3), (64, 48), (10, 9)]


@pytest.mark.parametrize("M", [1, 2, 3, 4, 5, 6])
@pytest.mark.parametrize("W,H", SIZES)
def test_scatter_gather_identity(M, W, H):
    rng = np.random.default_rng(M * 1000 + W * 10 + H)
    pat = InterleavePattern(M, W, H)
    for full in (rng.random((H, W)), rng.random((H, W, 3)).astype(np.float32)):
        subs = pat.gather(full)
        assert len(subs) == M * M
        for s, sub in enumerate(subs):
            assert sub.shape[:2] == pat.sub_shape(s)
            assert sub.flags.c_contiguous
        back = pat.scatter(subs)
        assert back.dtype == full.dtype
        np.testing.assert_array_equal(back, full)
        # and the other way round
        subs2 = [rng.random(sub.shape) for sub in subs]
        for a, b in zip(pat.gather(pat.scatter(subs2)), subs2):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("M", [1, 2, 3, 4, 6])
@pytest.mark.parametrize("W,H", SIZES)
def test_every_pixel_in_exactly_one_set(M, W, H):
    pat = InterleavePattern(M, W, H)
    hits = np.zeros((H, W), int)
    owner = np.full((H, W), -1)
    for s in range(pat.n_sets):
        rows, cols = pat.set_pixels(s)
        hits[np.ix_(rows, cols)] += 1
        owner[np.ix_(rows, cols)] = s
        a, b = pat.set_offset(s)
        assert s == b * M + a
        assert pat.sub_shape(s) == (-(-(H - b) // M), -(-(W - a) // M))
        assert pat.n_pixels(s) == rows.size * cols.size
    np.testing.assert_array_equal(hits, 1)
    np.testing.assert_array_equal(owner, pat.set_index_image())
    assert sum(pat.n_pixels(s) for s in range(pat.n_sets)) == W * H
    y, x = np.mgrid[0:H, 0:W]
    np.testing.assert_array_equal(pat.set_of(x, y), owner)
    assert pat.set_of(W - 1, H - 1) == owner[H - 1, W - 1]


def test_set_index_convention():
    pat = InterleavePattern(3, 8, 7)
    assert pat.set_of(0, 0) == 0
    assert pat.set_of(1, 0) == 1          # a = x mod M
    assert pat.set_of(0, 1) == 3          # b = y mod M, s = b·M + a
    assert pat.set_of(5, 4) == 1 * 3 + 2
    assert pat.set_offset(5) == (2, 1)


@pytest.mark.parametrize("M", [1, 2, 3, 4, 5, 6])
@pytest.mark.parametrize("n_clients", [1, 2, 3, 4, 5, 7, 9, 16, 36])
def test_assignment_is_balanced_round_robin(M, n_clients):
    pat = InterleavePattern(M, 33, 17)
    if n_clients > pat.n_sets:
        with pytest.raises(LightsimError, match="interleave sets"):
            pat.assign(n_clients)
        groups = pat.assign(n_clients, allow_idle=True)
        assert sum(1 for g in groups if not g) == n_clients - pat.n_sets
    else:
        groups = pat.assign(n_clients)
    assert len(groups) == n_clients
    flat = sorted(s for g in groups for s in g)
    assert flat == list(range(pat.n_sets))                       # each set exactly once
    sizes = [len(g) for g in groups]
    assert max(sizes) - min(sizes) <= 1                          # balanced
    for k, g in enumerate(groups):
        assert g == list(range(k, pat.n_sets, n_clients))        # deterministic round robin
    assert groups == pat.assign(n_clients, allow_idle=True)


def test_m1_degenerates_to_one_set():
    pat = InterleavePattern(1, 5, 4)
    assert pat.n_sets == 1
    full = np.arange(20.0).reshape(4, 5)
    (sub,) = pat.gather(full)
    np.testing.assert_array_equal(sub, full)
    assert pat.assign(1) == [[0]]
    with pytest.raises(LightsimError):
        pat.assign(2)


def test_bad_arguments():
    for bad in ((0, 5, 5), (2, 0, 5), (2, 5, -1), (2.0, 5, 5), (True, 5, 5)):
        with pytest.raises(ValueError):
            InterleavePattern(*bad)
    pat = InterleavePattern(2, 5, 5)
    with pytest.raises(ValueError):
        pat.sub_shape(4)
    with pytest.raises(ValueError):
        pat.scatter([np.zeros((3, 3))] * 3)
    with pytest.raises(ValueError):
        pat.insert(np.zeros((5, 5)), 0, np.zeros((2, 2)))
    with pytest.raises(ValueError):
        pat.gather(np.zeros((4, 5)))
    with pytest.raises(LightsimError):
        pat.assign(0)


WALL = {"centre": [0.0, 0.0, 25.0], "h_axis": [-1.0, 0.0, 0.0], "v_axis": [0.0, 1.0, 0.0],
        "normal": [0.0, 0.0, -1.0], "h_range_m": [-10.0, 14.0], "v_range_m": [-4.0, 5.0],
        "distance_m": 25.0, "resolution": [13, 7]}


@pytest.mark.parametrize("M", [1, 2, 3, 4])
def test_wall_coordinates_of_set_pixels(M):
    pat = InterleavePattern.from_wall(M, WALL)
    W, H = WALL["resolution"]
    dh, dv = pat.pixel_size(WALL["h_range_m"], WALL["v_range_m"])
    assert dh == pytest.approx(24.0 / W) and dv == pytest.approx(9.0 / H)
    # full-image pixel centres per the conventions: column 0 = smallest H, row 0 = top
    hc = -10.0 + (np.arange(W) + 0.5) * dh
    vc = 5.0 - (np.arange(H) + 0.5) * dv
    full_h = np.broadcast_to(hc, (H, W))
    full_v = np.broadcast_to(vc[:, None], (H, W))
    for s in range(pat.n_sets):
        h, v = pat.set_wall_coords(s, WALL["h_range_m"], WALL["v_range_m"])
        np.testing.assert_allclose(h, pat.gather_set(full_h, s), rtol=0, atol=1e-12)
        np.testing.assert_allclose(v, pat.gather_set(full_v, s), rtol=0, atol=1e-12)
        pts = pat.set_wall_points(s, WALL)
        assert pts.shape == (*pat.sub_shape(s), 3)
        np.testing.assert_allclose(pts[..., 0], -h)      # H is world −X
        np.testing.assert_allclose(pts[..., 1], v)
        np.testing.assert_allclose(pts[..., 2], 25.0)
    h0, v0 = pat.set_wall_coords(0, WALL["h_range_m"], WALL["v_range_m"])
    assert h0[0, 0] == pytest.approx(-10.0 + 0.5 * dh)
    assert v0[0, 0] == pytest.approx(5.0 - 0.5 * dv)
    with pytest.raises(ValueError):
        pat.set_wall_coords(0, [1.0, -1.0], [0.0, 1.0])
    with pytest.raises(ValueError):
        InterleavePattern(M, 12, 7).set_wall_points(0, WALL)
