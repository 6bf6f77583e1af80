"""Incremental O(1)-per-pixel box filter for lux images (paper section 4.1).

The server combines the M×M interleaved sub-images of the clients into one image and
smooths it with an n×n box filter (normally n = M). As in the paper, a row buffer holds
the *vertical* sums of the n image rows inside the window, updated by adding the row that
enters and subtracting the row that leaves when moving down one row; along each row a
running *horizontal* sum of that buffer is updated by adding the column that enters and
subtracting the one that leaves. The work per pixel is a fixed handful of additions, so
the cost does not depend on n.

Parameters (user documentation)
-------------------------------
=================  ===============  ==========================  ==========================
name               unit             default                     meaning
=================  ===============  ==========================  ==========================
``image``          image's (lx)     required                    (H, W) or (H, W, C) array
``n``              pixels           required                    window side, 1 ≤ n ≤ 64
``weights``        1                ``None``                    (H, W) weights ≥ 0 or bool
                                                                valid-mask
``fill``           image's (lx)     ``0.0``                     output where a weighted
                                                                window has no weight
``dtype``          –                float32 in → float32,       output dtype (float32 or
                                    else float64                float64)
``exact``          –                ``True``                    drift-free accumulation
``parallel``       –                ``False``                   split the rows into bands
                                                                filtered on all CPUs
``ddof``           1                ``1``                       variance: k − ddof divisor
=================  ===============  ==========================  ==========================

Window and borders
------------------
The window of output pixel (y, x) covers rows ``y − n//2 … y + n − n//2 − 1`` and the same
columns. For odd n that is centred; for even n it reaches one pixel further up/left than
down/right (the window centre is half a pixel up-left of the pixel centre; this is
``scipy.ndimage.uniform_filter``'s alignment with ``origin=0``). Any n consecutive rows and
columns contain exactly one pixel of each of the n×n interleave sets, so for n = M every
interior window averages one pixel of every client's photon map. At the image border the
window is clipped to the image and the mean is taken over the k pixels inside it (no
padding, no mirroring); border windows therefore hold fewer than M² sets.

Numerics
--------
Lux maps have a huge dynamic range (a 1e9 lx hot spot next to 1 lx). Plain running sums
that add and later subtract such a value leave an absolute error of ≈ 1e9 · 2⁻⁵³ ≈ 1e-7 lx
behind it — a relative error of 1e-7 on the 1 lx pixels, growing along the row. With
``exact=True`` (default) every value v is split once, as it enters the row buffer, into
``v_hi = round(v / q) · q`` and ``v_lo = v − v_hi`` (both exact), with q a power of two
chosen from the image maximum so that every running sum of ``v_hi`` values is an integer
multiple of q of magnitude ≤ 2⁵⁰·q and is therefore computed *exactly* in float64 (the
``ExtractScalar`` splitting of Rump, Ogita & Oishi, "Accurate floating-point summation",
SIAM J. Sci. Comput. 31, 2008); q ≈ (n² + n) · max · 2⁻⁵⁰. The ``v_lo`` parts are at most
q/2 and each update of their running sums rounds by at most ≈ n² · q · 2⁻⁵⁴ (≈ 1e-19 lx
for a 1e9 lx spot at n = 6) — nothing measurable drifts. The result is the window mean to
within a few ulp, independent of the image size, with no periodic refresh.
It costs a second running sum: ≈ 0.76 ms vs 0.57 ms for the plain filter at 640×480
float32 (≈ 1300 vs 1800 frames/s on one core of the 2-CPU development VM; scipy's
``uniform_filter`` ≈ 2.7 ms; ``lightsim bench filter`` measures all of them). ``exact=False``
uses plain float64 running sums (the paper's version).

With non-negative input the output is clamped at 0, so it is never negative. NaN or ±inf
in ``image`` raises ``ValueError`` (a caller's bug: one NaN would otherwise spread along
the rows and columns of the running sums); pixels whose weight is 0 are ignored and may
hold NaN, which is the way to filter images in which some pixels were not computed.
Outputs never contain NaN.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

__all__ = [
    "MAX_N",
    "box_filter",
    "box_filter_naive",
    "box_stats",
    "box_sum",
    "window_counts",
    "window_offsets",
]

#: Largest supported window side in pixels (the paper uses 3…6).
MAX_N = 64

#: Largest |value| accepted (window sums of MAX_N² such values stay finite).
_MAX_ABS = 1e300


def window_offsets(n: int) -> tuple[int, int]:
    """Rows (and columns) of the window relative to the output pixel.

    Parameters
    ----------
    n : int
        Window side in pixels (≥ 1).

    Returns
    -------
    (lo, hi) : tuple of int
        The window of pixel y covers rows ``y − lo … y + hi`` with ``lo = n // 2`` and
        ``hi = n − lo − 1`` (for even n, one more row above than below).
    """
    n = _check_n(n)
    lo = n // 2
    return lo, n - lo - 1


def window_counts(height: int, width: int, n: int) -> np.ndarray:
    """Number of image pixels inside each clipped n×n window, shape (height, width), int64."""
    lo, hi = window_offsets(n)
    ys = np.arange(height)
    xs = np.arange(width)
    rows = np.minimum(ys + hi, height - 1) - np.maximum(ys - lo, 0) + 1
    cols = np.minimum(xs + hi, width - 1) - np.maximum(xs - lo, 0) + 1
    return np.outer(rows, cols).astype(np.int64)


# ---------------------------------------------------------------------------------------
# numba kernels
# ---------------------------------------------------------------------------------------

@njit(cache=True)
def _vertical(src, enter, leave, nrows, colh, coll, split, exact):
    """Update the row buffer (vertical window sums): add row ``enter``, remove ``leave``.

    ``enter``/``leave`` outside [0, nrows) are skipped. With ``exact`` the values are split
    with the constant ``split`` = 1.5·2⁵²·q: hi = (v + split) − split is v rounded to a
    multiple of q, lo = v − hi (both exact).
    """
    L = colh.size
    has_e = 0 <= enter < nrows
    has_l = 0 <= leave < nrows
    if exact:
        if has_e and has_l:
            re = src[enter]
            rl = src[leave]
            for i in range(L):
                a = np.float64(re[i])
                b = np.float64(rl[i])
                ah = (a + split) - split
                bh = (b + split) - split
                colh[i] += ah - bh
                coll[i] += (a - ah) - (b - bh)
        elif has_e:
            re = src[enter]
            for i in range(L):
                a = np.float64(re[i])
                ah = (a + split) - split
                colh[i] += ah
                coll[i] += a - ah
        elif has_l:
            rl = src[leave]
            for i in range(L):
                b = np.float64(rl[i])
                bh = (b + split) - split
                colh[i] -= bh
                coll[i] -= b - bh
    else:
        if has_e and has_l:
            re = src[enter]
            rl = src[leave]
            for i in range(L):
                colh[i] += np.float64(re[i]) - np.float64(rl[i])
        elif has_e:
            re = src[enter]
            for i in range(L):
                colh[i] += np.float64(re[i])
        elif has_l:
            rl = src[leave]
            for i in range(L):
                colh[i] -= np.float64(rl[i])


@njit(cache=True)
def _horizontal(colh, coll, orow, W, C, lo, hi, rscale, cscale, clamp0, exact):
    """Running horizontal sums of the row buffer into one output row (all channels).

    ``orow[x*C + c] = (Σ window columns of channel c) · rscale · cscale[x]``. Indices are
    unsigned so numba emits no negative-index wrap-around code in the inner loops.
    """
    uC = np.uint64(C)
    lowest = 0.0 if clamp0 else -np.inf
    xa = min(lo + 1, W)          # [0, xa): no column leaves yet
    xb = max(xa, W - hi)         # [xa, xb): one column enters and one leaves
    m = xb - xa
    sc_int = rscale * cscale[xa] if m > 0 else 0.0
    for c in range(C):
        sh = 0.0
        sl = 0.0
        for x in range(min(hi, W)):
            p = np.uint64(x * C + c)
            sh += colh[p]
            sl += coll[p]
        # left border
        for x in range(xa):
            if x + hi < W:
                p = np.uint64((x + hi) * C + c)
                sh += colh[p]
                sl += coll[p]
            v = (sh + sl) * (rscale * cscale[x])
            if v < lowest:
                v = lowest
            orow[np.uint64(x * C + c)] = v
        # interior: the hot loop
        pe = np.uint64((xa + hi) * C + c)
        pl = np.uint64((xa - lo - 1) * C + c) if m > 0 else np.uint64(0)
        po = np.uint64(xa * C + c)
        if exact:
            for _ in range(m):
                sh += colh[pe] - colh[pl]
                sl += coll[pe] - coll[pl]
                v = (sh + sl) * sc_int
                if v < lowest:
                    v = lowest
                orow[po] = v
                pe += uC
                pl += uC
                po += uC
        else:
            for _ in range(m):
                sh += colh[pe] - colh[pl]
                v = sh * sc_int
                if v < lowest:
                    v = lowest
                orow[po] = v
                pe += uC
                pl += uC
                po += uC
        # right border
        for x in range(xb, W):
            if x - lo - 1 >= 0:
                p = np.uint64((x - lo - 1) * C + c)
                sh -= colh[p]
                sl -= coll[p]
            v = (sh + sl) * (rscale * cscale[x])
            if v < lowest:
                v = lowest
            orow[np.uint64(x * C + c)] = v


@njit(cache=True, nogil=True)
def _rows(src, out, W, C, n, y0, y1, q, exact, normalize, clamp0):
    """Filter output rows [y0, y1) of ``src`` (H, W·C) into ``out`` (H, W·C)."""
    H = src.shape[0]
    L = W * C
    lo = n // 2
    hi = n - lo - 1
    split = 1.5 * 4503599627370496.0 * q  # 1.5 · 2^52 · q
    colh = np.zeros(L)
    coll = np.zeros(L)
    cscale = np.ones(W)
    if normalize:
        for x in range(W):
            cscale[x] = 1.0 / (min(x + hi, W - 1) - max(x - lo, 0) + 1)
    # prime the buffer with the window rows of y0 except the one entering at y0, plus
    # the one leaving at y0 (a band need not start at row 0)
    for r in range(max(y0 - lo - 1, 0), min(y0 + hi, H)):
        _vertical(src, r, -1, H, colh, coll, split, exact)
    for y in range(y0, y1):
        _vertical(src, y + hi, y - lo - 1, H, colh, coll, split, exact)
        rscale = 1.0
        if normalize:
            rscale = 1.0 / (min(y + hi, H - 1) - max(y - lo, 0) + 1)
        _horizontal(colh, coll, out[y], W, C, lo, hi, rscale, cscale, clamp0, exact)


@njit(cache=True)
def _naive(src, out, W, C, n):
    """Direct O(n²) window mean in float64, the baseline of ``lightsim bench filter``."""
    H = src.shape[0]
    lo = n // 2
    hi = n - lo - 1
    for y in range(H):
        ya = max(y - lo, 0)
        yb = min(y + hi, H - 1)
        for x in range(W):
            xa = max(x - lo, 0)
            xb = min(x + hi, W - 1)
            inv = 1.0 / ((yb - ya + 1) * (xb - xa + 1))
            for c in range(C):
                s = 0.0
                for r in range(ya, yb + 1):
                    row = src[r]
                    for xx in range(xa, xb + 1):
                        s += row[xx * C + c]
                out[y, x * C + c] = s * inv


# ---------------------------------------------------------------------------------------
# Python wrappers
# ---------------------------------------------------------------------------------------

def _check_n(n: int) -> int:
    if isinstance(n, bool) or int(n) != n:
        raise ValueError(f"box filter size must be an integer, got {n!r}")
    n = int(n)
    if not 1 <= n <= MAX_N:
        raise ValueError(f"box filter size must be 1…{MAX_N} pixels, got {n}")
    return n


def _as_2d(image: np.ndarray) -> tuple[np.ndarray, int, int, int]:
    """(H, W) or (H, W, C) float image → C-contiguous (H, W·C) float32/float64 view/copy."""
    a = np.asarray(image)
    if a.ndim not in (2, 3):
        raise ValueError(f"image must be (H, W) or (H, W, C), got shape {a.shape}")
    if a.dtype.kind not in "fiub":
        raise ValueError(f"image must be real-valued, got dtype {a.dtype}")
    if a.dtype not in (np.float32, np.float64):
        a = a.astype(np.float64)
    a = np.ascontiguousarray(a)
    H, W = a.shape[:2]
    C = a.shape[2] if a.ndim == 3 else 1
    if H == 0 or W == 0 or C == 0:
        raise ValueError(f"image must not be empty, got shape {a.shape}")
    return a.reshape(H, W * C), H, W, C


def _split_quantum(max_abs: float, n: int) -> float:
    """Power of two q with (n² + n) · max_abs ≤ 2^50 · q (see module notes)."""
    if not max_abs > 0.0:
        return 1.0
    e = math.frexp(max_abs * (n * n + n))[1]
    return math.ldexp(1.0, max(e - 50, -1000))


def _range(a2: np.ndarray, what: str = "image") -> tuple[float, float]:
    lo = float(np.min(a2))
    hi = float(np.max(a2))
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"{what} contains NaN or ±inf; mask such pixels with weights=0")
    if max(-lo, hi) > _MAX_ABS:
        raise ValueError(f"{what} values beyond ±{_MAX_ABS:g} would overflow window sums")
    return lo, hi


def _run(a2, out2, W, C, n, q, exact, normalize, clamp0, parallel):
    H = a2.shape[0]
    nbands = min(n_workers(), H // max(4 * n, 16)) if parallel else 1
    if nbands <= 1:
        _rows(a2, out2, W, C, n, 0, H, q, exact, normalize, clamp0)
        return
    bounds = [(H * b) // nbands for b in range(nbands + 1)]
    futures = [_pool().submit(_rows, a2, out2, W, C, n, bounds[b], bounds[b + 1], q, exact,
                              normalize, clamp0) for b in range(1, nbands)]
    _rows(a2, out2, W, C, n, bounds[0], bounds[1], q, exact, normalize, clamp0)
    for f in futures:
        f.result()


_POOL: ThreadPoolExecutor | None = None


def n_workers() -> int:
    """Bands a ``parallel=True`` filter splits an image into at most: the CPUs this process
    may run on (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def _pool() -> ThreadPoolExecutor:
    """Threads for ``parallel=True`` (the numba kernel releases the GIL)."""
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=max(1, n_workers() - 1),
                                   thread_name_prefix="lightsim-boxfilter")
    return _POOL


