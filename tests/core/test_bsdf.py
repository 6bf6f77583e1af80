"""BSDF kernels (lightsim.materials), called through :func:`scatter` as the tracer calls
them: energy, Fresnel limits, TIR, reciprocity, grazing angles and degenerate normals, one
kind at a time, against closed forms; and one bounce of the tracer equals the kernel's."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from lightsim.materials import (
    DIELECTRIC,
    DIFFUSE,
    MIRROR,
    WALL,
    Material,
    MaterialTable,
    fresnel_dielectric,
    scatter,
)
from lightsim.sampling import photon_keys
from lightsim.scene import SURFACE, Part, Scene
from lightsim.tracer import LEDGER, PhotonTracer
from lightsim.validation.scenes import primitives as prim

N = 20_000


def table(kind: int, value: float = 1.0, ior: float = 1.5, sigma: float = 0.0):
    m = Material("m", kind, np.full(3, value), ior, np.full(3, sigma))
    return MaterialTable.build([m], channels=1).arrays


def unit(*v: float) -> tuple[float, float, float]:
    a = np.asarray(v, float)
    a = a / np.linalg.norm(a)
    return float(a[0]), float(a[1]), float(a[2])


@njit(cache=False)
def _run(kind, mats, d, ng, ns, front, t, keys):
    """One :func:`scatter` per photon i (incident direction d[i], key keys[i], counter 0):
    unit outgoing directions, sides, power after and the flux the surface took."""
    n = keys.shape[0]
    out = np.empty((n, 3))
    side = np.empty(n)
    power = np.ones((n, 1))
    ledger = np.zeros((n, 1, 1))
    for i in range(n):
        wx, wy, wz, s = scatter(kind, mats, 0, (d[i, 0], d[i, 1], d[i, 2]), ng, ns, front, t,
                                keys[i], np.uint64(0), power, i, ledger, i, 0)
        ln = math.sqrt(wx * wx + wy * wy + wz * wz)
        out[i, 0], out[i, 1], out[i, 2] = wx / ln, wy / ln, wz / ln
        side[i] = s
    return out, side, power[:, 0], ledger[:, 0, 0]


def run(kind, mats, d, ng, ns=None, front=True, t=0.0, n=N):
    keys = np.arange(n, dtype=np.uint64) * np.uint64(7919) + np.uint64(1)
    return _run(kind, mats, np.tile(np.asarray(d, float), (n, 1)), ng, ng if ns is None else ns,
                front, t, keys)


UP = (0.0, 0.0, 1.0)


# -- diffuse ------------------------------------------------------------------------------

@pytest.mark.parametrize("rho", [0.0, 0.3, 1.0])
def test_diffuse_energy_and_cosine_lobe(rho):
    d = unit(0.3, 0.1, -1.0)
    w, side, p, loss = run(DIFFUSE, table(DIFFUSE, rho), d, UP)
    np.testing.assert_allclose(p + loss, 1.0, rtol=0, atol=1e-15)  # every lumen booked
    np.testing.assert_allclose(p, rho, rtol=0, atol=1e-15)
    assert np.all(side == 1.0)
    cos = w[:, 2]
    assert cos.min() >= 0.0  # reflection only, on the side the photon came from
    # cosine lobe: E[cos θ] = 2/3, E[cos² θ] = 1/2
    assert cos.mean() == pytest.approx(2 / 3, abs=4 * math.sqrt(1 / 18 / N))
    assert (cos ** 2).mean() == pytest.approx(0.5, abs=4 * math.sqrt(1 / 12 / N))


def test_diffuse_ignores_the_incident_direction_and_any_normal_orientation():
    for ng in (UP, unit(1, 1, 1), (0.0, 0.0, -1.0), unit(1e-30, 0, -1)):
        w, *_ = run(DIFFUSE, table(DIFFUSE, 0.5), unit(0, 0, -1), ng, n=2000)
        assert (w @ np.asarray(ng)).min() >= 0.0


# -- mirror -------------------------------------------------------------------------------

@pytest.mark.parametrize("R", [0.0, 0.88, 1.0])
def test_mirror_energy_and_law_of_reflection(R):
    d = unit(0.4, -0.2, -1.0)
    w, side, p, loss = run(MIRROR, table(MIRROR, R), d, UP, n=10)
    np.testing.assert_allclose(p + loss, 1.0, atol=1e-15)
    np.testing.assert_allclose(p, R, atol=1e-15)
    np.testing.assert_allclose(w, np.tile([d[0], d[1], -d[2]], (10, 1)), atol=1e-15)
    assert np.all(side == 1.0)


def test_mirror_is_reciprocal():
    mats = table(MIRROR, 1.0)
    n = unit(0.1, 0.2, 1.0)
    d = unit(0.5, -0.3, -1.0)
    w, *_ = run(MIRROR, mats, d, n, n=1)
    back, *_ = run(MIRROR, mats, tuple(-w[0]), n, n=1)  # the reversed path
    np.testing.assert_allclose(back[0], -np.asarray(d), atol=1e-14)


def test_mirror_grazing_and_bent_shading_normal_stay_above_the_surface():
    mats = table(MIRROR, 1.0)
    graze = unit(1.0, 0.0, -1e-9)
    w, *_ = run(MIRROR, mats, graze, UP, n=1)
    assert w[0, 2] > 0.0 and w[0, 0] == pytest.approx(1.0)
    # a shading normal tilted so far that the mirror image would go through the surface:
    # the kernel reflects about the geometric normal instead
    ns = unit(1.0, 0.0, 0.05)
    w, *_ = run(MIRROR, mats, unit(1.0, 0.0, -0.2), UP, ns, n=1)
    assert w[0, 2] > 0.0
    np.testing.assert_allclose(w[0], unit(1.0, 0.0, 0.2), atol=1e-14)


# -- dielectric ---------------------------------------------------------------------------

def test_fresnel_normal_incidence_and_brewster():
    for n in (1.33, 1.5, 2.4):
        assert fresnel_dielectric(1.0, 1.0, n) == pytest.approx(((n - 1) / (n + 1)) ** 2,
                                                                rel=1e-14)
        assert fresnel_dielectric(1.0, n, 1.0) == pytest.approx(((n - 1) / (n + 1)) ** 2,
                                                                rel=1e-14)
        tb = math.atan(n)  # Brewster: p-polarised reflectance vanishes, F = rs²/2
        ct = math.cos(math.asin(math.sin(tb) / n))
        rs = (math.cos(tb) - n * ct) / (math.cos(tb) + n * ct)
        assert fresnel_dielectric(math.cos(tb), 1.0, n) == pytest.approx(0.5 * rs * rs,
                                                                         rel=1e-12)
    assert fresnel_dielectric(0.0, 1.0, 1.5) == 1.0  # grazing: all reflected
    assert fresnel_dielectric(1e-12, 1.0, 1.5) == pytest.approx(1.0, abs=1e-11)


def test_fresnel_reciprocity_and_total_internal_reflection():
    n = 1.5
    for theta_i in np.radians([0, 10, 30, 41, 60, 85]):
        theta_t = math.asin(math.sin(theta_i) / n)
        assert fresnel_dielectric(math.cos(theta_i), 1.0, n) == pytest.approx(
            fresnel_dielectric(math.cos(theta_t), n, 1.0), rel=1e-12)
    crit = math.asin(1 / n)
    assert fresnel_dielectric(math.cos(crit + 1e-9), n, 1.0) == 1.0
    assert fresnel_dielectric(math.cos(crit - 1e-3), n, 1.0) < 1.0


@pytest.mark.parametrize("deg", [0.0, 45.0, 56.31])
def test_dielectric_reflects_with_the_fresnel_probability_and_refracts_by_snell(deg):
    n = 1.5
    th = math.radians(deg)
    d = (math.sin(th), 0.0, -math.cos(th))
    w, side, p, loss = run(DIELECTRIC, table(DIELECTRIC, ior=n), d, UP)
    np.testing.assert_array_equal(p, 1.0)  # the choice is the weighting: flux unchanged
    np.testing.assert_array_equal(loss, 0.0)
    F = fresnel_dielectric(math.cos(th), 1.0, n)
    refl = side == 1.0
    assert refl.mean() == pytest.approx(F, abs=4 * math.sqrt(F * (1 - F) / N) + 1e-12)
    np.testing.assert_allclose(w[refl], np.tile([d[0], 0, -d[2]], (refl.sum(), 1)),
                               atol=1e-14)
    t = w[~refl]
    assert np.all(side[~refl] == -1.0) and np.all(t[:, 2] < 0)
    np.testing.assert_allclose(np.hypot(t[:, 0], t[:, 1]), math.sin(th) / n, atol=1e-14)


def test_dielectric_total_internal_reflection_from_inside():
    n = 1.5
    th = math.asin(1 / n) + 0.01  # just beyond the critical angle, inside the glass
    d = (math.sin(th), 0.0, math.cos(th))  # travelling out through the face z = 0
    # from inside the photon meets the back of the face: the facing normal points down
    w, side, p, _ = run(DIELECTRIC, table(DIELECTRIC, ior=n), d, (0.0, 0.0, -1.0), front=False)
    assert np.all(side == 1.0)
    np.testing.assert_allclose(w, np.tile([d[0], 0, -d[2]], (N, 1)), atol=1e-14)
    np.testing.assert_array_equal(p, 1.0)


def test_dielectric_refraction_is_reversible():
    n = 1.5
    th = math.radians(35.0)
    d = (math.sin(th), 0.0, -math.cos(th))
    w, side, *_ = run(DIELECTRIC, table(DIELECTRIC, ior=n), d, UP, n=200)
    t = w[side == -1.0][0]
    # back along the refracted ray from inside: it leaves along the reversed incident ray
    w2, side2, *_ = run(DIELECTRIC, table(DIELECTRIC, ior=n), tuple(-t), (0.0, 0.0, -1.0),
                        front=False, n=200)
    np.testing.assert_allclose(w2[side2 == -1.0][0], -np.asarray(d), atol=1e-14)


def test_dielectric_beer_lambert_inside_only():
    mats = table(DIELECTRIC, ior=1.5, sigma=20.0)
    d = unit(0, 0, 1)
    _, _, p, loss = run(DIELECTRIC, mats, d, (0.0, 0.0, -1.0), front=False, t=0.01, n=10)
    np.testing.assert_allclose(p, math.exp(-0.2), rtol=1e-14)
    np.testing.assert_allclose(p + loss, 1.0, rtol=1e-15)
    _, _, p, loss = run(DIELECTRIC, mats, unit(0, 0, -1), UP, front=True, t=0.01, n=10)
    np.testing.assert_array_equal(loss, 0.0)  # arriving from air: nothing absorbed


def test_dielectric_degenerate_shading_normal_uses_the_geometry():
    n = 1.5
    d = unit(0.3, 0.0, -1.0)
    away = unit(1.0, 0.0, -0.5)  # a shading normal facing away from the light
    w, side, *_ = run(DIELECTRIC, table(DIELECTRIC, ior=n), d, UP, away, n=4000)
    w_ref, side_ref, *_ = run(DIELECTRIC, table(DIELECTRIC, ior=n), d, UP, UP, n=4000)
    np.testing.assert_allclose(w, w_ref, atol=1e-15)
    np.testing.assert_array_equal(side, side_ref)
    # grazing incidence: almost everything reflects, nothing goes through the surface
    w, side, *_ = run(DIELECTRIC, table(DIELECTRIC, ior=n), unit(1.0, 0.0, -1e-7), UP, n=4000)
    assert (side == 1.0).mean() > 0.999
    assert np.all(w[side == 1.0][:, 2] > 0) and np.all(w[side == -1.0][:, 2] < 0)


# -- wall detector ------------------------------------------------------------------------

def test_wall_detects_everything_and_ends_the_photon():
    _, side, p, loss = run(WALL, table(DIFFUSE, 0.8), unit(0.1, 0, 1), (0.0, 0.0, -1.0), n=5)
    np.testing.assert_array_equal(side, 0.0)
    np.testing.assert_array_equal(p, 0.0)
    np.testing.assert_array_equal(loss, 1.0)


# -- the tracer's bounce is the kernel's --------------------------------------------------

def _plane(material: Material) -> Part:
    """The square z = 0, |x|, |y| ≤ 1, front face +Z (geometric normal exactly (0, 0, 1))."""
    verts = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
    return Part("plane", SURFACE, verts, np.array([[0, 1, 2], [0, 2, 3]]), None, material)


@pytest.mark.parametrize("material, below", [
    (Material("m", DIFFUSE, np.full(3, 0.6)), False),
    (Material("m", MIRROR, np.full(3, 0.85)), False),
    (Material("m", DIELECTRIC, np.ones(3), 1.5), False),
    (Material("m", DIELECTRIC, np.ones(3), 1.5, np.full(3, 4.0)), True),
])
def test_one_bounce_of_the_tracer_equals_the_kernel(material, below):
    """Photons hit the plane once and escape: their escaped flux, direction and the ledger
    are the kernel's, bit for bit (same random numbers, same floating-point operations)."""
    n = 2000
    rng = np.random.default_rng(4)
    if below:  # from inside the glass, straight up: t = 0.25 exactly (Beer–Lambert)
        o = np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), np.full(n, -0.25)])
        d = np.tile([0.0, 0.0, 1.0], (n, 1))
    else:  # from above, spread over ±37° of incidence
        o = np.column_stack([rng.uniform(-0.3, 0.3, (n, 2)), np.full(n, 0.5)])
        d = np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), -np.ones(n)])
        d /= np.linalg.norm(d, axis=1, keepdims=True)
    keys = photon_keys(9, 0, 0, np.arange(n))
    scene = Scene([prim.point_source(1.0, centre=(40.0, 40.0, 40.0)), _plane(material)],
                  None, channels=1)
    tracer = PhotonTracer(scene, threads=1)
    res = tracer.trace(o, d, np.full((n, 1), 0.5), keys, record_escaped=True)
    tracer.close()

    front = not below
    fs = 1.0 if front else -1.0
    ng = tuple(float(fs * g) for g in scene.face_normals[0])  # facing the photon
    mats = MaterialTable.build([material], channels=1).arrays
    w, side, p, taken = _run(material.kind, mats, d, ng, ng, front, 0.25 if below else 0.0,
                             keys)
    p, taken = 0.5 * p, 0.5 * taken  # flux factors: the kernel ran with flux 1
    assert len(res.escaped_power) == n  # one bounce each, then out
    if below:  # exp(−σ t) reads embree's float32 hit distance, which is 0.25 to within
        # one float32 step depending on the CPU's instruction set: the same to 2 ulp
        np.testing.assert_allclose(res.escaped_power[:, 0], p, rtol=2.0 ** -22, atol=0)
    else:
        np.testing.assert_array_equal(res.escaped_power[:, 0], p)
    np.testing.assert_array_equal(res.escaped_dir, w.astype(np.float32))
    col = {DIFFUSE: "absorbed_diffuse", MIRROR: "absorbed_mirror",
           DIELECTRIC: "absorbed_volume"}[material.kind]
    assert res.ledger[0, LEDGER.index(col), 0] == pytest.approx(
        taken.sum(), rel=2.0 ** -22 if below else 1e-12)
    if material.kind == DIELECTRIC:
        assert 0.0 < (side == 1.0).mean() < 0.2  # both branches of the Fresnel choice ran
