"""The plot process (lightsim/io/plot_worker.py): the same files, byte for byte, as drawing
them in-process; errors raised where the caller asks; a plot process that dies or is given
up costs no plot; ``lightsim simulate`` starts and stops it."""

from __future__ import annotations

import json
import os
import signal
import time

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.io import plot_worker
from lightsim.io.plot_worker import InProcess, PlotProcess
from lightsim.options import lookup
from lightsim.simulate import SimulateOptions
from lightsim.wall import WallFrame

from support import run_cli, write_point_lamp


def _beam(H: int = 48, W: int = 96) -> tuple[np.ndarray, dict]:
    """A low-beam-like map (lx): a smooth spot cut off above a kinked line."""
    frame = WallFrame(np.array([0.0, 0.0, 25.0]), np.array([-1.0, 0.0, 0.0]),
                      np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0]), (-12.0, 12.0),
                      (-4.0, 2.0), 25.0, (W, H)).to_dict()
    y, x = np.mgrid[0:H, 0:W]
    lux = 40.0 * np.exp(-(((x - 0.55 * W) / (0.2 * W)) ** 2 + ((y - 0.5 * H) / (0.3 * H)) ** 2))
    lux[y < 0.35 * H + 0.1 * np.clip(x - 0.5 * W, 0, None)] *= 0.02
    return lux, frame


def _draw_all(plots, out, lux, frame):
    """The four plots of a run, as the outputs hand them over."""
    marks = [{"name": "75R", "h_deg": 1.15, "v_deg": -0.57, "verdict": "pass"}]
    return [
        plots.draw("lux_png", out / "wall_lux.png", lux, frame, log=False, title="beam"),
        plots.draw("error_vs_time", out / "error_vs_time.png",
                   [{"photons": 1000 * k, "seconds": 0.1 * k, "rel_error": 0.2 / k ** 0.5}
                    for k in range(1, 6)]),
        plots.draw("isolux", out / "isolux.png", lux, frame, results=marks,
                   title="iso-lux on the screen", noise_floor_lx=0.05,
                   estimate_area_px=4.0),
        plots.draw("road", out / "road.png", lux, frame, mount_height_m=0.65),
    ]


#: patience where a test checks that the plot process drew a plot: at nice 10 it may get
#: little of a loaded CI machine, where the 5 s default would (rightly) draw it here
SLOW = 300.0


def _ready(h: PlotProcess, limit: float = 60.0) -> None:
    """Wait (bounded) until the plot process has warmed up and asked for a plot."""
    t0 = time.monotonic()
    while not h._idle:
        assert h.alive and time.monotonic() - t0 < limit, "the plot process never asked for work"
        time.sleep(0.02)


@pytest.fixture()
def plots():
    h = PlotProcess()
    assert h.alive
    yield h
    h.close()


def test_same_files_byte_for_byte(plots, tmp_path):
    lux, frame = _beam()
    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir()
    there.mkdir()
    local = [p.result() for p in _draw_all(InProcess(), here, lux, frame)]
    _ready(plots)
    pend = _draw_all(plots, there, lux, frame)
    remote = [p.result(patience=SLOW) for p in pend]
    assert all(p.remote for p in pend)  # the plot process drew every one
    for name in ("wall_lux.png", "error_vs_time.png", "isolux.png", "road.png"):
        assert (here / name).read_bytes() == (there / name).read_bytes(), name
    # the road illuminance comes back with the plot (the summary's reach reads it)
    a, b = local[3], remote[3]
    assert np.array_equal(a.lux, b.lux, equal_nan=True) and a.reach_m(1.0) == b.reach_m(1.0)


def test_error_is_raised_by_result(plots, tmp_path):
    lux, frame = _beam()
    _ready(plots)
    p = plots.draw("isolux", tmp_path / "isolux.png", lux, frame, levels=[-1.0])
    with pytest.raises(InputError, match="iso-lux levels must be positive"):
        p.result(patience=SLOW)
    assert p.remote
    # the plot process goes on after a failed plot
    q = plots.draw("road", tmp_path / "road.png", lux, frame)
    assert q.result(patience=SLOW) is not None and q.remote and (tmp_path / "road.png").is_file()


