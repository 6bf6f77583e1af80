"""``lightsim simulate`` end to end: outputs, units, bookkeeping, and bad input (exit 2)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lightsim.io.exr import read_exr

from support import run_cli as _run
from support import write_point_lamp


@pytest.fixture(scope="module")
def point_lamp(tmp_path_factory):
    """An isotropic 1000 lm source 2 m from the wall, nothing else."""
    return write_point_lamp(tmp_path_factory.mktemp("lamp") / "point.glb")


def test_simulate_writes_outputs_in_lux(point_lamp, tmp_path, capsys):
    out = tmp_path / "run"
    code, _, err = _run(["simulate", str(point_lamp), "--photons", "400000",
                              "--wall-distance", "2", "--wall-size", "4x4",
                              "--resolution", "40x40", "--estimator", "bin",
                              "--frame-photons", "100000", "--out", str(out), "--quiet"], capsys)
    assert code == 0, err
    chans, meta = read_exr(out / "wall_lux.exr")
    lux = chans["Y"]
    assert lux.shape == (40, 40) and lux.dtype == np.float32
    assert meta["units"] == "lx" and meta["photons"] == 400000 and meta["seed"] == 1
    summary = json.loads((out / "summary.json").read_text())
    # exact centre illuminance Φ/(4π d²), averaged over the 4 central pixels (0.1 m)
    centre = lux[19:21, 19:21].mean()
    assert centre == pytest.approx(1000 / (4 * np.pi * 4), rel=0.08)
    e = summary["energy_lm"]
    parts = sum(v for k, v in e.items() if k not in ("emitted", "sum_of_parts",
                                                     "closure_relative"))
    assert e["emitted"] == pytest.approx(1000.0, rel=1e-12)
    assert abs(parts - e["emitted"]) <= 1e-6 * e["emitted"]
    w = summary["wall"]
    assert w["distance_m"] == 2.0 and w["resolution"] == [40, 40]
    assert w["h_axis"] == [-1.0, 0.0, 0.0] and w["v_axis"] == [0.0, 1.0, 0.0]
    # error estimates at doubling photon counts, then the final map's
    assert [e["photons"] for e in summary["error_vs_time"]] == [100_000, 200_000, 400_000]
    assert all(s["run"] is False for s in summary["plan"]["stages"]
               if s["stage"].startswith("selective"))
    assert (out / "wall_lux.png").stat().st_size > 1000
    assert (out / "error_vs_time.png").exists()


@pytest.mark.parametrize("argv,match", [
    (["simulate", "missing.glb"], "no such file"),
    (["simulate", "{lamp}", "--flux", "-3"], "--flux must be > 0 lm"),
    (["simulate", "{lamp}", "--resolution", "0x5"], "--resolution"),
    (["simulate", "{lamp}", "--interleave", "0"], "interleave"),
    (["simulate", "{lamp}", "--photons", "0"], "--photons"),
    (["simulate", "{lamp}", "--target-error", "3"], "--target-error must be in (0, 1)"),
    (["simulate", "{lamp}", "--filament", "H99", "--filament-at", "0,0,0"], "H99"),
    (["simulate", "{lamp}", "--out", "{file}/sub"], "not writable"),
    (["simulate", "{lamp}", "--out", "{file}"], "is a file"),  # click's check, one line
    (["simulate", "{lamp}", "--bogus-option"], "No such option"),
    (["simulate", "{lamp}", "--ies", "--ldt"], "must end in .ies"),  # checked before the run
    (["simulate", "{lamp}", "--ldt", "beam.txt"], "must end in .ldt"),
])
def test_bad_options_exit_2_with_one_line(point_lamp, tmp_path, capsys, argv, match):
    afile = tmp_path / "afile"
    afile.write_text("x")
    argv = [a.format(lamp=point_lamp, file=afile) for a in argv]
    if "--out" not in argv:
        argv += ["--out", str(tmp_path / "o")]
    code, _, err = _run(argv + ["--quiet"], capsys)
    assert code == 2
    lines = [ln for ln in err.strip().splitlines() if ln]
    assert len(lines) == 1 and lines[0].startswith("lightsim: error:"), err
    assert match in lines[0]
    assert "Traceback" not in err
    assert not (tmp_path / "o").exists()  # bad input leaves nothing, not even the folder
    out = tmp_path / "o"  # nothing written: bad options fail before the run
    assert not out.exists() or not any(out.iterdir())


def test_failed_run_keeps_earlier_outputs(point_lamp, tmp_path, capsys):
    """A run that fails on bad input leaves the previous results untouched."""
    out = tmp_path / "run"
    args = ["simulate", str(point_lamp), "--photons", "50000", "--frame-photons", "50000",
            "--estimator", "bin", "--resolution", "20x20", "--wall-distance", "2",
            "--out", str(out), "--quiet"]
    assert _run(args, capsys)[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert _run(args[:2] + ["--flux", "nan"] + args[2:], capsys)[0] == 2
    after = {p.name: p.read_bytes() for p in out.iterdir()}
    assert before == after


def test_lamp_that_lights_no_road_still_finishes(tmp_path, capsys):
    """All light backwards: wall and road have nothing to show; the run must still write its
    set and say so (found by the fuzz study: a traceback after the plots)."""
    from lightsim.luminaires.photometric import CandelaGrid, write_ies

    c = np.arange(0.0, 360.0, 10.0)
    g = np.arange(0.0, 181.0, 5.0)
    backwards = (c > 100.0) & (c < 260.0)  # C = 180° is straight behind the lamp
    cd = np.where(backwards[:, None], 1000.0, 0.0) * np.ones((1, len(g)))
    lamp = write_ies(tmp_path / "back.ies", CandelaGrid(c, g, cd, None, {}))
    out = tmp_path / "run"
    code, _, err = _run(["simulate", str(lamp), "--photons", "20000", "--resolution", "64x32",
                         "--out", str(out), "--quiet"], capsys)
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["road"]["reach_m"] is None and (out / "road.png").exists()


def test_a_coarse_far_field_file_warns_in_one_line(tmp_path, capsys):
    """``--ies-step 5``: the file cannot hold the headlamp's peak; one warning line says so
    and names the option; the run's outputs are written as always."""
    lamp = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "headlight.glb"
    out = tmp_path / "run"
    code, _, err = _run(["simulate", str(lamp), "--photons", "300000", "--resolution",
                         "160x64", "--regulation", "r112-b-passing", "--farfield-photons",
                         "100000", "--ies", str(out / "coarse.ies"), "--ies-step", "5",
                         "--ies-type", "C", "--out", str(out), "--quiet"], capsys)
    assert code == 0, err
    lines = [ln for ln in err.splitlines() if "does not reproduce" in ln]
    assert len(lines) == 1 and lines[0].startswith("lightsim: warning: coarse.ies does not")
    assert "--ies-step 5° is too coarse" in lines[0] and "Imax" in lines[0]
    ff = json.loads((out / "summary.json").read_text())["farfield"]
    check = ff["checks"][str(out / "coarse.ies")]
    assert check["step_deg"] == 5.0 and check["angles"] == [72, 37]
    assert check["peak_cd"] < 0.9 * check["run_imax_cd"]
    assert ff["warnings"] == [ff["warning"]]
