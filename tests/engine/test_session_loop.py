"""The render loop as named stages (shoot → insert → estimate → error and stopping rule →
final image) and its pipeline speed-ups: each must leave the written map bit-identical."""

from __future__ import annotations

import itertools
import math
from statistics import NormalDist

import numpy as np
import pytest

from lightsim.engine.backend import Backend
from lightsim.engine.config import RunConfig
from lightsim.engine.local import LocalBackend
from lightsim.engine.photonset import DeferredPhotonMap, add_to_cells
from lightsim.engine.ray_backend import RayBackend
from lightsim.engine.results import FrameResult
from lightsim.engine.server import (
    EXPONENT_RANGE,
    STOP_ALPHA,
    ErrorSchedule,
    MapErrorRule,
    Session,
    StoppingRule,
    look_z,
    stop_level,
)
from lightsim.photonmap.density import PhotonMap
from lightsim.render.frame import ErrorEstimate
from lightsim.sampling import (
    DIGITS,
    N_DIMS,
    PRIMES,
    digit_permutations,
    digit_permutations_reference,
    halton_points,
    halton_points_grouped,
)
from lightsim.validation.bench.pipeline import StageRecorder, bench_pipeline, timed_run
from lightsim.validation.scenes.analytic import isotropic_case


@pytest.fixture(scope="module")
def point():
    return isotropic_case(resolution=(24, 24)).scene


def test_both_backends_implement_the_protocol(point):
    cfg = RunConfig(frame_photons=4_000, interleave=2)
    with Session(point, cfg) as s:
        assert isinstance(s.backend, LocalBackend) and isinstance(s.backend, Backend)
    members = [m for m in vars(Backend) if not m.startswith("_")]
    assert {"shoot", "render", "probe", "replay", "close"} <= set(members)
    for m in members:
        assert callable(getattr(RayBackend, m)), m


def test_deferred_map_gives_the_batchwise_estimates():
    rng = np.random.default_rng(4)
    n, q = 60_000, 500
    pts = rng.random((n, 3)).astype(np.float32)
    pts[:, 2] = 0.0
    nrm = np.tile(np.float32([0, 0, 1]), (n, 1))
    pw = rng.random((n, 1))
    qp = rng.random((q, 3)).astype(np.float32)
    qp[:, 2] = 0.0
    qn = np.tile(np.float32([0, 0, 1]), (q, 1))
    eager, deferred = PhotonMap("middle"), DeferredPhotonMap("middle", 1)
    for lo in range(0, n, 7_500):  # eight frames
        eager.add(pts[lo:lo + 7_500], nrm[lo:lo + 7_500], pw[lo:lo + 7_500])
        deferred.add(pts[lo:lo + 7_500], nrm[lo:lo + 7_500], pw[lo:lo + 7_500])
        if lo == 15_000:  # a query in between: the rest comes as a second batch
            deferred.ready()
    assert len(deferred) == n
    for kw in ({"k": 64, "max_radius": 0.05, "min_radius": 0.01}, {"k": 8}):
        a = eager.estimate(qp, qn, **kw)
        b = deferred.ready().estimate(qp, qn, **kw)
        np.testing.assert_array_equal(a.E, b.E)
        np.testing.assert_array_equal(a.r, b.r)


@pytest.mark.parametrize("channels", [1, 3])
def test_sparse_cell_sums_equal_a_whole_image_bincount(channels):
    rng = np.random.default_rng(channels)
    cells = 5_000
    store = rng.random((cells, channels)) * 1e3
    expected = store.copy()
    for _ in range(3):
        flat = rng.integers(0, 40, 3_000) * 97 % cells  # many photons per touched cell
        power = rng.random((3_000, channels)) * 10.0 ** rng.uniform(-30, 30, (3_000, 1))
        for c in range(channels):
            expected[:, c] += np.bincount(flat, weights=power[:, c], minlength=cells)
        add_to_cells(store, flat, power)
    np.testing.assert_array_equal(store, expected)
    add_to_cells(store, np.zeros(0, np.int64), np.zeros((0, channels)))  # empty frame
    np.testing.assert_array_equal(store, expected)


def _est(upper: float | None) -> FrameResult:
    err = None if upper is None else ErrorEstimate(upper, upper, 0.0, 0.0)  # .upper = noise
    return FrameResult(None, None, None, upper, 0, 0.0, error=err)


