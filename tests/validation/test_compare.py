"""``lightsim compare``: registration against a known truth, metrics, outputs and errors.

Photos are made with the synthetic camera (:mod:`lightsim.validation.synthetic_photo`)
from a synthetic low-beam pattern, written as 8-bit sRGB PNGs and read back, so every test
goes through quantisation and sRGB decoding. "Within 1 px" is measured on the simulation
grid over the photo's lit part (pixels ≥ 1 % of the peak, where a pattern constrains the
transform): RMS and 95th percentile of |H_found·x − H_true·x|.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from lightsim.errors import InputError
from lightsim.render.cutoff import apply_shift
from lightsim.validation import synthetic_photo as sp
from lightsim.validation.compare import (
    CompareOptions,
    compare_images,
    failed_thresholds,
    load_transform,
    parse_threshold,
    run_compare,
)
from lightsim.validation.photo_io import PhotoImage, load_simulation, read_photo
from lightsim.validation.photo_lamps import find_lamps
from lightsim.validation.photo_metrics import HIGHER_IS_BETTER, LOWER_IS_BETTER
from lightsim.validation.photo_register import apply_matrix, decompose, register
from lightsim.validation.synthetic_photo import (
    CameraSettings,
    LowBeam,
    lowbeam_lux,
    render_photo,
    wall_frame,
    write_photo,
    write_result,
)

from support import run_cli as _run

FRAME = wall_frame((400, 160))        # the simulate default wall (30 × 12 m at 25 m)
LAMP_A = LowBeam(texture=0.02)
# another lamp: longer focal length and the filament further back — a wider, lower,
# softer pattern with its hot spot further right
LAMP_B = LowBeam(hotspot_deg=(3.0, -2.0), hotspot_sigma_deg=(4.0, 1.3),
                 spread_sigma_deg=(14.0, 3.0), cutoff_v_deg=-1.0, cutoff_width_deg=0.2,
                 texture=0.02, seed=3)
REAL_PHOTO = Path(__file__).parents[1] / "data" / "zoe-lowbeam-garage-door.jpg"   # CC BY 4.0


@pytest.fixture(scope="module")
def lux_a():
    return lowbeam_lux(FRAME, LAMP_A)


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory, lux_a):
    return write_result(tmp_path_factory.mktemp("sim") / "lamp_a", lux_a, FRAME)


@pytest.fixture(scope="module")
def sim_a(sim_dir):
    return load_simulation(sim_dir)


def _shoot(lux, folder: Path, name: str, **camera):
    """Photograph ``lux``, write an 8-bit PNG, read it back; (photo, truth matrix, path)."""
    shot = render_photo(lux, CameraSettings(**camera))
    path, _ = write_photo(folder / f"{name}.png", shot)
    return read_photo(path), shot.matrix, path


def transform_error(found, truth, photo_shape, lux) -> dict[str, float]:
    """Displacement (sim px) between two photo→sim maps over the photo's lit pixels."""
    hp, wp = photo_shape
    yy, xx = np.mgrid[0:hp, 0:wp].astype(float)
    tx, ty = apply_matrix(truth, xx, yy)
    fx, fy = apply_matrix(found, xx, yy)
    hs, ws = lux.shape
    inside = (tx >= 0) & (tx <= ws - 1) & (ty >= 0) & (ty <= hs - 1)
    lit = np.zeros_like(inside)
    lit[inside] = map_coordinates(lux, [ty[inside], tx[inside]], order=1) >= 0.01 * lux.max()
    d = np.hypot(fx - tx, fy - ty)[lit]
    return {"rms": float(np.sqrt(np.mean(d**2))), "p95": float(np.percentile(d, 95)),
            "max": float(d.max())}


def assert_recovered(found, truth, photo_shape, lux):
    err = transform_error(found, truth, photo_shape, lux)
    f, t = decompose(found, photo_shape), decompose(truth, photo_shape)
    assert err["rms"] <= 1.0 and err["p95"] <= 1.0, err
    assert abs(f["rotation_deg"] - t["rotation_deg"]) <= 0.5
    assert f["scale"] == pytest.approx(t["scale"], rel=0.01)


