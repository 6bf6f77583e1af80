"""Clean engineering plots: iso-lux levels above the noise floor, labels in lx and cd,
and the road view's reach for 1, 3 and 10 lx."""

from __future__ import annotations

import json
import math

import contourpy
import numpy as np
import pytest
from scipy import ndimage

from lightsim.io.plots import isolux_levels, isolux_noise_floor, isolux_plot
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb
from lightsim.render.road import REACH_LEVELS, road_illuminance
from lightsim.scene import make_wall

from support import run_cli


def test_noise_floor_formula():
    # 16 photons of Φ/N = 1 mlm in 0.035 m² → 0.457 lx
    assert isolux_noise_floor(1_000_000, 1000.0, 0.035) == pytest.approx(16e-3 / 0.035)
    assert isolux_noise_floor(1000, 10.0, 0.01, max_rel_noise=0.5) == pytest.approx(4.0)
    for bad in ((0, 1.0, 1.0), (10, 1.0, math.inf), (10, float("nan"), 1.0)):
        assert isolux_noise_floor(*bad) is None


def _lines(img, level):
    gen = contourpy.contour_generator(z=img, line_type="Separate")
    return len(gen.lines(level))


def test_levels_above_the_floor_have_little_speckle():
    """A Gaussian beam from Poisson photons, averaged over a disk as a fixed-radius
    estimate does: below the floor the contours break into dozens of islands; from the
    floor up each level is a handful of lines."""
    rng = np.random.default_rng(7)
    y, x = np.mgrid[-1:1:128j, -1:1:256j]
    beam = 20.0 * np.exp(-(x**2 / 0.15 + y**2 / 0.05))  # lx
    pixel_area, photons, flux = 1e-4, 5_000_000, 1000.0   # m², −, lm
    per_photon = flux / photons
    yy, xx = np.mgrid[-4:5, -4:5]
    disk = (xx**2 + yy**2 <= 16).astype(float)
    counts = rng.poisson(beam * pixel_area / per_photon).astype(float)
    img = ndimage.convolve(counts, disk, mode="constant") * per_photon / (
        pixel_area * disk.sum())
    floor = isolux_noise_floor(photons, flux, pixel_area * disk.sum())
    drawn = isolux_levels(float(img.max()), None, floor)
    assert drawn and min(drawn) >= floor
    assert max(_lines(img, lv) for lv in drawn) <= 6
    below = [lv for lv in isolux_levels(float(img.max())) if lv < floor]
    assert below and max(_lines(img, lv) for lv in below) > 15


def test_isolux_plot_with_floor_writes(tmp_path):
    _, frame = make_wall(25.0, (30.0, 12.0), resolution=(64, 32))
    img = np.full((32, 64), 2.0)
    img[10:20, 20:40] = 30.0
    out = isolux_plot(tmp_path / "iso.png", img, frame.to_dict(), noise_floor_lx=1.0)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_road_reach_of_a_uniform_lamp():
    """I0 everywhere: on the road axis E = I0·h/(h² + z²)^1.5, so each level's reach is
    z = √((I0 h / E)^(2/3) − h²)."""
    i0, h, d = 10_000.0, 0.65, 25.0
    _, frame = make_wall(d, (40.0, 12.0), resolution=(400, 120))
    hc, vc = frame.pixel_centres()
    H, V = np.meshgrid(hc, vc)
    lux = i0 * d / (H**2 + V**2 + d**2) ** 1.5  # I0 cos³θ / D²
    road = road_illuminance(lux, frame.to_dict(), mount_height_m=h, resolution_m=0.05)
    for level in REACH_LEVELS:
        exact = math.sqrt((i0 * h / level) ** (2 / 3) - h * h)
        assert road.reach_m(level) == pytest.approx(exact, abs=0.1)
    assert road.reach_text() == "reach 1 lx 19 m, 3 lx 13 m, 10 lx 9 m"


def test_simulate_reports_floor_and_reach(tmp_path, capsys):
    m = GltfMaterial("e", emissive=(1.0, 1.0, 1.0))
    v = 1e-3 * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    path = tmp_path / "lamp.glb"
    write_glb(path, [GltfPart("bulb", v, f, None, m, extras={"lightsim": {"flux_lm": 900}})])
    code, out, err = run_cli(["simulate", str(path), "--photons", "40000", "--resolution",
                              "64x32", "--out", str(tmp_path / "o")], capsys)
    assert code in (0, None), err
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    r = s["estimator"]["max_radius_m"]
    assert s["isolux"]["noise_floor_lx"] == pytest.approx(16 * 900 / (40_000 * math.pi * r * r))
    assert set(s["road"]["reach_m"]) >= {"1", "3", "10"}
    assert "road view (lamp 0.65 m high): reach 1 lx" in out
