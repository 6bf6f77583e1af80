"""``lightsim road RUN_DIR`` on a run folder whose far field is a constant-intensity point
source: the written wall map read back, reach to 1 %, intervals from per-set maps, the
sensitivity re-projection, and bad input (one line, exit 2, nothing written)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from lightsim.io.exr import write_exr
from lightsim.io.summary import write_json
from lightsim.road_evaluation import (
    ROAD_FILE,
    WALL_SETS_FILE,
    RoadSettings,
    evaluate_road,
    load_far_field,
)
from lightsim.wall import WallFrame

from support import run_cli, write_point_lamp

I0 = 20_000.0
FRAME = {"centre": [0.0, 0.0, 25.0], "h_axis": [-1.0, 0.0, 0.0], "v_axis": [0.0, 1.0, 0.0],
         "normal": [0.0, 0.0, -1.0], "h_range_m": [-20.0, 20.0], "v_range_m": [-6.0, 6.0],
         "distance_m": 25.0, "resolution": [400, 120]}


def _lux_of_constant(frame: WallFrame, scale: float = 1.0) -> np.ndarray:
    h, v = frame.pixel_centres()
    H, V = np.meshgrid(h, v)
    d = frame.distance_m
    return scale * I0 * d / (d * d + H * H + V * V) ** 1.5  # E = I·cosθ/r² on the wall


def write_run(out: Path, sets: int = 0, scale: float = 1.0) -> Path:
    """A finished run's files: summary.json with the wall frame, wall_lux.exr (and the
    per-set maps of ``simulate --road`` when ``sets``)."""
    out.mkdir(parents=True, exist_ok=True)
    frame = WallFrame.from_any(FRAME)
    write_exr(out / "wall_lux.exr", {"Y": _lux_of_constant(frame, scale)})
    write_json(out / "summary.json", {"wall": FRAME, "photons": 0})
    if sets:
        sub = frame.with_resolution(200, 60)
        rng = np.random.default_rng(1)
        f = 1.0 + 0.03 * rng.standard_normal(sets)
        f /= f.mean()
        maps = np.stack([_lux_of_constant(sub, x) for x in f]).astype(np.float32)
        np.savez(out / WALL_SETS_FILE, lux=maps, frame=np.asarray(json.dumps(sub.to_dict())))
    return out


def _exact_reach(level: float, offset: float, spacing: float = 1.2, h: float = 0.65) -> float:
    def e(s: float) -> float:
        return sum(I0 * s / ((offset - x) ** 2 + (0.25 - h) ** 2 + s * s) ** 1.5
                   for x in (-spacing / 2, spacing / 2)) - level
    return brentq(e, 10.0, 199.0)


def test_reach_from_the_written_map(tmp_path: Path) -> None:
    far = load_far_field(write_run(tmp_path / "run"))
    ev = evaluate_road(far, RoadSettings(approaches=("straight",), step=0.1))
    row = next(r for r in ev.reach if r["sensor"] == "right_edge" and r["level_lux"] == 5.0)
    assert row["distance_m"] == pytest.approx(_exact_reach(5.0, 1.8), rel=0.01)
    assert "interval_m" not in row and ev.n_sets == 0


def test_cli_writes_table_plots_and_intervals(tmp_path: Path, capsys) -> None:
    run = write_run(tmp_path / "run", sets=4)
    code, out, err = run_cli(["road", str(run), "--approaches", "straight,right-150",
                              "--step", "0.5"], capsys)
    assert code == 0, err
    assert "from 4 interleave sets" in out and "No rating score" in out
    doc = json.loads((run / ROAD_FILE).read_text())
    assert doc["intervals"] and doc["score"] is None
    row = next(r for r in doc["reach"] if r["approach"] == "straight"
               and r["sensor"] == "right_edge" and r["level_lux"] == 5.0)
    exact = _exact_reach(5.0, 1.8)
    lo, hi = row["interval_m"]
    assert lo <= exact <= hi and hi - lo < 0.2 * exact
    assert {v["variant"] for v in doc["sensitivity"]} == {
        "pitch +0.5°", "pitch −0.5°", "height +0.1 m", "height −0.1 m"}
    assert all(v["photons_traced"] == 0 for v in doc["sensitivity"])
    for name in ("straight", "right-150"):
        png = run / f"road_{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_sensitivity_height_matches_a_direct_evaluation(tmp_path: Path) -> None:
    far = load_far_field(write_run(tmp_path / "run"))
    base = evaluate_road(far, RoadSettings(approaches=("straight",), step=0.1))
    moved = evaluate_road(far, RoadSettings(approaches=("straight",), step=0.1,
                                            mount_height=0.75, sensitivity=False))
    var = next(v for v in base.sensitivity if v["variant"] == "height +0.1 m")
    want = {(r["sensor"], r["level_lux"]): r["distance_m"] for r in moved.reach}
    for r in var["rows"]:
        if r["sensor"] != "glare":
            assert r["distance_m"] == pytest.approx(want[(r["sensor"], r["level_lux"])])


@pytest.mark.parametrize("args, text", [
    (["--approaches", "left-0"], "radius must be > 0"),
    (["--approaches", "right--150"], "radius"),
    (["--mount-height", "9"], "outside the screen's field"),
    (["--mount-height", "0"], "--mount-height"),
    (["--pitch", "nan"], "--pitch"),
])
def test_bad_input_one_line_nothing_written(tmp_path: Path, capsys, args, text) -> None:
    run = write_run(tmp_path / "run")
    before = sorted(p.name for p in run.iterdir())
    code, _out, err = run_cli(["road", str(run), *args], capsys)
    assert code == 2
    assert text in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in run.iterdir()) == before


def test_not_a_run(tmp_path: Path, capsys) -> None:
    code, _, err = run_cli(["road", str(tmp_path)], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1


def test_simulate_road_stores_sets_and_table(tmp_path: Path, capsys) -> None:
    """``simulate --road`` on a real (small) run: the table in summary.json, road.json, the
    per-set maps; ``lightsim road`` on the folder then has intervals."""
    lamp = write_point_lamp(tmp_path / "lamp.glb")
    out = tmp_path / "out"
    code, text, err = run_cli(["simulate", str(lamp), "-n", "40000", "--road", "--out",
                               str(out), "--outputs", "exr,json"], capsys)
    assert code == 0, err
    assert "road evaluation" in text
    summary = json.loads((out / "summary.json").read_text())
    table = summary["road_evaluation"]
    assert table["intervals"] and table["interleave_sets"] > 1
    assert (out / WALL_SETS_FILE).is_file() and (out / ROAD_FILE).is_file()
    with np.load(out / WALL_SETS_FILE) as data:
        assert data["lux"].shape[0] == table["interleave_sets"]
    code, text, err = run_cli(["road", str(out), "--approaches", "straight", "--no-plots"],
                              capsys)
    assert code == 0, err
    assert "from 4 interleave sets" in text or "interleave sets" in text


def test_simulate_road_keeps_no_photon(tmp_path: Path, capsys) -> None:
    """``--road`` reads its per-set maps at points known before the run: the run keeps no
    photon, and the maps and the table equal those of a run keeping every photon, bit for
    bit."""
    lamp = write_point_lamp(tmp_path / "lamp.glb")
    maps, tables = {}, {}
    for extra in ([], ["--keep-photons"]):
        out = tmp_path / f"out{len(extra)}"
        code, _, err = run_cli(["simulate", str(lamp), "-n", "40000", "--road", "--out",
                                str(out), "--outputs", "exr,json", *extra], capsys)
        assert code == 0, err
        summary = json.loads((out / "summary.json").read_text())
        assert summary["config"]["keep_photons"] is bool(extra)
        table = summary["road_evaluation"]
        table.pop("seconds", None)
        tables[bool(extra)] = table
        with np.load(out / WALL_SETS_FILE) as data:
            maps[bool(extra)] = data["lux"]
    assert maps[False].max() > 0 and np.array_equal(maps[False], maps[True])
    assert tables[False] == tables[True]


def test_left_lamp_from_a_second_run(tmp_path: Path, capsys) -> None:
    """``--left-run``: a dark left lamp leaves only the right lamp's light."""
    run = write_run(tmp_path / "right")
    dark = write_run(tmp_path / "left", scale=0.0)
    code, _, err = run_cli(["road", str(run), "--left-run", str(dark), "--approaches",
                            "straight", "--step", "0.1", "--no-plots", "--no-sensitivity"],
                           capsys)
    assert code == 0, err
    row = next(r for r in json.loads((run / ROAD_FILE).read_text())["reach"]
               if r["sensor"] == "right_edge" and r["level_lux"] == 3.0)

    def e(s: float) -> float:  # the right lamp alone, 0.6 m right of the lane centre
        return I0 * s / ((1.8 - 0.6) ** 2 + 0.4 ** 2 + s * s) ** 1.5 - 3.0
    assert row["distance_m"] == pytest.approx(brentq(e, 10.0, 199.0), rel=0.01)
    assert not (dark / ROAD_FILE).exists()


