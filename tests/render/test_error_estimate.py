"""The error estimate (noise + blur bias) from the interleave sets' probes and windows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.render.frame import luminous, probe_error, probe_stats
from lightsim.validation.converge import analytic_target, error_metrics, lit_mask
from lightsim.validation.scenes import analytic as an


def _sets(truth: np.ndarray, offset: np.ndarray, sd: float, S: int, seed: int
          ) -> dict[int, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {s: (truth + offset + rng.normal(0, sd, truth.shape))[:, None] for s in range(S)}


def test_bias_and_noise_recovered_from_synthetic_sets():
    G, S = 4000, 16
    truth = np.full(G, 100.0)
    bias = np.where(np.arange(G) % 2 == 0, 3.0, -3.0)  # ±3 %: rms bias 3 %
    probes = _sets(truth, bias, 5.0, S, 1)       # kNN: biased, noise 5 % per set
    windows = _sets(truth, 0.0, 20.0, S, 2)      # windows: unbiased, 4× noisier
    err = probe_error(probe_stats(probes, windows), G)
    assert err.noise == pytest.approx(0.05 / math.sqrt(S), rel=0.05)
    assert err.bias == pytest.approx(0.03, rel=0.1)
    assert err.total == pytest.approx(math.hypot(err.noise, err.bias))


def test_no_bias_reads_as_nearly_none():
    G, S = 4000, 16
    truth = np.linspace(50.0, 150.0, G)
    err = probe_error(probe_stats(_sets(truth, 0.0, 5.0, S, 3),
                                  _sets(truth, 0.0, 20.0, S, 4)), G)
    # the windows' noise is subtracted; what is left is the estimate's own scatter,
    # about (2/G)^¼ × the difference's standard error (0.8 % here), far below 5 %
    assert err.bias < 0.015


def test_one_set_or_nothing_lit_gives_none():
    one = {0: np.ones((10, 1))}
    assert probe_error(probe_stats(one, one), 10) is None
    dark = {s: np.zeros((10, 1)) for s in range(4)}
    assert probe_error(probe_stats(dark, dark), 10) is None


@pytest.mark.parametrize("estimator,bandwidth", [("knn", "knn"), ("knn", "ici"),
                                                 ("bin", "ici")])
def test_estimate_is_honest_on_the_paraboloid(estimator, bandwidth):
    """Against the exact answer: the estimated error is within a factor 2 of the actual
    one (noise alone underestimates the r_k map's error several times, as r_k blurs the
    rim of the reflected beam); the default (ICI) map within 0.8–1.25."""
    target = analytic_target("paraboloid")
    cfg = RunConfig(seed=1, interleave=4, estimator=estimator, spt=False,
                    frame_photons=50_000, bandwidth=bandwidth)
    with Session(target.scene, cfg) as s:
        est = s.run(photons=1_000_000)
    truth = target.truth
    actual = error_metrics(luminous(est.lux), truth, lit_mask(truth))["rel_rmse"]
    assert 0.5 * actual < est.rel_error < 2.0 * actual
    if estimator == "bin":
        assert est.error.bias is None  # pixel bins carry no blur
    elif bandwidth == "knn":
        assert est.error.bias > est.error.noise  # blur dominates at this photon count
    else:
        assert 0.8 * actual <= est.rel_error <= 1.25 * actual
        if not est.rungs.any():  # it fell back to the pixel counts: noise only
            assert est.error.bias == 0.0


def test_windows_measure_the_pixel_mean():
    """The pixel windows at the grid probes are unbiased estimates of E there."""
    case = an.isotropic_case()
    cfg = RunConfig(seed=2, interleave=2, estimator="knn", bandwidth="knn",
                    frame_photons=250_000)  # the windows are the kNN figure's store
    with Session(case.scene, cfg) as s:
        est = s.run(photons=1_000_000)
        hv = s.probes_hv[:s.grid_count]
        dh, dv = case.scene.wall.pixel_size_m
    mean = luminous(est.probes.windows).mean(axis=0)  # (G,) lx
    exact = case.exact(hv[:, 0], hv[:, 1])
    # photons counted over all windows: the relative error of their sum is 1/√count
    count = mean.sum() * dh * dv * est.photons / case.flux
    assert abs(mean.sum() / exact.sum() - 1) < 4 / math.sqrt(count)
    # and where: bright where E is bright (cos³θ falls off towards the wall's corners)
    inner = np.hypot(hv[:, 0], hv[:, 1]) < 1.0
    outer = np.hypot(hv[:, 0], hv[:, 1]) > 2.0
    ratio = mean[inner].mean() / mean[outer].mean()
    assert ratio == pytest.approx(exact[inner].mean() / exact[outer].mean(), rel=0.05)


def test_unresolved_blur_is_reported_as_a_bound():
    """Windows much noisier than the bias: the point estimate may read 0, the bound not."""
    G, S = 600, 16
    truth = np.full(G, 100.0)
    err = probe_error(probe_stats(_sets(truth, 1.0, 5.0, S, 5),
                                  _sets(truth, 0.0, 150.0, S, 6)), G)
    assert err.bias_upper > 0.05  # 150 % window noise: blur below ~5 % is invisible
    assert not err.bias_resolved and "not resolved" in err.describe()
    clear = probe_error(probe_stats(_sets(truth, 10.0, 5.0, S, 7),
                                    _sets(truth, 0.0, 20.0, S, 8)), G)
    assert clear.bias_resolved and "blur 9." in clear.describe()  # 10 lx of 110 lx
