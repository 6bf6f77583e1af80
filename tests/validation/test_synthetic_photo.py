"""Synthetic camera (``lightsim photo``), the synthetic low beam and photo/simulation reading."""

from __future__ import annotations

import json
import struct

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile
from PIL import Image

from lightsim.cli.main import main
from lightsim.errors import InputError
from lightsim.io.exr import write_exr
from lightsim.render.cutoff import find_cutoff
from lightsim.validation.photo_io import (
    load_simulation,
    luminance,
    read_photo,
    srgb_decode,
    srgb_encode,
)
from lightsim.validation.photo_png16 import is_png16, read_png16, write_png16
from lightsim.validation.photo_register import apply_matrix, decompose
from lightsim.validation.synthetic_photo import (
    DNG_BLACK,
    DNG_WHITE,
    CameraSettings,
    LowBeam,
    camera_matrix,
    lowbeam_lux,
    render_photo,
    truth_path,
    wall_frame,
    write_dng,
    write_photo,
    write_result,
)
from lightsim.wall import WallFrame

from support import run_cli as _run

FRAME = wall_frame((200, 80))


@pytest.fixture(scope="module")
def lux():
    return lowbeam_lux(FRAME, LowBeam(texture=0.02))


@pytest.fixture(scope="module")
def result_dir(tmp_path_factory, lux):
    return write_result(tmp_path_factory.mktemp("sim") / "run", lux, FRAME)


# --- colour ------------------------------------------------------------------------------

def test_srgb_curve_known_values_and_round_trip():
    assert srgb_decode(np.array([0.0, 1.0]))[[0, 1]].tolist() == [0.0, 1.0]
    assert srgb_decode(np.array(0.5)) == pytest.approx(0.21404, abs=1e-5)
    assert srgb_decode(np.array(0.04045)) == pytest.approx(0.04045 / 12.92)
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)), x, atol=1e-12)


def test_luminance_uses_rec709_weights():
    rgb = np.zeros((2, 2, 3))
    rgb[0, 0] = [1, 0, 0]
    rgb[0, 1] = [0, 1, 0]
    rgb[1, 0] = [0, 0, 1]
    rgb[1, 1] = [1, 1, 1]
    np.testing.assert_allclose(luminance(rgb), [[0.2126, 0.7152], [0.0722, 1.0]])


# --- the synthetic low beam -----------------------------------------------------------------

def test_lowbeam_has_cutoff_step_hotspot_and_dark_top(lux):
    wf = WallFrame.from_any(FRAME)
    h, v = wf.h_deg(), wf.v_deg()
    assert lux.max() == pytest.approx(40.0)
    row, col = np.unravel_index(np.argmax(lux), lux.shape)
    assert 0 < h[col] < 4 and -2.5 < v[row] < -0.5          # hot spot below H-V, right
    above = lux[v > 2.0]
    assert above.max() < 0.02 * lux.max()                    # dark region above
    cut = find_cutoff(lux, FRAME)
    assert cut.found and cut.v_cutoff_deg == pytest.approx(-0.57, abs=0.15)
    # the 15° step: on the right the light reaches higher than on the left
    left, right = np.argmin(np.abs(h + 4)), np.argmin(np.abs(h - 4))
    lit_top = [v[np.nonzero(lux[:, c] > 0.05 * lux.max())[0][0]] for c in (left, right)]
    assert lit_top[1] > lit_top[0] + 0.5
    mirrored = lowbeam_lux(FRAME, LowBeam(traffic="left", texture=0.02))
    np.testing.assert_allclose(mirrored, lux[:, ::-1], rtol=0.25, atol=0.05)


# --- camera geometry ------------------------------------------------------------------------

def test_identity_camera_is_identity_and_parameters_decompose():
    assert np.allclose(camera_matrix((80, 200), (80, 200), CameraSettings()), np.eye(3))
    cam = CameraSettings(rotate_deg=7.0, scale=1.25, shift_px=(10, -4))
    d = decompose(camera_matrix((80, 200), (80, 200), cam), (80, 200))
    assert d["rotation_deg"] == pytest.approx(7.0)
    assert d["scale"] == pytest.approx(1 / 1.25)
    assert d["anisotropy"] == pytest.approx(1.0)
    # the photo's centre shows the simulation's centre moved back by the shift
    cx, cy = d["photo_centre_to_px"]
    assert np.hypot(cx - 99.5, cy - 39.5) == pytest.approx(np.hypot(10, 4) / 1.25)


