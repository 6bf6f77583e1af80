"""`bench tracer` rows: photon tracing against raw embree in one run (small and fast)."""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.tracer import PhotonTracer
from lightsim.validation.bench.tracer import bench_tracer, stage_rows
from lightsim.validation.bench.tracer_aim import aim_rotation, bench_aim
from lightsim.validation.scenes.analytic import paraboloid_case


def test_bench_rows_compare_tracing_with_raw_embree():
    scene = paraboloid_case(resolution=(16, 16)).scene
    trace, raw = bench_tracer(scene, photons=20_000, repeats=2, threads=1)
    assert trace["what"] == "photon tracing" and raw["what"].startswith("raw embree")
    assert trace["rays"] == raw["rays"] > trace["photons"] == 20_000
    # the paraboloid: every photon casts one ray, those hitting the mirror a second
    assert 1.0 < trace["rays_per_photon"] < 2.0
    assert 0.2 < trace["wall_photons_per_emitted"] < 0.8
    for key in ("ratio_vs_raw_embree", "cpu_ratio_vs_raw_embree",
                "min_time_ratio_vs_raw_embree"):
        assert 0.0 < trace[key] < 10.0 and raw[key] == 1.0


def test_aim_bench_rows():
    scene = paraboloid_case(resolution=(16, 16)).scene
    rebuild, moved = bench_aim(scene, repeats=1, frame_photons=5000)
    assert "rebuilt" in rebuild["what"] and "wall_transform" in moved["what"]
    assert rebuild["update_s"] > 0 and moved["update_s"] > 0 and moved["frame_s"] > 0
    # the aim rotation turns the lamp axis +Z towards +H (world −X) and +V (up)
    axis = aim_rotation(10.0, 5.0)[:3, :3] @ [0.0, 0.0, 1.0]
    assert axis[0] < 0 and axis[1] > 0


def test_stage_rows_add_up_to_the_traced_time_and_leave_records_unchanged():
    scene = paraboloid_case(resolution=(16, 16)).scene
    rows = stage_rows(scene, photons=20_000, threads=1, repeats=1)
    assert [r["stage"] for r in rows] == ["emit", "start", "cast", "bounce", "rest"]
    assert all(r["thread_seconds"] >= 0 for r in rows)
    assert rows[2]["thread_seconds"] > 0 and rows[3]["thread_seconds"] > 0
    assert sum(r["share"] for r in rows) == pytest.approx(1.0, abs=1e-9)
    assert 1.0 < rows[0]["rays"] / rows[0]["photons"] < 2.0
    # the stage clock changes no record
    idx = np.arange(5000, dtype=np.int64)
    pts = halton_points(idx, digit_permutations(3, 0, None))
    keys = photon_keys(3, 0, 0, idx)
    tracer = PhotonTracer(scene, threads=2, min_chunk=1024)
    plain = tracer.trace_points(pts, keys)
    tracer.stages = {}
    timed = tracer.trace_points(pts, keys)
    tracer.close()
    assert set(tracer.stages) == {"emit", "start", "cast", "bounce"}
    np.testing.assert_array_equal(plain.records.position, timed.records.position)
    np.testing.assert_array_equal(plain.ledger, timed.ledger)
