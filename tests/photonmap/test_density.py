"""Density estimates of :class:`lightsim.photonmap.PhotonMap`: accuracy, radius rules, API.

A uniform photon field of known irradiance E₀ = NΦ/A must be recovered by every kernel
within 4σ of the Poisson prediction; min_radius, max_radius, the point focus and the
fixed-radius ("hash") map must follow the documented rules. Units: m, lm, lm/m².
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.photonmap import STRUCTURES, PhotonMap
from lightsim.photonmap.common import R_FLOOR_REL

N_FIELD = 200_000
PHI = 0.005  # lm per photon
K = 64


@pytest.fixture(scope="module")
def field() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Uniform photons on the unit square (z = 0) and 20 × 20 well-separated queries."""
    rng = np.random.default_rng(11)
    pos = np.zeros((N_FIELD, 3), np.float32)
    pos[:, :2] = rng.random((N_FIELD, 2))
    nrm = np.tile(np.float32([0.0, 0.0, 1.0]), (N_FIELD, 1))
    pw = np.full((N_FIELD, 1), PHI, np.float32)
    # r_64 ≈ 0.01 m; queries 0.045 m apart do not share photons: independent estimates
    g = np.linspace(0.05, 0.95, 20)
    qx, qy = np.meshgrid(g, g)
    q = np.stack([qx.ravel(), qy.ravel(), np.zeros(qx.size)], axis=1)
    return pos, nrm, pw, q, N_FIELD * PHI / 1.0  # E₀ in lm/m² (area 1 m²)


def _expected(kernel: str, k: int) -> tuple[float, float]:
    """(mean / E₀, relative std of one estimate) for a Poisson field and r = r_k.

    π r_k² λ ~ Gamma(k): E[1/r_k²] = πλ/(k−1), Var adds 1/(k−2). Given r_k the k−1 inner
    photons are uniform in the disc: box counts k photons (bias k/(k−1)); the cone weight
    1 − d/r has mean 1/3, variance 1/18; Epanechnikov 1 − d²/r² has mean 1/2, variance 1/12
    (both unbiased with their normalisations).
    """
    gamma_var = 1.0 / (k - 2)
    if kernel == "box":
        return k / (k - 1), math.sqrt(gamma_var)
    if kernel == "cone":
        return 1.0, math.sqrt(gamma_var + (1 / 18) / ((k - 1) / 9))
    return 1.0, math.sqrt(gamma_var + (1 / 12) / ((k - 1) / 4))


@pytest.mark.parametrize("kernel", ["box", "cone", "epanechnikov"])
def test_uniform_field_matches_poisson_prediction(field: tuple, kernel: str) -> None:
    pos, nrm, pw, q, e0 = field
    pm = PhotonMap("middle")
    pm.add(pos, nrm, pw)
    res = pm.estimate(q, np.tile([0.0, 0.0, 1.0], (len(q), 1)), k=K, kernel=kernel)
    assert res.E.shape == (len(q), 1) and res.E.dtype == np.float64
    assert (res.count == K).all()
    mean_ratio, rel_std = _expected(kernel, K)
    sigma = e0 * mean_ratio * rel_std / math.sqrt(len(q))
    assert abs(res.E[:, 0].mean() - e0 * mean_ratio) < 4 * sigma
    # the spread of single estimates also follows the prediction (±30 % for 400 samples)
    assert 0.7 < res.E[:, 0].std() / (e0 * mean_ratio * rel_std) < 1.3


def test_all_structures_give_the_same_estimate(field: tuple) -> None:
    pos, nrm, pw, q, _ = field
    qn = np.tile([0.0, 0.0, 1.0], (len(q), 1))
    results = {}
    for structure in ("middle", "median", "grid-lo", "grid-hi"):
        pm = PhotonMap(structure)
        pm.add(pos[:50_000], nrm[:50_000], pw[:50_000])
        results[structure] = pm.estimate(q, qn, k=32, kernel="cone")
    ref = results["middle"]
    for res in results.values():
        np.testing.assert_allclose(res.E, ref.E, rtol=1e-12)
        np.testing.assert_array_equal(res.r, ref.r)
        np.testing.assert_array_equal(res.count, ref.count)


def _brute_counts(pos: np.ndarray, q: np.ndarray, radius: float) -> np.ndarray:
    d2 = ((pos[None, :, :].astype(np.float64) - q[:, None, :]) ** 2).sum(axis=-1)
    return (d2 <= radius * radius).sum(axis=1)