CASES = [
    pytest.param(dict(rotate_deg=10, scale=1.2, shift_px=(15, -8)), "similarity",
                 id="rot+10-scale1.2-shift"),
    pytest.param(dict(rotate_deg=-10, scale=0.8, shift_px=(-20, 6), blur_px=1.5, noise=0.01,
                      vignetting=0.3, seed=1), "similarity",
                 id="rot-10-scale0.8-blur-noise-vignetting"),
    pytest.param(dict(rotate_deg=4, scale=1.25, gamma=2.2, saturate=0.6, noise=0.005,
                      seed=2), "similarity", id="gamma2.2-saturated-hotspot"),
    pytest.param(dict(tilt_deg=15, rotate_deg=3, scale=1.05, blur_px=1.0, noise=0.005,
                      gamma=2.2, saturate=0.8, seed=3), "homography", id="tilt+15"),
    pytest.param(dict(tilt_deg=-15, rotate_deg=-6, scale=0.9, shift_px=(10, 5),
                      vignetting=0.3, exposure_ev=-1.5), "homography", id="tilt-15-dark"),
]


@pytest.mark.parametrize("camera,model", CASES)
def test_registration_recovers_the_camera(camera, model, lux_a, sim_a, tmp_path):
    photo, truth, _ = _shoot(lux_a, tmp_path, "p", **camera)
    result = compare_images(photo, sim_a, CompareOptions(model=model, fit_gamma=True))
    assert_recovered(result.matrix, truth, photo.shape, lux_a)
    assert result.metrics["zncc"] >= 0.95
    assert result.transform_dict()["model"] == model


def test_same_lamp_scores_better_on_every_metric(lux_a, sim_a, tmp_path):
    camera = dict(rotate_deg=5, scale=1.1, shift_px=(8, -4), blur_px=0.7, noise=0.005,
                  vignetting=0.2, gamma=2.2, saturate=0.8, seed=4)
    same, _, _ = _shoot(lux_a, tmp_path, "same", **camera)
    other, _, _ = _shoot(lowbeam_lux(FRAME, LAMP_B), tmp_path, "other", **camera)
    opts = CompareOptions(fit_gamma=True)
    good = compare_images(same, sim_a, opts).metrics
    bad = compare_images(other, sim_a, opts).metrics
    for name in HIGHER_IS_BETTER:
        assert good[name] > bad[name], (name, good[name], bad[name])
    for name in LOWER_IS_BETTER:
        assert bad[name] is None or good[name] < bad[name], (name, good[name], bad[name])
    assert good["cutoff_shape_gap_deg"] < 0.05 and good["hotspot_offset_deg"] < 0.2


