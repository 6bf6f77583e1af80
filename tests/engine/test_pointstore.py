"""Estimates at fixed points from per-frame sums and a bounded pool equal a full map's."""

import json

import numpy as np
import pytest

from lightsim.engine import pointstore
from lightsim.engine.config import RunConfig
from lightsim.engine.pointstore import PointStore, floor_holds
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.photonmap.density import PhotonMap
from lightsim.simulate import SimulateOptions, photon_keeper
from lightsim.validation.bench.peer import CASES

from support import run_cli, write_point_lamp

NORMAL = np.array([0.0, 0.0, 1.0])


def _frames(rng, n_frames, n, spread=1.0, hot=(0.3, 0.2)):
    """Photons on the plane z = 25 m: a bright spot and a dim background, with a few
    back-facing and off-plane records, powers of a few magnitudes."""
    for _ in range(n_frames):
        xy = rng.uniform(-spread, spread, (n, 2))
        m = n // 3
        xy[:m] = np.asarray(hot) + 0.02 * rng.standard_normal((m, 2))
        z = np.full((n, 1), 25.0)
        z[: n // 50] += rng.uniform(-0.01, 0.01, (n // 50, 1))
        pos = np.hstack([xy, z]).astype(np.float32)
        nrm = np.tile(np.float32([0, 0, 1]), (n, 1))
        nrm[::37] = (0, 0, -1)
        pw = (rng.uniform(0.5, 2.0, (n, 1)) * 1e-3).astype(np.float32)
        yield pos, nrm, pw


def _points(rng, p=300):
    xy = np.vstack([rng.uniform(-1, 1, (p, 2)), np.array([[0.3, 0.2], [0.31, 0.2]]),
                    np.array([[5.0, 5.0]])])  # one far outside every photon
    return np.hstack([xy, np.full((len(xy), 1), 25.0)])


@pytest.mark.parametrize("kernel", ["box", "epanechnikov"])
@pytest.mark.parametrize("pool_min", [1000, 2**18])
def test_store_equals_full_map(kernel, pool_min, monkeypatch):
    monkeypatch.setattr(pointstore, "POOL_MIN", pool_min)  # cut often, or only at the end
    rng = np.random.default_rng(3)
    pts = _points(rng)
    k, r_max, r_min = 16, 0.2, 0.02
    store = PointStore(pts, NORMAL, 1, k=k, max_radius=r_max, min_radius=r_min,
                       kernel=kernel)
    full = PhotonMap("middle", channels=1)
    for pos, nrm, pw in _frames(rng, 12, 4000):
        store.add(pos, nrm, pw)
        full.add(pos, nrm, pw)
    q32 = pts.astype(np.float32)
    n32 = np.broadcast_to(NORMAL, pts.shape).astype(np.float32)
    want = full.estimate(q32, n32, k=k, max_radius=r_max, min_radius=r_min, kernel=kernel)
    got = store.estimate(q32, n32, k=k, max_radius=r_max, min_radius=r_min, kernel=kernel)
    assert store.resolved.any() and (~store.resolved).any()  # both kinds of point
    if kernel == "box":  # float32 powers summed in float64: exact in any order
        np.testing.assert_array_equal(got.E, want.E)
    else:  # weights round: the order of the additions shows in the last bits
        np.testing.assert_allclose(got.E, want.E, rtol=1e-12)
    np.testing.assert_array_equal(got.count, want.count)
    np.testing.assert_array_equal(got.r, want.r)
    assert len(store) == len(full)
    store.compact()
    assert store.kept <= k * len(pts)  # cut to the unresolved points' k nearest
    again = store.estimate(q32, n32, k=k, max_radius=r_max, min_radius=r_min, kernel=kernel)
    np.testing.assert_allclose(again.E, got.E, rtol=0 if kernel == "box" else 1e-12)


def test_pool_stays_bounded_as_photons_grow(monkeypatch):
    monkeypatch.setattr(pointstore, "POOL_MIN", 2000)
    rng = np.random.default_rng(5)
    pts = _points(rng, 100)
    store = PointStore(pts, NORMAL, 1, k=8, max_radius=0.1, min_radius=0.01)
    sizes = []
    for pos, nrm, pw in _frames(rng, 40, 5000):
        store.add(pos, nrm, pw)
        sizes.append(store.kept)
    assert max(sizes[20:]) <= 2 * 8 * len(pts) + 2000 + 5000
    assert store.nbytes() < 200_000 * 40 * 0.05  # far below the 200 k photons' bytes


def test_unregistered_points_and_other_settings_are_refused():
    rng = np.random.default_rng(1)
    pts = _points(rng, 10)
    store = PointStore(pts, NORMAL, 1, k=4, max_radius=0.1, min_radius=0.01)
    for pos, nrm, pw in _frames(rng, 1, 1000):
        store.add(pos, nrm, pw)
    n = np.broadcast_to(NORMAL, (1, 3)).astype(np.float32)
    with pytest.raises(InputError, match="--keep-photons"):
        store.estimate(np.float32([[0.123, 0.456, 25.0]]), n, k=4, max_radius=0.1,
                       min_radius=0.01)
    with pytest.raises(InputError, match="--keep-photons"):
        store.estimate(pts[:1].astype(np.float32), n, k=5, max_radius=0.1, min_radius=0.01)


def test_empty_input_and_no_points():
    store = PointStore(np.zeros((0, 3)), NORMAL, 3, k=4, max_radius=0.1, min_radius=0.01)
    store.add(np.zeros((5, 3), np.float32), np.tile(np.float32([0, 0, 1]), (5, 1)),
              np.ones((5, 3), np.float32))
    assert len(store) == 5 and store.kept == 0
    one = PointStore(np.zeros((1, 3)), NORMAL, 1, k=4, max_radius=0.1, min_radius=0.01)
    one.add(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32),
            np.zeros((0, 1), np.float32))
    est = one.estimate(np.zeros((1, 3), np.float32), np.float32([[0, 0, 1]]), k=4,
                       max_radius=0.1, min_radius=0.01)
    assert est.E[0, 0] == 0.0


