"""Sample generation: scrambled Halton points, counter-based random numbers, and
Selective Photon Tracing (paper section 5.1, figure 2).

Every photon is a pure function of (seed, interleave set, pass, Halton index), so a lost
client can be replayed exactly and runs are bit-identical across backends.

Emission dimensions (one Halton base each):

=====  =====  ==========================================================
dim    base   use
=====  =====  ==========================================================
0      2      direction, first coordinate (cos θ or r² of a Lambert disk)
1      3      direction, azimuth
2      5      which emitter triangle (flux × area weighted)
3      7      position on the triangle, first barycentric coordinate
4      11     position on the triangle, second barycentric coordinate
=====  =====  ==========================================================

Each interleave set scrambles the digits of every dimension with its own random digit
permutations (a randomised QMC point set), so the M² sets are independent, unbiased
estimates — their spread is the error estimate of the filtered image.

Selective Photon Tracing
------------------------
The direction square (dims 0, 1) is split into L = 2^a · 3^b cells. Halton indices
i, i + L, i + 2L, … share their first a base-2 and first b base-3 digits, hence lie in the
same cell (the periodicity of the Halton sequence). A *pass* shoots every cell c
n_c times at indices c + jL, j < n_c: n_c = 1 for ordinary cells and 1 + J for cells in
which an earlier pass found a caustic path (light that hit a specular surface and then a
diffuse one). Within a pass each photon carries power Φ · n_pass / (L n_c), with
n_pass = Σ_c n_c; the estimate divides by the total number of photons emitted in the set.
Each pass therefore estimates every cell with its exact share of the flux, and because the
refinement decision uses earlier passes only while every pass re-scrambles the digits
below the cell level, each pass is an unbiased estimate of the whole pattern. Leading
(cell) digits keep one scramble across passes so a cell stays the same cell.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

PRIMES = np.array([2, 3, 5, 7, 11], dtype=np.int64)
N_DIMS = 5
# digits per base so that base**-digits < 2**-53: the scrambled tail is fully random
DIGITS = np.array([53, 34, 23, 19, 16], dtype=np.int64)
MAX_DIGITS = int(DIGITS.max())
#: 2⁶⁴ / φ, SplitMix64's increment (the key chain of :func:`photon_keys`)
GOLDEN = np.uint64(0x9E3779B97F4A7C15)


# --------------------------------------------------------------------------------------
# Counter-based random numbers (splitmix64 finaliser)
# --------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def mix64(z: np.uint64) -> np.uint64:
    """SplitMix64 finaliser: a bijective 64-bit hash."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, inline="always")
def uniform(key: np.uint64, counter: np.uint64) -> float:
    """A uniform number in [0, 1) that depends only on (key, counter)."""
    z = mix64(key + (counter + np.uint64(1)) * np.uint64(0x9E3779B97F4A7C15))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


def mix64_np(z: np.ndarray) -> np.ndarray:
    """:func:`mix64` on a uint64 array (NumPy; wrapping arithmetic)."""
    z = np.asarray(z, dtype=np.uint64)
    with np.errstate(over="ignore"):
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def photon_keys(seed: int, set_index: int, pass_index: int, indices: np.ndarray) -> np.ndarray:
    """uint64 random-number keys of photons: a hash of (seed, set, pass, Halton index)."""
    with np.errstate(over="ignore"):
        base = mix64_np(np.uint64(seed & 0xFFFFFFFFFFFFFFFF) + GOLDEN)
        base = mix64_np(base ^ np.uint64(set_index + 1))
        base = mix64_np(base ^ (np.uint64(pass_index + 1) * GOLDEN))
    indices = np.ascontiguousarray(indices, dtype=np.int64)
    out = np.empty(indices.shape, np.uint64)
    _keys_of(np.uint64(base), indices.reshape(-1), out.reshape(-1))
    return out


@njit(cache=True, nogil=True)
def _keys_of(base: np.uint64, indices: np.ndarray, out: np.ndarray) -> None:
    """out[i] = mix64(base ^ indices[i]) (the index's bits as uint64): NumPy's
    ``mix64_np`` of the array in one pass, without its five temporaries."""
    for i in range(indices.shape[0]):
        out[i] = mix64(base ^ np.uint64(indices[i]))


# --------------------------------------------------------------------------------------
# Scrambled Halton points
# --------------------------------------------------------------------------------------