def test_dead_plot_process_costs_no_plot(plots, tmp_path):
    lux, frame = _beam()
    plots._proc.kill()
    plots._proc.wait()
    p = plots.draw("lux_png", tmp_path / "a.png", lux, frame)
    assert p.result() is None and not p.remote
    assert (tmp_path / "a.png").is_file()


def test_abandoned_plot_process_leaves_its_plots_to_the_caller(plots, tmp_path):
    lux, frame = _beam()
    pend = [plots.draw("isolux", tmp_path / f"{k}.png", lux, frame) for k in range(3)]
    plots.abandon()  # e.g. the output set is given up
    assert plots._proc.poll() is not None and not plots.alive
    for k, p in enumerate(pend):
        p.result()
        assert (tmp_path / f"{k}.png").is_file() and not p.remote


@pytest.mark.skipif(not hasattr(signal, "SIGSTOP"), reason="needs POSIX job control")
def test_a_stalled_plot_process_is_ended_and_the_plot_drawn_here(plots, tmp_path):
    lux, frame = _beam()
    _ready(plots)
    p = plots.draw("road", tmp_path / "road.png", lux, frame)  # taken at once
    os.kill(plots._proc.pid, signal.SIGSTOP)  # as if it got no core
    t0 = time.monotonic()
    assert p.result(patience=0.3) is not None and not p.remote
    assert time.monotonic() - t0 < 20
    assert plots._proc.poll() is not None and not plots.alive  # killed: no late file


@pytest.mark.skipif(not hasattr(signal, "SIGSTOP"), reason="needs POSIX job control")
def test_plots_a_busy_plot_process_has_not_taken_are_drawn_here_at_once(tmp_path):
    """On a loaded machine the low-priority plot process may still be starting when the outputs
    ask for their plots: the run draws them itself instead of waiting."""
    lux, frame = _beam()
    h = PlotProcess()
    try:
        os.kill(h._proc.pid, signal.SIGSTOP)
        pend = [h.draw(n, tmp_path / f"{n}.png", lux, frame) for n in ("lux_png", "road")]
        t0 = time.monotonic()
        for p in pend:
            p.result(patience=60.0)
            assert not p.remote
        assert time.monotonic() - t0 < 30  # no wait for the plot process's patience
        assert h.alive  # the plot process was not needed, not ended
    finally:
        h.close()
    assert h._proc.poll() is not None


def test_plot_process_of_another_lightsim_draws_nothing(monkeypatch):
    """main() returns at once where the lightsim it imported is not the caller's."""
    touched = []
    monkeypatch.setattr(plot_worker, "_serve", lambda *a: touched.append(a))
    plot_worker.main("/nonexistent/lightsim")
    assert touched == []


def test_unknown_plot_and_start_policy(monkeypatch, plots):
    monkeypatch.setattr(plot_worker, "_cores", lambda: 2)
    with pytest.raises(ValueError, match="unknown plot"):
        plots.draw("pie_chart")
    assert isinstance(plot_worker.start(wanted=False), InProcess)
    monkeypatch.setenv("LIGHTSIM_PLOT_PROCESS", "0")
    assert isinstance(plot_worker.start(), InProcess)
    monkeypatch.setattr(plot_worker, "_cores", lambda: 1)
    monkeypatch.setenv("LIGHTSIM_PLOT_PROCESS", "1")
    assert isinstance(plot_worker.start(), InProcess)  # one core: nothing to overlap


