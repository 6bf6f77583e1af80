"""The Halton kernel's shortcuts (digit-group tables, the zero digits' tail sums, base 2 by
bit reversal) give the digit-by-digit radical inverse, at the indices where digit counts
change: base 2 bit for bit, the other bases to a few units in the last place (the same
terms summed in another order)."""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.sampling import (
    GOLDEN,
    GROUP,
    N_DIMS,
    PRIMES,
    digit_permutations,
    digit_permutations_reference,
    halton_points,
    halton_points_grouped,
    mix64_np,
    pass_indices,
    photon_keys,
    radical_inverse,
)

#: the points' largest difference from the digit loop: a few units in the last place of
#: a number below 1 (2.2e-16)
ULPS = 8 * 2.0**-53


def assert_definition(got: np.ndarray, want: np.ndarray) -> None:
    """Base 2 (dimension 0) bit for bit, bases 3–11 within :data:`ULPS`."""
    np.testing.assert_array_equal(got[:, 0], want[:, 0])
    np.testing.assert_allclose(got[:, 1:], want[:, 1:], rtol=0, atol=ULPS)


def _edge_indices() -> np.ndarray:
    """0, 1 and every power of each base (±1) up to 2⁶³: where an index gains a digit."""
    out = {0, 1, 2**63 - 1}
    for b in (int(p) for p in PRIMES):
        q = 1
        while q < 2**63:
            out.update(x for x in (q - 1, q, q + 1) if 0 <= x < 2**63)
            q *= b
    return np.array(sorted(out), dtype=np.int64)


@pytest.mark.parametrize("pass_index", [None, 0, 5])
def test_tables_and_bit_reversal_are_the_digit_loop(pass_index):
    idx = _edge_indices()
    perms = digit_permutations(4, 2, pass_index, (5, 3))
    got = halton_points(idx, perms)
    want = np.array([[radical_inverse(int(i), d, perms) for d in range(N_DIMS)]
                     for i in idx])
    assert_definition(got, want)
    assert got.min() >= 0.0 and got.max() < 1.0


def test_grouped_points_keep_each_groups_scramble():
    perms = np.stack([digit_permutations(1, s, None) for s in range(4)])
    idx = np.tile(_edge_indices()[:40], 4)
    group = np.repeat(np.arange(4), 40)
    got = halton_points_grouped(idx, group, perms)
    for g in range(4):
        np.testing.assert_array_equal(got[group == g], halton_points(idx[group == g], perms[g]))
    assert halton_points_grouped(idx[:0], group[:0], perms).shape == (0, N_DIMS)


@pytest.mark.parametrize("n", [1, 2, 3, 5, 4 * 37 + 3])
def test_points_four_at_a_time_each_keep_their_own_scramble(n):
    """The kernel takes four points at once: groups that change inside a four, indices
    of very different digit counts side by side and a count that is not a multiple of
    4 each give the digit loop's point under the point's own scramble."""
    rng = np.random.default_rng(n)
    perms = np.stack([digit_permutations(9, s, None if s % 2 else s, (5, 3))
                      for s in range(5)])
    edges = _edge_indices()
    idx = np.where(rng.random(n) < 0.5, rng.choice(edges, n),
                   rng.integers(0, 2**40, n)).astype(np.int64)
    group = rng.integers(0, 5, n)
    got = halton_points_grouped(idx, group, perms)
    want = np.array([[radical_inverse(int(i), d, perms[g]) for d in range(N_DIMS)]
                     for i, g in zip(idx, group, strict=True)])
    assert_definition(got, want)


def test_digit_group_boundaries():
    """Indices whose digits end exactly at, one before and one after the end of a digit
    group (b^(M·m) ± 1), and at the last digit the definition reads: the group tables
    and the tail sums take over at the right digit."""
    perms = digit_permutations(3, 1, 2, (5, 3))
    idx = {0, 1}
    for d in range(1, N_DIMS):
        b, M = int(PRIMES[d]), int(GROUP[d])
        q = 1
        while q < 2**63:
            idx.update(x for x in (q - 1, q, q + 1, 2 * q - 1) if 0 <= x < 2**63)
            q *= b**M
    idx = np.array(sorted(idx), dtype=np.int64)
    got = halton_points(idx, perms)
    want = np.array([[radical_inverse(int(i), d, perms) for d in range(N_DIMS)]
                     for i in idx])
    assert_definition(got, want)


@pytest.mark.parametrize("L", [1, 7, 864])
def test_pass_indices_are_the_cells_repeated(L):
    """SPT's pass layout: cell c at c + jL for j < n_c, weight n_pass / (L n_c)."""
    n_c = np.random.default_rng(L).integers(1, 40, L).astype(np.int64)
    cells = np.repeat(np.arange(L, dtype=np.int64), n_c)
    j = np.arange(len(cells)) - np.repeat(np.cumsum(n_c) - n_c, n_c)
    idx, w = pass_indices(n_c)
    np.testing.assert_array_equal(idx, cells + j * L)
    np.testing.assert_array_equal(w, len(cells) / (L * n_c[cells].astype(np.float64)))
    assert len(np.unique(idx)) == len(idx) and np.all(idx % L == cells)


@pytest.mark.parametrize("seed", [0, 7, 2**40 + 3, 2**63 - 1])
def test_own_pcg64_steps_give_numpys_permutations(seed):
    """The compiled shuffles step PCG64 themselves: NumPy's permutations for every kind of
    pass (plain, SPT passes with cell digits, all digits fixed)."""
    for s, p, cells in [(0, None, (0, 0)), (3, 0, (5, 3)), (1, 17, (5, 3)), (2, 4, (53, 34))]:
        np.testing.assert_array_equal(digit_permutations(seed, s, p, cells),
                                      digit_permutations_reference(seed, s, p, cells))


def test_photon_keys_are_the_numpy_hash_bit_for_bit():
    """The compiled keys (one pass) are the NumPy SplitMix64 chain of the definition:
    every seed, set and pass, indices 0, 1, 2⁶³ − 1 and random ones, any shape."""
    def numpy_keys(seed, s, p, idx):
        with np.errstate(over="ignore"):
            base = mix64_np(np.uint64(seed & 0xFFFFFFFFFFFFFFFF) + GOLDEN)
            base = mix64_np(base ^ np.uint64(s + 1))
            base = mix64_np(base ^ (np.uint64(p + 1) * GOLDEN))
            return mix64_np(base ^ np.asarray(idx, dtype=np.int64).astype(np.uint64))

    rng = np.random.default_rng(0)
    idx = np.r_[0, 1, 2**63 - 1, rng.integers(0, 2**63 - 1, 2000)].astype(np.int64)
    for seed, s, p in ((0, 0, 0), (7, 15, 3), (2**64 - 1, 3, 99), (2**63 + 5, 0, 0)):
        got = photon_keys(seed, s, p, idx)
        assert got.dtype == np.uint64
        np.testing.assert_array_equal(got, numpy_keys(seed, s, p, idx))
    grid = idx[:2000].reshape(40, 50)
    np.testing.assert_array_equal(photon_keys(1, 2, 3, grid), numpy_keys(1, 2, 3, grid))
    assert photon_keys(1, 2, 3, idx[:0]).shape == (0,)