def digit_permutations(seed: int, set_index: int, pass_index: int | None,
                       cell_digits: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Random digit permutations, (N_DIMS, MAX_DIGITS, 11) int64.

    Parameters
    ----------
    seed, set_index : int
        The set's identity; every set has its own scramble.
    pass_index : int or None
        ``None``: one scramble for all photons of the set (plain sampling). Otherwise the
        digits below the cell level are re-scrambled per pass (SPT, see module docstring).
    cell_digits : (a, b)
        Number of leading base-2 and base-3 digits that define an SPT cell; they keep the
        pass-independent scramble.

    Each (dimension, digit) takes ``Generator.permutation(base)`` in turn from the set's
    generator (leading cell digits, or every digit without a pass) or the pass's; the
    shuffles run in one compiled loop that steps the generators' PCG64 states itself
    (:func:`_pcg64_next`, NumPy's ``random_interval`` and Fisher–Yates order), so the
    permutations are NumPy's, bit for bit (:func:`digit_permutations_reference` is the
    plain loop) — 3× cheaper than numba's ``Generator`` (whose every bounded draw goes
    through the bit generator's function pointers, ~66 ns a draw).
    """
    fixed = np.random.default_rng([seed & 0xFFFFFFFF, seed >> 32, set_index, 0x5EED])
    per_pass = (None if pass_index is None else
                np.random.default_rng([seed & 0xFFFFFFFF, seed >> 32, set_index, 0xA55,
                                       pass_index]))
    lead = np.array([cell_digits[0], cell_digits[1], 0, 0, 0], dtype=np.int64)
    if pass_index is None:
        lead[:] = MAX_DIGITS
    f_state = _pcg64_state(fixed)
    p_state = f_state if per_pass is None else _pcg64_state(per_pass)
    return _shuffled_digits(*f_state, *p_state, lead)


def _pcg64_state(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A PCG64 generator's state as (state high, state low, increment high, increment
    low) uint64 and its 32-bit buffer (has_uint32, uinteger), for :func:`_pcg64_next`."""
    s = rng.bit_generator.state
    if s["bit_generator"] != "PCG64":
        raise ValueError(f"expected a PCG64 generator, got {s['bit_generator']}")
    st, inc = int(s["state"]["state"]), int(s["state"]["inc"])
    lo = (1 << 64) - 1
    return (np.array([st >> 64, st & lo, inc >> 64, inc & lo], dtype=np.uint64),
            np.array([s["has_uint32"], s["uinteger"]], dtype=np.uint64))


_PCG_MULT_HI = np.uint64(0x2360ED051FC65DA4)  # PCG's default 128-bit multiplier
_PCG_MULT_LO = np.uint64(0x4385DF649FCCF645)
_LO32 = np.uint64(0xFFFFFFFF)


@njit(cache=True, inline="always")
def _mulhi64(a: np.uint64, b: np.uint64) -> np.uint64:
    """The high 64 bits of the 128-bit product a · b."""
    a0, a1 = a & _LO32, a >> np.uint64(32)
    b0, b1 = b & _LO32, b >> np.uint64(32)
    p01, p10 = a0 * b1, a1 * b0
    mid = ((a0 * b0) >> np.uint64(32)) + (p01 & _LO32) + (p10 & _LO32)
    return a1 * b1 + (p01 >> np.uint64(32)) + (p10 >> np.uint64(32)) + (mid >> np.uint64(32))


@njit(cache=True, inline="always")
def _pcg64_next(st: np.ndarray) -> np.uint64:
    """NumPy's PCG64 step (128-bit LCG, then the XSL-RR output of the new state) on
    ``st`` = (state high, state low, increment high, increment low)."""
    hi, lo = st[0], st[1]
    n_lo = lo * _PCG_MULT_LO
    n_hi = _mulhi64(lo, _PCG_MULT_LO) + lo * _PCG_MULT_HI + hi * _PCG_MULT_LO
    lo2 = n_lo + st[3]
    hi2 = n_hi + st[2] + (np.uint64(1) if lo2 < n_lo else np.uint64(0))
    st[0], st[1] = hi2, lo2
    x = hi2 ^ lo2
    rot = hi2 >> np.uint64(58)
    return (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))


