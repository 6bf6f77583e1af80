"""The frame loop: accumulation, interaction and walkthrough, camera view, SPT."""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.render.camera import PinholeCamera
from lightsim.validation.scenes import analytic as an
from lightsim.validation.scenes import paper


@pytest.fixture(scope="module")
def ring():
    return paper.ring((64, 64))


def test_accumulation_interaction_and_walkthrough(ring):
    cfg = RunConfig(frame_photons=40_000, interleave=2, spt=False)
    with Session(ring, cfg) as s:
        s.frame()
        s.frame()
        assert sum(s.emitted_per_set().values()) == 80_000
        est = s.walkthrough()
        assert sum(s.emitted_per_set().values()) == 80_000  # walkthrough shoots nothing
        again = s.walkthrough()
        np.testing.assert_array_equal(est.lux, again.lux)
        # a material change discards the photons; the next frame starts from scratch
        s.update(material=("ring", {"reflectance": 0.5}))
        assert sum(s.emitted_per_set().values()) == 0
        after = s.frame()
        assert after.photons == 40_000
        # less reflectance, less caustic light (the direct light is unchanged)
        assert after.probes.mean.sum() < est.probes.mean.sum()


def test_same_seed_same_image_other_seed_differs(ring):
    imgs = []
    for seed in (5, 5, 6):
        with Session(ring, RunConfig(frame_photons=30_000, interleave=2, seed=seed,
                                     spt=True)) as s:
            s.frame()
            imgs.append(s.frame().lux)
    np.testing.assert_array_equal(imgs[0], imgs[1])
    assert not np.array_equal(imgs[0], imgs[2])


def test_error_estimate_falls_with_photons(ring):
    cfg = RunConfig(frame_photons=50_000, interleave=3, estimator="bin", spt=False)
    with Session(ring, cfg) as s:
        s.run(photons=800_000)
        log = [e for e in s.log if e.get("rel_error")]
    first, last = log[1], log[-1]
    ratio = first["rel_error"] / last["rel_error"]
    expected = np.sqrt(last["photons"] / first["photons"])  # 1/√N for binning
    assert 0.6 * expected < ratio < 1.5 * expected


def test_camera_sees_luminance_rho_e_over_pi(ring):
    """A camera looking down at the floor: L = ρ E / π of the wall detector's E."""
    cam = PinholeCamera(position=(0.0, 3.0, 0.0), look_at=(0.0, 0.0, 0.0), up=(0, 0, -1),
                        fov_deg=30, resolution=(64, 64))
    cfg = RunConfig(frame_photons=100_000, interleave=2)
    with Session(ring, cfg, camera=True) as s:
        s.run(photons=400_000)
        est = s.walkthrough(camera=cam)
        lum = est.camera[..., 0]
        # the floor point under the camera axis is the image centre and H-V of the floor
        e_centre = s.probe(np.array([[0.0, 0.0]])).mean[0, 0]
    l_centre = lum[30:34, 30:34].mean()
    assert l_centre == pytest.approx(0.8 * e_centre / np.pi, rel=0.15)
    assert np.all(np.isfinite(lum)) and lum.min() >= 0


def test_camera_needs_the_camera_plan(ring):
    cam = PinholeCamera(position=(0.0, 3.0, 0.0), look_at=(0.0, 0.0, 0.0), up=(0, 0, -1))
    with Session(ring, RunConfig(frame_photons=20_000, interleave=1)) as s:
        with pytest.raises(Exception, match="camera"):
            s.frame(camera=cam)


def test_spt_raises_yield_and_agrees_with_plain(ring):
    """SPT (section 5.1) shoots more caustic photons, and the pattern in lux is the same.

    Compared with the fixed-radius estimator: its expectation is the pattern blurred by a
    fixed disk whatever the photon density. kNN's radius follows the photon density, which
    SPT changes on purpose (more photons in caustics, fewer elsewhere), so next to shadow
    edges kNN's blur — not the flux — differs between the two.
    """
    res = {}
    for spt in (False, True):
        # the interleaved probes' radius (a 3×3-pixel disk) holds enough photons for the
        # per-set values to be near-normal, so the z-scores below are meaningful
        cfg = RunConfig(frame_photons=100_000, interleave=3, spt=spt, probe_grid=(24, 24),
                        estimator="radius", final="interleaved")
        with Session(ring, cfg) as s:
            s.run(photons=900_000)
            res[spt] = (s.caustic_yield(), s.last.probes)
    (y0, p0), (y1, p1) = res[False], res[True]
    assert y1 > 3 * y0
    m0, m1 = p0.mean[:, 0], p1.mean[:, 0]
    se = np.sqrt(p0.se[:, 0] ** 2 + p1.se[:, 0] ** 2)
    lit = m0 > 0.05 * m0.max()
    z = (m1[lit] - m0[lit]) / se[lit]
    # independent estimates of the same pattern: z ~ N(0, 1) up to the t-tails of 9 sets
    assert np.mean(z**2) < 2.0
    assert np.mean(np.abs(z) > 4) < 0.02


def test_written_map_is_the_ici_choice_and_independent_of_batching():
    """The pooled map is each pixel's pooled value at its ICI rung; frames of another size
    (same photons per set) give the bit-identical map; ``bandwidth="knn"`` the old rule."""
    case = an.shield_case(resolution=(32, 16))
    maps = []
    for frame_photons in (64_000, 32_000):
        cfg = RunConfig(seed=3, interleave=2, spt=False, frame_photons=frame_photons)
        with Session(case.scene, cfg) as s:
            est = s.run(photons=128_000)
        maps.append(est)
    a, b = maps
    assert a.rungs is not None and a.rungs.shape == (16, 32)
    np.testing.assert_array_equal(a.lux, b.lux)
    np.testing.assert_array_equal(a.rungs, b.rungs)
    assert set(np.unique(a.rungs)) <= {0, 1, 2, 3} and (a.rungs == 3).any()
    assert a.error is not None and a.error.total > 0
    cfg = RunConfig(seed=3, interleave=2, spt=False, frame_photons=64_000, bandwidth="knn")
    with Session(case.scene, cfg) as s:
        old = s.run(photons=128_000)
    assert old.rungs is None and not np.array_equal(old.lux, a.lux)
    # the flux on the wall: windows are clipped to the wall, so its border is not dimmed
    # the way a disk half outside the wall dims it
    exact = case.pixel_means(case.frame).sum()
    assert abs(a.lux.sum() / exact - 1) < 0.03
    assert abs(a.lux.sum() / exact - 1) < abs(old.lux.sum() / exact - 1)