def test_coincident_photons_resolve_a_point():
    store = PointStore(np.zeros((1, 3)), NORMAL, 1, k=4, max_radius=0.1, min_radius=0.01)
    pos = np.zeros((100, 3), np.float32)
    store.add(pos, np.tile(np.float32([0, 0, 1]), (100, 1)), np.full((100, 1), 1e-30,
                                                                      np.float32))
    store.compact()
    assert store.resolved[0] and store.kept == 0
    full = PhotonMap("middle", channels=1)
    full.add(pos, np.tile(np.float32([0, 0, 1]), (100, 1)), np.full((100, 1), 1e-30,
                                                                    np.float32))
    args = dict(k=4, max_radius=0.1, min_radius=0.01)
    q, n = np.zeros((1, 3), np.float32), np.float32([[0, 0, 1]])
    assert store.estimate(q, n, **args).E[0, 0] == full.estimate(q, n, **args).E[0, 0]


def test_floor_holds():
    assert floor_holds(0.01, 30.0)
    assert not floor_holds(1e-6, 30.0)
    assert not floor_holds(1e-3, 1e30)


def test_session_without_kept_photons_probes_as_one_that_keeps_them():
    """A run that keeps no photon answers the per-set estimates at its registered points
    bit for bit as one that keeps them all, and refuses any other point in one line."""
    scene = CASES["paraboloid"](16).scene
    (h0, h1), (v0, v1) = scene.wall.h_range_m, scene.wall.v_range_m
    rng = np.random.default_rng(2)
    hv = np.column_stack([rng.uniform(h0, h1, 200), rng.uniform(v0, v1, 200)])
    values = {}
    for keep in (True, False):
        cfg = RunConfig(frame_photons=20_000, spt=False, keep_photons=keep)
        with Session(scene, cfg, extra_probes=hv) as s:
            s.run(photons=4 * cfg.frame_photons, probes=False)
            values[keep] = s.probe(hv).values
            if not keep:
                stores = [st.photonmap for c in s.backend.clients
                          for st in c.photons.sets.values()]
                assert all(isinstance(p, PointStore) for p in stores)
                with pytest.raises(InputError, match="--keep-photons"):
                    s.probe(hv[:1] + 1e-3)
    assert np.array_equal(values[True], values[False]) and values[True].max() > 0


