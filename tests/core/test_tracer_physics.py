"""The tracer against exact answers. Tolerances come from the photon counts."""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.materials import DIELECTRIC, Material, fresnel_dielectric, slab_transmittance
from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.scene import Scene, make_wall
from lightsim.tracer import LEDGER, PhotonTracer
from lightsim.validation.scenes import primitives as prim


def _shoot(scene: Scene, n: int, seed: int = 3, **kw):
    tracer = PhotonTracer(scene, **kw)
    idx = np.arange(n, dtype=np.int64)
    pts = halton_points(idx, digit_permutations(seed, 0, None))
    return tracer, tracer.trace_points(pts, photon_keys(seed, 0, 0, idx))


def _collimated(tracer: PhotonTracer, n: int, origin_z: float, flux: float = 1.0,
                direction=(0.0, 0.0, 1.0), spread: float = 0.01, seed: int = 5):
    rng = np.random.default_rng(seed)
    o = np.zeros((n, 3))
    o[:, :2] = rng.uniform(-spread, spread, (n, 2))
    o[:, 2] = origin_z
    d = np.tile(np.asarray(direction, float) / np.linalg.norm(direction), (n, 1))
    power = np.full((n, 1), flux / n)
    return tracer.trace(o, d, power, photon_keys(seed, 0, 0, np.arange(n)))


def _assert_budget(res) -> None:
    total = res.ledger.sum(axis=(0, 1))
    emitted = res.emitted.sum(axis=0)
    np.testing.assert_allclose(total, emitted, rtol=1e-9)


def test_isotropic_source_on_plane_follows_cos3():
    """E(θ) = Φ cos³θ / (4π d²) for an isotropic source at distance d from a plane."""
    phi, d = 1000.0, 2.0
    wall, frame = make_wall(d, (8.0, 8.0))
    scene = Scene([prim.point_source(phi, radius=1e-5), wall], frame)
    n = 400_000
    _, res = _shoot(scene, n)
    h, v = frame.to_hv(res.records.position)
    r = np.hypot(h, v)
    edges = np.linspace(0.0, 3.6, 13)  # annuli in wall radius (inside the 8 m square)
    flux_in = np.histogram(r, bins=edges, weights=res.records.power[:, 0].astype(float))[0] / n
    count = np.histogram(r, bins=edges)[0]
    # ∫ Φ cos³θ / (4π d²) dA over an annulus of the wall = Φ/2 (cos θ1 − cos θ2)
    cos_t = d / np.hypot(edges, d)
    exact = phi / 2 * (cos_t[:-1] - cos_t[1:])
    sigma = exact / np.sqrt(count)
    assert np.all(np.abs(flux_in - exact) < 4 * sigma + 1e-12)
    _assert_budget(res)
    assert res.ledger[0, LEDGER.index("escaped"), 0] > 0


def test_paraboloid_focus_gives_parallel_beam():
    """A source at the focus of a paraboloid: reflected directions parallel to the axis."""
    f, rim, refl = 0.025, 0.06, 0.88
    mirror = prim.paraboloid(f, rim, reflectance=refl, radial=160, azimuthal=1024)
    src = prim.point_source(100.0, radius=1e-7, centre=(0.0, 0.0, f))
    wall, frame = make_wall(25.0, (1.0, 1.0))
    scene = Scene([src, mirror, wall], frame, channels=1)
    tracer = PhotonTracer(scene)
    n = 100_000
    idx = np.arange(n, dtype=np.int64)
    pts = halton_points(idx, digit_permutations(11, 0, None))
    # no wall in the way of the escaping beam: record escape directions
    scene_nowall = Scene([src, mirror], None, channels=1)
    tracer = PhotonTracer(scene_nowall)
    res = tracer.trace_points(pts, photon_keys(11, 0, 0, idx), record_escaped=True)
    d = res.escaped_dir.astype(np.float64)
    p = res.escaped_power[:, 0]
    reflected = np.isclose(p, refl * 100.0, rtol=1e-6)
    assert reflected.sum() > 0.3 * n
    ang = np.arccos(np.clip(d[reflected, 2], -1, 1))
    assert np.quantile(ang, 0.99) < 1e-4
    # the mirror absorbs exactly (1 − R) of what it reflects
    led = res.ledger[0, :, 0]
    assert led[LEDGER.index("absorbed_mirror")] == pytest.approx(
        (1 - refl) / refl * p[reflected].sum(), rel=1e-9)
    _assert_budget(res)