def test_cli_writes_outputs_and_reports_the_transform(sim_dir, lux_a, tmp_path, capsys):
    _, truth, path = _shoot(lux_a, tmp_path, "cam", rotate_deg=-7, scale=1.15,
                            shift_px=(6, 4), blur_px=0.8, noise=0.005, seed=5)
    out = tmp_path / "cmp"
    code, stdout, err = _run(["compare", str(path), "--sim", str(sim_dir), "--out", str(out),
                              "--fit-gamma", "--fail-below", "zncc=0.95",
                              "--fail-below", "iou_30=0.8",
                              "--fail-above", "hotspot_offset_deg=0.2",
                              "--credit", "synthetic photo"], capsys)
    assert code == 0, err
    assert "rotation" in stdout and "zncc" in stdout
    doc = json.loads((out / "comparison.json").read_text())
    tr = doc["transform"]
    assert set(tr) >= {"rotation_deg", "scale", "translation_px", "matrix"}
    assert np.asarray(tr["matrix"]).shape == (3, 3)
    assert_recovered(np.asarray(tr["matrix"]), truth, (160, 400), lux_a)
    for name, value in doc["metrics"].items():
        assert value is None or math.isfinite(value), name
    assert doc["photometric"]["fitted_gamma"] is True and doc["credit"] == "synthetic photo"
    for png in ("overlay.png", "difference.png", "contours.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert (out / png).stat().st_size > 20_000


def test_fail_below_exits_1_naming_the_metric(sim_dir, lux_a, tmp_path, capsys):
    _, _, path = _shoot(lux_a, tmp_path, "cam", rotate_deg=3, blur_px=1.0)
    truth = path.with_name("cam.truth.json")
    base = ["compare", str(path), "--sim", str(sim_dir), "--out", str(tmp_path / "o"),
            "--transform", str(truth), "-q"]
    code, _, err = _run([*base, "--fail-below", "zncc=0.9999", "--fail-below", "ssim=0.5"],
                        capsys)
    assert code == 1
    assert err.strip().splitlines() == [err.strip()]      # one line
    assert "zncc" in err and "below 0.9999" in err and "ssim" not in err
    code, _, err = _run([*base, "--fail-above", "rel_rmse=0.0001"], capsys)
    assert code == 1 and "rel_rmse" in err
    code, _, err = _run([*base, "--fail-below", "sharpness=1"], capsys)
    assert code == 2 and "METRIC=VALUE" in err and "Traceback" not in err


def test_given_transform_skips_registration(sim_a, lux_a, tmp_path):
    photo, truth, path = _shoot(lux_a, tmp_path, "g", rotate_deg=2, scale=0.9)
    m = load_transform(path.with_name("g.truth.json"))
    np.testing.assert_allclose(m, truth / truth[2, 2])
    result = compare_images(photo, sim_a, CompareOptions(transform=m))
    assert result.registration is None and result.transform_dict()["model"] == "given"
    assert result.metrics["zncc"] > 0.99


# --- errors ------------------------------------------------------------------------------

def test_unreadable_black_and_missing_inputs_exit_2(sim_dir, tmp_path, capsys):
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"\xff\xd8\xff garbage")
    black = tmp_path / "black.png"
    iio.imwrite(black, np.zeros((60, 90, 3), np.uint8))
    for argv, message in (
        ([str(bad), "--sim", str(sim_dir)], "cannot read photo"),
        ([str(black), "--sim", str(sim_dir)], "all black"),
        ([str(tmp_path / "none.png"), "--sim", str(sim_dir)], "not found"),
        ([str(black), "--sim", str(tmp_path / "nosim")], "simulation not found"),
    ):
        code, _, err = _run(["compare", *argv, "--out", str(tmp_path / "o")], capsys)
        assert code == 2, err
        assert message in err and "Traceback" not in err
        assert len(err.strip().splitlines()) == 1


def test_no_overlap_is_an_input_error(sim_dir, sim_a, lux_a, tmp_path, capsys):
    photo, _, path = _shoot(lux_a, tmp_path, "far", rotate_deg=1)
    away = np.array([[1.0, 0, 5000.0], [0, 1.0, 0], [0, 0, 1.0]])
    with pytest.raises(InputError, match="no overlap"):
        compare_images(photo, sim_a, CompareOptions(transform=away))
    with pytest.raises(InputError, match="no overlap"):
        register(photo.luminance, ~photo.clipped, sim_a.lux, initial=away)
    (tmp_path / "away.json").write_text(json.dumps({"matrix": away.tolist()}))
    code, _, err = _run(["compare", str(path), "--sim", str(sim_dir), "--out",
                         str(tmp_path / "o"), "--transform", str(tmp_path / "away.json")],
                        capsys)
    assert code == 2 and "no overlap" in err


def test_fully_clipped_photo_is_an_input_error(sim_a):
    lum = np.ones((160, 400))
    photo = PhotoImage(lum, np.ones(lum.shape, bool), "white.png", "srgb-8")
    with pytest.raises(InputError, match="usable pixels"):
        compare_images(photo, sim_a)


def test_fail_thresholds_are_parsed_and_judged():
    assert parse_threshold("zncc=0.9") == ("zncc", 0.9)
    for text in ("zncc", "nope=1", "zncc=abc", "zncc=nan"):
        with pytest.raises(InputError):
            parse_threshold(text)
    metrics = {"zncc": 0.9, "rel_rmse": 0.2, "cutoff_shape_gap_deg": None}
    assert failed_thresholds(metrics, [("zncc", 0.8)], [("rel_rmse", 0.3)]) == []
    fails = failed_thresholds(metrics, [("zncc", 0.95), ("cutoff_shape_gap_deg", 0.1)],
                              [("rel_rmse", 0.1)])
    assert len(fails) == 3 and "undefined" in fails[1]


# --- the real photograph -------------------------------------------------------------------