@njit(cache=True, inline="always")
def _random_interval(st: np.ndarray, buf: np.ndarray, top: int) -> int:
    """NumPy's ``random_interval(top)`` (top < 2³²): masked 32-bit draws, rejected above
    ``top``; 32-bit draws take the two halves of a 64-bit one (``buf``), low half first."""
    if top == 0:
        return np.int64(0)
    mask = np.uint64(top)
    for sh in (1, 2, 4, 8, 16, 32):
        mask |= mask >> np.uint64(sh)
    while True:
        if buf[0] != 0:
            buf[0] = 0
            v = buf[1]
        else:
            nx = _pcg64_next(st)
            buf[0] = 1
            buf[1] = nx >> np.uint64(32)
            v = nx & _LO32
        v &= mask
        if v <= np.uint64(top):
            return np.int64(v)


@njit(cache=True, nogil=True)
def _shuffled_digits(f_st: np.ndarray, f_buf: np.ndarray, p_st: np.ndarray,
                     p_buf: np.ndarray, lead: np.ndarray) -> np.ndarray:
    """The permutations of :func:`digit_permutations`: digit k of dimension d shuffles
    0 … base−1 (NumPy's ``shuffle``: i from base−1 down to 1 swaps with
    ``random_interval(i)``) with the fixed generator for k < lead[d], else with the
    pass's, in (d, k) order."""
    perms = np.zeros((N_DIMS, MAX_DIGITS, 11), dtype=np.int64)
    for d in range(N_DIMS):
        base = PRIMES[d]
        for k in range(MAX_DIGITS):
            row = perms[d, k]
            for j in range(base):
                row[j] = j
            fixed = k < lead[d]
            for i in range(base - 1, 0, -1):
                j = (_random_interval(f_st, f_buf, i) if fixed
                     else _random_interval(p_st, p_buf, i))
                row[i], row[j] = row[j], row[i]
    return perms


def digit_permutations_reference(seed: int, set_index: int, pass_index: int | None,
                                  cell_digits: tuple[int, int] = (0, 0)) -> np.ndarray:
    """:func:`digit_permutations` as a Python loop over ``Generator.permutation`` (the
    definition its compiled loop must reproduce bit for bit; tests)."""
    perms = np.zeros((N_DIMS, MAX_DIGITS, 11), dtype=np.int64)
    fixed = np.random.default_rng([seed & 0xFFFFFFFF, seed >> 32, set_index, 0x5EED])
    per_pass = (None if pass_index is None else
                np.random.default_rng([seed & 0xFFFFFFFF, seed >> 32, set_index, 0xA55,
                                       pass_index]))
    for d in range(N_DIMS):
        base = int(PRIMES[d])
        lead = cell_digits[d] if d < 2 else 0
        for k in range(MAX_DIGITS):
            rng = fixed if (per_pass is None or k < lead) else per_pass
            perms[d, k, :base] = rng.permutation(base)
    return perms


@njit(cache=True)
def radical_inverse(index: np.int64, d: int, perms: np.ndarray) -> float:
    """The scrambled radical inverse of ``index`` in dimension ``d`` (digit permutations
    ``perms``), digit by digit: the definition the Halton kernels reproduce (tests)."""
    base = PRIMES[d]
    inv = 1.0 / base
    f = inv
    x = 0.0
    i = index
    for k in range(DIGITS[d]):
        digit = i % base
        i //= base
        x += perms[d, k, digit] * f
        f *= inv
    return min(x, 1.0 - 1.1102230246251565e-16)