def test_simulate_draws_with_the_plot_process(monkeypatch, tmp_path, capsys):
    """The command's plots come from the plot process (started with the command, stopped at its
    end) and are the files an in-process run writes."""
    lamp = write_point_lamp(tmp_path / "point.glb")
    args = ["--photons", "40000", "--wall-distance", "2", "--wall-size", "4x4",
            "--resolution", "24x24", "--frame-photons", "20000", "--quiet"]
    started = []
    real = plot_worker.start

    def spy(wanted=True):
        h = real(wanted)
        started.append(h)
        return h

    monkeypatch.setattr(plot_worker, "start", spy)
    monkeypatch.setattr(plot_worker, "_cores", lambda: 2)  # also on a one-core runner
    monkeypatch.setenv("LIGHTSIM_PLOT_PROCESS", "1")
    code, _, err = run_cli(["simulate", str(lamp), *args, "--out", str(tmp_path / "a")],
                           capsys)
    assert code == 0, err
    assert len(started) == 1 and isinstance(started[0], PlotProcess)
    assert started[0]._proc.poll() is not None  # stopped with the command
    monkeypatch.setenv("LIGHTSIM_PLOT_PROCESS", "0")
    code, _, err = run_cli(["simulate", str(lamp), *args, "--out", str(tmp_path / "b")],
                           capsys)
    assert code == 0, err
    assert isinstance(started[1], InProcess)
    for name in ("wall_lux.png", "isolux.png", "road.png"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    s = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert "error_vs_time.png" in s["outputs"] and s["road"] == json.loads(
        (tmp_path / "b" / "summary.json").read_text())["road"]
    # a run that asks for no plot starts no plot process
    code, _, err = run_cli(["simulate", str(lamp), *args, "--out", str(tmp_path / "c"),
                            "--outputs", "exr,json"], capsys)
    assert code == 0, err
    assert isinstance(started[2], InProcess)


def test_plot_outputs_are_the_option_s_plots():
    choices = lookup(SimulateOptions, "outputs").choices
    assert set(plot_worker.PLOT_OUTPUTS) == set(choices) - {"exr", "json"}


@pytest.mark.parametrize(("argv", "started"), [
    (["simulate", "lamp.glb"], True),
    (["simulate", "lamp.glb", "--outputs", "exr,isolux"], True),
    (["simulate", "lamp.glb", "--outputs=all"], True),
    (["simulate", "lamp.glb", "--outputs", "exr,json"], False),
    (["simulate", "lamp.glb", "--outputs=json"], False),
    (["report", "out"], True),
    (["report", "--list-rulesets"], False),
    (["view", "lamp.glb"], False),
    ([], False),
])
def test_prestart_reads_the_command_line(monkeypatch, argv, started):
    monkeypatch.setattr(plot_worker, "_cores", lambda: 2)
    monkeypatch.setenv("LIGHTSIM_PLOT_PROCESS", "1")
    monkeypatch.setattr(plot_worker, "_early", None)
    plot_worker.prestart(argv)
    early = plot_worker._early
    try:
        assert (early is not None) == started
        if started:  # start() hands the very plot process over; not wanted, it is stopped
            assert plot_worker.start(wanted=True) is early and plot_worker._early is None
    finally:
        if early is not None:
            early.close()
    plot_worker.prestart(["simulate", "lamp.glb"])
    early = plot_worker._early
    assert isinstance(plot_worker.start(wanted=False), InProcess)
    assert early._proc.poll() is not None


def test_report_draws_with_the_plot_process(monkeypatch, tmp_path, capsys):
    """``lightsim report`` redraws a run's plots with the plot process: the same files as the
    run's own; a bad rule set stops it with one line and leaves the plots whole."""
    lamp = write_point_lamp(tmp_path / "point.glb")
    run = tmp_path / "run"
    monkeypatch.setenv("LIGHTSIM_PLOT_PROCESS", "0")
    code, _, err = run_cli(["simulate", str(lamp), "--photons", "40000", "--wall-distance",
                            "2", "--wall-size", "4x4", "--resolution", "24x24", "--quiet",
                            "--out", str(run)], capsys)
    assert code == 0, err
    names = ("wall_lux.png", "error_vs_time.png", "isolux.png", "road.png")
    first = {n: (run / n).read_bytes() for n in names}
    for n in names:
        (run / n).unlink()
    started = []
    real = plot_worker.start
    monkeypatch.setattr(plot_worker, "start", lambda wanted=True: started.append(
        real(wanted)) or started[-1])
    monkeypatch.setattr(plot_worker, "_cores", lambda: 2)
    monkeypatch.setenv("LIGHTSIM_PLOT_PROCESS", "1")
    code, _, err = run_cli(["report", str(run)], capsys)
    assert code == 0, err
    assert isinstance(started[0], PlotProcess) and started[0]._proc.poll() is not None
    assert {n: (run / n).read_bytes() for n in names} == first
    code, _, err = run_cli(["report", str(run), "--regulation", "no-such-rules"], capsys)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert sorted(p.name for p in run.iterdir() if p.name.startswith(".")) == []