def test_simulate_road_checks_the_field_before_shooting(tmp_path: Path, capsys) -> None:
    lamp = write_point_lamp(tmp_path / "lamp.glb")
    out = tmp_path / "out"
    code, _, err = run_cli(["simulate", str(lamp), "-n", "1000", "--road", "--mount-height",
                            "8", "--out", str(out)], capsys)
    assert code == 2 and "outside the screen's field" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()


def test_mirror_left_swaps_a_skewed_beam(tmp_path: Path) -> None:
    """A far field brighter to the right: with ``mirror_left`` the left lamp throws it to
    the left, so the pair lights the left edge more than without."""
    run = write_run(tmp_path / "run")
    far = load_far_field(run)
    h = far.frame.h_deg()[None, :]
    skewed = far.lux * (1.0 + 0.9 * np.tanh(h / 5.0))
    far = type(far)(skewed, far.frame)
    base = RoadSettings(approaches=("straight",), sensitivity=False)
    plain = evaluate_road(far, base)
    mirrored = evaluate_road(far, RoadSettings(approaches=("straight",), sensitivity=False,
                                               mirror_left=True))
    left_plain = plain.curves["straight"][1].lux
    left_mirr = mirrored.curves["straight"][1].lux
    assert np.nanmean(left_mirr) > 1.2 * np.nanmean(left_plain)
