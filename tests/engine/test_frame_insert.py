"""The compiled frame insertion (lightsim.engine.frame_insert) against the per-set NumPy
path it replaces: bit-identical stores, records in the same order, and the kernels' edge
cases (nothing to insert, photons off the wall, extreme coordinates)."""

from __future__ import annotations

import numpy as np
import pytest

import lightsim.engine.photonset as photonset
from lightsim.engine.config import RunConfig
from lightsim.engine.frame_insert import insert_wall, sort_by_source
from lightsim.engine.photonset import SPLIT_RECORDS, PhotonSets, window_offsets
from lightsim.engine.plan import make_plan
from lightsim.validation.scenes.analytic import isotropic_case, paraboloid_case


def _sets(scene, config, per_set: bool) -> PhotonSets:
    """The client's photon sets; ``per_set``: the per-set NumPy insertion (the reference)."""
    plan = make_plan(scene, config)
    sets = PhotonSets(scene, config, plan, list(range(config.n_sets)))
    if per_set:
        sets._insert_frame = lambda *a, **k: False  # type: ignore[method-assign]
    return sets


def _assert_same_stores(a: PhotonSets, b: PhotonSets) -> None:
    for s in a.set_indices:
        x, y = a.sets[s], b.sets[s]
        for name in ("windows", "lattice", "wall_moments"):
            u, w = getattr(x, name), getattr(y, name)
            assert (u is None) == (w is None), name
            if u is not None:
                np.testing.assert_array_equal(u, w, err_msg=name)
        assert x.photonmap._n_pending == y.photonmap._n_pending
        for p, q in zip(x.photonmap._pending, y.photonmap._pending, strict=True):
            for u, w in zip(p, q, strict=True):
                np.testing.assert_array_equal(u, w)
        np.testing.assert_array_equal(x.ledger, y.ledger)
        assert (x.emitted, x.caustic, x.records) == (y.emitted, y.caustic, y.records)


@pytest.mark.parametrize("case, channels, resolution, bandwidth", [
    ("paraboloid", 1, (40, 40), "ici"), ("paraboloid", 3, (17, 23), "ici"),
    ("isotropic", 1, (5, 7), "ici"), ("paraboloid", 1, (40, 40), "knn"),
    ("isotropic", 3, (5, 7), "knn")])
def test_frame_insertion_is_the_per_set_insertion_bit_for_bit(case, channels, resolution,
                                                              bandwidth):
    """Every store as the per-set path makes it: with ICI the lattice (and no probe
    windows: only the kNN figure reads them), without it the probe windows."""
    make = paraboloid_case if case == "paraboloid" else isotropic_case
    scene = make(resolution=resolution).scene
    config = RunConfig(frame_photons=8_000, interleave=2, seed=3, channels=channels,
                       probe_grid=(16, 8) if case == "paraboloid" else (32, 32),
                       bandwidth=bandwidth)
    fast, ref = _sets(scene, config, False), _sets(scene, config, True)
    for _ in range(3):  # frames accumulate into stores that already hold photons
        fast.shoot()
        ref.shoot()
        _assert_same_stores(fast, ref)
    st = fast.sets[0]  # the compiled pass filled it (a row of the stacked stores)
    if bandwidth == "ici":
        assert any(st.lattice is not None for st in fast.sets.values())
        assert st.lattice.base is fast._blocks["lattice"] and ref.sets[0].lattice.base is None
        assert all(st.windows is None for st in fast.sets.values())
    else:
        assert all(st.lattice is None for st in fast.sets.values())
        assert st.windows.base is fast._blocks["windows"] and ref.sets[0].windows.base is None
        assert any(st.windows.any() for st in fast.sets.values())
    fast.reset()  # a reset starts from empty stores again
    ref.reset()
    fast.shoot(2_000)
    ref.shoot(2_000)
    _assert_same_stores(fast, ref)


