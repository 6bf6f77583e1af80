"""The tracer's fast paths (the wall slab skip, chunks and threads, the false-hit kernels,
records sorted by photon) give the same answers as the plain formulations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.simulate import SimulateOptions, load
from lightsim.tracer import PhotonTracer, false_hits, near_hits, sort_by_source
from lightsim.validation.scenes.analytic import covered_paraboloid_case, paraboloid_case


def _photons(n: int, seed: int = 3):
    idx = np.arange(n, dtype=np.int64)
    return halton_points(idx, digit_permutations(seed, 0, None)), photon_keys(seed, 0, 0, idx)


def _same(a, b):
    for f in ("position", "normal", "power", "part", "flags", "source"):
        assert np.array_equal(getattr(a.records, f), getattr(b.records, f)), f
    for f in ("emitted", "ledger", "caustic_source"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert a.rays == b.rays


@pytest.fixture(scope="module")
def scene():
    return paraboloid_case(resolution=(16, 16)).scene


def test_wall_slab_skip_changes_no_hit(scene):
    """Rays whose lamp hit is nearer than the wall's slab skip the exact wall test: the
    same trace as with the test on every ray (a slab of infinite thickness)."""
    pts, keys = _photons(20_000)
    fast = PhotonTracer(scene, threads=1)
    slow = PhotonTracer(scene, threads=1)
    assert np.isfinite(fast.geometry.wall_slab[4])
    slow.geometry = slow.geometry._replace(wall_slab=np.array([0.0, 0.0, 1.0, 0.0, np.inf]))
    _same(fast.trace_points(pts, keys), slow.trace_points(pts, keys))


def test_chunking_threads_and_group_sums_do_not_change_the_trace(scene):
    """Ledgers and emitted flux are summed per group in photon order whatever the
    chunks and threads (and the last batch's smaller chunks); records come bounce-major
    per batch, so the batch is the same."""
    pts, keys = _photons(30_000)
    rng = np.random.default_rng(1)
    weight = rng.random(len(pts)) + 0.5
    group = rng.integers(0, 4, len(pts))
    one = PhotonTracer(scene, threads=1, batch=7000)
    many = PhotonTracer(scene, threads=2, batch=7000, min_chunk=500)
    a = one.trace_points(pts, keys, weight=weight, group=group, n_groups=4)
    b = many.trace_points(pts, keys, weight=weight, group=group, n_groups=4)
    _same(a, b)
    power = one.emitters.flux_lm * weight
    for g in range(4):  # the emitted flux as np.bincount sums it, bit for bit
        assert a.emitted[g, 0] == np.bincount(group, weights=power, minlength=4)[g]
    assert many.trace_points(pts[:0], keys[:0], n_groups=3).emitted.shape == (3, 1)


@pytest.mark.parametrize("bad", [-1, 4])
def test_group_outside_range_raises(scene, bad):
    pts, keys = _photons(100)
    group = np.zeros(100, np.int64)
    group[37] = bad
    with pytest.raises(ValueError):
        PhotonTracer(scene, threads=2).trace_points(pts, keys, group=group, n_groups=4)


def test_false_hits_match_the_numpy_test(scene):
    """false_hits picks the same rays (and steps) as the same test in NumPy passes,
    origins on triangle edges (exactly on the neighbouring faces' planes)."""
    tracer = PhotonTracer(scene, threads=1)
    tri, fn = tracer.geometry.tri_v, tracer.geometry.face_n
    rng = np.random.default_rng(5)
    lamp = np.flatnonzero(~scene.tri_is_wall)
    n = 50_000
    k = lamp[rng.integers(0, len(lamp), n)]
    e = rng.integers(0, 3, n)
    a, b = tri[k, e], tri[k, (e + 1) % 3]
    o = a + rng.random(n)[:, None] * (b - a)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    prim, tfar, _, _ = tracer.caster.cast_lamp(o32, d32)
    bound = 4 * 3.814697265625e-06 * (tracer.scene_extent + tracer.eps_floor)
    near = near_hits(prim, tfar, bound)
    close, step = false_hits(near, o, d, prim, tfar, tracer.eps_floor, tri, fn)
    # the same test in NumPy
    t_min = np.full(n, -1.0)
    t_min[near] = 4 * 3.814697265625e-06 * (np.abs(o[near]).max(axis=1) + tracer.eps_floor)
    ref = np.flatnonzero((prim >= 0) & (tfar < t_min))
    kk = prim[ref]
    side = np.einsum("ij,ij->i", o[ref] - tri[kk, 0], fn[kk])
    moving = np.einsum("ij,ij->i", d[ref], fn[kk])
    ref = ref[side * moving > 0]
    assert len(ref) > 100
    assert np.array_equal(close, ref) and np.array_equal(step, t_min[ref])
    empty = false_hits(near[:0], o, d, prim, tfar, tracer.eps_floor, tri, fn)
    assert len(empty[0]) == len(empty[1]) == 0


@pytest.mark.parametrize("case, record", [("covered", "wall"), ("headlight", "all")])
def test_records_by_source_are_the_stable_sort_of_the_trace(case, record):
    """``by_source``: each chunk's records sorted on the tracer's threads, the chunks in
    photon order — the same arrays as one stable counting sort of the trace's
    bounce-major records (what ``PhotonSets.shoot`` did after the trace), whatever the
    threads, batches and chunks; ledgers and the rest as without it."""
    if case == "covered":
        scene = covered_paraboloid_case(resolution=(16, 16)).scene
    else:  # diffuse parts: with record="all" a photon can leave records on two bounces
        glb = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "headlight.glb"
        scene = load(SimulateOptions(scene_path=str(glb)))
    n = 20_000 if case == "covered" else 6_000
    pts, keys = _photons(n)
    group = np.random.default_rng(2).integers(0, 3, n)
    want = None
    for threads, batch, min_chunk in ((1, 262144, 8192), (2, 7000, 500), (2, 1501, 64)):
        tr = PhotonTracer(scene, threads=threads, batch=batch, min_chunk=min_chunk,
                          record=record)
        base = tr.trace_points(pts, keys, group=group, n_groups=3)
        r = base.records
        assert np.any(np.diff(r.source) < 0)  # bounce-major: not in photon order
        sorted_ = sort_by_source(r.position, r.normal, r.power, r.part, r.flags, r.source, n)
        if want is None:
            want = sorted_
            if record == "all":  # photons with records on two bounces, in bounce order
                assert len(np.unique(want[5])) < len(want[5])
        got = tr.trace_points(pts, keys, group=group, n_groups=3, by_source=True)
        for f, w, s_ in zip(("position", "normal", "power", "part", "flags", "source"), want,
                            sorted_, strict=True):
            assert np.array_equal(getattr(got.records, f), s_), (threads, batch, f)
            assert np.array_equal(s_, w), (threads, batch, f)  # the same for any batching
        for f in ("emitted", "ledger", "caustic_source"):
            assert np.array_equal(getattr(got, f), getattr(base, f)), f
        assert got.rays == base.rays
    empty = PhotonTracer(scene, threads=2).trace_points(pts[:0], keys[:0], by_source=True)
    assert len(empty.records) == 0


def test_sort_by_source_with_an_offset():
    """The chunk sort: sources in [first, first + n), the same order and values as the
    sort of sources from 0."""
    rng = np.random.default_rng(4)
    n, first, m = 500, 10_000, 60
    src = rng.integers(0, m, n).astype(np.int64)
    arrays = (rng.random((n, 3)).astype(np.float32), rng.random((n, 3)).astype(np.float32),
              rng.random((n, 2)).astype(np.float32), rng.integers(0, 5, n).astype(np.int32),
              rng.integers(0, 3, n).astype(np.uint8))
    a = sort_by_source(*arrays, src, m)
    b = sort_by_source(*arrays, src + first, m, first)
    for x, y in zip(a[:5], b[:5], strict=True):
        assert np.array_equal(x, y)
    assert np.array_equal(a[5] + first, b[5])
    order = np.argsort(src, kind="stable")
    assert np.array_equal(a[0], arrays[0][order]) and np.array_equal(a[5], src[order])
