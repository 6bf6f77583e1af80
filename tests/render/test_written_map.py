"""The written map's compiled passes against the NumPy forms they replaced."""

from __future__ import annotations

import multiprocessing as mp

import numpy as np
import pytest

from lightsim.engine.estimator import normalise_flux
from lightsim.render.directional import pixel_sat
from lightsim.render.ici import (
    add_scaled,
    chosen_per_set,
    halves,
    held_out_blur,
    ici_rungs,
    raster_lux,
    raster_queries,
    window_sums,
)
from lightsim.threads import second_thread


def _reference(rungs, emitted, q, areas, gamma, groups=None, blas=False):
    """:func:`held_out_blur` as it was written in NumPy (one (J+1, Q) pass per pair), with
    the total Σ e_s R_s summed in set order (``blas``: by ``tensordot``, as before)."""
    order = sorted(rungs)
    S = len(order)
    areas = np.asarray(areas, dtype=np.float64)[:np.asarray(rungs[order[0]]).shape[0]]
    R = np.stack([np.asarray(rungs[k], np.float64)[..., 0] for k in order])
    e = np.array([emitted[k] for k in order], dtype=np.float64)
    if blas:
        total = R.sum(axis=0) if e.sum() <= 0 else np.tensordot(e, R, 1)
    else:
        total = np.zeros(R.shape[1:])
        for s in range(S):
            total = total + (e[s] * R[s] if e.sum() > 0 else R[s])
    n_all = float(e.sum())
    D = R - R[:, :1]
    groups = [np.arange(S)] if groups is None else groups
    out = np.zeros((len(groups), R.shape[2]))
    cols = np.arange(R.shape[2])
    for g, members in enumerate(groups):
        pairs = 0
        for i, a in enumerate(members):
            for b in members[i + 1:]:
                n = n_all - e[a] - e[b]
                if n <= 0:
                    continue
                E = (total - e[a] * R[a] - e[b] * R[b]) / n
                j = ici_rungs(E, n, q, areas, gamma)
                out[g] += D[a, j, cols] * D[b, j, cols]
                pairs += 1
        out[g] /= max(pairs, 1)
    return out