def test_counting_sort_is_the_stable_argsort():
    rng = np.random.default_rng(1)
    n = 5_000
    src = rng.integers(0, 700, n)
    arrays = (rng.random((n, 3)).astype(np.float32), rng.random((n, 3)).astype(np.float32),
              rng.random((n, 3)).astype(np.float32), rng.integers(0, 9, n).astype(np.int32),
              rng.integers(0, 4, n).astype(np.uint8), src)
    order = np.argsort(src, kind="stable")
    for got, want in zip(sort_by_source(*arrays, 700), arrays, strict=True):
        np.testing.assert_array_equal(got, want[order])
    empty = sort_by_source(*(a[:0] for a in arrays), 0)
    assert all(len(e) == 0 for e in empty) and empty[2].shape == (0, 3)


def _insert(part, pos, bounds, need_hv=True, channels=1):
    """insert_wall on a 4 × 4 probe grid and a 4 × 4-pixel lattice over [-0.5, 0.5]²."""
    S = len(bounds) - 1
    win = np.zeros((S, 16, channels))
    lat = np.zeros((S, 64, channels))
    work = np.full(64, -1, np.int32)
    win_work = np.zeros((9, 16, channels))
    power = np.ones((len(pos), channels), np.float32)
    axes = np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0]])
    out = insert_wall(part, np.array([0]), pos, power, np.asarray(bounds, np.int64), axes,
                      win, (-0.5, -0.5, 0.25, 0.25, 0.125, 0.125), (-1, 1, -1, 1, 4, 4),
                      win_work, lat, (-0.5, 0.5, 0.25, 0.25), (4, 4), work, need_hv)
    assert not win_work.any() and (work == -1).all()  # the work arrays are left clean
    return win, lat, out


def test_wall_kernel_takes_empty_input_and_extreme_coordinates():
    pos = np.array([[0, 0, 1], [1e30, -1e30, 1], [1e-30, 1e-30, 1], [np.nan, 0, 1],
                    [0.1, 0.1, 1], [0.1, 0.1, 1]], np.float32)  # the last two coincide
    part = np.array([0, 0, 0, 0, 1, 0], np.int32)
    # set 0: records 0-1, set 1: none, set 2: records 2-5
    win, lat, (counts, ok, pb, index, h, v) = _insert(part, pos, [0, 2, 2, 6])
    assert list(counts) == [2, 0, 3] and list(index) == [0, 1, 2, 3, 5]
    np.testing.assert_array_equal(h[[0, 2]], [0.0, np.float64(np.float32(1e-30))])
    np.testing.assert_array_equal(v[[0, 2]], h[[0, 2]])
    # on the wall and inside: 0 (set 0), the 1e-30 one and the coincident one (set 2);
    # neither the huge nor the NaN one
    assert list(ok) == [0, 2, 5] and list(pb) == [0, 1, 1, 3]
    assert win[:, :, 0].sum(axis=1).tolist() == [1.0, 0.0, 2.0]
    assert lat[:, :, 0].sum(axis=1).tolist() == [1.0, 0.0, 2.0]
    assert lat[2].max() == 1.0  # (0.1, 0.1) and 1e-30 fall in different cells
    _, _, (counts, ok, _, index, h, _) = _insert(part, pos, [0, 6], need_hv=False)
    assert counts[0] == 5 and len(index) == len(h) == 0 and len(ok) == 3
    empty = _insert(part[:0], pos[:0], [0, 0, 0])
    assert empty[0].sum() == 0 and len(empty[2][1]) == 0 and list(empty[2][2]) == [0, 0, 0]


