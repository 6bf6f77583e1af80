"""Shared pieces of the photon-map structures: input checks, leaf scans, density kernels.

Every structure (kd-trees, grids) stores its photons reordered so that each leaf or cell row
is one contiguous *slot* range; the numba kernels here scan such a range for one query.

Units: positions and radii in metres (m), squared distances in m², photon power Φ in the
caller's unit (lm for luminous flux), density estimates in that unit per m² (lm/m² = lx
once divided by the number of emitted photons, which the caller does).

Numba's on-disk cache (``cache=True``) is invalidated only by changes to a kernel's own
file: after editing a kernel here or in :mod:`~lightsim.photonmap.select` that others
inline (``scan_knn``, ``finish_*``, ``hint_bound``), delete
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
from numba import njit

from lightsim.errors import InputError
from lightsim.photonmap.select import select_k, sort_k

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

_EMPTY_KEYS = np.zeros(0, np.int64)


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
def hint_bound(qx: float, qy: float, qz: float, px: float, py: float, pz: float,
               prev_rk2: float, max_r2: float) -> float:
    """Initial squared search bound (m²) from the previous query's r_k (−1: none).

    The previous query's k photons lie within r_prev + |q − q_prev| of q (triangle
    inequality), so that radius bounds r_k(q) and prunes from the first node on. Used only
    when the previous query is within r_prev (coherent queries) and both share the same
    normal; inflated by 1e-9 relative against rounding.
    """
    if prev_rk2 < 0.0:
        return max_r2
    dd = math.sqrt((qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2)
    r_prev = math.sqrt(prev_rk2)
    if dd > r_prev:
        return max_r2
    b = ((r_prev + dd) * (1.0 + 1e-9)) ** 2
    return b if b < max_r2 else max_r2
