"""Detector apertures: exact solid angles, direct photon counts, aiming strips, Imax raster."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from lightsim.engine.apertures import (
    ApertureCounter,
    ApertureLayout,
    count_interval,
    intensities,
    raster_tiles,
    rect_solid_angle,
)

D = 25.0


def _omega_numeric(h0, h1, v0, v1):
    """∫∫ dΩ over the wall rectangle between wall angles, numerically (scipy)."""
    def f(v, h):
        th, tv = math.tan(math.radians(h)), math.tan(math.radians(v))
        return ((1 + th * th) * (1 + tv * tv) / (1 + th * th + tv * tv) ** 1.5
                * math.radians(1) ** 2)
    return integrate.dblquad(f, h0, h1, v0, v1, epsabs=1e-14, epsrel=1e-11)[0]


@pytest.mark.parametrize("rect", [(-0.075, 0.075, -0.075, 0.075), (10, 10.15, -3, -2.85),
                                  (-40, 20, 5, 30), (0, 1e-6, 0, 1e-6)])
def test_rect_solid_angle_matches_quadrature(rect):
    exact = float(rect_solid_angle(*rect))
    assert exact == pytest.approx(_omega_numeric(*rect), rel=1e-8)


def test_whole_hemisphere_limit():
    # a huge rectangle approaches the half space: 2π sr
    assert float(rect_solid_angle(-89.9999, 89.9999, -89.9999, 89.9999)) == pytest.approx(
        2 * math.pi, rel=1e-4)


def _wall(h_deg, v_deg):
    return D * np.tan(np.radians(h_deg)), D * np.tan(np.radians(v_deg))


def test_counter_counts_exactly_the_photons_inside():
    lay = ApertureLayout([0.0, 3.0], [0.0, -1.0], 0.2, D)
    c = ApertureCounter(lay, 1)
    rng = np.random.default_rng(4)
    h = rng.uniform(-1, 4, 50_000)
    v = rng.uniform(-2, 1, 50_000)
    p = rng.uniform(0.5, 2.0, (50_000, 1))
    c.add(*_wall(h, v), p)
    for k, (hc, vc) in enumerate([(0.0, 0.0), (3.0, -1.0)]):
        inside = (h >= hc - 0.1) & (h < hc + 0.1) & (v >= vc - 0.1) & (v < vc + 0.1)
        # ties at the half-open edges are measure zero for random angles
        assert c.counts[k, 0] == pytest.approx(p[inside, 0].sum(), rel=1e-12)
        assert c.counts[k, 1] == pytest.approx((p[inside, 0] ** 2).sum(), rel=1e-12)


def test_point_source_intensity_is_unbiased():
    """Isotropic point source (I = Φ/4π): directions sampled on the sphere, counted."""
    lay = ApertureLayout([0.0, 12.0, -5.0], [0.0, 4.0, -2.0], 0.5, D)
    rng = np.random.default_rng(7)
    S, n = 8, 400_000
    counts, emitted = [], []
    for _ in range(S):
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        fwd = d[:, 2] > 0
        h, v = -d[fwd, 0] / d[fwd, 2] * D, d[fwd, 1] / d[fwd, 2] * D  # H is world −X
        c = ApertureCounter(lay, 1)
        c.add(h, v, np.full((fwd.sum(), 1), 1000.0))  # Φ = 1000 lm per photon
        counts.append(c.counts)
        emitted.append(n)
    cd = intensities(np.stack(counts), np.array(emitted), lay)[..., 0]
    mean = cd.mean(axis=0)
    se = cd.std(axis=0, ddof=1) / math.sqrt(S)
    assert np.all(np.abs(mean - 1000 / (4 * math.pi)) < 4.5 * se)


def test_strip_shift_equals_a_moved_aperture():
    lay = ApertureLayout([1.0], [-0.5], 0.15, D, shift_deg=0.6, substeps=5)
    moved = ApertureLayout([1.0], [-0.5 + 0.33], 0.15, D)
    rng = np.random.default_rng(2)
    h, v = rng.uniform(0.5, 1.5, 200_000), rng.uniform(-1.5, 0.5, 200_000)
    a, b = ApertureCounter(lay, 1), ApertureCounter(moved, 1)
    for c in (a, b):
        c.add(*_wall(h, v), np.ones((len(h), 1)))
    k, applied = lay.quantize_shift(0.33)
    assert k == 11
    assert applied == pytest.approx(0.33)
    ia = intensities(a.counts[None], [1], lay, 0.33)
    ib = intensities(b.counts[None], [1], moved, 0.0)
    assert ia[0, 0, 0] == pytest.approx(ib[0, 0, 0], rel=1e-9)
    with pytest.raises(ValueError, match="exceeds"):
        lay.quantize_shift(0.7)


def test_raster_tiles_find_the_peak_and_agree_with_apertures():
    lay = ApertureLayout([0.6], [-1.2], 0.2, D, substeps=2, raster=(-2, 2, -3, 1))
    rng = np.random.default_rng(3)
    n = 300_000
    h = rng.normal(0.6, 0.5, n)
    v = rng.normal(-1.2, 0.4, n)
    c = ApertureCounter(lay, 1)
    c.add(*_wall(h, v), np.ones((n, 1)))
    t = raster_tiles(c.counts[None], [n], lay)
    i, k = np.unravel_index(np.argmax(t.values[0, :, :, 0]), t.values.shape[1:3])
    assert abs(t.h_deg[i] - 0.6) <= 0.3 and abs(t.v_deg[k] + 1.2) <= 0.3
    # the raster tile centred exactly on the test aperture counts the same photons
    ii = int(np.argmin(np.abs(t.h_deg - 0.7)))
    kk = int(np.argmin(np.abs(t.v_deg + 1.2)))
    direct = ApertureLayout([t.h_deg[ii]], [t.v_deg[kk]], 0.2, D)
    cd = ApertureCounter(direct, 1)
    cd.add(*_wall(h, v), np.ones((n, 1)))
    assert t.values[0, ii, kk, 0] == pytest.approx(
        intensities(cd.counts[None], [n], direct)[0, 0, 0], rel=1e-9)


def test_count_interval_poisson_limits_and_empty_aperture():
    lay = ApertureLayout([0.0, 5.0], [0.0, 0.0], 0.2, D)
    counts = np.zeros((4, 2, 2))
    counts[0, 0] = [3.0, 3.0]  # three photons of power 1 in set 0, none elsewhere
    n_eff, lo, hi = count_interval(counts, np.full(4, 100.0), np.full((4, 1), 100.0), lay)
    omega = lay.solid_angles()
    assert n_eff[0] == pytest.approx(3.0) and n_eff[1] == 0.0
    q = 1.0 / (4 * 100 * omega[0])  # one photon's share of the mean over 4 sets
    # mid-p 95 % bounds for n = 3, checked on the Poisson law itself (scipy.stats)
    from scipy.stats import poisson

    mu_lo, mu_hi = lo[0] / q, hi[0] / q
    assert poisson.sf(3, mu_lo) + 0.5 * poisson.pmf(3, mu_lo) == pytest.approx(0.025, abs=1e-9)
    assert poisson.cdf(3, mu_hi) - 0.5 * poisson.pmf(3, mu_hi) == pytest.approx(0.025, abs=1e-9)
    assert 0.6 < mu_lo < 1.0 and 7.0 < mu_hi < 8.8   # inside the exact (Garwood) interval
    # nothing caught: [0, −ln 0.05 = 3.0 average photons]
    assert lo[1] == 0.0 and hi[1] * 4 * 100 * omega[1] == pytest.approx(-math.log(0.05))


def test_empty_and_bad_layouts():
    lay = ApertureLayout([], [], 0.15, D)
    c = ApertureCounter(lay, 3)
    assert c.add(np.zeros(5), np.zeros(5), np.ones((5, 3))).sum() == 0
    for kw in ({"size_deg": 0.0}, {"size_deg": math.nan}, {"shift_deg": -1.0}):
        with pytest.raises(ValueError):
            ApertureLayout([0.0], [0.0], **{"size_deg": 0.15, "distance_m": D, **kw})
    with pytest.raises(ValueError):
        ApertureLayout([math.nan], [0.0], 0.15, D)


# ---- Selective Photon Tracing aimed at test points ---------------------------------------
def test_refine_share_keeps_every_cell_at_its_exact_share():
    from lightsim.sampling import SelectiveSampler

    sp = SelectiveSampler(3, 0, pass_photons=20_000, refine_share=0.5)
    _, idx, _pts, w = sp.next_pass()           # nothing refined yet: plain stratified
    assert np.allclose(w, 1.0)
    trigger = np.zeros(len(idx), bool)
    trigger[:40] = True                        # a few photons landed near a target
    sp.update(idx, trigger)
    refined = np.unique(idx[:40] % sp.n_cells)
    _, idx2, _, w2 = sp.next_pass()
    cells = idx2 % sp.n_cells
    share = np.bincount(cells, weights=w2, minlength=sp.n_cells) / w2.sum()
    np.testing.assert_allclose(share, 1.0 / sp.n_cells, rtol=1e-12)  # unbiased weights
    per_cell = np.bincount(cells, minlength=sp.n_cells)
    assert per_cell[refined].min() > 10 * np.delete(per_cell, refined).max()
    assert len(idx2) <= 20_000 and len(idx2) > 0.95 * 20_000
    # the refinement follows the last pass only: no trigger, no refined cell
    sp.update(idx2, np.zeros(len(idx2), bool))
    assert not sp.refined.any()


def test_spt_on_points_concentrates_photons_and_stays_unbiased(tmp_path):
    from lightsim.luminaires.photometric import write_ies
    from lightsim.validation.coverage import run_lamp, synthetic_lamp

    grid, _ = synthetic_lamp(np.random.default_rng(11))
    path = tmp_path / "lamp.ies"
    write_ies(path, grid)
    plain = run_lamp(path, 300_000, quad=16)
    spt = run_lamp(path, 300_000, spt=True, quad=16)
    i = plain.names.index("B50L")
    assert spt.n_eff[i] > 2 * plain.n_eff[i]      # more photons where they are few
    for run in (plain, spt):
        # the well-lit points: errors in units of the half-width (≈ 0.4 on average for a
        # calibrated unbiased 95 % interval; a bias of one half-width would show as ≥ 1)
        z = []
        for name in ("75R", "50R", "50V", "50L", "25L", "25R"):
            k = run.names.index(name)
            lo, hi = run.interval_cd[k]
            z.append(abs(run.per_set_cd[:, k].mean() - run.truth_cd[k]) / (0.5 * (hi - lo)))
        assert np.mean(z) < 1.0, z