def test_error_schedule_spacing():
    plain = ErrorSchedule()
    assert plain.due(0)
    plain.estimated(1_000, _est(0.5))
    assert not plain.due(1_999) and plain.due(2_000)  # doubling without a target
    aimed = ErrorSchedule(target_error=0.1, aim=1.0)
    aimed.estimated(1_000, _est(0.4))  # 16× the photons expected: capped at 2×
    assert aimed.next_photons == 2_000 and not aimed.stop_expected
    aimed.estimated(2_000, _est(0.19))  # measured law: p = 1.07, clamped to 1 → 1.9×
    assert aimed.exponent("probes") == EXPONENT_RANGE[1]
    assert aimed.next_photons == pytest.approx(3_800) and aimed.stop_expected
    aimed.estimated(4_000, _est(0.11))  # a line through the three points
    x, y = np.log([1_000, 2_000, 4_000]), np.log([0.4, 0.19, 0.11])
    p = -np.polyfit(x, y, 1)[0]
    assert aimed.exponent("probes") == pytest.approx(p)
    assert aimed.next_photons == pytest.approx(4_000 * 1.1 ** (1 / p))
    aimed.estimated(5_000, _est(0.09))  # below the target: the very next frame
    assert aimed.due(5_000)
    aimed.estimated(5_000, _est(None))  # no figure: plain doubling
    assert aimed.next_photons == 10_000


def test_error_schedule_fits_each_figure_and_clamps_the_law():
    s = ErrorSchedule(target_error=0.1, aim=1.0)
    s.estimated(1_000, _est(0.15), "probes")
    s.estimated(1_500, _est(0.12), "map")  # another figure: its own law (0.5 at first)
    assert s.exponent("map") == 0.5 and s.next_photons == pytest.approx(1_500 * 1.44)
    s.estimated(2_000, _est(0.105), "probes")  # p = 0.51 from this figure's two points
    assert s.exponent("probes") == pytest.approx(np.log(0.15 / 0.105) / np.log(2))
    s.estimated(3_000, _est(0.16), "probes")  # the error grew: the slowest law allowed
    assert s.exponent("probes") == EXPONENT_RANGE[0]
    assert s.next_photons == pytest.approx(3_000 * 2)  # 1.6^(1/0.35) > growth
    s.estimated(4_000, _est(0.0))  # a zero figure: look again after the next frame
    assert s.next_photons == 4_000 and not s.stop_expected


def test_error_schedule_estimates_at_the_nearest_frame_to_the_stop():
    s = ErrorSchedule(target_error=0.1, aim=1.0)
    for n in (1_000, 2_000):
        assert s.due(n)
    s.estimated(2_000, _est(0.106))  # the law puts the stop at 2 247 photons
    assert s.stop_expected and s.next_photons == pytest.approx(2_000 * 1.06**2)
    assert s.due(2_200)  # frames of 200: 2 200 is nearer than 2 400
    s = ErrorSchedule(target_error=0.1, aim=1.0)
    s.due(1_000)
    s.due(2_000)
    s.estimated(2_000, _est(0.2))  # the stop at 8 000, beyond growth: plain ×2 rule
    assert not s.stop_expected and not s.due(3_900) and s.due(4_000)


def test_run_estimates_on_schedule_and_the_map_does_not_depend_on_it(point):
    cfg = RunConfig(frame_photons=8_000, interleave=2, seed=3)
    with Session(point, cfg) as s:
        seen: list[FrameResult] = []
        final = s.run(photons=64_000, callback=seen.append)
        logged = [e["photons"] for e in s.log if "photons" in e]
    assert logged == [8_000, 16_000, 32_000, 64_000]  # doubling, then the final map
    assert len(seen) == 7  # every frame but the last reports progress
    stale = [e for e in seen if "render" not in e.timings]  # frames that only shot
    assert stale and all(e.error_photons < e.photons for e in stale)
    with Session(point, cfg) as s:  # estimate after every frame instead
        for _ in range(8):
            s.frame(image=False)
        again = s.final_image()
    np.testing.assert_array_equal(final.lux, again.lux)
    assert final.rel_error == again.rel_error


def _halton_reference(index: int, perms: np.ndarray) -> list[float]:
    """The scrambled radical inverse written out digit by digit in Python."""
    out = []
    for d in range(N_DIMS):
        base, inv = int(PRIMES[d]), 1.0 / int(PRIMES[d])
        f, x, i = inv, 0.0, index
        for k in range(int(DIGITS[d])):
            i, digit = divmod(i, base)
            x += float(perms[d, k, digit]) * f
            f *= inv
        out.append(min(x, 1.0 - 1.1102230246251565e-16))
    return out