def test_frame_insertion_on_two_threads_is_the_per_set_insertion_bit_for_bit(monkeypatch):
    """A frame of ≥ SPLIT_RECORDS records (after the first) is inserted in two halves of
    the sets, one half on a second thread: every store (windows, lattice, moments, the
    detector apertures' counts and their SPT triggers) as the per-set path and as one
    thread."""
    handed = []
    helper = photonset.second_thread

    class Counting:
        def submit(self, fn, *args):
            if len(args) > 1 and args[-1] == "b":  # the second half of a frame's sets
                handed.append(args)  # (not the lattice's pages: _prefault_lattice)
            return helper().submit(fn, *args)

    monkeypatch.setattr(photonset, "second_thread", Counting)
    scene = paraboloid_case(resolution=(48, 40)).scene
    config = RunConfig(frame_photons=4 * SPLIT_RECORDS, interleave=4, seed=5,
                       probe_grid=(16, 8), apertures=((0.0, 0.0), (3.0, -2.0), (-6.0, 4.0)),
                       aperture_targets=(0, 1))
    two, one = _sets(scene, config, False), _sets(scene, config.with_(threads=1), False)
    ref = _sets(scene, config, True)
    for frame in range(3):
        for sets in (two, one, ref):
            sets.shoot()
        assert len(handed) == frame  # the first frame on one thread, then two halves
        for other in (one, ref):
            _assert_same_stores(two, other)
            for s in two.set_indices:
                x, y = two.sets[s], other.sets[s]
                np.testing.assert_array_equal(x.apertures.counts, y.apertures.counts)
                np.testing.assert_array_equal(x.aperture_hits, y.aperture_hits)
    assert any(st.apertures.counts.any() for st in two.sets.values())


@pytest.mark.parametrize("reach", [0.0, 0.05, 0.2499, 0.5, 0.5000001, 0.7, 1.0, 1.3, 2.5])
def test_window_offsets_keep_every_window_that_can_hold_a_photon(reach):
    """No probe window outside :func:`window_offsets` holds a photon (the window test of
    ``insert_wall``, on photons at and next to the half-way points between centres),
    and the range is never wider than ⌈reach⌉."""
    lo, hi = window_offsets(reach)
    assert lo == -hi and 0 <= hi <= int(np.ceil(reach))
    pitch = 0.37
    half = reach * pitch
    k = np.arange(-40, 41)
    u = np.concatenate([k + 0.5, np.nextafter(k + 0.5, -np.inf), np.nextafter(k + 0.5, np.inf),
                        np.random.default_rng(3).uniform(-40, 40, 2000), k.astype(float)])
    r = np.rint(u)
    for i in range(-int(np.ceil(reach)) - 1, int(np.ceil(reach)) + 2):
        off = (u - (r + i)) * pitch
        held = (off >= -half) & (off < half)
        if lo <= i <= hi:
            continue
        assert not held.any(), (i, u[held][:3])


def test_lattice_pages_are_written_ahead_of_the_first_frame(monkeypatch):
    """The ICI lattice block exists (zeros, written on the second thread) before the first
    frame and is the block the frames sum into; not for the ``bin`` estimator, nor for a
    block above PREFAULT_MAX_BYTES (made by the first frame, as before)."""
    scene = paraboloid_case(resolution=(40, 24)).scene
    config = RunConfig(frame_photons=8_000, interleave=2, seed=3)
    sets = _sets(scene, config, False)
    block = sets._blocks["lattice"]
    assert block.shape == (4, 4 * 40 * 24, 1)
    sets._lattice_ready.result()
    assert not block.any()
    sets.shoot()
    assert sets._lattice_ready is None and sets._blocks["lattice"] is block
    assert any(st.lattice is not None and st.lattice.base is block
               for st in sets.sets.values())
    sets.reset()  # a reset writes a fresh block ahead again
    assert sets._blocks["lattice"] is not block and sets._lattice_ready is not None
    assert _sets(scene, config.with_(estimator="bin"), False)._lattice_ready is None
    # frames too small to reach every page (the live view's): the first frame makes it
    pages = 8 * 4 * 40 * 24 / 4096
    assert _sets(scene, config.with_(frame_photons=int(4 * pages) - 4), False
                 )._lattice_ready is None
    monkeypatch.setattr(photonset, "PREFAULT_MAX_BYTES", block.nbytes - 1)
    late = _sets(scene, config, False)
    assert late._lattice_ready is None and "lattice" not in late._blocks
    late.shoot()
    assert late._blocks["lattice"].shape == block.shape