def _prepare_out(out, shape, dtype):
    if out is None:
        return np.empty(shape, dtype=dtype)
    if out.shape != shape or out.dtype != dtype or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous {np.dtype(dtype).name} array of "
                         f"shape {shape}, got {out.dtype} {out.shape}")
    return out


def box_sum(image: np.ndarray, n: int, *, exact: bool = True,
            parallel: bool = False) -> np.ndarray:
    """Sum of the pixels in each clipped n×n window, float64.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        Finite values (unit of the image, e.g. lx).
    n : int
        Window side in pixels (window alignment: :func:`window_offsets`).
    exact : bool, default True
        Drift-free split accumulation (module notes); False: plain running sums.
    parallel : bool, default False
        Filter horizontal bands of rows concurrently (see :func:`box_filter`).

    Returns
    -------
    ndarray, float64, same shape as ``image``
        Window sums (unit of the image · pixels).
    """
    n = _check_n(n)
    a2, _, W, C = _as_2d(image)
    lo, hi = _range(a2)
    out2 = np.empty(a2.shape, dtype=np.float64)
    _run(a2, out2, W, C, n, _split_quantum(max(-lo, hi), n), exact, False, lo >= 0.0, parallel)
    return out2.reshape(np.shape(image))


def box_filter(image: np.ndarray, n: int, *, weights: np.ndarray | None = None,
               fill: float = 0.0, dtype: np.dtype | type | None = None, exact: bool = True,
               parallel: bool = False, out: np.ndarray | None = None) -> np.ndarray:
    """Mean over the clipped n×n window of every pixel, O(1) work per pixel.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        Image to filter (e.g. illuminance in lx), float32 or float64 (other real dtypes
        are converted to float64). Must be finite where the weight is non-zero.
    n : int
        Window side in pixels, 1 ≤ n ≤ :data:`MAX_N` (normally the interleave size M).
        The window of pixel y spans rows ``y − n//2 … y + n − n//2 − 1``, likewise for x.
    weights : ndarray, shape (H, W), optional
        Per-pixel weights ≥ 0 (or a bool valid-mask), shared by all channels. The output
        is ``Σ w·v / Σ w`` over the window; pixels with weight 0 are ignored even if they
        hold NaN. Without weights every pixel inside the image has weight 1.
    fill : float, default 0.0
        Output (image unit) for windows whose weights sum to 0 (only with ``weights``).
    dtype : float32 or float64, optional
        Output dtype; default float32 for float32 input, float64 otherwise. The
        accumulation is float64 in every case.
    exact : bool, default True
        Drift-free accumulation (see the module notes); ``False`` gives the paper's plain
        running sums, ≈ 25 % faster, with an absolute error ≈ 2⁻⁵³ × the largest value
        that has passed through the running sums.
    parallel : bool, default False
        Split the rows into one band per CPU, filtered concurrently (the kernel releases
        the GIL; each band primes its own row buffer, so results agree with the serial
        filter to a few ulp). Worth it only for large images or idle CPUs.
    out : ndarray, optional
        Preallocated C-contiguous output of the right shape and dtype (no allocation per
        frame).

    Returns
    -------
    ndarray, same shape as ``image``
        Window means (image unit); never NaN, and ≥ 0 when the input is ≥ 0.

    Raises
    ------
    ValueError
        Bad n, shapes or weights, or NaN/±inf in ``image`` where the weight is non-zero.
    """
    n = _check_n(n)
    a2, H, W, C = _as_2d(image)
    if dtype is None:
        dtype = np.float32 if a2.dtype == np.float32 else np.float64
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    shape = np.shape(image)
    if weights is None:
        lo, hi = _range(a2)
        res = _prepare_out(out, shape, dtype)
        _run(a2, res.reshape(H, W * C), W, C, n, _split_quantum(max(-lo, hi), n), exact,
             True, lo >= 0.0, parallel)
        return res

    w = np.asarray(weights)
    if w.shape != (H, W):
        raise ValueError(f"weights must have shape {(H, W)}, got {w.shape}")
    w = w.astype(np.float64)
    wlo, _ = _range(w, "weights")
    if wlo < 0.0:
        raise ValueError("weights must be ≥ 0")
    valid = w > 0.0
    v = a2.reshape(H, W, C).astype(np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        wv = np.where(valid[:, :, None], v * w[:, :, None], 0.0)
    num = box_sum(wv, n, exact=exact, parallel=parallel)          # (H, W, C)
    den = box_sum(w, n, exact=exact, parallel=parallel)           # (H, W)
    has = den > 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(has[:, :, None], num / np.where(has, den, 1.0)[:, :, None],
                        float(fill))
    if bool(np.all(v[valid] >= 0.0)) and fill >= 0.0:
        np.maximum(mean, 0.0, out=mean)
    res = _prepare_out(out, shape, dtype)
    res[...] = mean.reshape(shape)
    return res


def box_stats(image: np.ndarray, n: int, *, ddof: int = 1,
              parallel: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Window mean and sample variance (spread) of the n×n values, both float64.

    The variance is ``(S2 − S1²/k) / (k − ddof)`` from exact running sums S1 = Σv and
    S2 = Σv² (float64, split accumulation) over the k pixels of the clipped window,
    clamped at ≥ 0; windows with k ≤ ddof get 0. The standard error of the window mean
    is ``sqrt(var / k)`` (k: :func:`window_counts`).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        Finite values (image unit, e.g. lx); |v| < 1e154 so that v² is finite.
    n : int
        Window side in pixels (alignment as :func:`box_filter`).
    ddof : int, default 1
        Delta degrees of freedom (1: unbiased sample variance, 0: population variance).
    parallel : bool, default False
        As in :func:`box_filter`.

    Returns
    -------
    mean, var : ndarray, float64, same shape as ``image``
        Window mean (image unit) and variance (image unit²). The variance has an absolute
        error of a few ulp of the window's mean square (cancellation in S2 − S1²/k);
        relative accuracy is lost only where the spread is below ≈ 1e-7 of the values.
    """
    n = _check_n(n)
    a2, H, W, _ = _as_2d(image)
    lo, hi = _range(a2)
    if max(-lo, hi) >= 1e154:
        raise ValueError("image values too large for a variance (|v| ≥ 1e154)")
    v = a2.astype(np.float64)
    s1 = box_sum(v.reshape(np.shape(image)), n, parallel=parallel)
    s2 = box_sum((v * v).reshape(np.shape(image)), n, parallel=parallel)
    k = window_counts(H, W, n).astype(np.float64)
    if len(np.shape(image)) == 3:
        k = k[:, :, None]
    mean = s1 / k
    var = np.maximum(s2 - s1 * mean, 0.0)
    dof = k - ddof
    with np.errstate(invalid="ignore", divide="ignore"):
        var = np.where(dof > 0, var / np.where(dof > 0, dof, 1.0), 0.0)
    return mean, var


def box_filter_naive(image: np.ndarray, n: int) -> np.ndarray:
    """Reference O(n²)-per-pixel window mean (float64 sums, same window and borders).

    The baseline of ``lightsim bench filter``; plain float64 summation of each window
    (rounding error ≈ n² · 2⁻⁵³ · window maximum).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        Image (image unit).
    n : int
        Window side in pixels.

    Returns
    -------
    ndarray, float64, same shape as ``image``
    """
    n = _check_n(n)
    a2, _, W, C = _as_2d(image)
    out2 = np.empty(a2.shape, dtype=np.float64)
    _naive(a2, out2, W, C, n)
    return out2.reshape(np.shape(image))