def test_halton_points_match_the_digit_by_digit_definition():
    rng = np.random.default_rng(9)
    idx = np.concatenate([np.arange(50), rng.integers(0, 2**62, 50)]).astype(np.int64)
    perms = digit_permutations(11, 3, 2, (5, 3))
    got = halton_points(idx, perms)
    ref = np.array([_halton_reference(int(i), perms) for i in idx])
    np.testing.assert_array_equal(got[:, 0], ref[:, 0])  # base 2: the same bits
    # bases 3–11: the same terms summed in another order (digit-group tables)
    np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=8 * 2.0**-53)


def test_bench_pipeline_rows(point):
    rows = bench_pipeline(point, RunConfig(frame_photons=10_000, interleave=2),
                          photons=30_000, repeats=1)
    assert [r["what"] for r in rows] == ["pair 1", "median"]
    r = rows[0]
    assert r["frames"] == 3 and r["estimates"] == 2
    assert r["ratio"] == pytest.approx(r["simulate_photons_per_s"] / r["tracer_photons_per_s"])
    assert 0 < r["ratio"] < 10
    # the run's own clock split: sampling + tracing + insertion = shooting, within the run
    assert 0 < r["sample_s"] and 0 < r["trace_s"] and r["insert_s"] >= 0
    assert r["sample_s"] + r["trace_s"] + r["insert_s"] <= r["run_s"]
    assert 0 < r["trace_share"] < 1 and 0 < r["ray_ratio"] < 10
    # the like-with-like baseline: the bare tracer on the run's own photons
    assert r["ratio_same_photons"] == pytest.approx(
        r["simulate_photons_per_s"] / r["tracer_same_photons_per_s"])
    assert 0 < r["ratio_same_photons"] < 10
    # without the final map the run is shorter, so its rate is higher
    assert r["frames_ratio_same_photons"] == pytest.approx(
        r["simulate_photons_per_s"] * r["run_s"] / (r["run_s"] - r["final_s"])
        / r["tracer_same_photons_per_s"], rel=1e-9)
    assert r["frames_ratio_same_photons"] > r["ratio_same_photons"]
    assert 0 < r["cpu_ratio_same_photons"] < 10  # CPU-seconds, the same comparison


def test_pipeline_recorder_keeps_the_runs_photons(point):
    cfg = RunConfig(frame_photons=10_000, interleave=2, seed=2)
    rec = StageRecorder()
    a = timed_run(point, cfg, 30_000, rec)
    pts, keys, w = rec.photons()
    assert len(pts) == len(keys) == len(w) == a["photons"] == 30_000
    b = timed_run(point, cfg, 30_000)  # recording does not change the run
    assert (a["photons"], a["rays"]) == (b["photons"], b["rays"])


def test_session_sums_what_the_clients_shot(point):
    with Session(point, RunConfig(frame_photons=8_000, interleave=2, spt=False)) as s:
        s.run(photons=24_000)
        tot = s.shoot_totals
    assert tot.photons == 24_000 and tot.rays >= tot.photons
    assert 0 < tot.sample_s + tot.trace_s <= tot.seconds


def test_grouped_halton_points_are_each_sets_points():
    perms = np.stack([digit_permutations(1, s, None) for s in range(3)])
    idx = [np.arange(5, 900), np.arange(0), np.arange(2**40, 2**40 + 77)]
    group = np.concatenate([np.full(len(i), s) for s, i in enumerate(idx)])
    got = halton_points_grouped(np.concatenate(idx), group, perms)
    want = np.concatenate([halton_points(i, perms[s]) for s, i in enumerate(idx)])
    np.testing.assert_array_equal(got, want)


def test_target_error_stops_at_the_first_estimate_below_it(point):
    cfg = RunConfig(frame_photons=8_000, interleave=2, seed=5)
    with Session(point, cfg) as s:
        seen: list[FrameResult] = []
        final = s.run(target_error=0.08, photons=2_000_000, callback=seen.append)
        estimated = [e for e in seen if "render" in e.timings]
    assert final.photons < 2_000_000 and s.frames >= 3
    # the probes' figure proposed the stop and the written map's own figure confirmed it
    assert stop_level(estimated[-1].error) <= 0.08 and stop_level(final.error) <= 0.08
    # no stop was proposed before the minimum frames
    assert all(e.photons >= 3 * 8_000 for e in estimated if stop_level(e.error) <= 0.08)
    assert len(estimated) < s.frames  # not every frame paid for an estimate
    # the stop reads the figure's upper bound at the look's z: the figure is below the
    # target, the bound at the first look's z within it
    assert final.error.total <= 0.08
    assert stop_level(final.error, look_z(1)) <= 0.08 or \
        stop_level(final.error, look_z(2)) <= 0.08
    assert final.rel_error == final.error.total