class _Reads:
    name = "reads"
    reads_photons = "--aperture 0"


class _ReadsNone:
    name = "quiet"
    reads_photons = None


class _Unknown:
    name = "custom"


def test_photon_keeper_names_the_option_that_keeps_photons():
    opts = SimulateOptions(scene_path="x.glb")
    cfg = opts.run_config()
    assert photon_keeper(opts, cfg, []) is None
    assert photon_keeper(opts, cfg, [_ReadsNone()]) is None
    assert photon_keeper(opts, cfg, [_ReadsNone(), _Reads()]) == "--aperture 0"
    assert photon_keeper(opts, cfg, [_Unknown()]) == "the custom analysis"
    keep = SimulateOptions(scene_path="x.glb", keep_all_photons=True)
    assert photon_keeper(keep, cfg, []) == "--keep-photons"
    assert photon_keeper(opts, cfg.with_(bandwidth="knn"), []) == "--bandwidth knn"
    assert photon_keeper(opts, cfg.with_(final="interleaved"), []) == \
        "--final interleaved"
    assert photon_keeper(keep, cfg.with_(estimator="bin"), []) is None  # no map at all


def test_explain_says_what_grows_with_photons(tmp_path, capsys):
    lamp = write_point_lamp(tmp_path / "point.glb")
    for extra, grows in (([], "nothing"), (["--keep-photons"], "--keep-photons")):
        out = tmp_path / f"run{len(extra)}"
        code, stdout, err = run_cli(["simulate", str(lamp), "--photons", "20000",
                                     "--frame-photons", "20000", "--resolution", "16x16",
                                     "--wall-distance", "2", "--explain", *extra,
                                     "--out", str(out), "--quiet"], capsys)
        assert code == 0, err
        lines = stdout.splitlines()
        at = lines.index("memory:")
        assert lines[at + 1].startswith("  grows with photons:") and grows in lines[at + 1]
        assert lines[at + 2].startswith("  predicted peak: about")
        summary = json.loads((out / "summary.json").read_text())
        assert summary["config"]["keep_photons"] is bool(extra)


def test_near_indices_from_one_store_serve_another(monkeypatch):
    """A frame's photons near the points, found once (:meth:`PointStore.near`), give
    every store with the same points the state its own lookup gives."""
    monkeypatch.setattr(pointstore, "POOL_MIN", 1000)
    rng = np.random.default_rng(9)
    pts = _points(rng, 100)[:-1]  # not the point far from every photon
    args = dict(k=8, max_radius=0.1, min_radius=0.03)
    own, shared = PointStore(pts, NORMAL, 1, **args), PointStore(pts, NORMAL, 1, **args)
    for pos, nrm, pw in _frames(rng, 30, 3000):
        own.add(pos, nrm, pw)
        shared.add(pos, nrm, pw, own.near(pos))
    assert own.resolved.all()  # the r_lo-only lookup after every point resolved, too
    q = pts.astype(np.float32)
    n = np.broadcast_to(NORMAL, q.shape).astype(np.float32)
    np.testing.assert_array_equal(own.estimate(q, n, **args).E, shared.estimate(q, n, **args).E)
    assert np.array_equal(own.count, shared.count) and len(own) == len(shared)
