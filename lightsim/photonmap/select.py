"""Candidate buffer for exact k-nearest-neighbour search: quickselect instead of a heap.

A search appends every photon closer than its current bound to a buffer of capacity
``CAND_FACTOR · k``; when the buffer is full, quickselect keeps the k closest and the k-th
squared distance becomes the new bound. Compared with a bounded max-heap (one sift-down of
log₂ k levels with unpredictable branches per accepted photon) the append is branch-light
and the selection is linear; on a 1M-photon caustic set with k = 64 this measured ≈ 1.2×
faster per query. Correctness is the same: the final k are the k smallest squared
distances (up to ties at the k-th distance).

Squared distances are in m²; slots index a structure's reordered photon arrays.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: buffer capacity in units of k
CAND_FACTOR = 2


@njit(cache=True, inline="always")
def median_of_three(x0: float, x1: float, x2: float) -> float:
    """Median of three values: a pivot that is a value of the range (no run-off)."""
    if x0 > x1:
        x0, x1 = x1, x0
    if x1 > x2:
        x1 = x2
    return x1 if x1 > x0 else x0


@njit(cache=True, inline="always")
def _partition(cd: np.ndarray, cs: np.ndarray, lo: int, hi: int) -> tuple[int, int]:
    """Hoare partition of ``cd[lo:hi+1]`` (and ``cs``) around the median of three.

    Returns (i, j) with ``cd[lo:j+1] ≤ pivot ≤ cd[i:hi+1]``; slots strictly between j
    and i hold the pivot value.
    """
    pivot = median_of_three(cd[lo], cd[(lo + hi) >> 1], cd[hi])
    i = lo
    j = hi
    while i <= j:
        while cd[i] < pivot:
            i += 1
        while cd[j] > pivot:
            j -= 1
        if i <= j:
            d = cd[i]
            cd[i] = cd[j]
            cd[j] = d
            s = cs[i]
            cs[i] = cs[j]
            cs[j] = s
            i += 1
            j -= 1
    return i, j


@njit(cache=True)
def select_k(cd: np.ndarray, cs: np.ndarray, n: int, k: int) -> float:
    """Reorder ``cd[:n]`` (and ``cs``) so the k smallest come first; return the k-th (m²).

    Needs ``1 ≤ k ≤ n``. Afterwards ``cd[:k-1] ≤ cd[k-1] ≤ cd[k:n]``.
    """
    lo = 0
    hi = n - 1
    t = k - 1
    while hi > lo:
        i, j = _partition(cd, cs, lo, hi)
        if t <= j:
            hi = j
        elif t >= i:
            lo = i
        else:
            break  # cd[t] equals the pivot and sits between the two parts
    return cd[t]


@njit(cache=True)
def _insertion_sort(cd: np.ndarray, cs: np.ndarray, lo: int, hi: int) -> None:
    for i in range(lo + 1, hi + 1):
        d = cd[i]
        s = cs[i]
        j = i - 1
        while j >= lo and cd[j] > d:
            cd[j + 1] = cd[j]
            cs[j + 1] = cs[j]
            j -= 1
        cd[j + 1] = d
        cs[j + 1] = s


@njit(cache=True)
def sort_k(cd: np.ndarray, cs: np.ndarray, n: int, stack: np.ndarray) -> None:
    """Sort ``cd[:n]`` (and ``cs``) ascending in place; ``stack``: ≥ 128 int64 scratch.

    Quicksort (median-of-three pivot, Hoare partition, smaller side first so the explicit
    stack stays ≤ 2 log₂ n deep) with insertion sort below 16 elements.
    """
    sp = 0
    lo = 0
    hi = n - 1
    while True:
        if hi - lo < 16:
            _insertion_sort(cd, cs, lo, hi)
            if sp == 0:
                return
            sp -= 2
            lo = stack[sp]
            hi = stack[sp + 1]
            continue
        i, j = _partition(cd, cs, lo, hi)
        # continue with the smaller side, push the larger
        if j - lo < hi - i:
            stack[sp] = i
            stack[sp + 1] = hi
            hi = j
        else:
            stack[sp] = lo
            stack[sp + 1] = j
            lo = i
        sp += 2