def test_the_stop_level_is_the_figures_upper_bound_at_the_looks_z():
    """stop_level: √(noise² + max(blur², 0) + z·se); the figure itself at z = 0 and
    without a blur estimate; a negative blur² estimate does not eat the margin."""
    assert stop_level(None) is None
    e = ErrorEstimate(0.019, 0.015, 0.0117, 0.0150, bias2=0.0117**2, bias2_se=4e-5)
    assert stop_level(e) == pytest.approx(math.hypot(0.015, 0.0117))
    assert stop_level(e, 2.0) == pytest.approx(math.sqrt(0.015**2 + 0.0117**2 + 8e-5))
    neg = ErrorEstimate(0.015, 0.015, 0.0, 0.0, bias2=-3e-4, bias2_se=5e-5)
    assert stop_level(neg, 1.5) == pytest.approx(math.sqrt(0.015**2 + 7.5e-5))
    assert stop_level(ErrorEstimate(0.03, 0.03, None)) == 0.03  # binning: the figure


def test_the_looks_spend_the_error_budget_by_halves():
    """look j tests at α·2^-j one-sided: Σ over any number of looks stays ≤ α."""
    zs = [look_z(j) for j in range(1, 8)]
    assert zs[0] == pytest.approx(NormalDist().inv_cdf(1 - STOP_ALPHA / 2))
    assert all(a < b for a, b in itertools.pairwise(zs))
    spent = sum(1 - NormalDist().cdf(z) for z in [look_z(j) for j in range(1, 201)])
    assert spent <= STOP_ALPHA + 1e-12
    with pytest.raises(ValueError):
        look_z(0)


def test_the_rule_spends_a_look_only_on_a_written_map_at_or_below_the_target():
    rule = MapErrorRule(0.02, min_frames=1)
    err = ErrorEstimate(0.018, 0.015, 0.01, 0.012, bias2=1e-4, bias2_se=2e-5)
    probes = FrameResult(None, None, None, 0.018, 0, 0.0, error=err)
    written = FrameResult(np.zeros((2, 2, 1)), None, None, 0.018, 0, 0.0, error=err)
    high = FrameResult(np.zeros((2, 2, 1)), None, None, 0.03, 0, 0.0,
                       error=ErrorEstimate(0.03, 0.03, 0.0, 0.0, 0.0, 1e-5))
    assert rule.level(err) == pytest.approx(stop_level(err, look_z(1)))
    rule.satisfied(probes, 5)
    rule.satisfied(high, 5)
    assert rule.looks == 0  # the probes propose, a figure above the target is no test
    ok = rule.satisfied(written, 5)
    assert rule.looks == 1 and ok == (stop_level(err, look_z(1)) <= 0.02)
    assert rule.level(err) == pytest.approx(stop_level(err, look_z(2)))


def test_final_map_without_probes_is_the_ici_map(point):
    """``simulate`` asks the final image without probe estimates (``probes=False``): the
    written ICI map must still be chosen with the sets' ΣΦ² (q), i.e. be the same map as
    with probes; without them every pixel fell back to its plain count (rung 0)."""
    cfg = RunConfig(frame_photons=8_000, interleave=2, spt=False)
    maps, rungs = [], []
    for probes in (True, False):
        with Session(point, cfg) as s:
            est = s.run(photons=32_000, probes=probes)
            maps.append(est.lux)
            rungs.append(est.rungs)
    assert np.array_equal(maps[0], maps[1])
    assert np.array_equal(rungs[0], rungs[1]) and rungs[1].max() > 0  # windows were used


@pytest.mark.parametrize("args", [(1, 3, None), (1, 3, 0, (5, 3)), (2**40 + 7, 15, 12, (5, 3)),
                                  (0, 0, None, (2, 1)), (5, 2, 3), (9, 1, 7, (60, 40))])
def test_compiled_digit_permutations_are_numpys(args):
    """The compiled shuffles draw from the same bit generators in the same order as a
    Python loop over ``Generator.permutation``: the same scramble, bit for bit."""
    got = digit_permutations(*args)
    np.testing.assert_array_equal(got, digit_permutations_reference(*args))
    for d in range(N_DIMS):  # each row a permutation of its base's digits
        b = int(PRIMES[d])
        assert np.array_equal(np.sort(got[d, :, :b], axis=1), np.tile(np.arange(b), (53, 1)))


