"""False-colour lux PNGs and plain previews: valid files, sizes, orientation, edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from skimage.io import imread

from lightsim.io.png import wall_angles, write_lux_png, write_preview_png

WALL = {"h_range_m": [-10.0, 10.0], "v_range_m": [-5.0, 5.0], "distance_m": 25.0,
        "resolution": [80, 40]}


def _read(path) -> np.ndarray:
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = imread(path)
    assert img.dtype == np.uint8
    return img


def _beam(H=40, W=80) -> np.ndarray:
    y, x = np.mgrid[0:H, 0:W]
    return 200.0 * np.exp(-(((x - 50) / 15.0) ** 2 + ((y - 15) / 6.0) ** 2))


def test_wall_angles():
    h, v = wall_angles(WALL, 80, 40)
    assert h.shape == (81,) and v.shape == (41,)
    assert h[0] == pytest.approx(math.degrees(math.atan(-10 / 25)))
    assert h[-1] == pytest.approx(math.degrees(math.atan(10 / 25)))
    assert v[0] == pytest.approx(math.degrees(math.atan(5 / 25)))     # row 0 = top
    assert v[-1] == pytest.approx(math.degrees(math.atan(-5 / 25)))
    assert np.all(np.diff(h) > 0) and np.all(np.diff(v) < 0)
    with pytest.raises(ValueError):
        wall_angles({"h_range_m": [0, 1], "v_range_m": [0, 1]}, 4, 4)


def test_lux_png_is_valid_with_expected_size(tmp_path):
    path = tmp_path / "lux.png"
    write_lux_png(path, _beam(), WALL, title="beam", contours=[1, 10, 100, 1e6],
                  points=[("50R", 1.72, -0.86, "cyan"), ("B50L", -3.43, 0.57, "lime")])
    img = _read(path)
    assert img.shape[:2] == (500, 800)                    # figsize (8, 5) × 100 dpi
    write_lux_png(path, _beam(), WALL, figsize=(4, 3), dpi=50)
    assert _read(path).shape[:2] == (150, 200)
    assert [p.name for p in tmp_path.iterdir()] == ["lux.png"]


@pytest.mark.parametrize("log", [False, True])
def test_all_zero_and_nan_images(tmp_path, log):
    small = {"figsize": (4, 2.5), "dpi": 50}                # 200×125 px, quick
    zero = np.zeros((40, 80))
    write_lux_png(tmp_path / "z.png", zero, WALL, log=log, contours=[1.0], **small)
    assert _read(tmp_path / "z.png").shape[:2] == (125, 200)
    holes = _beam()
    holes[:5, :5] = np.nan                                 # not computed
    holes[10:20, 0:10] = 0.0
    write_lux_png(tmp_path / "h.png", holes, WALL, log=log, vmax=150.0, **small)
    assert _read(tmp_path / "h.png").shape[:2] == (125, 200)


def test_log_scale_with_zeros_and_explicit_limits(tmp_path):
    E = _beam()
    E[:, :20] = 0.0
    small = {"figsize": (4, 2.5), "dpi": 50}
    write_lux_png(tmp_path / "l.png", E, WALL, log=True, vmin=0.1, vmax=1000.0, **small)
    write_lux_png(tmp_path / "l2.png", E, WALL, log=True, vmin=0.0, **small)  # floor instead
    for name in ("l.png", "l2.png"):
        assert _read(tmp_path / name).shape[:2] == (125, 200)


def test_orientation_row0_top_column0_left(tmp_path):
    """Light only in the top-right quadrant (H > 0, V > 0) must appear top-right."""
    E = np.zeros((40, 80))
    E[:20, 40:] = 100.0
    path = tmp_path / "q.png"
    write_lux_png(path, E, WALL, cmap="gray")
    img = _read(path)[..., :3].astype(float).mean(axis=2)
    # the plot area lies roughly in the middle of the figure (colour bar on the far right)
    top_right = img[int(0.35 * 500), int(0.6 * 800)]
    bottom_left = img[int(0.65 * 500), int(0.25 * 800)]
    top_left = img[int(0.35 * 500), int(0.25 * 800)]
    assert top_right > 200 and bottom_left < 50 and top_left < 50


def test_resolution_mismatch(tmp_path):
    with pytest.raises(ValueError):
        write_lux_png(tmp_path / "x.png", np.zeros((10, 10)), WALL)
    with pytest.raises(ValueError):
        write_lux_png(tmp_path / "x.png", np.zeros(10), WALL)
    assert not list(tmp_path.iterdir())


def test_preview_png(tmp_path):
    E = _beam()
    write_preview_png(tmp_path / "p.png", E)
    img = _read(tmp_path / "p.png")
    assert img.shape[:2] == (40, 80)                       # one PNG pixel per image pixel
    assert img[15, 50, 0] == 255 and img[39, 0, 0] == 0    # max white, min black, row 0 top
    E[0, 0] = np.nan
    write_preview_png(tmp_path / "p.png", E, log=True)
    assert _read(tmp_path / "p.png").shape[:2] == (40, 80)
    write_preview_png(tmp_path / "z.png", np.zeros((3, 4)))
    assert _read(tmp_path / "z.png").shape[:2] == (3, 4)
    rgb = np.random.default_rng(0).random((6, 5, 3))
    write_preview_png(tmp_path / "rgb.png", rgb)
    back = _read(tmp_path / "rgb.png")
    assert back.shape[:2] == (6, 5)
    np.testing.assert_array_equal(back[..., :3], np.round(rgb * 255).astype(np.uint8))
    with pytest.raises(ValueError):
        write_preview_png(tmp_path / "bad.png", np.zeros((2, 2, 2)))