def _case(S, J1, Q, seed, scale=1.0):
    rng = np.random.default_rng(seed)
    smooth = scale * np.linspace(1.0, 3.0, Q)
    step = np.where(np.arange(Q) < Q // 2, 0.2, 1.0)
    rungs = {}
    for s in range(S):
        base = smooth * step
        noise = rng.normal(0.0, 0.3, (J1, Q)) / np.sqrt(np.arange(1, J1 + 1))[:, None]
        r = np.maximum(base[None, :] * (1 + noise), 0.0)
        r[:, ::7] = 0.0  # dark queries: empty small rungs
        rungs[s] = r[..., None].astype(np.float32)
    emitted = {s: int(rng.integers(1000, 5000)) for s in range(S)}
    areas = np.array([(j + 1) ** 2 for j in range(J1)], np.float64) * 1e-6
    return rungs, emitted, areas


@pytest.mark.parametrize("S, J1, Q, seed, scale", [
    (16, 8, 500, 1, 1.0), (4, 4, 37, 2, 1.0), (8, 2, 1, 3, 1.0), (5, 6, 64, 4, 1e-30),
    (6, 5, 64, 5, 1e30), (16, 8, 0, 6, 1.0)])
def test_same_numbers_as_numpy(S, J1, Q, seed, scale):
    rungs, emitted, areas = _case(S, J1, Q, seed, scale)
    q = 0.37 * scale
    for groups in (None, halves(S)):
        got = held_out_blur(rungs, emitted, q, areas, 2.0, groups)
        want = _reference(rungs, emitted, q, areas, 2.0, groups)
        assert got.shape == want.shape
        assert np.array_equal(got, want, equal_nan=True)
        # the BLAS total sums in another order: the same blur to rounding
        blas = _reference(rungs, emitted, q, areas, 2.0, groups, blas=True)
        scale = max(float(np.abs(want).max(initial=0.0)), 1e-300)
        assert np.allclose(got, blas, rtol=1e-9, atol=1e-9 * scale)


def test_per_query_areas_no_power_and_empty_sets():
    rungs, emitted, areas = _case(8, 5, 90, 7)
    per_query = areas[:, None] * np.linspace(0.5, 2.0, 90)[None, :]
    for q in (0.0, 0.2):
        got = held_out_blur(rungs, emitted, q, per_query, 1.5, halves(8))
        assert np.array_equal(got, _reference(rungs, emitted, q, per_query, 1.5, halves(8)))
    # sets that emitted nothing: pairs whose other sets hold no photons are skipped
    none = {s: 0 for s in emitted}
    none[0] = 10
    got = held_out_blur(rungs, none, 0.2, areas, 2.0)
    assert np.array_equal(got, _reference(rungs, none, 0.2, areas, 2.0))


def test_subset_of_queries_matches_the_whole():
    rungs, emitted, areas = _case(16, 8, 300, 8)
    read = np.arange(3, 300, 5)
    full = held_out_blur(rungs, emitted, 0.4, areas, 2.0, halves(16))
    part = held_out_blur(rungs, emitted, 0.4, areas, 2.0, halves(16), queries=read)
    assert np.array_equal(part[:, read], full[:, read])
    assert not part[:, np.setdiff1d(np.arange(300), read)].any()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("C", [1, 3])
def test_pooling_and_chosen_values_match_numpy(dtype, C):
    rng = np.random.default_rng(11)
    rungs = {s: (rng.random((5, 333, C)) * 10.0 ** rng.integers(-30, 30)).astype(dtype)
             for s in range(7)}
    w = rng.random(7)
    want = np.zeros((5, 333, C))
    got = np.zeros((5, 333, C))
    for wi, s in zip(w, sorted(rungs), strict=True):
        want += wi * np.asarray(rungs[s], np.float64)
        assert add_scaled(got, rungs[s], wi) is got
    assert np.array_equal(got, want)
    # a strided target falls back to NumPy, with the same result
    strided = np.zeros((5, 666, C))[:, ::2]
    for wi, s in zip(w, sorted(rungs), strict=True):
        add_scaled(strided, rungs[s], wi)
    assert np.array_equal(strided, want)
    rung = rng.integers(0, 5, 333)
    ref = np.stack([np.take_along_axis(rungs[s], rung[None, :, None], 0)[0].astype(np.float64)
                    for s in sorted(rungs)])
    assert np.array_equal(chosen_per_set(rungs, rung), ref)
    empty = {s: r[:, :0] for s, r in rungs.items()}
    assert chosen_per_set(empty, rung[:0]).shape == (7, 0, C)


@pytest.mark.parametrize("shape", [(16, 64, 160), (3, 1, 1), (2, 5, 1), (1, 1, 7), (4, 33, 17),
                                   (2, 0, 4)])
def test_pixel_sat_matches_numpys_two_cumsums(shape):
    rng = np.random.default_rng(5)
    img = rng.random(shape) * 10.0 ** rng.integers(-30, 30, shape)
    img[..., ::5] = -0.0  # signed zeros as NumPy leaves them
    want = np.zeros((*shape[:-2], shape[-2] + 1, shape[-1] + 1))
    np.cumsum(img, axis=-2, out=want[..., 1:, 1:])
    np.cumsum(want[..., 1:, 1:], axis=-1, out=want[..., 1:, 1:])
    got = pixel_sat(img)
    assert got.tobytes() == want.tobytes()
    assert pixel_sat(img[0]).tobytes() == want[0].tobytes()  # one image: NumPy's path


def _on_branch_thread(x):
    return second_thread().submit(lambda: x + 1).result(timeout=30)


def test_the_branch_thread_in_a_forked_child_after_the_parent_used_it():
    assert second_thread().submit(lambda: 1).result(timeout=30) == 1  # parent's thread
    with mp.get_context("fork").Pool(1) as pool:  # the child makes its own thread
        assert pool.apply_async(_on_branch_thread, (41,)).get(timeout=60) == 42


@pytest.mark.parametrize("H, W, C, emitted, scale", [
    (1, 1, 1, 1, 1.0), (5, 7, 3, 123_457, 1.0), (16, 40, 1, 2**40 + 3, 1.0),
    (3, 64, 1, 999, 1e-30), (9, 33, 2, 7, 1e30), (4, 2, 1, 5, 1.0)])
def test_raster_lux_is_the_normalised_window_sums_cast(H, W, C, emitted, scale):
    """A set's part of the written map in one pass (:func:`raster_lux`): the window sums
    of every pixel, normalised by normalise_flux and cast to float32, bit for bit (sums
    over clipped windows, windows wider than the wall, rows with unclipped windows on
    one and on several channels, empty cells, a tiny and a huge photon count, powers of
    1e-30 and 1e30 lm)."""
    rng = np.random.default_rng(H * W * C)
    sub = scale * rng.random((2 * H, 2 * W, C)) * (rng.random((2 * H, 2 * W, 1)) < 0.3)
    sides = np.arange(1, 6)
    rows, cols, geometry = raster_queries(H, W, tuple(int(m) for m in sides))
    sums, cells = window_sums(sub, rows, cols, sides, geometry)
    area = 0.25 * 0.047 * 0.031
    want = normalise_flux(sums, emitted, np.maximum(cells, 1.0)[..., None], area)
    got = raster_lux(sub, sides, emitted, area)
    assert got.dtype == np.float32 and got.shape == (5, H * W, C)
    np.testing.assert_array_equal(got, want.astype(np.float32))
    np.testing.assert_array_equal(raster_lux(sub, sides, emitted, area, np.float64), want)