def test_real_photo_goes_through(sim_dir, tmp_path):
    """Not a ground truth (unknown distance and aim, two beams): outputs exist and are finite."""
    out = tmp_path / "zoe"
    result = run_compare(REAL_PHOTO, sim_dir, out,
                         CompareOptions(credit="photo: landswellsong, CC BY 4.0"))
    assert result.photo.encoding == "srgb-8" and result.photo.clipped.any()
    assert np.all(np.isfinite(result.matrix))
    doc = json.loads((out / "comparison.json").read_text())
    for name, value in doc["metrics"].items():
        assert value is None or math.isfinite(value), name
    assert doc["metrics"]["zncc"] is not None and doc["metrics"]["ssim"] is not None
    for png in ("overlay.png", "difference.png", "contours.png"):
        assert (out / png).stat().st_size > 20_000
    # no markers or points on this photo: the report says aim cannot be judged from it
    assert doc["geometry"]["source"] == "beam registration" and not doc["aim"]["judgeable"]
    assert "cannot be judged" in doc["aim"]["statement"]
    assert any("2 lamps found" in w for w in doc["photo"]["warnings"])


# --- broader sweep -------------------------------------------------------------------------

def _sweep_cases(n: int = 24) -> list:
    rng = np.random.default_rng(2024)
    cases = []
    for i in range(n):
        tilt = float(rng.choice([0.0, 0.0, rng.uniform(-15, 15)]))
        gamma = rng.choice([0, 2.2])
        saturate = rng.choice([0, 0.6, 0.8])
        camera = dict(rotate_deg=float(rng.uniform(-10, 10)),
                      scale=float(np.exp(rng.uniform(np.log(0.8), np.log(1.25)))),
                      shift_px=(float(rng.uniform(-25, 25)), float(rng.uniform(-12, 12))),
                      tilt_deg=tilt, blur_px=float(rng.choice([0, 0.7, 1.5])),
                      noise=float(rng.choice([0, 0.005, 0.01])),
                      vignetting=float(rng.choice([0, 0.3])),
                      gamma=float(gamma) or None, saturate=float(saturate) or None, seed=i)
        cases.append(pytest.param(camera, "homography" if tilt else "similarity", id=f"s{i}"))
    return cases


@pytest.mark.slow
@pytest.mark.parametrize("camera,model", _sweep_cases())
def test_registration_sweep(camera, model, lux_a, sim_a, tmp_path):
    photo, truth, _ = _shoot(lux_a, tmp_path, "p", **camera)
    result = compare_images(photo, sim_a, CompareOptions(model=model, fit_gamma=True))
    assert_recovered(result.matrix, truth, photo.shape, lux_a)
    assert result.metrics["zncc"] >= 0.95


# --- two lamps in one frame ------------------------------------------------------------------

def test_two_lamps_are_found_and_one_can_be_picked(lux_a, sim_dir, tmp_path, capsys):
    both = lux_a + apply_shift(lux_a, FRAME, 8.0, 0.0)      # a second lamp 8° to the right
    photo, truth, path = _shoot(both, tmp_path, "two", rotate_deg=3, noise=0.004)
    lamps = find_lamps(photo)
    assert lamps.count == 2
    # the hot spots' columns: simulation hot spot (1.5° R) and 8° further right
    wall = load_simulation(sim_dir).wall
    hs = np.interp([1.5, 9.5], wall.h_deg(), np.arange(wall.width))
    inv = np.linalg.inv(truth)
    px = [float(apply_matrix(inv, np.array(c), np.array(wall.height / 2))[0]) for c in hs]
    assert lamps.peaks_px == pytest.approx(px, abs=12)
    assert px[0] < lamps.split_px < px[1]
    known = tmp_path / "truth.json"                    # skip the registration: faster
    known.write_text(json.dumps({"matrix": truth.tolist()}))
    code, _, err = _run(["compare", str(path), "--sim", str(sim_dir), "--out",
                         str(tmp_path / "c2"), "--transform", str(known)], capsys)
    assert code == 0 and "2 lamps found" in err and err.count("\n") == 1
    code, _, err = _run(["compare", str(path), "--sim", str(sim_dir), "--out",
                         str(tmp_path / "cl"), "--lamp", "left", "--transform", str(known)],
                        capsys)
    assert code == 0 and err == ""
    doc = json.loads((tmp_path / "cl" / "comparison.json").read_text())
    assert doc["details"]["lamps"]["kept"] == "left" and doc["details"]["lamps"]["count"] == 2