def test_min_radius_switches_to_fixed_radius(field: tuple) -> None:
    pos, nrm, pw, q, _ = field
    pm = PhotonMap("middle")
    pm.add(pos[:20_000], nrm[:20_000], pw[:20_000])
    plain = pm.estimate(q, k=16)
    r_min = 3.0 * float(plain.r.max())
    res = pm.estimate(q, k=16, min_radius=r_min)
    assert np.all(res.r == r_min)
    counts = _brute_counts(pos[:20_000], q, r_min)
    np.testing.assert_array_equal(res.count, counts)
    np.testing.assert_allclose(res.E[:, 0], counts * PHI / (math.pi * r_min**2), rtol=1e-6)
    # a floor below every r_k changes nothing
    low = pm.estimate(q, k=16, min_radius=0.5 * float(plain.r.min()))
    np.testing.assert_array_equal(low.E, plain.E)
    np.testing.assert_array_equal(low.r, plain.r)


def test_max_radius_caps_r_and_keeps_all_inside(field: tuple) -> None:
    pos, nrm, pw, q, _ = field
    pm = PhotonMap("middle")
    pm.add(pos[:5_000], nrm[:5_000], pw[:5_000])
    r_max = 0.01  # ≈ 1.6 photons expected inside: fewer than k everywhere
    res = pm.estimate(q, k=K, max_radius=r_max, kernel="box")
    assert np.all(res.r == r_max)
    counts = _brute_counts(pos[:5_000], q, r_max)
    np.testing.assert_array_equal(res.count, counts)
    np.testing.assert_allclose(res.E[:, 0], counts * PHI / (math.pi * r_max**2), rtol=1e-6)
    assert (res.E[counts == 0] == 0).all()


def test_fewer_photons_than_k_uses_farthest() -> None:
    pos = np.float32([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.5, 0.0]])
    pm = PhotonMap("middle")
    pm.add(pos, powers=np.ones(3))
    res = pm.estimate(np.zeros((1, 3)), k=10)
    assert res.count[0] == 3
    assert res.r[0] == pytest.approx(0.5)
    assert res.E[0, 0] == pytest.approx(3.0 / (math.pi * 0.25))


@pytest.mark.parametrize("structure", ["middle", "median", "grid-hi"])
def test_point_focus_gives_capped_value(structure: str) -> None:
    n = 200_000
    focus = np.float32([0.2, -1.5, 25.0])
    pos = np.tile(focus, (n, 1))
    pm = PhotonMap(structure)
    pm.add(pos, np.tile(np.float32([0, 0, -1]), (n, 1)), np.full(n, PHI, np.float32))
    q = np.array([focus, focus + [0.004, 0.0, 0.0], focus + [0.5, 0.0, 0.0]], np.float64)
    qn = np.tile([0.0, 0.0, -1.0], (3, 1))
    r_min = 0.01
    res = pm.estimate(q, qn, k=K, min_radius=r_min)
    capped = n * float(np.float32(PHI)) / (math.pi * r_min**2)  # Φ is stored as float32
    np.testing.assert_allclose(res.E[:2, 0], capped, rtol=1e-9)
    assert res.r[0] == r_min and res.count[0] == n
    # 0.5 m away: the k nearest (all tied) lie at r_k = 0.5 m > min_radius; the k-th on the
    # circle counts half in the box sum
    assert res.r[2] == pytest.approx(0.5, rel=1e-6) and res.count[2] == K
    assert res.E[2, 0] == pytest.approx((K - 0.5) * PHI / (math.pi * 0.25), rel=1e-5)
    # without a floor the estimate is still finite: r never drops below r_floor
    bare = pm.estimate(q[:1], qn[:1], k=K)
    floor = R_FLOOR_REL * 25.0
    assert np.isfinite(bare.E).all() and bare.r[0] == pytest.approx(floor)


@pytest.mark.slow
def test_ten_million_coincident_photons_stay_finite() -> None:
    n = 10_000_000
    pm = PhotonMap("middle")
    pm.add(np.zeros((n, 3), np.float32), powers=np.ones(n, np.float32))
    res = pm.estimate(np.zeros((2, 3)), k=K)
    assert np.isfinite(res.E).all() and (res.E > 0).all()
    assert res.count[0] == n