def test_tilt_is_a_perspective_with_the_right_side_nearer():
    m = camera_matrix((80, 200), (80, 200), CameraSettings(tilt_deg=12.0))
    d = decompose(m, (80, 200))
    assert d["perspective"][0] != 0 and d["anisotropy"] > 1.01
    # photo px per sim px: larger on the right (nearer) than on the left
    x = np.array([20.0, 21.0, 180.0, 181.0])
    sx, _ = apply_matrix(m, x, np.full(4, 40.0))
    assert 1 / (sx[3] - sx[2]) > 1 / (sx[1] - sx[0])
    centre = apply_matrix(m, np.array(99.5), np.array(39.5))
    assert np.allclose([float(centre[0]), float(centre[1])], [99.5, 39.5])


# --- rendering and files ---------------------------------------------------------------------

def test_render_exposure_saturation_noise_and_determinism(lux):
    plain = render_photo(lux)
    assert plain.linear.max() == pytest.approx(1 / 1.05, rel=1e-6)
    assert (plain.linear >= 1.0).sum() == 0
    sat = render_photo(lux, CameraSettings(saturate=0.6))
    assert 0 < (sat.linear >= 1.0).mean() < 0.1
    assert sat.full_scale_lx == pytest.approx(0.6 * 40.0)
    brighter = render_photo(lux, CameraSettings(exposure_ev=-1.0))
    np.testing.assert_allclose(brighter.linear, plain.linear / 2, atol=1e-12)
    a = render_photo(lux, CameraSettings(noise=0.01, seed=3))
    b = render_photo(lux, CameraSettings(noise=0.01, seed=3))
    c = render_photo(lux, CameraSettings(noise=0.01, seed=4))
    assert np.array_equal(a.encoded, b.encoded) and not np.array_equal(a.encoded, c.encoded)
    g = render_photo(lux, CameraSettings(gamma=2.2))
    np.testing.assert_allclose(g.encoded, plain.linear ** (1 / 2.2), atol=1e-12)
    vig = render_photo(lux, CameraSettings(vignetting=0.4))
    assert vig.linear[0, 0] < plain.linear[0, 0] or plain.linear[0, 0] == 0


@pytest.mark.parametrize("name,bits,tol", [("p.png", 8, 0.005), ("p16.png", 16, 2e-5),
                                           ("p.tif", 16, 2e-5), ("p.exr", 8, 1e-6)])
def test_written_photo_reads_back_as_linear_luminance(lux, tmp_path, name, bits, tol):
    shot = render_photo(lux, CameraSettings(rotate_deg=3, saturate=0.7, bits=bits))
    path, side = write_photo(tmp_path / name, shot)
    photo = read_photo(path)
    assert photo.shape == lux.shape
    np.testing.assert_allclose(photo.luminance, shot.linear, atol=tol)
    if name.endswith(".exr"):
        assert photo.encoding == "linear" and not photo.clipped.any()
    else:
        assert photo.encoding == f"srgb-{bits}"
        assert photo.clipped.sum() >= (shot.linear >= 1.0).sum() > 0
    truth = json.loads(side.read_text())
    assert side == truth_path(path)
    np.testing.assert_allclose(truth["matrix"], shot.matrix)
    assert truth["rotation_deg"] == pytest.approx(3.0)
    assert truth["camera"]["saturate"] == 0.7 and truth["photo_size"] == [200, 80]


def test_jpeg_is_8_bit_only(lux, tmp_path):
    shot = render_photo(lux, CameraSettings(bits=16))
    with pytest.raises(InputError, match="8-bit"):
        write_photo(tmp_path / "p.jpg", shot)
    with pytest.raises(InputError, match="must end in"):
        write_photo(tmp_path / "p.gif", shot)
    photo = read_photo(write_photo(tmp_path / "ok.jpg", render_photo(lux))[0])
    assert photo.encoding == "srgb-8"


def test_png16_reader_matches_pillow_and_round_trips_colour(tmp_path):
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:37, 0:53]
    grey = (30000 + 20000 * np.sin(xx / 5.0) * np.cos(yy / 7.0)
            + rng.integers(0, 500, xx.shape)).astype(np.uint16)
    iio.imwrite(tmp_path / "g.png", grey)          # Pillow filters rows adaptively
    assert is_png16(tmp_path / "g.png")
    assert np.array_equal(read_png16(tmp_path / "g.png"), grey)
    rgb = rng.integers(0, 65536, (21, 34, 3)).astype(np.uint16)
    write_png16(tmp_path / "c.png", rgb)
    assert np.array_equal(read_png16(tmp_path / "c.png"), rgb)
    assert read_photo(tmp_path / "c.png").encoding == "srgb-16"
    assert not is_png16(tmp_path / "missing.png")


