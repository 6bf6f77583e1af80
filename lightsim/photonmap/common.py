"""Shared pieces of the photon-map structures: input checks, leaf scans, density kernels.

Every structure (kd-trees, grids) stores its photons reordered so that each leaf or cell row
is one contiguous *slot* range; the numba kernels here scan such a range for one query.

Units: positions and radii in metres (m), squared distances in m², photon power Φ in the
caller's unit (lm for luminous flux), density estimates in that unit per m² (lm/m² = lx
once divided by the number of emitted photons, which the caller does).

Numba's on-disk cache (``cache=True``) is invalidated only by changes to a kernel's own
file: after editing a kernel here or in :mod:`~lightsim.photonmap.select` that others
inline (``scan_knn``, ``finish_*``, ``hint_bound``, ``query_*``), delete
``lightsim/photonmap/__pycache__/*.nb[ic]`` or the callers keep the old code.

Density kernels (``r`` = radius used, ``d`` = photon distance, ``k_c = 1`` for the cone)
-------------------------------------------------------------------------------------
==============  ======  ==========================================
name            code    estimate E
==============  ======  ==========================================
``box``         0       ΣΦ / (π r²)
``cone``        1       ΣΦ (1 − d/r) / ((1 − 2/(3 k_c)) π r²)
``epanechnikov``  2     ΣΦ · 2 (1 − d²/r²) / (π r²)
==============  ======  ==========================================
"""

from __future__ import annotations

import math
import types
from typing import Any, NamedTuple

import numpy as np
from numba import njit, parallel_chunksize

from lightsim.errors import InputError
from lightsim.photonmap.select import CAND_FACTOR, select_k, sort_k

#: kernel name -> integer code used inside the numba kernels
KERNELS: dict[str, int] = {"box": 0, "cone": 1, "epanechnikov": 2}

#: r never falls below ``R_FLOOR_REL · max(1 m, largest |coordinate|)`` (≈ 8 float32 ulps):
#: a smaller radius is below the resolution of the stored positions and would let a point
#: focus (r_k → 0) produce an infinite estimate.
R_FLOOR_REL = 2.0**-20

#: parallel query loops hand out this many blocks of queries at a time (a dynamic
#: schedule: the cost per query varies by orders of magnitude between dark regions and
#: caustics, so a static split leaves one thread idle)
QUERY_CHUNK = 4

#: kNN results of up to this many photons are ordered by rank sort (n² branch-free
#: compares), larger ones by quicksort
RANK_SORT_MAX = 128


class RadiusNeighbours(NamedTuple):
    """All photons within a fixed radius of each query, in CSR form.

    ``indices[offsets[i]:offsets[i+1]]`` are the photons (insertion-order indices, int64)
    near query ``i`` and ``d2`` their squared distances (m², float32), in no fixed order.
    """

    offsets: np.ndarray
    indices: np.ndarray
    d2: np.ndarray


class Estimate(NamedTuple):
    """Density estimate per query: E (Q, C) power per m², r (Q,) m, count (Q,) photons."""

    E: np.ndarray
    r: np.ndarray
    count: np.ndarray


# --------------------------------------------------------------------------- input checks
def _count_bad(a: np.ndarray) -> int:
    return int(np.count_nonzero(~np.isfinite(a).all(axis=1))) if a.ndim == 2 else 0


def as_positions(positions: np.ndarray, what: str = "photon positions") -> np.ndarray:
    """Return ``positions`` as a C-contiguous float32 (n, 3) array (m), rejecting NaN/inf.

    Raises
    ------
    InputError
        If the shape is not (n, 3) or any point has a NaN or infinite coordinate.
    """
    a = np.asarray(positions)
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"{what}: expected an (n, 3) array, got shape {a.shape}")
    with np.errstate(over="ignore", invalid="ignore"):  # overflow → inf, reported below
        a = np.ascontiguousarray(a, dtype=np.float32)
    if not np.isfinite(a).all():
        raise InputError(f"{what}: {_count_bad(a)} of {a.shape[0]} points have NaN or "
                         "infinite coordinates (or overflow float32)")
    return a