#: digits of base PRIMES[d] one table lookup of :func:`halton_points_grouped` takes:
#: M digits as one digit of base b^M ≤ 128 (3⁴ = 81, 5³ = 125, 7² = 49, 11² = 121)
GROUP = np.array([1, 4, 3, 2, 2], dtype=np.int64)
#: digit groups per dimension (the last may be short) and table entries per group (the
#: last entry stays 0: what a point whose index is spent adds)
N_GROUPS = int(max(-(-int(DIGITS[d]) // int(GROUP[d])) for d in range(1, N_DIMS)))
GROUP_SIZE = 128


def _radical_inverse_in(d: int):
    """:func:`radical_inverse` for dimension ``d``, with its base and digit count as
    compile-time constants (the divisions become multiplications).

    Base 2 needs no loop at all: its terms are distinct powers of two, so the sum is
    exact in any order — the index's 53 low bits reversed, each digit through its
    permutation (a bit flip where ``perms[0, k, 0]`` is 1), times 2⁻⁵³: the same bits as
    the definition. The other bases take four points at a time, each with its own
    scramble, M = :data:`GROUP` [d] digits per step: the index's digits m·M … m·M + M − 1
    are one digit v of base b^M, whose terms Σ perms[d, k, digit_k(v)] · f_k are one
    table entry ``tab[d, m, v]`` (:func:`_digit_tables`); once the index is spent, the
    zero digits left add ``tail[d, m]``, their sum. The same terms as the definition,
    summed in another order: the points agree with it to a few units in the last place
    (``tests/core/test_sampling.py``).
    """
    base, digits = int(PRIMES[d]), int(DIGITS[d])

    if base == 2:
        @njit(cache=True, inline="always")
        def radical_inverse_2(index: np.int64, flips: np.uint64) -> float:
            r = np.uint64(index)
            r = ((r >> np.uint64(1)) & np.uint64(0x5555555555555555)) | \
                ((r & np.uint64(0x5555555555555555)) << np.uint64(1))
            r = ((r >> np.uint64(2)) & np.uint64(0x3333333333333333)) | \
                ((r & np.uint64(0x3333333333333333)) << np.uint64(2))
            r = ((r >> np.uint64(4)) & np.uint64(0x0F0F0F0F0F0F0F0F)) | \
                ((r & np.uint64(0x0F0F0F0F0F0F0F0F)) << np.uint64(4))
            r = ((r >> np.uint64(8)) & np.uint64(0x00FF00FF00FF00FF)) | \
                ((r & np.uint64(0x00FF00FF00FF00FF)) << np.uint64(8))
            r = ((r >> np.uint64(16)) & np.uint64(0x0000FFFF0000FFFF)) | \
                ((r & np.uint64(0x0000FFFF0000FFFF)) << np.uint64(16))
            r = (r >> np.uint64(32)) | (r << np.uint64(32))
            bits = (r >> np.uint64(11)) ^ flips  # digit k at bit 52 − k
            x = np.float64(bits) * 1.1102230246251565e-16
            return min(x, 1.0 - 1.1102230246251565e-16)

        return radical_inverse_2

    M = int(GROUP[d])
    groups = -(-digits // M)
    ubig = np.uint64(base ** M)
    zero = np.uint64(0)
    spent = np.uint64(GROUP_SIZE - 1)  # an empty slot: b^M < GROUP_SIZE

    @njit(cache=True, inline="always")
    def radical_inverse4(j0: np.int64, j1: np.int64, j2: np.int64, j3: np.int64,
                         a0: np.ndarray, a1: np.ndarray, a2: np.ndarray, a3: np.ndarray,
                         t0: np.ndarray, t1: np.ndarray, t2: np.ndarray, t3: np.ndarray
                         ) -> tuple[float, float, float, float]:
        # four points in step (their digit tables a, tail sums t): four independent
        # chains of additions instead of one, which the core overlaps. A point whose
        # index is spent adds the table's empty slot (+0.0, exact) while the others go
        # on, and its own tail once at the end: each point gets the sums it gets alone
        x0 = x1 = x2 = x3 = 0.0
        i0, i1 = np.uint64(j0), np.uint64(j1)  # indices are ≥ 0: unsigned division
        i2, i3 = np.uint64(j2), np.uint64(j3)  # by a constant is cheapest
        m0 = m1 = m2 = m3 = 0
        m = 0
        while (i0 | i1 | i2 | i3) != zero and m < groups:
            q0, q1, q2, q3 = i0 // ubig, i1 // ubig, i2 // ubig, i3 // ubig
            x0 += a0[d, m, i0 - q0 * ubig if i0 != zero else spent]
            x1 += a1[d, m, i1 - q1 * ubig if i1 != zero else spent]
            x2 += a2[d, m, i2 - q2 * ubig if i2 != zero else spent]
            x3 += a3[d, m, i3 - q3 * ubig if i3 != zero else spent]
            m0 += i0 != zero
            m1 += i1 != zero
            m2 += i2 != zero
            m3 += i3 != zero
            i0, i1, i2, i3 = q0, q1, q2, q3
            m += 1
        x0 += t0[d, m0]  # the zero digits left (0 once every group is taken)
        x1 += t1[d, m1]
        x2 += t2[d, m2]
        x3 += t3[d, m3]
        top = 1.0 - 1.1102230246251565e-16
        return min(x0, top), min(x1, top), min(x2, top), min(x3, top)

    return radical_inverse4


_RI0, _RI1, _RI2, _RI3, _RI4 = (_radical_inverse_in(d) for d in range(N_DIMS))


@njit(cache=True)
def _digit_tables(perms: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per scramble g ((G, N_DIMS, MAX_DIGITS, 11)) the tables of
    :func:`_radical_inverse_in` for bases 3–11: ``tab[g, d, m, v]``, the terms of the M
    digits of v (base b, least significant first) at digits m·M …, each
    ``perms[g, d, k, digit] · f_k`` with ``f_k`` = b^-(k+1) as the definition's running
    product makes it (digits past ``DIGITS[d]`` add nothing); ``tail[g, d, m]``, what
    the zero digits from m·M on add, summed from the last digit up (smallest first);
    and base 2's bit flips (bit 52 − k set where ``perms[g, 0, k, 0]`` is 1)."""
    G = perms.shape[0]
    tab = np.zeros((G, N_DIMS, N_GROUPS, GROUP_SIZE))
    tail = np.zeros((G, N_DIMS, N_GROUPS + 1))
    flips = np.zeros(G, np.uint64)
    f = np.zeros(MAX_DIGITS)
    for g in range(G):
        for d in range(1, N_DIMS):
            base, digits, M = PRIMES[d], DIGITS[d], GROUP[d]
            inv = 1.0 / base
            fk = inv
            for k in range(digits):
                f[k] = fk
                fk *= inv
            for m in range(-(-digits // M)):
                for v in range(base ** M):
                    x = 0.0
                    rest = v
                    for i in range(M):
                        k = m * M + i
                        if k < digits:
                            x += perms[g, d, k, rest % base] * f[k]
                        rest //= base
                    tab[g, d, m, v] = x
            acc = 0.0
            for k in range(digits - 1, -1, -1):
                acc += perms[g, d, k, 0] * f[k]
                if k % M == 0:
                    tail[g, d, k // M] = acc
        for k in range(DIGITS[0]):
            if perms[g, 0, k, 0] == 1:
                flips[g] |= np.uint64(1) << np.uint64(52 - k)
    return tab, tail, flips


@njit(cache=True, parallel=True)
def halton_points_grouped(indices: np.ndarray, group: np.ndarray, perms: np.ndarray
                          ) -> np.ndarray:
    """:func:`halton_points` of several sets in one parallel pass: point i is index
    ``indices[i]`` under the scramble ``perms[group[i]]`` ((G, N_DIMS, MAX_DIGITS, 11));
    one thread launch per frame instead of one per set, the same points. Four points at
    a time (the last ones repeated where ``n`` is not a multiple of 4)."""
    n = indices.shape[0]
    tab, tail, flips = _digit_tables(perms)
    out = np.empty((n, N_DIMS), dtype=np.float64)
    for b in prange((n + 3) // 4):
        a0 = 4 * b
        a1, a2, a3 = min(a0 + 1, n - 1), min(a0 + 2, n - 1), min(a0 + 3, n - 1)
        j0, j1, j2, j3 = indices[a0], indices[a1], indices[a2], indices[a3]
        g0, g1, g2, g3 = group[a0], group[a1], group[a2], group[a3]
        p0, p1, p2, p3 = tab[g0], tab[g1], tab[g2], tab[g3]
        t0, t1, t2, t3 = tail[g0], tail[g1], tail[g2], tail[g3]
        out[a0, 0] = _RI0(j0, flips[g0])
        out[a1, 0] = _RI0(j1, flips[g1])
        out[a2, 0] = _RI0(j2, flips[g2])
        out[a3, 0] = _RI0(j3, flips[g3])
        y0, y1, y2, y3 = _RI1(j0, j1, j2, j3, p0, p1, p2, p3, t0, t1, t2, t3)
        out[a0, 1], out[a1, 1], out[a2, 1], out[a3, 1] = y0, y1, y2, y3
        y0, y1, y2, y3 = _RI2(j0, j1, j2, j3, p0, p1, p2, p3, t0, t1, t2, t3)
        out[a0, 2], out[a1, 2], out[a2, 2], out[a3, 2] = y0, y1, y2, y3
        y0, y1, y2, y3 = _RI3(j0, j1, j2, j3, p0, p1, p2, p3, t0, t1, t2, t3)
        out[a0, 3], out[a1, 3], out[a2, 3], out[a3, 3] = y0, y1, y2, y3
        y0, y1, y2, y3 = _RI4(j0, j1, j2, j3, p0, p1, p2, p3, t0, t1, t2, t3)
        out[a0, 4], out[a1, 4], out[a2, 4], out[a3, 4] = y0, y1, y2, y3
    return out


def halton_points(indices: np.ndarray, perms: np.ndarray) -> np.ndarray:
    """Scrambled Halton points, (n, N_DIMS) float64 in [0, 1), for int64 ``indices``
    under one set's scramble ``perms`` ((N_DIMS, MAX_DIGITS, 11)): the grouped kernel with
    a single group."""
    indices = np.ascontiguousarray(indices, dtype=np.int64)
    return halton_points_grouped(indices, np.zeros(len(indices), np.int64),
                                 np.ascontiguousarray(perms)[None])


# --------------------------------------------------------------------------------------
# Selective Photon Tracing: cells and passes
# --------------------------------------------------------------------------------------

@njit(cache=True, nogil=True)
def pass_indices(n_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A pass's Halton indices, cell by cell (cell c: c + jL for j < n_c[c], L cells),
    and their weights n_pass / (L · n_c[c]) (float64, the same division as NumPy's)."""
    L = n_c.shape[0]
    n_pass = 0
    for c in range(L):
        n_pass += n_c[c]
    indices = np.empty(n_pass, np.int64)
    weight = np.empty(n_pass)
    k = 0
    for c in range(L):
        w = n_pass / (L * np.float64(n_c[c]))
        for j in range(n_c[c]):
            indices[k] = c + j * L
            weight[k] = w
            k += 1
    return indices, weight


class SelectiveSampler:
    """Per-set state of Selective Photon Tracing (one instance per interleave set).

    Parameters
    ----------
    seed, set_index : int
        Identity of the set.
    cell_digits : (a, b)
        L = 2^a · 3^b cells over the direction square (default (5, 3): 864 cells).
    pass_photons : int
        Target number of photons per pass; the refinement count J per refined cell is
        chosen before each pass from it (allocation never depends on the pass's own
        photons, which keeps the pass unbiased).
    refine_share : float, optional
        None (the paper's caustic SPT): ordinary cells get one photon per pass and the
        refined cells the rest. A share f in (0, 1): every cell keeps
        n₀ = ⌊(1 − f)·pass_photons / L⌋ photons and the refined cells share the other
        f·pass_photons — used to aim at test points without starving the rest of the
        map (the weights n_pass / (L n_c) keep every pass unbiased either way).
    """

    def __init__(self, seed: int, set_index: int, cell_digits: tuple[int, int] = (5, 3),
                 pass_photons: int = 4096, refine_share: float | None = None) -> None:
        self.refine_share = refine_share
        self.seed = seed
        self.set_index = set_index
        self.cell_digits = cell_digits
        self.n_cells = int(2 ** cell_digits[0] * 3 ** cell_digits[1])
        self.pass_photons = max(int(pass_photons), self.n_cells)
        self.refined = np.zeros(self.n_cells, dtype=np.bool_)
        self.passes_done = 0

    def next_pass(self) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """Indices, points and per-photon weights of the next pass.

        Returns
        -------
        pass_index : int
        indices : (n,) int64
            Halton indices c + jL.
        points : (n, N_DIMS) float64
        weight : (n,) float64
            Power factor n_pass / (L n_c) (multiply by the emitted flux Φ).
        """
        p, indices, perms, weight = self.next_pass_indices()
        return p, indices, halton_points(indices, perms), weight

    def next_pass_indices(self) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`next_pass` with the pass's digit permutations instead of its points
        (for :func:`halton_points_grouped`, which makes the points of many sets at once)."""
        L = self.n_cells
        n_ref = int(self.refined.sum())
        if n_ref == 0:  # nothing known yet: plain stratified sampling of every cell
            n_c = np.full(L, max(1, self.pass_photons // L), dtype=np.int64)
        elif self.refine_share is not None:
            base = max(1, int((1.0 - self.refine_share) * self.pass_photons) // L)
            J = max(self.pass_photons - base * L, 0) // n_ref
            n_c = np.where(self.refined, base + J, base).astype(np.int64)
        else:
            J = max(self.pass_photons - L, 0) // n_ref
            n_c = np.where(self.refined, 1 + J, 1).astype(np.int64)
        indices, weight = pass_indices(n_c)
        perms = digit_permutations(self.seed, self.set_index, self.passes_done,
                                   self.cell_digits)
        p = self.passes_done
        self.passes_done += 1
        return p, indices, perms, weight

    def update(self, indices: np.ndarray, caustic: np.ndarray) -> None:
        """Mark the cells of photons whose paths were caustic (refined from now on).

        With a ``refine_share`` (SPT aimed at test points) the refined cells are those of
        the last pass's triggering photons only, so a point that has enough photons
        stops drawing the refinement.
        """
        if self.refine_share is not None:
            self.refined[:] = False
        if len(indices):
            self.refined[(indices[caustic] % self.n_cells)] = True