# --- reading errors ----------------------------------------------------------------------

def test_unreadable_missing_black_and_tiny_photos(tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG not really")
    with pytest.raises(InputError, match="cannot read photo"):
        read_photo(bad)
    with pytest.raises(InputError, match="not found"):
        read_photo(tmp_path / "missing.jpg")
    black = tmp_path / "black.png"
    iio.imwrite(black, np.zeros((40, 60, 3), np.uint8))
    with pytest.raises(InputError, match="all black"):
        read_photo(black)
    tiny = tmp_path / "tiny.png"
    iio.imwrite(tiny, np.full((8, 8), 200, np.uint8))
    with pytest.raises(InputError, match="too small"):
        read_photo(tiny)
    grey_alpha = tmp_path / "ga.png"
    img = np.zeros((40, 60, 2), np.uint8)
    img[..., 0], img[..., 1] = 128, 255
    iio.imwrite(grey_alpha, img)
    assert read_photo(grey_alpha).luminance.mean() == pytest.approx(srgb_decode(128 / 255))


def test_simulation_loading_and_its_errors(result_dir, tmp_path, lux):
    sim = load_simulation(result_dir)
    np.testing.assert_allclose(sim.lux, lux.astype(np.float32))
    assert sim.frame["resolution"] == [200, 80]
    assert load_simulation(result_dir / "wall_lux.exr").wall == sim.wall
    with pytest.raises(InputError, match="not found"):
        load_simulation(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"no wall_lux\.exr"):
        load_simulation(tmp_path / "empty")
    (tmp_path / "junk.exr").write_bytes(b"junk")
    with pytest.raises(InputError, match="not an OpenEXR"):
        load_simulation(tmp_path / "junk.exr")

    write_exr(tmp_path / "noframe.exr", {"Y": lux.astype(np.float32)}, {})
    with pytest.raises(InputError, match="no wall frame"):
        load_simulation(tmp_path / "noframe.exr")
    dark = write_result(tmp_path / "dark", np.zeros_like(lux), FRAME)
    with pytest.raises(InputError, match="no light"):
        load_simulation(dark)


# --- command line -----------------------------------------------------------------------------

def test_cli_photo_writes_photo_and_truth(result_dir, tmp_path, capsys):
    out = tmp_path / "shot.png"
    code, stdout, err = _run(["photo", str(result_dir), str(out), "--rotate", "4",
                              "--scale", "1.1", "--shift", "5,-3", "--tilt", "6", "--blur", "1",
                              "--noise", "0.01", "--vignetting", "0.2", "--gamma", "2.2",
                              "--exposure", "0.5", "--saturate", "0.8", "--bits", "16",
                              "--seed", "2", "--size", "240x100"], capsys)
    assert code == 0, err
    assert "true transform" in stdout
    truth = json.loads(truth_path(out).read_text())
    assert truth["photo_size"] == [240, 100] and truth["camera"]["tilt_deg"] == 6.0
    assert truth["simulation"].endswith("wall_lux.exr")
    assert read_photo(out).encoding == "srgb-16"


@pytest.mark.parametrize("args,message", [
    (["--saturate", "1.5"], "--saturate"),
    (["--shift", "3"], "--shift"),
    (["--vignetting", "1"], "--vignetting"),
])
def test_cli_photo_rejects_bad_options(result_dir, tmp_path, capsys, args, message):
    code, _, err = _run(["photo", str(result_dir), str(tmp_path / "x.png"), *args], capsys)
    assert code == 2 and message in err and "Traceback" not in err


# --- camera raw files, EXIF and library messages -----------------------------------------

def test_dng_reads_as_linear_sensor_data_with_black_white_levels_and_exif(lux, tmp_path):
    """A DNG written by tifffile, decoded by LibRaw (rawpy): values back to 1 code in 3839."""
    shot = render_photo(lux, CameraSettings(rotate_deg=4, saturate=0.7, noise=0.004, seed=3))
    path = write_dng(tmp_path / "beam.dng", shot.linear)
    photo = read_photo(path)
    assert photo.encoding == "raw-linear" and photo.shape == shot.linear.shape
    assert photo.info["black_level"] == [DNG_BLACK] * 4
    assert photo.info["white_level"] == DNG_WHITE
    expect = np.round(DNG_BLACK + shot.linear * (DNG_WHITE - DNG_BLACK))
    expect = (expect - DNG_BLACK) / (DNG_WHITE - DNG_BLACK)
    np.testing.assert_allclose(photo.luminance, expect, atol=1e-9)
    np.testing.assert_array_equal(photo.clipped, expect >= 0.98)
    assert photo.clipped.any()
    exif = photo.info["exif"]
    assert exif["exposure_time_s"] == pytest.approx(1 / 50)
    assert exif["f_number"] == pytest.approx(2.8) and exif["iso"] == 200
    assert exif["relative_exposure"] == pytest.approx(200 / 50 / 2.8**2)
    assert photo.info["warnings"] == []


def test_jpeg_exif_exposure_is_read(tmp_path):
    img = Image.fromarray(np.full((32, 48, 3), 120, np.uint8))
    exif = Image.Exif()
    exif.get_ifd(0x8769).update({33434: 0.004, 33437: 4.0, 34855: 400})
    path = tmp_path / "e.jpg"
    img.save(path, exif=exif)
    info = read_photo(path).info["exif"]
    assert info["exposure_time_s"] == pytest.approx(0.004) and info["iso"] == 400
    assert info["relative_exposure"] == pytest.approx(0.004 * 400 / 16)


@pytest.mark.parametrize("cut", [0.5, 0.05])
def test_truncated_raw_is_one_input_error(lux, tmp_path, cut):
    good = write_dng(tmp_path / "g.dng", render_photo(lux).linear).read_bytes()
    bad = tmp_path / "bad.dng"
    bad.write_bytes(good[: int(len(good) * cut)])
    with pytest.raises(InputError) as exc:
        read_photo(bad)
    assert "\n" not in str(exc.value)


def _tiff_with_bad_tag(path, codes):
    """A TIFF whose private tag 65000 points beyond the end of the file."""
    tifffile.imwrite(path, codes, photometric="rgb", extratags=[(65000, "I", 8, tuple(range(8)))])
    data = bytearray(path.read_bytes())
    i = data.find(struct.pack("<HHI", 65000, 4, 8))
    assert i > 0
    data[i + 8:i + 12] = struct.pack("<I", 0x7FFFFFF0)
    path.write_bytes(bytes(data))


def test_tiff_library_warning_becomes_our_one_line_warning(lux, result_dir, tmp_path, capsys):
    shot = render_photo(lux, CameraSettings(rotate_deg=3))
    codes = np.repeat(np.round(shot.encoded * 255).astype(np.uint8)[..., None], 3, axis=-1)
    path = tmp_path / "badtag.tif"
    _tiff_with_bad_tag(path, codes)
    photo = read_photo(path)
    assert len(photo.info["warnings"]) == 1 and "tifffile" in photo.info["warnings"][0]
    assert capsys.readouterr().err == ""               # nothing leaked to the terminal
    known = tmp_path / "truth.json"                    # the true transform: no registration
    known.write_text(json.dumps({"matrix": shot.matrix.tolist()}))
    code, _, err = _run(["compare", str(path), "--sim", str(result_dir), "--out",
                         str(tmp_path / "c"), "-q", "--transform", str(known)], capsys)
    assert code == 0 and err == ""
    code, _, err = _run(["compare", str(path), "--sim", str(result_dir), "--out",
                         str(tmp_path / "c2"), "--transform", str(known)], capsys)
    assert code == 0 and err.count("\n") == 1 and err.startswith("lightsim: warning: photo")


def test_cli_photo_writes_a_raw_dng_that_compare_reads(result_dir, tmp_path, capsys):
    out = tmp_path / "p.dng"
    code, _, err = _run(["photo", str(result_dir), str(out), "--rotate", "5", "--scale",
                         "1.1"], capsys)
    assert code == 0, err
    code, _, err = _run(["compare", str(out), "--sim", str(result_dir), "--out",
                         str(tmp_path / "c"), "-q"], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "c" / "comparison.json").read_text())
    assert doc["photo"]["encoding"] == "raw-linear"
    assert doc["transform"]["rotation_deg"] == pytest.approx(5, abs=0.3)


