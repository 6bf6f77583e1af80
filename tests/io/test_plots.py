"""Iso-lux and road-view plots (valid PNGs, atomic) and the road-illuminance physics."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from matplotlib.image import imread

from lightsim.errors import InputError
from lightsim.io.errorplot import error_vs_time_plot
from lightsim.io.placeholder import image_problem
from lightsim.io.plots import auto_levels, isolux_plot, road_view_plot
from lightsim.io.png import write_lux_png
from lightsim.luminaires.photometric import CandelaGrid
from lightsim.luminaires.regulations import evaluate, load_ruleset, probe_points, sample_wall
from lightsim.render.road import road_illuminance, road_illuminance_from
from lightsim.wall import WallFrame, lux_from_candela, wall_m_from_deg

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
D = 25.0
FRAME = {"distance_m": D, "h_range_m": [-wall_m_from_deg(15.0), wall_m_from_deg(15.0)],
         "v_range_m": [-wall_m_from_deg(6.0), wall_m_from_deg(5.0)], "resolution": [300, 110]}


def wall_from_intensity(intensity_cd) -> np.ndarray:
    wf = WallFrame.from_any(FRAME)
    hm, vm = np.meshgrid(wf.h_m(), wf.v_m())
    hd, vd = np.meshgrid(wf.h_deg(), wf.v_deg())
    return lux_from_candela(intensity_cd(hd, vd), hm, vm, D)


def beam(hd, vd):
    below = 0.5 * (1 - np.tanh((vd + 0.57) / 0.1))
    return 30000 * np.exp(-(hd / 5) ** 2 - ((vd + 1.5) / 1.5) ** 2) * below + 200


def check_png(path) -> np.ndarray:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    img = imread(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    assert float(np.ptp(img[..., :3])) > 0.5     # not a blank image
    assert not list(path.parent.glob(".*.tmp*"))  # no temporary file left behind
    return img


def test_isolux_plot_with_results(tmp_path):
    lux = wall_from_intensity(beam)
    rs = load_ruleset("r112-b-passing")
    pr = probe_points(rs, frame=FRAME)
    rng = np.random.default_rng(0)
    vals = sample_wall(lux, FRAME, pr.h_deg, pr.v_deg) * (1 + 0.03 * rng.standard_normal(
        (9, len(pr))))
    results = evaluate(rs, pr, vals)
    assert {r["verdict"] for r in results} >= {"pass", "fail"}
    out = isolux_plot(tmp_path / "iso.png", lux, FRAME, results, title="test beam")
    img = check_png(out)
    # verdict colours are drawn: some red (fail) and green (pass) pixels
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    assert np.any((r > 0.75) & (g < 0.3) & (b < 0.3))
    assert np.any((g > 0.5) & (r < 0.25) & (b < 0.45))
    # overwriting keeps a valid file
    isolux_plot(out, lux, FRAME, None, levels=[1, 5, 20])
    check_png(out)


def test_isolux_plot_dark_wall(tmp_path):
    out = isolux_plot(tmp_path / "dark.png", np.zeros((110, 300)), FRAME)
    assert out.read_bytes()[:8] == PNG_MAGIC
    with pytest.raises(InputError, match="positive"):
        isolux_plot(tmp_path / "x.png", np.ones((110, 300)), FRAME, levels=[0, 1])


def test_auto_levels():
    assert auto_levels(60.0) == [0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50]
    assert auto_levels(0.0) == []


def test_road_view_png(tmp_path):
    lux = wall_from_intensity(beam)
    road = road_view_plot(tmp_path / "road.png", lux, FRAME, mount_height_m=0.65)
    check_png(tmp_path / "road.png")
    s = road.summary()
    assert s["mount_height_m"] == 0.65 and s["reach_m"]["1"] is not None
    with pytest.raises(InputError, match="lux map"):
        road_view_plot(tmp_path / "r.png")


def test_road_physics_uniform_source_hand_calculation():
    I0 = 10000.0                                       # cd in every direction
    lux = wall_from_intensity(lambda h, v: np.full_like(h, I0))
    road = road_illuminance(lux, FRAME, mount_height_m=0.65, x_range_m=(-4.0, 4.0),
                            z_range_m=(0.0, 40.0), resolution_m=0.5)
    # straight ahead at 20 m: r² = 400 + 0.4225, E = I·h/r³ = 10000·0.65/20.0106^3 = 0.81117
    k = np.flatnonzero(road.z_m == 20.0)[0]
    j = np.flatnonzero(road.x_m == 0.0)[0]
    assert road.lux[k, j] == pytest.approx(0.811174, rel=1e-4)
    # 2 m to the right at 10 m: r² = 4 + 0.4225 + 100 = 104.4225, E = 6500/1067.07 = 6.0914
    k = np.flatnonzero(road.z_m == 10.0)[0]
    j = np.flatnonzero(road.x_m == 2.0)[0]
    assert road.lux[k, j] == pytest.approx(6.09147, rel=1e-4)
    # close to the lamp the road is below the wall's 6° D: unknown, not zero
    assert np.isnan(road.lux[road.z_m < 6.0]).all()
    assert road.reach_m(1.0) == pytest.approx(18.5)     # 6500/r³ ≥ 1 ⇔ r ≤ 18.66 m


def test_road_from_an_intensity_function_and_mirror_symmetry():
    c = np.arange(0.0, 360.0, 5.0)
    g = np.arange(0.0, 180.1, 2.5)
    grid = CandelaGrid(c, g, np.full((len(c), len(g)), 500.0))
    road = road_illuminance_from(grid.intensity_hv, mount_height_m=1.0, x_range_m=(-5, 5),
                                 z_range_m=(0, 10), resolution_m=1.0)
    x, z = np.meshgrid(road.x_m, road.z_m)
    assert np.allclose(road.lux, 500.0 * 1.0 / (x * x + 1.0 + z * z) ** 1.5)
    assert np.allclose(road.lux, road.lux[:, ::-1])
    with pytest.raises(InputError, match="mount_height_m"):
        road_illuminance_from(grid.intensity_hv, mount_height_m=0.0)


# -- degenerate data: the image says why, nothing raises ---------------------------------

@pytest.mark.parametrize("kind", ["zero", "constant", "one_pixel_lit", "nan", "negative"])
def test_plots_survive_degenerate_data(tmp_path, kind):
    h, w = 110, 300
    lux = {"zero": np.zeros((h, w)), "constant": np.full((h, w), 3.0),
           "one_pixel_lit": np.zeros((h, w)), "nan": np.full((h, w), np.nan),
           "negative": -np.ones((h, w))}[kind]
    if kind == "one_pixel_lit":
        lux[50, 150] = 7.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no matplotlib/numpy warning either
        out = isolux_plot(tmp_path / "iso.png", lux, FRAME)
        road_view_plot(tmp_path / "road.png", lux, FRAME)
        for log in (False, True):
            write_lux_png(tmp_path / "wall.png", lux, FRAME, log=log, contours=[1.0, 5.0])
    assert (tmp_path / "wall.png").read_bytes()[:8] == PNG_MAGIC
    assert out.read_bytes()[:8] == PNG_MAGIC
    assert (tmp_path / "road.png").read_bytes()[:8] == PNG_MAGIC
    if kind != "one_pixel_lit":
        assert image_problem(lux, contours=True) is not None
    logs = {"zero": [{"seconds": 1.0, "photons": 10, "rel_error": 0.0}],
            "constant": [{"seconds": s, "photons": 10, "rel_error": 0.1} for s in (1, 2, 3)],
            "one_pixel_lit": [{"seconds": 1.0, "photons": 10, "rel_error": 0.1}],
            "nan": [{"seconds": float("nan"), "photons": 10, "rel_error": float("inf")}],
            "negative": [{"seconds": 1.0, "photons": 10, "rel_error": -0.5}]}[kind]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        error_vs_time_plot(tmp_path / "err.png", logs)
    assert (tmp_path / "err.png").read_bytes()[:8] == PNG_MAGIC
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_placeholder_names_the_reason(tmp_path):
    assert "zero everywhere" in image_problem(np.zeros((4, 4)))
    assert "constant" in image_problem(np.ones((4, 4)), contours=True)
    assert image_problem(np.ones((4, 4))) is None  # a flat map can still be coloured
    assert "too few" in image_problem(np.ones((1, 5)), contours=True)
    assert "no finite" in image_problem(np.full((3, 3), np.inf))
    assert image_problem(np.arange(16.0).reshape(4, 4), contours=True) is None
