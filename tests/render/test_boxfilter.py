"""O(1) box filter: exactness against references, drift-free numerics, the paper's claim
that M×M interleaved maps of N photons, box-filtered, estimate what one map of M²N
photons gives (paper section 5), and the benchmark command."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.ndimage import uniform_filter

from lightsim.cli.bench_filter import command
from lightsim.render.boxfilter import (
    MAX_N,
    box_filter,
    box_filter_naive,
    box_stats,
    box_sum,
    window_counts,
    window_offsets,
)
from lightsim.render.interleave import InterleavePattern


def exact_mean(img: np.ndarray, n: int, pixels=None) -> np.ndarray:
    """Correctly rounded window means (math.fsum) for the clipped window, float64."""
    H, W = img.shape[:2]
    lo, hi = n // 2, n - 1 - n // 2
    out = np.full(img.shape, np.nan)
    coords = pixels if pixels is not None else [(y, x) for y in range(H) for x in range(W)]
    for y, x in coords:
        blk = img[max(y - lo, 0):min(y + hi, H - 1) + 1,
                  max(x - lo, 0):min(x + hi, W - 1) + 1].astype(np.float64)
        k = blk.shape[0] * blk.shape[1]
        if img.ndim == 2:
            out[y, x] = math.fsum(blk.ravel()) / k
        else:
            for c in range(img.shape[2]):
                out[y, x, c] = math.fsum(blk[..., c].ravel()) / k
    return out


def rel_err(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.max(np.abs(a - ref) / np.maximum(np.abs(ref), 1e-300)))


# -- exactness -------------------------------------------------------------------------

@pytest.mark.parametrize("shape", [(23, 31), (5, 3), (1, 1), (2, 9), (17, 12, 3)])
@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6, 7, 8])
def test_equals_exact_reference(shape, n):
    rng = np.random.default_rng(n * 100 + len(shape))
    img = rng.random(shape) + 0.1
    ref = exact_mean(img, n)
    for exact in (True, False):
        assert rel_err(box_filter(img, n, exact=exact), ref) < 1e-12
    assert rel_err(box_filter(img, n, parallel=True), ref) < 1e-12
    assert rel_err(box_filter_naive(img, n), ref) < 1e-12
    # float32 in → float32 out, rounded from the float64 mean
    f32 = img.astype(np.float32)
    out32 = box_filter(f32, n)
    assert out32.dtype == np.float32 and out32.shape == shape
    assert rel_err(out32.astype(np.float64), exact_mean(f32, n)) < 1.2e-7


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6, 8])
def test_matches_scipy_uniform_filter_in_interior(n):
    rng = np.random.default_rng(7)
    img = rng.random((64, 80)) * 1e3
    ours = box_filter(img, n)
    lo, hi = window_offsets(n)
    interior = (slice(lo, img.shape[0] - hi), slice(lo, img.shape[1] - hi))
    theirs = uniform_filter(img, n, mode="constant")
    assert rel_err(ours[interior], theirs[interior]) < 1e-12


def test_window_alignment_and_counts():
    assert window_offsets(1) == (0, 0)
    assert window_offsets(3) == (1, 1)
    assert window_offsets(4) == (2, 1)  # one more row/column above/left for even n
    # a single hot pixel spreads to exactly the pixels whose window contains it
    img = np.zeros((9, 9))
    img[4, 4] = 1.0
    out = box_filter(img, 4)
    ys, xs = np.nonzero(out)
    assert (ys.min(), ys.max(), xs.min(), xs.max()) == (3, 6, 3, 6)
    k = window_counts(5, 7, 3)
    assert k[0, 0] == 4 and k[2, 3] == 9 and k[4, 6] == 4 and k[0, 3] == 6
    s = box_sum(np.ones((5, 7)), 3)
    np.testing.assert_array_equal(s, k)


def test_one_pixel_of_each_interleave_set_per_window():
    """With n = M every interior window holds exactly one pixel of each of the M² sets."""
    for M in (2, 3, 4, 5, 6):
        pat = InterleavePattern(M, 29, 23)
        sets = pat.set_index_image()
        lo, hi = window_offsets(M)
        for s in range(pat.n_sets):
            frac = box_filter((sets == s).astype(np.float64), M)
            inner = frac[lo:23 - hi, lo:29 - hi]
            np.testing.assert_allclose(inner, 1.0 / M**2, rtol=1e-14)


# -- numerics: 1e9 dynamic range --------------------------------------------------------

def _hot_image(seed: int, shape=(61, 83)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = 0.5 + rng.random(shape)          # 0.5 … 1.5 lx
    img[20:23, 30:33] = 1e9                # hot spot, 1e9 lx
    img[40, 50] = 3.7e8
    img[10:12, 60] = 1e-3
    return img


@pytest.mark.parametrize("n", [2, 3, 5, 6, 8])
def test_dynamic_range_1e9_is_exact_in_the_dim_part(n):
    img = _hot_image(n)
    ref = exact_mean(img, n)
    out = box_filter(img, n)
    dim = ref < 10.0
    assert dim.sum() > 3000
    assert rel_err(out[dim], ref[dim]) < 1e-12
    assert rel_err(out, ref) < 1e-12
    assert np.all(out >= 0) and not np.isnan(out).any()
    # the test is sensitive: plain running sums leave the expected drift behind
    plain = box_filter(img, n, exact=False)
    assert rel_err(plain[dim], ref[dim]) > 1e-10
    # float32 output: the exact mean, rounded once
    out32 = box_filter(img, n, dtype=np.float32)
    assert rel_err(out32[dim].astype(np.float64), ref[dim]) < 6e-8


def test_dynamic_range_large_float32_image_with_many_hot_spots():
    rng = np.random.default_rng(3)
    img = (rng.gamma(2.0, 0.5, size=(480, 640)) + 1e-3).astype(np.float32)
    spots = rng.integers(0, [480, 640], size=(40, 2))
    img[spots[:, 0], spots[:, 1]] = 1e9
    pixels = [tuple(p) for p in rng.integers(0, [480, 640], size=(1500, 2))]
    for n in (3, 6):
        out = box_filter(img, n, dtype=np.float64)
        ref = exact_mean(img, n, pixels)
        ys, xs = np.array(pixels).T
        assert rel_err(out[ys, xs], ref[ys, xs]) < 1e-12


def test_zero_after_hot_spot_is_zero_not_negative():
    img = np.zeros((40, 40))
    img[5, 5] = 1e9 + 0.1
    img[6, 6] = 1.0 / 3.0
    for exact in (True, False):
        out = box_filter(img, 3, exact=exact)
        assert np.all(out >= 0)
    out = box_filter(img, 3)
    assert np.all(out[10:, :] == 0) and np.all(out[:, 10:] == 0)


def test_non_finite_input_raises_and_masked_nan_is_ignored():
    img = np.ones((10, 10))
    img[3, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        box_filter(img, 3)
    img[3, 3] = np.inf
    with pytest.raises(ValueError, match="NaN"):
        box_filter(img, 3)
    img[3, 3] = np.nan
    w = np.isfinite(img)
    out = box_filter(img, 3, weights=w)
    assert not np.isnan(out).any()
    np.testing.assert_allclose(out, 1.0, rtol=1e-15)


# -- weights ------------------------------------------------------------------------------

def test_weighted_and_masked_variants():
    rng = np.random.default_rng(11)
    img = rng.random((21, 17, 2))
    ones = np.ones((21, 17))
    np.testing.assert_allclose(box_filter(img, 4, weights=ones), box_filter(img, 4),
                               rtol=1e-14)
    mask = rng.random((21, 17)) > 0.6
    mask[:6, :6] = False                      # windows without any valid pixel
    out = box_filter(img, 3, weights=mask, fill=-1.0)
    lo, hi = window_offsets(3)
    for y in range(21):
        for x in range(17):
            sl = (slice(max(y - lo, 0), y + hi + 1), slice(max(x - lo, 0), x + hi + 1))
            m = mask[sl]
            if m.any():
                np.testing.assert_allclose(out[y, x], img[sl][m].mean(axis=0), rtol=1e-13)
            else:
                assert np.all(out[y, x] == -1.0)
    w = rng.random((21, 17))
    out = box_filter(img[..., 0], 2, weights=w)
    num = exact_mean(img[..., 0] * w, 2)
    den = exact_mean(w, 2)
    np.testing.assert_allclose(out, num / den, rtol=1e-13)
    with pytest.raises(ValueError, match="≥ 0"):
        box_filter(img, 3, weights=-ones)


# -- spread (variance) ------------------------------------------------------------------

def test_box_stats_against_numpy():
    rng = np.random.default_rng(5)
    img = rng.random((19, 23)) * 100
    for n, ddof in ((3, 1), (4, 0), (6, 1)):
        mean, var = box_stats(img, n, ddof=ddof)
        lo, hi = window_offsets(n)
        for y in range(19):
            for x in range(23):
                blk = img[max(y - lo, 0):y + hi + 1, max(x - lo, 0):x + hi + 1]
                assert mean[y, x] == pytest.approx(blk.mean(), rel=1e-13)
                want = blk.var(ddof=ddof) if blk.size > ddof else 0.0
                assert var[y, x] == pytest.approx(want, rel=1e-9, abs=1e-12)
    flat_var = box_stats(np.full((8, 8), 0.1), 3)[1]
    assert np.all(flat_var >= 0) and np.max(flat_var) < 1e-15
    np.testing.assert_array_equal(box_stats(img, 1)[1], 0.0)   # one pixel: no spread
    # dim windows next to a 1e9 hot spot keep their spread to ~1e-9 relative
    hot = _hot_image(1)
    _, var = box_stats(hot, 3)
    y, x = 50, 10
    assert var[y, x] == pytest.approx(hot[y - 1:y + 2, x - 1:x + 2].var(ddof=1), rel=1e-9)


def test_argument_checks():
    img = np.ones((5, 5))
    for bad in (0, -1, MAX_N + 1, 2.5):
        with pytest.raises(ValueError):
            box_filter(img, bad)
    with pytest.raises(ValueError):
        box_filter(np.ones(5), 3)
    with pytest.raises(ValueError):
        box_filter(img, 3, dtype=np.int32)
    out = np.empty((5, 5), np.float64)
    assert box_filter(img, 3, out=out) is out
    with pytest.raises(ValueError):
        box_filter(img, 3, out=np.empty((5, 5), np.float32))
    assert box_filter(np.ones((4, 4), np.int64), 3).dtype == np.float64


# -- the paper's claim: M×M interleaved maps of N photons ≈ one map of M²N photons --------

@pytest.mark.parametrize("M", [3, 4])
def test_interleaved_maps_estimate_like_one_big_map(M):
    """Per-pixel photon counts are Poisson (histogram estimator of a Poisson photon map).

    Interleaved: set s's pixels use map s (N photons); the scattered image is box-filtered
    with n = M. Single: every pixel uses one map of M²N photons. Both must have the same
    mean (up to the box average of the smooth irradiance) and the same variance; the
    unfiltered interleaved image must be M² times noisier. Pixels on a stride-M grid have
    disjoint windows, so their estimates are independent and the tolerances follow from
    the sample size P: 5σ with σ(mean z) = 1/√P and σ(var z) = √((2 + κ)/(P − 1)).
    """
    rng = np.random.default_rng(20040621 + M)
    H = W = 240
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)

    def irradiance(yy, xx):  # smooth beam (lx) on a floor
        return 1.0 + 4.0 * np.exp(-(((xx - 140) / 70.0) ** 2 + ((yy - 110) / 55.0) ** 2))

    e = irradiance(y, x)
    total = e.sum()
    mean_count_single = 60.0                      # photons per pixel of the big map
    n_big = mean_count_single * H * W / e.mean()  # M²N
    n_map = n_big / M**2                          # N
    q = e / total                                 # probability a photon lands in a pixel

    pat = InterleavePattern(M, W, H)
    subs = []
    for s in range(pat.n_sets):
        a, b = pat.set_offset(s)
        counts = rng.poisson(n_map * q[b::M, a::M])    # map s, evaluated at its pixels
        subs.append(counts * total / n_map)            # unbiased estimate of e
    interleaved = pat.scatter(subs)
    filtered = box_filter(interleaved, M)
    single = rng.poisson(n_big * q) * total / n_big

    expect_f = box_filter(e, M)                         # E[filtered] exactly
    var_single = e * total / n_big                      # Var of one-map estimate
    var_f = box_filter(e, M) * total / n_big            # (1/M⁴)·Σ e·total/N = same form

    lo, hi = window_offsets(M)
    sel = (slice(M, H - M, M), slice(M, W - M, M))     # disjoint windows
    z_f = ((filtered - expect_f) / np.sqrt(var_f))[sel].ravel()
    z_s = ((single - e) / np.sqrt(var_single))[sel].ravel()
    z_raw = ((interleaved - e) / np.sqrt(var_single))[sel].ravel()
    P = z_f.size
    kappa = 1.0 / (mean_count_single * e.min() / e.mean())   # Poisson excess kurtosis bound
    tol_mean = 5.0 / math.sqrt(P)
    tol_var = 5.0 * math.sqrt((2.0 + kappa) / (P - 1))
    assert P > 3000
    assert abs(z_f.mean()) < tol_mean and abs(z_s.mean()) < tol_mean
    assert abs(z_f.var(ddof=1) - 1.0) < tol_var
    assert abs(z_s.var(ddof=1) - 1.0) < tol_var
    assert abs(z_f.var(ddof=1) - z_s.var(ddof=1)) < math.sqrt(2) * tol_var
    # without the filter the interleaved image is M² times noisier (sensitivity check)
    assert abs(z_raw.var(ddof=1) / M**2 - 1.0) < 0.1
    # "the same": the filtered estimate targets the irradiance at the window centre
    # (half a pixel up-left for even M) up to the box's curvature term
    shift = 0.5 if M % 2 == 0 else 0.0
    centre = irradiance(y - shift, x - shift)
    inner = (slice(lo, H - hi), slice(lo, W - hi))
    assert rel_err(expect_f[inner], centre[inner]) < 1e-3


# -- benchmark command ---------------------------------------------------------------------

def test_bench_filter_command(tmp_path):
    out = tmp_path / "bench.json"
    res = CliRunner().invoke(command, ["--width", "64", "--height", "48", "--repeats", "2",
                                       "--sizes", "3,6", "--json", str(out)])
    assert res.exit_code == 0, res.output
    doc = json.loads(out.read_text())
    methods = {r["method"] for r in doc["rows"]}
    assert {"O(1) exact", "O(1) plain", "O(1) exact par", "naive O(n²)", "scipy"} <= methods
    assert all(r["fps"] > 0 for r in doc["rows"])
    assert "size_spread" in doc["meta"]["O(1) exact"]
