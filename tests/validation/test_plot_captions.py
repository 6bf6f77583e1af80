"""Every plot the product writes carries its caption (lamp, seed, photons, error figure,
rule set and version, lightsim's version), under the axes and in the PNG's
``Description`` metadata, read back here from the files the commands wrote."""

from __future__ import annotations

import json

import numpy as np
import pytest

import lightsim
from lightsim.io.caption import read_caption, run_text
from lightsim.io.plots import PlotCaption, isolux_plot, wall_lux_plot
from lightsim.report import plot_caption
from lightsim.validation.converge import ConvergeResult, Point
from lightsim.validation.converge import plot as converge_plot
from lightsim.validation.fuzz import photo_seeds, small_scene_glb
from lightsim.validation.photo_plots import plot_pair_difference
from lightsim.validation.stop_study import StopRun, StopStudy
from lightsim.validation.stop_study import plot as stop_plot
from lightsim.validation.synthetic_photo import wall_frame

from support import run_cli

VERSION = f"lightsim {lightsim.__version__}"


@pytest.fixture(scope="module")
def compare_inputs(tmp_path_factory):
    root = tmp_path_factory.mktemp("captions")
    sim, photos = photo_seeds(root)
    (root / "shot.png").write_bytes(photos[".png"])
    return root, sim


def _compare(root, sim, out, capsys):
    code, _, err = run_cli(["compare", str(root / "shot.png"), "--sim", str(sim), "--out",
                            str(out), "-q"], capsys)
    assert code == 0, err
    return [read_caption(out / f) for f in ("overlay.png", "difference.png", "contours.png")]


def test_compare_figures_carry_the_runs_caption(compare_inputs, tmp_path, capsys):
    root, sim = compare_inputs
    summary = json.loads((sim / "summary.json").read_text())
    summary.update(seed=7, photons=123456, error_text="±1.8 % (95 %)", lightsim_version="9.9",
                   scene={"source": "/lamps/lowbeam.glb"},
                   regulation={"ruleset": "r112-b-passing", "version": "2024-1"})
    (sim / "summary.json").write_text(json.dumps(summary))
    caps = _compare(root, sim, tmp_path / "out", capsys)
    assert caps[0] == caps[1] == caps[2]
    for part in ("lowbeam.glb", "seed 7", "123,456 photons", "error ±1.8 % (95 %)",
                 "r112-b-passing (2024-1)", "lightsim 9.9", "photo: shot.png"):
        assert part in caps[0], (part, caps[0])
    assert caps[0].startswith(plot_caption(summary).text())


def test_compare_without_a_summary_says_what_it_knows(compare_inputs, tmp_path, capsys):
    root, sim = compare_inputs
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "wall_lux.exr").write_bytes((sim / "wall_lux.exr").read_bytes())
    caps = _compare(root, bare, tmp_path / "out", capsys)
    assert all(c is not None and "photo: shot.png" in c and VERSION in c for c in caps)
    assert "no run metadata" in caps[0]


def test_photo_pair_plot_carries_its_caption(tmp_path):
    text = run_text("photo B b.jpg against photo A a.jpg", "relative difference")
    p = plot_pair_difference(tmp_path / "rd.png", np.zeros((20, 30)), caption=text)
    assert read_caption(p) == text and VERSION in text


def test_simulate_and_road_plots_carry_the_runs_caption(tmp_path, capsys):
    scene = tmp_path / "lamp.glb"
    scene.write_bytes(small_scene_glb())
    out = tmp_path / "run"
    code, _, err = run_cli(["simulate", str(scene), "--photons", "3000", "--frame-photons",
                            "3000", "--resolution", "32x16", "--seed", "5", "--regulation",
                            "r112-b-passing", "-q", "--out", str(out)], capsys)
    assert code == 0, err
    expected = plot_caption(json.loads((out / "summary.json").read_text())).text()
    assert "seed 5" in expected and "r112-b-passing (" in expected and VERSION in expected
    for name in ("wall_lux.png", "isolux.png", "road.png", "error_vs_time.png"):
        assert read_caption(out / name) == expected, name
    code, _, err = run_cli(["road", str(out), "--approaches", "straight"], capsys)
    assert code == 0, err
    roads = sorted(out.glob("road_*.png"))
    assert roads and all(read_caption(p) == expected for p in roads)


def test_study_plots_carry_their_caption(tmp_path):
    result = ConvergeResult(
        target="lambertian disc", mode="exact",
        points=[Point("knn", 1.0, 1.0, 1000, 1, {"rel_rmse": 0.1}, 0.1),
                Point("knn", 4.0, 4.0, 8000, 2, {"rel_rmse": 0.04}, 0.05)],
        runs={}, reference={}, skipped=[], lit_pixels=100)
    converge_plot(result, tmp_path / "converge.png")
    cap = read_caption(tmp_path / "converge.png")
    assert "lambertian disc" in cap and "1,000–8,000 photons" in cap and VERSION in cap

    runs = [StopRun("disc", "lit", 0.02, s, 1000 * s, 1, 1.0, 0.02, 0.019) for s in (1, 2)]
    stop_plot(StopStudy(runs), tmp_path / "stop.png")
    cap = read_caption(tmp_path / "stop.png")
    assert "disc" in cap and "seeds 1–2" in cap and VERSION in cap


def test_a_plot_with_nothing_to_show_keeps_its_caption(tmp_path):
    """Dark maps give a placeholder image that says why; it still says what run it is."""
    cap = PlotCaption("lamp.glb", 3, 5000, None, (("r112-b-passing", "01"),))
    frame = wall_frame((32, 16))
    for draw in (isolux_plot, wall_lux_plot):
        p = draw(tmp_path / f"{draw.__name__}.png", np.zeros((16, 32)), frame, caption=cap)
        assert read_caption(p) == cap.text()