def test_a_large_wall_checks_the_probes_until_the_law_expects_the_stop(point):
    """Where the written map costs more than the probes' figure (here 576 pixels for 64
    grid probes) the run estimates at the probes, and measures the written map itself
    where the error law places the stop; a small wall measures the map every time."""
    cfg = RunConfig(frame_photons=8_000, interleave=2, seed=7, probe_grid=(8, 8))
    with Session(point, cfg) as s:
        assert not s.map_check_is_cheap()
        seen: list[FrameResult] = []
        final = s.run(target_error=0.08, photons=2_000_000, callback=seen.append)
    estimated = [e for e in seen if "render" in e.timings]
    maps = [e for e in estimated if e.lux is not None]
    assert maps and estimated[0].lux is None  # the probes first, the map near the stop
    assert stop_level(final.error) <= 0.08 and final.photons == maps[-1].photons
    with Session(point, RunConfig(frame_photons=8_000, interleave=2)) as s:
        assert s.map_check_is_cheap()  # 576 pixels, 2 048 grid probes


def test_error_schedule_scales_the_probes_figure_to_the_written_maps():
    s = ErrorSchedule(target_error=0.1, aim=1.0)
    s.calibrate(_est(0.4), _est(0.2))  # the map's figure is half the probes'
    assert s.calibrated and s.probe_scale == pytest.approx(0.5)
    s.estimated(1_000, _est(0.24))  # as a map figure 0.12: (1.2)² photons
    assert s.stop_expected and s.next_photons == pytest.approx(1_440)
    s.estimated(1_440, _est(0.16), "map")  # one map point: the probes' law is borrowed
    assert s.exponent("map") == 0.5
    s.calibrate(_est(None), _est(0.2))  # no probe figure: the ratio measured stays
    assert s.probe_scale == pytest.approx(0.5)


def test_the_schedule_says_what_an_estimate_measures():
    assert ErrorSchedule().measure(10) == "probes"  # no target: the probes, always
    s = ErrorSchedule(target_error=0.1, min_frames=3)
    assert s.measure(2) == "probes" and s.measure(3) == "calibrate"
    s.calibrate(_est(0.4), _est(0.2))
    assert s.measure(3) == "probes"
    s.stop_expected = True
    assert s.measure(3) == "map"
    assert ErrorSchedule(target_error=0.1, map_is_cheap=True).measure(0) == "map"


def test_map_error_rule_reads_the_stop_level_after_the_minimum_frames():
    rule: StoppingRule = MapErrorRule(0.1, min_frames=3)
    assert rule.satisfied(_est(0.09), 3) and not rule.satisfied(_est(0.09), 2)
    assert not rule.satisfied(_est(0.11), 9) and not rule.satisfied(_est(None), 9)


class _SecondEstimate:
    """A stopping rule of another kind: satisfied from the second estimate it is asked
    about on (what it reads is up to the rule)."""

    def __init__(self) -> None:
        self.asked: list[int] = []

    def satisfied(self, est: FrameResult, frames: int) -> bool:
        self.asked.append(est.photons)
        return len(set(self.asked)) >= 2


def test_run_stops_where_another_stopping_rule_is_satisfied(point):
    """A rule other than the target error's plugs into the same loop: the probes propose
    the stop, the written map confirms it, and the run returns that map."""
    cfg = RunConfig(frame_photons=8_000, interleave=2, seed=3)
    rule = _SecondEstimate()
    with Session(point, cfg) as s:
        final = s.run(photons=2_000_000, rule=rule)
    assert final.photons == 16_000 and final.lux is not None  # estimates at 8 k and 16 k
    assert rule.asked == [8_000, 16_000, 16_000]  # the probes', then the written map's


def test_the_written_map_is_remade_from_its_inputs(point):
    """The written-map interface: the inputs a run's map was made from make the same map
    again, bit for bit (what studies such as validation/edge_study.py remake)."""
    cfg = RunConfig(frame_photons=8_000, interleave=2, seed=4)
    with Session(point, cfg) as s:
        s.map_estimator.keep_inputs = True
        final = s.run(photons=24_000, probes=False)
        inputs = s.map_estimator.last_inputs
    wm = inputs.make()
    H, W = inputs.shape
    assert np.array_equal(wm.lux.reshape(H, W, -1), final.lux)
    assert wm.error == final.error and wm.fused == s.last_map_fused