def as_queries(points: np.ndarray, what: str = "query points") -> np.ndarray:
    """Return query points as C-contiguous float64 (q, 3) (m), rejecting NaN/inf."""
    a = np.asarray(points)
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"{what}: expected a (q, 3) array, got shape {a.shape}")
    a = np.ascontiguousarray(a, dtype=np.float64)
    if not np.isfinite(a).all():
        raise InputError(f"{what}: {_count_bad(a)} of {a.shape[0]} points have NaN or "
                         "infinite coordinates")
    return a


def as_unit_normals(normals: np.ndarray, n: int, dtype: type = np.float32,
                    what: str = "photon normals") -> np.ndarray:
    """Return ``normals`` normalised to unit length as C-contiguous (n, 3) ``dtype``.

    Raises
    ------
    InputError
        On a wrong shape, NaN/inf components or zero-length normals.
    """
    a = np.asarray(normals)
    if a.shape != (n, 3):
        raise InputError(f"{what}: expected shape ({n}, 3), got {a.shape}")
    a = np.ascontiguousarray(a, dtype=np.float32 if dtype == np.float32 else np.float64)
    out, bad, zero = _unit_rows(a)
    if bad:
        raise InputError(f"{what}: {bad} of {n} normals have NaN or infinite components")
    if zero:
        raise InputError(f"{what}: {zero} of {n} normals have zero length")
    return out


def as_powers(powers: np.ndarray | None, n: int, channels: int) -> np.ndarray:
    """Return photon powers Φ as C-contiguous float32 (n, channels); ``None`` → zeros.

    A 1-D array is accepted when ``channels == 1``. Powers must be finite and ≥ 0.
    """
    if powers is None:
        return np.zeros((n, channels), np.float32)
    a = np.asarray(powers, dtype=np.float64)
    if a.ndim == 1 and channels == 1:
        a = a[:, None]
    if a.shape != (n, channels):
        raise InputError(f"photon powers: expected shape ({n}, {channels}), got {a.shape}")
    if n and not np.isfinite(a).all():
        bad = int(np.count_nonzero(~np.isfinite(a).all(axis=1)))
        raise InputError(f"photon powers: {bad} of {n} photons have NaN or infinite power")
    if n and (a < 0).any():
        bad = int(np.count_nonzero((a < 0).any(axis=1)))
        raise InputError(f"photon powers: {bad} of {n} photons have negative power")
    return np.ascontiguousarray(a, dtype=np.float32)


def check_k(k: int) -> int:
    """Validate the neighbour count k (≥ 0) and return it as ``int``."""
    if int(k) != k or k < 0:
        raise InputError(f"k must be a non-negative integer, got {k!r}")
    return int(k)


def check_radius(radius: float, what: str = "max_radius", allow_inf: bool = True) -> float:
    """Validate a radius (m): ≥ 0, not NaN, finite unless ``allow_inf``."""
    r = float(radius)
    if math.isnan(r) or r < 0 or (not allow_inf and math.isinf(r)):
        finite = "finite, " if not allow_inf else ""
        raise InputError(f"{what} must be {finite}≥ 0 m, got {radius!r}")
    return r


def kernel_code(kernel: str) -> int:
    """Integer code of a density kernel name (see :data:`KERNELS`)."""
    try:
        return KERNELS[kernel]
    except KeyError:
        raise InputError(f"unknown kernel {kernel!r}; choose one of "
                         f"{', '.join(KERNELS)}") from None


def query_normals(normals: np.ndarray | None, q: int, has_normals: bool,
                  ) -> tuple[np.ndarray, bool]:
    """Return (float64 (q, 3) unit query normals, use_filter) for the normal filter."""
    if normals is None:
        return np.zeros((q, 3), np.float64), False
    if not has_normals:
        raise InputError("query normals given but the photon map stores no photon normals")
    return as_unit_normals(normals, q, np.float64, "query normals"), True