def _mutations(data: bytes, n: int, rng) -> list[bytes]:
    """Byte flips, truncations, duplicated and zeroed chunks of a file (seeded)."""
    out = []
    for i in range(n):
        b = bytearray(data)
        kind = i % 4
        if kind == 0:
            for _ in range(int(rng.integers(1, 8))):
                j = int(rng.integers(0, len(b)))
                b[j] ^= 1 << int(rng.integers(0, 8))
        elif kind == 1:
            b = b[: int(rng.integers(0, len(b)))]
        elif kind == 2:
            j = int(rng.integers(0, len(b)))
            k = min(len(b), j + int(rng.integers(1, 500)))
            b = b[:k] + b[j:k] + b[k:]
        else:
            j = int(rng.integers(0, len(b)))
            n0 = min(len(b) - j, int(rng.integers(1, 200)))
            b[j:j + n0] = bytes(n0)
        out.append(bytes(b))
    return out


@pytest.mark.parametrize("suffix", [".jpg", ".png", ".tif", ".dng"])
def test_corrupt_photos_give_one_line_or_a_finite_photo_and_print_nothing(lux, tmp_path,
                                                                          capfd, suffix):
    """A seeded mutation corpus of each photo format (8 cases here, hundreds
    in the study): InputError with one line, or a photo with finite values — and nothing
    written to the terminal by the libraries (checked at the file-descriptor level, so
    LibRaw's C messages count too)."""
    shot = render_photo(lux, CameraSettings(rotate_deg=3))
    path, _ = write_photo(tmp_path / f"base{suffix}", shot)
    rng = np.random.default_rng(13)
    for i, data in enumerate(_mutations(path.read_bytes(), 8, rng)):
        bad = tmp_path / f"m{i}{suffix}"
        bad.write_bytes(data)
        try:
            photo = read_photo(bad)
        except InputError as exc:
            assert "\n" not in str(exc)
        else:
            assert np.all(np.isfinite(photo.luminance))
            assert all("\n" not in w for w in photo.info["warnings"])
        out, err = capfd.readouterr()
        assert out == "" and err == "", (i, out, err)