@pytest.mark.parametrize("ior", [1.5])
def test_slab_normal_incidence_transmittance(ior):
    """(1−R)/(1+R) = 0.9231 for n = 1.5, with multiple internal reflections."""
    wall, frame = make_wall(1.0, (2.0, 2.0))
    scene = Scene([prim.point_source(1.0), prim.slab(0.01, 0.5, 0.4, ior), wall], frame)
    tracer = PhotonTracer(scene)
    n = 200_000
    res = _collimated(tracer, n, origin_z=0.1)
    t = res.ledger[0, LEDGER.index("wall"), 0]
    r = fresnel_dielectric(1.0, 1.0, ior)
    expected = (1 - r) / (1 + r)
    assert expected == pytest.approx(0.9231, abs=1e-4)
    assert expected == pytest.approx(slab_transmittance(ior), rel=1e-12)
    sigma = np.sqrt(expected * (1 - expected) / n)
    assert abs(t - expected) < 4 * sigma
    assert res.ledger[0, LEDGER.index("escaped"), 0] == pytest.approx(1 - t, rel=1e-9)


def test_beer_lambert_absorption():
    """With absorption σ a plate transmits (1−R)² a / (1 − R² a²), a = exp(−σ t)."""
    sigma, thick, ior = 20.0, 0.02, 1.5
    wall, frame = make_wall(1.0, (2.0, 2.0))
    scene = Scene([prim.point_source(1.0), prim.slab(thick, 0.5, 0.4, ior, sigma), wall], frame)
    tracer = PhotonTracer(scene)
    n = 200_000
    res = _collimated(tracer, n, origin_z=0.1)
    a = np.exp(-sigma * thick)
    expected = slab_transmittance(ior, 1.0, a)
    t = res.ledger[0, LEDGER.index("wall"), 0]
    assert abs(t - expected) < 4 * np.sqrt(expected * (1 - expected) / n)
    # the plate absorbs about 1 − a of a single pass (plus a little from reflections)
    assert res.ledger[0, LEDGER.index("absorbed_volume"), 0] == pytest.approx(1 - a, rel=0.05)
    _assert_budget(res)


def test_total_internal_reflection_beyond_critical_angle():
    """Light inside glass hitting the face beyond the critical angle never leaves there."""
    ior = 1.5
    crit = np.arcsin(1 / ior)
    glass = prim.box((-1, -1, 0.0), (1, 1, 0.05),
                     Material("glass", DIELECTRIC, np.ones(3), ior), "glass")
    wall, frame = make_wall(1.0, (0.2, 0.2))
    scene = Scene([prim.point_source(1.0, centre=(0, 0, -5)), glass, wall], frame)
    tracer = PhotonTracer(scene, max_depth=6)
    for angle, expect_exit in ((crit + 0.02, False), (crit - 0.05, True)):
        n = 2000
        d = np.array([np.sin(angle), 0.0, np.cos(angle)])
        o = np.tile([0.0, 0.0, 0.025], (n, 1))  # inside the plate
        res = tracer.trace(o, np.tile(d, (n, 1)), np.full((n, 1), 1.0 / n),
                           photon_keys(1, 0, 0, np.arange(n)))
        # first interaction: the top face; under TIR nothing escapes through it upwards
        escaped_up = res.ledger[0, LEDGER.index("escaped"), 0]
        if expect_exit:
            assert escaped_up > 0.5
        else:
            # it bounces between the faces until the depth limit: no exit at all
            assert escaped_up == 0.0
            assert res.ledger[0, LEDGER.index("max_depth"), 0] == pytest.approx(1.0, rel=1e-9)


def test_mirror_scales_flux_by_reflectance_and_budget_closes():
    refl = 0.7
    wall, frame = make_wall(2.0, (4.0, 4.0))
    mirror = prim.mirror_plane(1.0, (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), refl)
    # a beam going +Z hits the mirror facing −Z and leaves the scene backwards
    scene = Scene([prim.point_source(1.0), mirror, wall], frame)
    tracer = PhotonTracer(scene)
    n = 10_000
    res = _collimated(tracer, n, origin_z=0.5, flux=3.0)
    led = res.ledger[0, :, 0]
    assert led[LEDGER.index("absorbed_mirror")] == pytest.approx(3.0 * (1 - refl), rel=1e-12)
    assert led[LEDGER.index("escaped")] + led[LEDGER.index("absorbed_diffuse")] \
        + led[LEDGER.index("wall")] + led[LEDGER.index("roulette")] \
        + led[LEDGER.index("max_depth")] == pytest.approx(3.0 * refl, rel=1e-12)
    _assert_budget(res)


def test_closed_diffuse_box_energy_balance_with_roulette():
    """Every lumen in a closed diffuse box ends absorbed or in roulette; budget exact."""
    inner = prim.box((-1, -1, -1), (1, 1, 1), Material("box", 0, np.full(3, 0.7)), "box")
    scene = Scene([prim.point_source(10.0), inner], None)
    _, res = _shoot(scene, 50_000, max_depth=64)
    led = res.ledger[0, :, 0]
    assert led[LEDGER.index("escaped")] == 0.0
    _assert_budget(res)
    # absorbed + roulette (net) = emitted; the roulette part averages to ~0
    assert abs(led[LEDGER.index("roulette")]) < 0.05 * res.emitted.sum()
