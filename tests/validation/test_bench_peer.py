"""`lightsim bench peer`: Mitsuba 3 and lightsim on the same analytic scene, scored alike."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from lightsim.validation.bench import peer


def test_ply_writer_round_trips_through_trimesh(tmp_path):
    case = peer.CASES["paraboloid"](8)
    mirror = case.scene.parts[1]
    path = peer.write_ply(tmp_path / "m.ply", mirror.vertices, mirror.faces, mirror.normals)
    m = trimesh.load(path, process=False)
    np.testing.assert_allclose(m.vertices, mirror.vertices, atol=1e-7)
    np.testing.assert_array_equal(m.faces, mirror.faces)


def test_covered_case_exact_is_transmittance_times_open_beam():
    open_ = peer.truth_of(peer.CASES["paraboloid"](16))
    covered = peer.truth_of(peer.CASES["covered"](16))
    t0 = (1 - 0.04) ** 2 / (1 - 0.04**2)  # n = 1.5: R = 0.04 at normal incidence
    ratio = covered.exact_px[covered.inner] / open_.exact_px[open_.inner]
    # the direct light (≈ 0.2 % of the beam) crosses the plate at other angles
    assert np.allclose(ratio, t0, rtol=3e-3)


def test_libllvm_version_parsing():
    assert peer.llvm_version("libLLVM.so.19.1") == 19
    assert peer.llvm_version("libLLVM-20.so") == 20
    assert peer.llvm_version("libLLVM-14.so.1") == 14
    assert peer.llvm_version("libfoo.so") == 0


@pytest.mark.skipif(peer.mitsuba_unavailable() is not None,
                    reason=f"Mitsuba side unavailable: {peer.mitsuba_unavailable()}")
def test_peer_bench_tiny_both_maps_follow_the_exact_law(tmp_path):
    res = peer.run_case("paraboloid", target=0.25, resolution=8, spp0=64, max_seconds=120,
                        lightsim_args=("--frame-photons", "20000"), ladder=False,
                        folder=tmp_path)
    mitsuba = [r for r in res.runs if r.tool == "mitsuba"]
    light = next(r for r in res.runs if r.tool == "lightsim")
    assert all(r.ok for r in res.runs), [r.note for r in res.runs]
    truth = peer.truth_of(peer.CASES["paraboloid"](8))
    for r in (mitsuba[-1], light):
        assert r.true_error < 0.25
        # unbiased both: the mean over the scored pixels is the exact one within noise
        mean = r.lux[truth.inner].mean() / truth.exact_px[truth.inner].mean()
        assert abs(mean - 1) < 0.05, (r.tool, mean)
    assert res.mitsuba_seconds is not None and res.ratio is not None
    assert math.isfinite(res.ratio) and light.own_error is not None
    # lightsim writes only what the score reads; its process time splits into phases
    assert sorted(p.name for p in (tmp_path / "lightsim-out").iterdir()) == [
        "summary.json", "wall_lux.exr"]
    b = light.breakdown()
    assert b is not None and b["startup"] > 0 and b["trace"] > 0
    inside = sum(v for k, v in b.items() if k not in ("case", "setting", "process_s",
                                                      "startup"))
    assert b["startup"] + inside == pytest.approx(light.seconds)


def test_second_score_covers_the_lit_pixels_rim_included():
    case = peer.CASES["paraboloid"](32)
    truth = peer.truth_of(case)
    h, v = case.frame.pixel_centres()
    r = np.hypot(*np.meshgrid(h, v))
    rim = case.params["rim_radius_m"]
    assert np.all(truth.lit[truth.inner]) and truth.lit.sum() > truth.inner.sum()
    assert not truth.lit[r > 1.05 * rim].any()  # outside the rim only the direct light
    assert truth.error(truth.exact_px) == 0.0 and truth.error(truth.exact_px, "lit") == 0.0
    # a map wrong only on the rim: the inner score does not see it, the lit one does
    lux = truth.exact_px * np.where(truth.lit & ~truth.inner, 1.1, 1.0)
    assert truth.error(lux) == 0.0 and truth.error(lux, "lit") > 0.02


def test_summary_rows_say_where_each_figure_landed():
    runs = [peer.PeerRun("paraboloid", "mitsuba", "spp 9", 6.0, 9, 0.0195, None, 0.021),
            peer.PeerRun("paraboloid", "lightsim", "--target-error 0.02", 3.0, 10, 0.011,
                         0.0185, 0.0172)]
    lit_stop = peer.PeerRun("paraboloid", "lightsim", "--target-error 0.02", 4.0, 20, 0.008,
                            0.0196, 0.0203)
    res = peer.PeerResult("paraboloid", [*runs, lit_stop], 6.0, 3.0, 2.0, True, False,
                          stops={"inner": runs[1], "lit": lit_stop})
    row = peer.summary_rows([res], 0.02)[0]
    assert row["mitsuba_err"] == 0.0195 and row["mitsuba_err_lit"] == 0.021
    assert row["ls_true_err_lit"] == 0.0172  # the inner stop's map on the lit pixels
    assert row["ls_own_within_10pct"] is True and row["ls_stop_within_10pct"] is False
    # the lit score reads the lit stop: its figure and its true error there
    assert row["ls_own_err_lit"] == 0.0196 and row["ls_true_err_lit_stop"] == 0.0203
    assert row["ls_lit_within_10pct"] is True


def test_both_tools_are_timed_on_both_scores(monkeypatch):
    """Mitsuba renders until each score is below the target (its spp from the 1/√spp law
    of the score not reached yet); lightsim's self-stop counts on a score only where its
    true error there is below the target; each score gets its own ratio."""
    spps: list[int] = []

    def mitsuba(case, truth, folder, spp, seed=0, timeout=300.0):
        spps.append(spp)  # 1/√spp noise: 2 % inner at spp 100, 2 % lit at spp 144
        return peer.PeerRun(case.name, "mitsuba", f"spp {spp}", spp / 10, spp,
                            0.2 / math.sqrt(spp), true_error_lit=0.24 / math.sqrt(spp))

    stop_args = []

    def lightsim(case, truth, folder, target, extra_args=(), timeout=300.0, photons=None):
        if photons is None:  # the self-stops: inner reached, lit just above the target
            stop_args.append(tuple(extra_args))
            if "interior" in extra_args:
                return peer.PeerRun(case.name, "lightsim", "stop", 2.0, 1000, 0.019, 0.0195,
                                    0.03)
            return peer.PeerRun(case.name, "lightsim", "stop", 3.0, 2000, 0.01, 0.0195,
                                0.0205)
        e = 0.0205 * math.sqrt(1000 / photons)
        return peer.PeerRun(case.name, "lightsim", "fixed", 2.5, photons, e / 2, None, e)

    monkeypatch.setattr(peer, "run_mitsuba", mitsuba)
    monkeypatch.setattr(peer, "run_lightsim", lightsim)
    res = peer.run_case("paraboloid", resolution=8, spp0=4)
    assert spps[0] == 4 and spps[1] == math.ceil(4 * (0.1 / (0.97 * 0.02)) ** 2)
    m_inner, m_lit = res.mitsuba_seconds, res.mitsuba_seconds_lit
    assert m_inner == spps[1] / 10 and m_lit == spps[-1] / 10 and m_lit > m_inner
    assert 0.24 / math.sqrt(spps[-1]) < 0.02 <= 0.24 / math.sqrt(spps[-2])
    # each score's stop reads its own region: the interior for the inner score
    assert stop_args == [("--error-region", "interior"), ()]
    assert res.lightsim_seconds == 2.0 and res.ratio == pytest.approx(m_inner / 2.0)
    assert res.stopped_near_target is True  # 1.9 % inner at the interior stop
    assert res.lightsim_reached_lit is False and res.lightsim_seconds_lit is None
    assert res.ratio_lit is None  # the self-stop did not reach 2 % on the lit pixels
    assert res.lightsim_fixed_seconds_lit == 2.5  # a fixed budget did
    assert res.ratio_fixed_lit == pytest.approx(m_lit / 2.5)
    row = peer.summary_rows([res], 0.02)[0]
    assert row["ratio_lit"] is None and row["mitsuba_s_lit"] == m_lit
    assert row["ls_own_within_10pct"] is True and row["ls_lit_within_10pct"] is True