def test_corrupt_photo_through_the_cli_is_one_line_exit_2(result_dir, lux, tmp_path, capfd):
    shot = render_photo(lux)
    for suffix in (".jpg", ".dng"):
        path, _ = write_photo(tmp_path / f"g{suffix}", shot)
        bad = tmp_path / f"cut{suffix}"
        bad.write_bytes(path.read_bytes()[:200])
        with pytest.raises(SystemExit) as exc:
            main(["compare", str(bad), "--sim", str(result_dir), "--out",
                  str(tmp_path / f"o{suffix}")])
        _, err = capfd.readouterr()
        assert exc.value.code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
        assert not (tmp_path / f"o{suffix}").exists()


def test_raw_without_decodable_data_falls_back_to_its_preview_with_a_warning(tmp_path):
    """A DNG whose raw sub-image LibRaw cannot decode (deflate-compressed CFA here) but
    whose first image is an RGB preview: read as the 8-bit preview, with one warning."""
    rng = np.random.default_rng(0)
    thumb = (40 + 200 * rng.random((64, 96, 3))).astype(np.uint8)
    dng = [(50706, "B", 4, (1, 4, 0, 0), True), (50707, "B", 4, (1, 1, 0, 0), True),
           (50708, "s", 0, "lightsim test", True)]
    cfa = [(33421, "H", 2, (2, 2), True), (33422, "B", 4, (0, 1, 1, 2), True),
           (50710, "B", 3, (0, 1, 2), True), (50711, "H", 1, 1, True),
           (50714, "H", 1, 256, True), (50717, "H", 1, 4095, True)]
    path = tmp_path / "preview-only.dng"
    with tifffile.TiffWriter(path) as tif:
        tif.write(thumb, photometric="rgb", subfiletype=1, subifds=1, extratags=dng,
                  metadata=None)
        tif.write(np.full((128, 192), 1000, np.uint16), photometric=32803, subfiletype=0,
                  extratags=cfa, metadata=None, compression="zlib")
    photo = read_photo(path)
    assert photo.encoding == "srgb-8" and photo.info["preview"] and photo.shape == (64, 96)
    np.testing.assert_allclose(photo.luminance, luminance(srgb_decode(thumb / 255)))
    assert len(photo.info["warnings"]) == 1 and "preview" in photo.info["warnings"][0]