def r_floor(lo: np.ndarray, hi: np.ndarray) -> float:
    """Smallest radius used by density estimates (m), from the photons' bounding box."""
    scale = max(1.0, float(np.max(np.abs(lo))), float(np.max(np.abs(hi))))
    return R_FLOOR_REL * scale


def block_size(q: int) -> int:
    """Queries handled per scratch allocation in the parallel query loops."""
    return 32 if q >= 4096 else 4


# --------------------------------------------------------------------------- numba kernels
#: below this many photons of work a kernel with a serial twin runs serially
SERIAL_BELOW = 65_536


def serial_twin(dispatcher: Any) -> Any:
    """A serial (``parallel=False``) compilation of a parallel ``@njit`` kernel.

    A parallel region costs a thread barrier, and on a loaded machine a descheduled
    thread stalls every barrier by a scheduler time slice (measured 10–25 ms per call),
    so small work runs serially. The twin gets its own name: numba's cache keys on the
    function's qualified name and would otherwise hand it the parallel compilation.
    """
    f = dispatcher.py_func
    g = types.FunctionType(f.__code__, f.__globals__, f.__name__ + "_serial",
                           f.__defaults__, f.__closure__)
    g.__qualname__ = f.__qualname__ + "_serial"
    g.__doc__ = f.__doc__
    return njit(cache=True)(g)