def test_lamp_on_a_one_lamp_photo_exits_2(lux_a, sim_dir, tmp_path, capsys):
    _, _, path = _shoot(lux_a, tmp_path, "one")
    code, _, err = _run(["compare", str(path), "--sim", str(sim_dir), "--out",
                         str(tmp_path / "c"), "--lamp", "right"], capsys)
    assert code == 2 and err.count("\n") == 1 and "one lamp" in err
    assert not (tmp_path / "c").exists()


def test_real_photo_shows_two_lamps():
    assert find_lamps(read_photo(REAL_PHOTO)).count == 2


# --- the fallback registration on patterns that are not a low beam ---------------------------

# a hard camera for the fallback registration: roll, zoom, keystone, blur, noise and gamma
HARD_CAMERA = dict(rotate_deg=7, scale=1.1, tilt_deg=5, blur_px=1.5, noise=0.01, gamma=2.2,
                   seed=1)


@pytest.mark.parametrize("pattern", ["two_spots", "ring_caustic", "lowbeam"])
@pytest.mark.parametrize("camera", [
    pytest.param(HARD_CAMERA, id="rot7-scale1.1-keystone-blur-noise-gamma"),
    pytest.param(dict(rotate_deg=-18, scale=0.6, shift_px=(10, -5), blur_px=1.0, noise=0.005,
                      seed=2), id="rot-18-scale0.6", marks=pytest.mark.slow),
])
def test_registration_of_any_pattern_within_a_pixel(pattern, camera, tmp_path):
    lux = (lowbeam_lux(FRAME, LAMP_A) if pattern == "lowbeam"
           else getattr(sp, f"{pattern}_lux")(FRAME))
    sim = load_simulation(write_result(tmp_path / "sim", lux, FRAME))
    photo, truth, _ = _shoot(lux, tmp_path, "p", **camera)
    model = "homography" if camera.get("tilt_deg") else "similarity"
    result = compare_images(photo, sim, CompareOptions(model=model, fit_gamma=True,
                                                       markers="off"))
    assert_recovered(result.matrix, truth, photo.shape, lux)
    assert not result.registration.blur_at_cap


def test_blur_cap_is_reported(lux_a, sim_a, tmp_path):
    photo, _, _ = _shoot(lux_a, tmp_path, "blurry", blur_px=4.0, scale=0.5, size=(200, 80),
                         rotate_deg=2)      # 8 simulation px of blur, the cap is 4
    result = compare_images(photo, sim_a, CompareOptions(markers="off"))
    t = result.transform_dict()
    assert t["blur_at_cap"] and result.registration.blur_at_cap
    assert t["photo_blur_px"] <= t["blur_cap_px"] + 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("camera", [
    pytest.param(HARD_CAMERA, id="rot7-scale1.1-keystone"),
    pytest.param(dict(rotate_deg=19, scale=1.1, blur_px=1.5, noise=0.01, seed=4), id="rot19"),
    pytest.param(dict(rotate_deg=-17, scale=0.6, shift_px=(10, -5), blur_px=1.0, noise=0.005,
                      seed=2), id="rot-17-scale0.6"),
])
def test_registration_of_the_shipped_headlight(camera, tmp_path_factory, capsys):
    """The simulated example headlight (a real photon-mapping run), photographed."""
    folder = tmp_path_factory.getbasetemp() / "h4-sim"
    if not (folder / "wall_lux.exr").exists():
        glb = Path(__file__).parents[2] / "luminaires" / "examples" / "headlight.glb"
        code, _, err = _run(["simulate", str(glb), "--photons", "1000000", "--out",
                             str(folder), "--quiet"], capsys)
        assert code == 0, err
    sim = load_simulation(folder)
    lux = np.nan_to_num(sim.lux)
    photo, truth, _ = _shoot(lux, tmp_path_factory.mktemp("h4p"), "p", **camera)
    model = "homography" if camera.get("tilt_deg") else "similarity"
    result = compare_images(photo, sim, CompareOptions(model=model, fit_gamma=True,
                                                       markers="off"))
    assert_recovered(result.matrix, truth, photo.shape, lux)