def test_normal_filter_blocks_light_through_a_wall() -> None:
    rng = np.random.default_rng(12)
    front = rng.random((20_000, 3)).astype(np.float32)
    front[:, 2] = 0.0
    back = front.copy()
    back[:, 2] = 0.001  # 1 mm behind: a thin wall lit from both sides
    pos = np.concatenate([front, back])
    nrm = np.zeros_like(pos)
    nrm[:20_000, 2] = 1.0
    nrm[20_000:, 2] = -1.0
    pw = np.concatenate([np.full(20_000, 1.0), np.full(20_000, 100.0)]).astype(np.float32)
    pm = PhotonMap("middle")
    pm.add(pos, nrm, pw)
    q = np.array([[0.5, 0.5, 0.0], [0.3, 0.6, 0.0]])
    lit = pm.estimate(q, np.tile([0.0, 0.0, 1.0], (2, 1)), k=32)
    back_side = pm.estimate(q, np.tile([0.0, 0.0, -1.0], (2, 1)), k=32)
    unfiltered = pm.estimate(q, k=32)
    assert np.all(back_side.E > 50 * lit.E)
    assert np.all(unfiltered.E > 2 * lit.E)


def test_hash_map_is_a_fixed_radius_estimate(field: tuple) -> None:
    pos, nrm, pw, q, _ = field
    pm = PhotonMap("hash")
    pm.add(pos[:30_000], nrm[:30_000], pw[:30_000])
    pm.add(pos[30_000:40_000], nrm[30_000:40_000], pw[30_000:40_000])
    assert len(pm) == 40_000
    radius = 0.02
    res = pm.estimate(q, np.tile([0.0, 0.0, 1.0], (len(q), 1)), max_radius=radius, k=999)
    counts = _brute_counts(pos[:40_000], q, radius)
    np.testing.assert_array_equal(res.count, counts)
    assert np.all(res.r == radius)
    np.testing.assert_allclose(res.E[:, 0], counts * PHI / (math.pi * radius**2), rtol=1e-6)
    with pytest.raises(InputError, match="finite max_radius"):
        pm.estimate(q)


def test_multi_channel_powers() -> None:
    rng = np.random.default_rng(13)
    pos = rng.random((5_000, 3)).astype(np.float32)
    pw = rng.random((5_000, 3)).astype(np.float32)
    pm = PhotonMap("middle", channels=3)
    pm.add(pos, powers=pw)
    assert pm.n_channels == 3 and len(pm) == 5_000 and pm.structure == "middle"
    q = rng.random((50, 3))
    res = pm.estimate(q, k=20)
    single = [PhotonMap("middle") for _ in range(3)]
    for c, m in enumerate(single):
        m.add(pos, powers=pw[:, c])
        np.testing.assert_allclose(res.E[:, c], m.estimate(q, k=20).E[:, 0], rtol=1e-12)


def test_empty_map_estimates_zero() -> None:
    for structure in STRUCTURES:
        pm = PhotonMap(structure)
        res = pm.estimate(np.zeros((4, 3)), k=8, max_radius=1.0)
        assert (res.E == 0).all() and (res.count == 0).all() and res.E.shape == (4, 1)


@pytest.mark.parametrize("kwargs, message", [
    ({"kernel": "gauss"}, "unknown kernel"),
    ({"k": 0}, "k must be"),
    ({"min_radius": 2.0, "max_radius": 1.0}, "exceeds max_radius"),
    ({"max_radius": -1.0}, "max_radius"),
    ({"min_radius": float("nan")}, "min_radius"),
])
def test_bad_parameters_raise_input_error(kwargs: dict, message: str) -> None:
    pm = PhotonMap("middle")
    pm.add(np.zeros((3, 3), np.float32))
    with pytest.raises(InputError, match=message):
        pm.estimate(np.zeros((1, 3)), **kwargs)


def test_bad_inputs_raise_input_error() -> None:
    with pytest.raises(InputError, match="unknown photon-map structure"):
        PhotonMap("octree")
    pm = PhotonMap("middle")
    pm.add(np.zeros((3, 3), np.float32), np.tile(np.float32([0, 0, 1]), (3, 1)))
    with pytest.raises(InputError, match="normals missing"):
        pm.add(np.zeros((2, 3), np.float32))
    with pytest.raises(InputError, match="zero length"):
        pm.add(np.zeros((2, 3), np.float32), np.zeros((2, 3), np.float32))
    with pytest.raises(InputError, match="negative power"):
        pm.add(np.zeros((2, 3), np.float32), np.ones((2, 3)), -np.ones(2))
    with pytest.raises(InputError, match="query points: 1 of 2"):
        pm.estimate(np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]]))
    with pytest.raises(InputError, match="query normals given"):
        plain = PhotonMap("middle")
        plain.add(np.zeros((3, 3), np.float32))
        plain.estimate(np.zeros((1, 3)), np.ones((1, 3)))