@njit(cache=True)
def _unit_rows(a: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Rows of ``a`` scaled to unit length (same dtype); counts of non-finite, zero rows."""
    n = a.shape[0]
    out = np.empty_like(a)
    bad = 0
    zero = 0
    for i in range(n):
        x = np.float64(a[i, 0])
        y = np.float64(a[i, 1])
        z = np.float64(a[i, 2])
        length = math.sqrt(x * x + y * y + z * z)
        if not np.isfinite(length):
            bad += 1
            length = 1.0
        elif length == 0.0:
            zero += 1
            length = 1.0
        out[i, 0] = x / length
        out[i, 1] = y / length
        out[i, 2] = z / length
    return out, bad, zero


@njit(cache=True)
def counting_sort(bucket: np.ndarray, n_buckets: int) -> tuple[np.ndarray, np.ndarray]:
    """Stable counting sort by bucket: (start table int64 (B+1,), order: slot → item)."""
    start = np.zeros(n_buckets + 1, np.int64)
    for i in range(bucket.shape[0]):
        start[bucket[i] + 1] += 1
    for b in range(n_buckets):
        start[b + 1] += start[b]
    cursor = start[:-1].copy()
    order = np.empty(bucket.shape[0], np.int64)
    for i in range(bucket.shape[0]):
        b = bucket[i]
        order[cursor[b]] = i
        cursor[b] += 1
    return start, order


@njit(cache=True)
def _take_rows(a: np.ndarray, order: np.ndarray, extra: np.ndarray) -> np.ndarray:
    out = np.empty((order.shape[0], a.shape[1]), a.dtype)
    n_a = a.shape[0]
    for i in range(order.shape[0]):
        t = order[i]
        if t < n_a:
            for c in range(a.shape[1]):
                out[i, c] = a[t, c]
        else:
            for c in range(a.shape[1]):
                out[i, c] = extra[t - n_a, c]
    return out


def take_rows(a: np.ndarray, order: np.ndarray, extra: np.ndarray | None = None,
              ) -> np.ndarray:
    """Rows of float32 ``a`` (followed by ``extra``) picked by ``order``.

    ``order`` indexes the concatenation [a; extra] without building it (numpy's fancy
    indexing of 2-D rows measured ≈ 3× slower). Serial: a parallel version saved a few ms
    per million rows but cost compile time and stalls on a loaded machine.
    """
    if extra is None:
        extra = a[:0]
    return _take_rows(a, order, extra)


@njit(cache=True, inline="always")
def kernel_weight(kernel: int, d2: float, r: float) -> float:
    """Unnormalised weight of a photon at squared distance ``d2`` (m²) for radius ``r`` (m)."""
    if kernel == 0:
        return 1.0
    if kernel == 1:
        w = 1.0 - math.sqrt(d2) / r
    else:
        w = 1.0 - d2 / (r * r)
    return w if w > 0.0 else 0.0


@njit(cache=True, inline="always")
def kernel_norm(kernel: int, r: float) -> float:
    """1 / (kernel integral) for radius ``r`` (1/m²): turns ΣΦw into power per m²."""
    if kernel == 0:
        return 1.0 / (math.pi * r * r)
    if kernel == 1:
        return 3.0 / (math.pi * r * r)  # cone k_c = 1: 1 / ((1 - 2/3) π r²)
    return 2.0 / (math.pi * r * r)


@njit(cache=True, inline="always")
def scan_knn(s0: int, s1: int, qx: float, qy: float, qz: float,
             qnx: float, qny: float, qnz: float,
             pts: np.ndarray, nrm: np.ndarray, use_nrm: bool, ncos: float,
             keys: np.ndarray, klo: int, khi: int,
             k: int, cd: np.ndarray, cs: np.ndarray, n: int, bound: float,
             rlo2: float, rlo: float, kernel: int, pw: np.ndarray, acc: np.ndarray,
             cnt_lo: int) -> tuple[int, float, int]:
    """Offer slots ``s0 … s1-1`` to the candidate buffer; return (n, bound, photons ≤ rlo).

    A photon with squared distance ``d2 ≤ bound`` (m²) is appended to ``cd``/``cs``; a full
    buffer is cut to its k closest and ``bound`` drops to the k-th squared distance.
    Photons whose normal disagrees with the query normal (dot < ``ncos``, when
    ``use_nrm``) are skipped and take no slot. Photons with ``d2 ≤ rlo2`` (the min-radius
    floor; ``rlo2 < 0`` = off) are summed into ``acc`` with kernel weights for radius
    ``rlo`` as a by-product, so the min-radius estimate needs no second traversal. A
    non-empty ``keys`` restricts the scan to slots whose cell key lies in ``[klo, khi)``
    (hashed grids).
    """
    cap = cd.shape[0]
    lim = bound if bound > rlo2 else rlo2
    use_keys = keys.shape[0] > 0
    for s in range(s0, s1):
        dx = pts[s, 0] - qx
        dy = pts[s, 1] - qy
        dz = pts[s, 2] - qz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > lim or (use_keys and (keys[s] < klo or keys[s] >= khi)):
            continue
        if use_nrm and nrm[s, 0] * qnx + nrm[s, 1] * qny + nrm[s, 2] * qnz < ncos:
            continue
        if d2 <= rlo2:
            w = kernel_weight(kernel, d2, rlo)
            for c in range(acc.shape[0]):
                acc[c] += w * pw[s, c]
            cnt_lo += 1
        if d2 <= bound:
            cd[n] = d2
            cs[n] = s
            n += 1
            if n == cap:
                bound = select_k(cd, cs, n, k)
                n = k
                lim = bound if bound > rlo2 else rlo2
    return n, bound, cnt_lo


@njit(cache=True)
def scan_radius(s0: int, s1: int, qx: float, qy: float, qz: float,
                qnx: float, qny: float, qnz: float,
                pts: np.ndarray, nrm: np.ndarray, use_nrm: bool, ncos: float,
                keys: np.ndarray, klo: int, khi: int, r2: float,
                out_i: np.ndarray, out_d: np.ndarray, pos: int, write: bool,
                r: float, kernel: int, pw: np.ndarray, acc: np.ndarray) -> int:
    """Visit slots within squared radius ``r2``; return the updated output position.

    With ``write`` the slot and its squared distance go to ``out_i[pos]``, ``out_d[pos]``;
    a non-empty ``acc`` receives ΣΦ·w(d, r) per channel. Filters as in :func:`scan_knn`.
    """
    use_keys = keys.shape[0] > 0
    n_acc = acc.shape[0]
    for s in range(s0, s1):
        dx = pts[s, 0] - qx
        dy = pts[s, 1] - qy
        dz = pts[s, 2] - qz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 > r2:
            continue
        if use_keys and (keys[s] < klo or keys[s] >= khi):
            continue
        if use_nrm and nrm[s, 0] * qnx + nrm[s, 1] * qny + nrm[s, 2] * qnz < ncos:
            continue
        if write:
            out_i[pos] = s
            out_d[pos] = d2
        if n_acc:
            w = kernel_weight(kernel, d2, r)
            for c in range(n_acc):
                acc[c] += w * pw[s, c]
        pos += 1
    return pos


@njit(cache=True)
def kth_d2(cd: np.ndarray, cs: np.ndarray, n: int, k: int) -> tuple[int, float]:
    """Cut the buffer to its k closest; return (count kept, largest kept d², m²)."""
    if n > k:
        return k, select_k(cd, cs, n, k)
    m = -1.0
    for j in range(n):
        if cd[j] > m:
            m = cd[j]
    return n, m


@njit(cache=True, inline="always")
def finish_knn(cd: np.ndarray, cs: np.ndarray, n: int, k: int, perm: np.ndarray,
               out_d: np.ndarray, out_i: np.ndarray, stack: np.ndarray) -> float:
    """Write the k closest as ascending float32 d² and original indices (rows padded with
    inf / −1); return r_k² or −1.

    ``r_k²`` (m²) is returned only when k photons were found (it bounds the next query);
    ``stack`` is scratch for :func:`~lightsim.photonmap.select.sort_k`.
    """
    n, kth = kth_d2(cd, cs, n, k)
    if n <= RANK_SORT_MAX:
        # rank sort straight into the output: photon i goes to the number of candidates
        # closer than it (ties by buffer position). Branch-free compares: on the
        # quickselected buffer of a query (k = 64) this measured ≈ 2× faster than
        # quicksort, whose partitions mispredict about every other comparison.
        for i in range(n):
            x = cd[i]
            r = 0
            for j in range(n):
                r += cd[j] < x
            for j in range(i):
                r += cd[j] == x
            out_d[r] = x
            out_i[r] = perm[cs[i]]
    else:
        sort_k(cd, cs, n, stack)
        for j in range(n):
            out_d[j] = cd[j]
            out_i[j] = perm[cs[j]]
    for j in range(n, out_d.shape[0]):
        out_d[j] = np.inf
        out_i[j] = -1
    return kth if n == k else -1.0


@njit(cache=True, inline="always")
def finish_estimate(cd: np.ndarray, cs: np.ndarray, n: int, k: int, max_r2: float,
                    rlo: float, kernel: int, pw: np.ndarray, acc: np.ndarray, cnt_lo: int,
                    out_e: np.ndarray) -> tuple[float, int, float]:
    """Turn a finished search into E (written to ``out_e``): return (r, photons used, r_k²).

    r = r_k when k photons were found within max_radius, else max_radius, else (infinite
    max_radius) the farthest photon found; whenever that r ≤ ``rlo`` the photons within
    ``rlo`` (already summed in ``acc``) are used with r = rlo. With r = r_k the box kernel
    counts the k-th photon, which lies on the circle, half (see below). ``r_k²`` is −1
    unless k photons were found.
    """
    C = out_e.shape[0]
    n, kth = kth_d2(cd, cs, n, k)
    rk2 = kth if n == k else -1.0
    if n == 0:
        for c in range(C):
            out_e[c] = 0.0
        return (math.sqrt(max_r2) if max_r2 < np.inf else 0.0), 0, rk2
    r2 = kth if (n == k or max_r2 == np.inf) else max_r2
    if r2 <= rlo * rlo:
        norm = kernel_norm(kernel, rlo)
        for c in range(C):
            out_e[c] = acc[c] * norm
        return rlo, cnt_lo, rk2
    r = math.sqrt(r2)
    for c in range(C):
        out_e[c] = 0.0
    # At r = r_k the k-th photon lies on the circle. For independent (Poisson) photons
    # (k − 1)/(π r_k²) is unbiased and k/(π r_k²) high by k/(k − 1); for evenly stratified
    # (quasi-random) photons k/(π r_k²) is right and (k − 1) low. Counting it half keeps
    # the bias within ±1/(2k) for both (±0.8 % at k = 64). Cone and Epanechnikov give it
    # weight 0 anyway.
    skip = -1
    if kernel == 0 and n == k and r2 == kth:
        for j in range(n):
            if cd[j] == kth:
                skip = j
                break
    for j in range(n):
        w = kernel_weight(kernel, cd[j], r)
        if j == skip:
            w *= 0.5
        s = cs[j]
        for c in range(C):
            out_e[c] += w * pw[s, c]
    norm = kernel_norm(kernel, r)
    for c in range(C):
        out_e[c] *= norm
    return r, n, rk2


@njit(cache=True, inline="always")
def hint_bound(queries: np.ndarray, qnrm: np.ndarray, use_nrm: bool, q: int, q0: int,
               prev_rk2: float, max_r2: float) -> float:
    """Initial squared search bound (m²) of query ``q`` in a block starting at ``q0``.

    The previous query's k photons (its r_k² = ``prev_rk2``, −1: none) lie within
    r_prev + |q − q_prev| of q (triangle inequality), so that radius bounds r_k(q) and
    prunes from the first node on. Used only when the previous query is in the same
    block, within r_prev (coherent queries) and, with the normal filter, has the same
    normal; inflated by 1e-9 relative against rounding. Otherwise ``max_r2``.
    """
    p = q - 1
    if q == q0 or (use_nrm and not (qnrm[q, 0] == qnrm[p, 0] and qnrm[q, 1] == qnrm[p, 1]
                                    and qnrm[q, 2] == qnrm[p, 2])):
        return max_r2
    if prev_rk2 < 0.0:
        return max_r2
    dd = math.sqrt((queries[q, 0] - queries[p, 0]) ** 2 + (queries[q, 1] - queries[p, 1]) ** 2
                   + (queries[q, 2] - queries[p, 2]) ** 2)
    r_prev = math.sqrt(prev_rk2)
    if dd > r_prev:
        return max_r2
    b = ((r_prev + dd) * (1.0 + 1e-9)) ** 2
    return b if b < max_r2 else max_r2


@njit(cache=True, inline="always")
def query_outputs(nq: int, k: int, fused: bool, channels: int,
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Result arrays of a kNN query (d², idx: (nq, k)) or, ``fused``, of a density
    estimate (E (nq, channels), r, count); the other kind gets empty arrays."""
    kq = 0 if fused else k
    nf = nq if fused else 0
    out_d = np.empty((nq, kq), np.float32)  # every row is written in full (padded)
    out_i = np.empty((nq, kq), np.int64)
    out_e = np.zeros((nf, channels if fused else 0), np.float64)
    out_r = np.zeros(nf, np.float64)
    out_n = np.zeros(nf, np.int64)
    return out_d, out_i, out_e, out_r, out_n


@njit(cache=True, inline="always")
def query_scratch(k: int, channels: int,
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-block scratch of a kNN search: candidate d² and slots (:data:`CAND_FACTOR`·k),
    the stack of :func:`~lightsim.photonmap.select.sort_k` and the min-radius sums."""
    cd = np.empty(CAND_FACTOR * k, np.float64)
    cs = np.empty(CAND_FACTOR * k, np.int64)
    sort_stack = np.empty(128, np.int64)
    acc = np.zeros(channels, np.float64)
    return cd, cs, sort_stack, acc


@njit(cache=True, inline="always")
def finish_query(q: int, fused: bool, cd: np.ndarray, cs: np.ndarray, n: int, k: int,
                 max_r2: float, rlo: float, kernel: int, pw: np.ndarray, acc: np.ndarray,
                 cnt_lo: int, perm: np.ndarray, sort_stack: np.ndarray, out_d: np.ndarray,
                 out_i: np.ndarray, out_e: np.ndarray, out_r: np.ndarray,
                 out_n: np.ndarray) -> float:
    """Write query ``q``'s result (:func:`finish_estimate` when ``fused``, else
    :func:`finish_knn`) into the arrays of :func:`query_outputs`; return r_k² or −1."""
    if fused:
        r, used, rk2 = finish_estimate(cd, cs, n, k, max_r2, rlo, kernel, pw, acc, cnt_lo,
                                       out_e[q])
        out_r[q] = r
        out_n[q] = used
        return rk2
    return finish_knn(cd, cs, n, k, perm, out_d[q], out_i[q], sort_stack)


# --------------------------------------------------------------------------- front end
class PhotonIndex:
    """Photon storage and the query front end shared by the kd-trees and the grids.

    A structure stores its photons reordered by slot (``_pts`` float32 positions in m,
    ``_nrm`` unit normals, ``_pw`` powers, ``_perm``: slot → insertion index) and
    implements ``_build`` (from photons in insertion order), ``bounds`` and the kernel
    calls :meth:`_knn` and :meth:`_radius`. This class checks the arguments, answers
    for an empty map, and runs the parallel kernels under the dynamic schedule of
    :data:`QUERY_CHUNK`. ``_finite_radius``: :meth:`query_radius` rejects an infinite
    radius.
    """

    _finite_radius = False

    def __init__(self, channels: int) -> None:
        if int(channels) != channels or channels < 0:
            raise InputError(f"channels must be a non-negative integer, got {channels!r}")
        self.n_channels = int(channels)
        self._has_normals: bool | None = None  # fixed by the first non-empty batch
        self._pts = np.zeros((0, 3), np.float32)
        self._nrm = np.zeros((0, 3), np.float32)
        self._pw = np.zeros((0, self.n_channels), np.float32)
        self._perm = np.zeros(0, np.int64)

    # ----------------------------------------------------------------- input
    def _prepare(self, positions: np.ndarray, normals: np.ndarray | None,
                 powers: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Check a batch: (positions float32, unit normals or (0, 3), powers (n, C))."""
        pts = as_positions(positions)
        n = pts.shape[0]
        if n and self._has_normals is None and len(self) == 0:
            self._has_normals = normals is not None
        if normals is not None and self._has_normals is False:
            raise InputError("photon normals given for a map built without normals")
        if normals is None and self._has_normals and n:
            raise InputError("photon normals missing: this map stores normals for every photon")
        nrm = (as_unit_normals(normals, n) if normals is not None and n
               else np.zeros((0, 3), np.float32))
        return pts, nrm, as_powers(powers, n, self.n_channels)

    def _insertion_order(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stored photons (positions, normals, powers) back in insertion order."""
        inv = np.empty_like(self._perm)
        inv[self._perm] = np.arange(self._perm.size)
        nrm = self._nrm[inv] if self._has_normals else self._nrm
        return self._pts[inv], nrm, self._pw[inv]

    def _add_rebuild(self, positions: np.ndarray, normals: np.ndarray | None,
                     powers: np.ndarray | None) -> None:
        """Append a batch (indices continue) and rebuild from all photons."""
        pts, nrm, pw = self._prepare(positions, normals, powers)
        if pts.shape[0] == 0:
            return
        if len(self):
            old_pts, old_nrm, old_pw = self._insertion_order()
            pts = np.concatenate([old_pts, pts])
            nrm = np.concatenate([old_nrm, nrm]) if self._has_normals else nrm
            pw = np.concatenate([old_pw, pw])
        self._build(pts, nrm, pw)

    # ----------------------------------------------------------------- info
    def __len__(self) -> int:
        return int(self._pts.shape[0])

    @property
    def has_normals(self) -> bool:
        """Whether photon normals are stored (needed by the normal filter)."""
        return bool(self._has_normals)

    # ----------------------------------------------------------------- kernels
    def _knn(self, q: np.ndarray, qn: np.ndarray, use_nrm: bool, ncos: float, k: int,
             max_r2: float, rlo: float, kernel: int, fused: bool,
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The structure's kNN kernel: (d², idx) or, ``fused``, (E, r, count) — the
        arrays of :func:`query_outputs`."""
        raise NotImplementedError

    def _radius(self, q: np.ndarray, qn: np.ndarray, use_nrm: bool, ncos: float, r: float,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The structure's fixed-radius kernel: CSR (offsets, indices, d²) for radius r (m)."""
        raise NotImplementedError

    # ----------------------------------------------------------------- queries
    def query(self, points: np.ndarray, k: int, *, max_radius: float = np.inf,
              normals: np.ndarray | None = None, normal_cos: float = 0.5,
              ) -> tuple[np.ndarray, np.ndarray]:
        """Exact k nearest photons of each query point.

        Parameters
        ----------
        points : (Q, 3) array_like
            Query points (m).
        k : int
            Neighbours per query; more than stored photons is fine (rows are padded).
        max_radius : float
            Only photons with distance ≤ max_radius (m) are returned.
        normals : (Q, 3) array_like, optional
            Query normals; when given, photons whose stored normal n has
            n·normal < ``normal_cos`` are skipped (they take no neighbour slot).
        normal_cos : float
            Cosine threshold of the normal filter (dimensionless).

        Returns
        -------
        d2 : (Q, k) float32
            Squared distances (m²), ascending, ``inf`` where fewer than k were found.
        idx : (Q, k) int64
            Insertion-order photon indices, −1 where fewer than k were found.
        """
        q = as_queries(points)
        k = check_k(k)
        max_r = check_radius(max_radius)
        qn, use_nrm = query_normals(normals, q.shape[0], self.has_normals)
        if k == 0 or len(self) == 0:
            return (np.full((q.shape[0], k), np.inf, np.float32),
                    np.full((q.shape[0], k), -1, np.int64))
        with parallel_chunksize(QUERY_CHUNK):
            d2, idx, _, _, _ = self._knn(q, qn, use_nrm, float(normal_cos), k, max_r * max_r,
                                         -1.0, 0, False)
        return d2, idx

    def query_radius(self, points: np.ndarray, radius: float, *,
                     normals: np.ndarray | None = None, normal_cos: float = 0.5,
                     ) -> RadiusNeighbours:
        """All photons within ``radius`` (m, inclusive) of each query point (CSR result).

        The normal filter works as in :meth:`query`.
        """
        q = as_queries(points)
        r = check_radius(radius, "radius", allow_inf=not self._finite_radius)
        qn, use_nrm = query_normals(normals, q.shape[0], self.has_normals)
        if len(self) == 0:
            return RadiusNeighbours(np.zeros(q.shape[0] + 1, np.int64), np.zeros(0, np.int64),
                                    np.zeros(0, np.float32))
        return RadiusNeighbours(*self._radius(q, qn, use_nrm, float(normal_cos), r))

    def estimate(self, points: np.ndarray, normals: np.ndarray | None = None, *, k: int = 64,
                 max_radius: float = np.inf, min_radius: float = 0.0, kernel: str = "box",
                 normal_cos: float = 0.5) -> Estimate:
        """Fused kNN density estimate (see :mod:`lightsim.photonmap.density` for semantics)."""
        q = as_queries(points)
        k = check_k(k)
        if k < 1:
            raise InputError("k must be ≥ 1 for a density estimate")
        max_r = check_radius(max_radius)
        min_r = check_radius(min_radius, "min_radius", allow_inf=False)
        if min_r > max_r:
            raise InputError(f"min_radius ({min_r} m) exceeds max_radius ({max_r} m)")
        code = kernel_code(kernel)
        qn, use_nrm = query_normals(normals, q.shape[0], self.has_normals)
        nq = q.shape[0]
        if len(self) == 0:
            return Estimate(np.zeros((nq, self.n_channels)),
                            np.full(nq, max_r if max_r < np.inf else 0.0),
                            np.zeros(nq, np.int64))
        rlo = min(max(min_r, r_floor(*self.bounds)), max_r)
        with parallel_chunksize(QUERY_CHUNK):
            _, _, E, r, count = self._knn(q, qn, use_nrm, float(normal_cos), k, max_r * max_r,
                                          rlo, code, True)
        return Estimate(E, r, count)
