"""The emission guide: the warp's density and weights, learning, targets, and a guided run
that stays unbiased, closes its energy ledger and replays bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.emitters.rayfile import RaySource
from lightsim.engine.apertures import intensities, layout_from_config
from lightsim.engine.config import RunConfig
from lightsim.engine.guiding import (
    EmissionGuide,
    aperture_rects,
    cell_of,
    heaviest_weight,
    run_targets,
    target_rows,
    targets_at,
    warp_points,
)
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.io.rayfile import write_tm25
from lightsim.scene import SceneSettings, load_scene

from support import run_cli, write_point_lamp


def _density(shape, rng, spread=3.0):
    p = np.exp(spread * rng.standard_normal(int(np.prod(shape))))
    return p / p.sum()


@pytest.mark.parametrize("shape", [(1, 8, 8), (4, 6, 5), (1, 64, 1)])
def test_warp_draws_the_cell_density_and_weights_undo_it(shape):
    rng = np.random.default_rng(3)
    p = _density(shape, rng)
    u = rng.random((200_000, 5))
    out, w, cells = warp_points(u, p, shape)
    n = int(np.prod(shape))
    # the photons land in cells with the density's probabilities (binomial error)
    freq = np.bincount(cells, minlength=n) / len(u)
    se = np.sqrt(p * (1 - p) / len(u))
    assert np.all(np.abs(freq - p) < 5 * se + 1e-12)
    # each cell's weight is 1 / (p · cells): relative to the uniform density
    np.testing.assert_allclose(w, 1.0 / (p[cells] * n), rtol=1e-9)
    # the cell of the warped point is the cell the kernel reports; u₃, u₄ untouched
    assert np.array_equal(cell_of(out, shape), cells)
    assert np.array_equal(out[:, 3:], u[:, 3:])
    assert np.all((out >= 0) & (out < 1))
    # E_p[f w] = ∫ f: an integral of a smooth and of a step function
    for f in (lambda x: 1 + np.sin(6 * x[:, 0]) * x[:, 1] + x[:, 2] ** 2,
              lambda x: (x[:, 0] > 0.37) * (x[:, 1] < 0.61)):
        exact = f(rng.random((2_000_000, 5))).mean()
        est = f(out) * w
        assert abs(est.mean() - exact) < 5 * est.std() / np.sqrt(len(u)) + 2e-3


def test_warp_is_monotone_in_each_coordinate_and_survives_edge_input():
    shape = (1, 16, 16)
    p = _density(shape, np.random.default_rng(1), spread=20.0)  # cells 1e-30 … 1
    p = 0.5 / p.size + 0.5 * p  # the defensive mixture keeps every cell ≥ α
    out, w, _ = warp_points(np.zeros((0, 5)), p, shape)
    assert out.shape == (0, 5) and w.shape == (0,)
    u = np.tile(np.linspace(0, 1 - 1e-16, 1001)[:, None], (1, 5))
    u[:, 1] = 0.3
    out, w, _ = warp_points(u, p, shape)
    assert np.all(np.diff(out[:, 0]) >= 0) and np.all(np.isfinite(w))
    assert np.all(w <= 2.0 + 1e-9)  # weight ≤ 1/α


def _guide(n_sets=1, goal=400.0):
    return EmissionGuide((1, 8, 8), 0.5, goal, n_sets, 1.0, 25.0)


def test_guide_learns_the_cells_that_reach_a_target_and_closes_it():
    g = _guide(goal=10)
    rect = aperture_rects([2.0], [1.0], 0.2)
    g.set_targets(np.column_stack([rect, [1.0]]))
    assert g.density() is None  # nothing learned: uniform
    h, v = 25 * np.tan(np.radians(2.0)), 25 * np.tan(np.radians(1.0))
    cells = np.array([5, 5, 9, 40])
    g.learn(cells, np.array([h, h, h + 0.2, 9.0]), np.array([v, v, v, 9.0]), np.ones(4))
    p = g.density()
    assert p is not None and abs(p.sum() - 1) < 1e-12
    # cells 5 (twice in the window) and 9 (once) get the learned half, the rest α / n
    assert p[5] == pytest.approx(0.5 / 64 + 0.5 * 2 / 3)
    assert p[9] == pytest.approx(0.5 / 64 + 0.5 / 3)
    assert p[40] == pytest.approx(0.5 / 64)
    # ten photons in the rectangle itself: the goal is met, the target closes
    g.learn(np.full(10, 7), np.full(10, h), np.full(10, v), np.ones(10))
    assert not g.open_targets()[0] and g.density() is None
    # importance 0 closes a target; a known rectangle keeps what it learned
    g2 = _guide()
    g2.set_targets(np.column_stack([rect, [1.0]]))
    g2.learn(cells, np.array([h, h, h, h]), np.array([v, v, v, v]), np.ones(4))
    g2.set_targets(np.column_stack([rect, [0.0]]))
    assert g2.density() is None
    g2.set_targets(np.column_stack([rect, [2.0]]))
    assert g2.moments[0, 2] == 4


def test_target_rows_and_the_run_targets():
    rows = target_rows([[0, 1, 0, 1], [1, 2, 1, 2]], [1, 0.5], frame=3)
    assert rows[0] == (3.0, 0.0, 1.0, 0.0, 1.0, 1.0)
    hist = target_rows([[5, 6, 0, 1]]) + rows
    assert targets_at(hist, 2).tolist() == [[5, 6, 0, 1, 1]]
    assert targets_at(hist, 3)[:, 4].tolist() == [1.0, 0.5]
    assert len(targets_at(rows, 0)) == 0
    for bad in ([[1, 0, 0, 1]], [[0, 1, 0, np.nan]], [[0, 100, 0, 1]]):
        with pytest.raises(ValueError):
            target_rows(bad)
    with pytest.raises(ValueError):
        target_rows([[0, 1, 0, 1]], [-1])
    cfg = RunConfig(guide="points", apertures=((0.0, 0.0), (2.0, 1.0)), aperture_deg=0.2)
    assert len(run_targets(cfg)) == 2 and heaviest_weight(cfg) == 2.0
    assert heaviest_weight(RunConfig()) == 1.0
    with pytest.raises(InputError, match="--regulation"):
        run_targets(RunConfig(guide="points"))
    with pytest.raises(InputError):
        RunConfig(guide_targets=((0.0, 1.0, 0.0, 0.0, 1.0, 1.0),))


@pytest.fixture(scope="module")
def lamp(tmp_path_factory):
    return load_scene(str(write_point_lamp(tmp_path_factory.mktemp("g") / "p.glb")),
                      SceneSettings(resolution=(64, 32)))


# glare-like apertures: small squares well off the lamp's axis, and one at H-V
APERTURES = ((0.0, 0.0), (3.0, 1.5), (-4.0, 2.0), (6.0, -1.0))


def _run(scene, frames, guide="points", seed=5, **kw):
    cfg = RunConfig(seed=seed, estimator="bin", frame_photons=90_000, interleave=3,
                    apertures=APERTURES, aperture_deg=1.5, guide=guide, **kw)
    s = Session(scene, cfg)
    for _ in range(frames):
        s.shoot()
    return s


def _aperture_cd(session):
    stats = session.backend.stats()
    per = session.backend.apertures()
    counts = np.stack([per[k] for k in sorted(per)])
    emitted = np.array([stats[k]["emitted"] for k in sorted(stats)], float)
    layout = layout_from_config(session.config, session.scene.wall.distance_m)
    return intensities(counts, emitted, layout)[..., 0]  # (S, P) cd


def test_guided_run_is_unbiased_closes_its_ledger_and_aims(lamp):
    plain, guided = _run(lamp, 6, "off"), _run(lamp, 6)
    try:
        # every photon's weight: the emitted power per photon stays Φ (E[1/p] = 1)
        e = guided.energy()
        assert e["emitted"] == pytest.approx(1000.0, rel=0.01)
        parts = sum(v for k, v in e.items() if k != "emitted")
        assert parts == pytest.approx(e["emitted"], rel=1e-9)  # the ledger closes
        # an isotropic 1000 lm source: I = 1000 / 4π cd everywhere
        truth = 1000.0 / (4 * np.pi)
        a, b = _aperture_cd(plain), _aperture_cd(guided)
        for cd in (a, b):
            mean, se = cd.mean(0), cd.std(0, ddof=1) / np.sqrt(len(cd))
            assert np.all(np.abs(mean - truth) < 4.5 * se + 1e-9)
        # the written map agrees within the two maps' errors
        pm, gm = plain.final_image(probes=False).lux, guided.final_image(probes=False).lux
        assert abs(gm.sum() / pm.sum() - 1) < 0.01
    finally:
        plain.close()
        guided.close()


def test_guided_sets_replay_and_resume_bit_for_bit(lamp):
    straight = _run(lamp, 4)
    try:
        # targets replaced between frames: the history travels in the config
        straight.guide(aperture_rects([3.0], [1.5], 1.5), [1.0])
        for _ in range(2):
            straight.shoot()
        ckpt = straight.checkpoint()
        want = straight.backend.apertures()
    finally:
        straight.close()
    first = _run(lamp, 2)
    try:
        mid = first.checkpoint()
    finally:
        first.close()
    cfg = RunConfig.from_dict(ckpt["config"])
    resumed = Session(lamp, cfg, checkpoint=ckpt)
    try:
        got = resumed.backend.apertures()
        for k in want:
            assert np.array_equal(got[k], want[k])
    finally:
        resumed.close()
    # a resumed run from frame 2 shoots the same photons as the straight one
    again = Session(lamp, RunConfig.from_dict(mid["config"]), checkpoint=mid)
    try:
        for _ in range(2):
            again.shoot()
        again.guide(aperture_rects([3.0], [1.5], 1.5), [1.0])
        for _ in range(2):
            again.shoot()
        got = again.backend.apertures()
        for k in want:
            assert np.array_equal(got[k], want[k])
    finally:
        again.close()


def test_guide_refuses_bad_targets(lamp):
    s = _run(lamp, 0)
    try:
        with pytest.raises(InputError, match="guide targets"):
            s.guide([[1.0, 0.0, 0.0, 1.0]])
    finally:
        s.close()


@pytest.mark.parametrize("extra, text", [
    ([], "--regulation"),
    (["--regulation", "r112-b-passing", "--guide", "sideways"], "--guide"),
])
def test_guide_option_errors_are_one_line_and_exit_2(tmp_path, capsys, extra, text):
    glb = write_point_lamp(tmp_path / "lamp.glb")
    argv = ["simulate", str(glb), "--out", str(tmp_path / "o"), *extra]
    if "--guide" not in extra:
        argv += ["--guide", "points"]
    code, _out, err = run_cli(argv, capsys)
    assert code == 2 and "Traceback" not in err
    lines = [ln for ln in err.strip().splitlines() if ln.strip() and "planning" not in ln]
    assert len(lines) == 1 and text in lines[0], err
    assert not (tmp_path / "o").exists()  # nothing half-written


def _iso_rays(path, n=200_000, seed=1, flux=None):
    rng = np.random.default_rng(seed)
    k = rng.standard_normal((n, 3))
    k /= np.linalg.norm(k, axis=1, keepdims=True)
    f = np.full(n, 1000.0 / n) if flux is None else flux
    return write_tm25(path, np.zeros((n, 3)), k, f), k, f


def test_ray_file_direction_order_keeps_every_rays_probability(tmp_path):
    n = 5000
    flux = np.random.default_rng(2).uniform(0.0, 2.0, n)
    flux[::7] = 0.0  # zero-flux rays are never drawn
    path, _k, _f = _iso_rays(tmp_path / "r.tm25ray", n, 2, flux)
    src = RaySource(path)
    perm, cdf = src.direction_order()
    assert sorted(perm.tolist()) == list(range(n)) and cdf is not None
    u = (np.arange(400_000) + 0.5) / 400_000  # stratified uniform u in direction order
    drawn = np.bincount(src.ray_indices(src.file_sample(u)), minlength=n)
    want = flux / flux.sum() * len(u)
    assert np.all(drawn[flux == 0] == 0)
    assert np.all(np.abs(drawn - want) <= 1.0 + 1e-9)  # stratified: off by at most one
    # near directions lie near in the order: neighbours in it are close on the sphere
    kk = _k[perm]
    cos = np.sum(kk[1:] * kk[:-1], axis=1)
    assert np.median(cos) > 0.99
    equal = RaySource(_iso_rays(tmp_path / "e.tm25ray", n, 3)[0])
    got = np.bincount(equal.ray_indices(equal.file_sample(u)), minlength=n)
    assert got.min() == got.max() == len(u) // n


def test_guided_ray_file_is_unbiased_and_aims(tmp_path):
    """A ray file guided as a point source is: 4096 direction-ordered cells along u₀,
    each aperture's estimate within its error of the file's own intensity, and more
    photons in the apertures than a uniform run sends there."""
    path, k, f = _iso_rays(tmp_path / "iso.tm25ray")
    scene = load_scene(str(path), SceneSettings(resolution=(64, 32)))
    plain, guided = _run(scene, 6, "off"), _run(scene, 6)
    try:
        clients = guided.backend.clients
        assert clients[0].photons._guide_shape == (1, 4096, 1)
        # the file's own aperture means: its rays' flux per solid angle
        h = np.degrees(np.arctan2(-k[:, 0], k[:, 2]))  # +H is the wall's −X (right)
        v = np.degrees(np.arctan2(k[:, 1], k[:, 2]))
        layout = layout_from_config(guided.config, guided.scene.wall.distance_m)
        truth = []
        for (hc, vc), om in zip(APERTURES, layout.solid_angles(0.0), strict=True):
            inside = (k[:, 2] > 0) & (np.abs(h - hc) < 0.75) & (np.abs(v - vc) < 0.75)
            truth.append(f[inside].sum() / om)
        truth = np.asarray(truth)
        a, b = _aperture_cd(plain), _aperture_cd(guided)
        for cd in (a, b):
            mean, se = cd.mean(0), cd.std(0, ddof=1) / np.sqrt(len(cd))
            assert np.all(np.abs(mean - truth) < 4.5 * se + 1e-6 * truth.max()), (mean, truth)
        # the guide sends photons there: more land in each aperture than uniform
        # emission's expectation (photons × Ω / 4π)
        caught = sum(st.guide.moments[:, 2] for c in clients for st in c.photons.sets.values())
        expected = guided.photons_emitted() * layout.solid_angles(0.0) / (4 * np.pi)
        assert np.all(caught > 1.5 * expected), (caught, expected)
        e = guided.energy()
        assert e["emitted"] == pytest.approx(1000.0, rel=0.01)
    finally:
        plain.close()
        guided.close()
