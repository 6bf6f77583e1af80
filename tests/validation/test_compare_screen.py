"""Screen geometry for ``lightsim compare``: control points, markers, aim read off the photo.

Truth comes from the synthetic camera (:mod:`lightsim.validation.synthetic_photo`): a wall
with the default marker board (:func:`screen_scene`), photographed turned, magnified, seen
at an angle, blurred and noisy, written as JPEG and read back. The "real lamp" is the
simulated beam re-aimed by :func:`lightsim.render.cutoff.apply_shift` (a rotation of the
lamp), so the true aim error is known exactly.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from scipy.ndimage import map_coordinates
from skimage.transform import ProjectiveTransform, warp

from lightsim.errors import InputError
from lightsim.luminaires.regulations.ruleset import load_ruleset
from lightsim.render.cutoff import apply_shift
from lightsim.validation.compare import CompareOptions, compare_images
from lightsim.validation.photo_io import load_simulation, read_photo, srgb_decode, srgb_encode
from lightsim.validation.photo_register import apply_matrix
from lightsim.validation.screen_geometry import fit_screen, parse_points, sim_matrix
from lightsim.validation.screen_target import (
    DEFAULT_LAYOUT,
    detect_markers,
    load_layout,
    write_target,
)
from lightsim.validation.synthetic_photo import (
    CameraSettings,
    LowBeam,
    lowbeam_lux,
    render_photo,
    screen_scene,
    wall_frame,
    write_dng,
    write_photo,
    write_result,
)
from lightsim.wall import WallFrame

from support import run_cli as _run

FRAME = wall_frame((400, 160))
CAMERA = dict(rotate_deg=5, scale=0.9, size=(1300, 560), tilt_deg=8, blur_px=1.0,
              noise=0.005, seed=1)


@pytest.fixture(scope="module")
def lux():
    return lowbeam_lux(FRAME, LowBeam(texture=0.02))


@pytest.fixture(scope="module")
def sim(tmp_path_factory, lux):
    return load_simulation(write_result(tmp_path_factory.mktemp("sim") / "a", lux, FRAME))


def _marker_photo(lux, folder, name, dv_deg=0.0, **camera):
    """JPEG of the beam re-aimed by dv_deg on a marker screen; (photo, truth matrix, path)."""
    aimed = apply_shift(lux, FRAME, 0.0, dv_deg) if dv_deg else lux
    scene, _, to_sim = screen_scene(aimed, FRAME)
    shot = render_photo(scene, CameraSettings(**{**CAMERA, **camera}))
    path, _ = write_photo(folder / f"{name}.jpg", shot)
    truth = to_sim @ shot.matrix
    return read_photo(path), truth / truth[2, 2], path


@pytest.fixture(scope="module")
def aimed_up(tmp_path_factory, lux):
    return _marker_photo(lux, tmp_path_factory.mktemp("photos"), "up", dv_deg=0.5)


def _max_error(found, truth, shape, frame=FRAME):
    """Largest displacement (simulation px) over the screen the markers span, |H| ≤ 10°,
    −6° ≤ V ≤ 4° (outside it a homography extrapolates)."""
    wall = WallFrame.from_any(frame)
    hp, wp = shape
    yy, xx = np.mgrid[0:hp:4, 0:wp:4].astype(float)
    tx, ty = apply_matrix(truth, xx, yy)
    fx, fy = apply_matrix(found, xx, yy)
    h = np.interp(tx, np.arange(wall.width), wall.h_deg())
    v = np.interp(ty, np.arange(wall.height), wall.v_deg())
    keep = (np.abs(h) <= 10) & (v >= -6) & (v <= 4)
    return float(np.max(np.hypot(fx - tx, fy - ty)[keep]))


# --- control points ------------------------------------------------------------------------

def test_homography_from_points_is_exact_and_its_residual_measures_the_noise():
    rng = np.random.default_rng(0)
    truth = np.array([[0.011, 0.001, -7.0], [0.0005, -0.012, 3.0], [1e-5, 2e-6, 1.0]])
    xy = rng.uniform(0, 1000, (12, 2))
    hm, vm = apply_matrix(truth, xy[:, 0], xy[:, 1])
    hv = np.degrees(np.arctan(np.column_stack([hm, vm]) / 25.0))
    exact = fit_screen(xy, hv)
    assert exact.residual_px[1] < 1e-3 and exact.residual_deg[1] < 1e-5
    np.testing.assert_allclose(exact.matrix, truth / truth[2, 2], rtol=1e-5, atol=1e-9)
    noisy = fit_screen(xy + rng.normal(0, 0.5, xy.shape), hv)
    assert 0.2 < noisy.residual_px[0] < 0.8           # σ = 0.5 px per coordinate
    assert noisy.sigma_deg is not None and noisy.sigma_deg > noisy.residual_deg[0]
    four = fit_screen(xy[:4], hv[:4])
    assert four.sigma_deg is None                       # exact fit: nothing to check it


@pytest.mark.parametrize("text,message", [
    ("1,2=3,4;5,6=7,8;9,10=11,12", "at least 4"),
    ("1,2=3", "must be 'x,y=H,V'"),
    ("0,0=0,0;1,1=1,1;2,2=2,2;3,3=3,3", "collinear"),
    ("0,0=0,0;10,0=1,0;20,0=2,0;30,0=3,0;0,10=0,-1", "general position"),
    ("0,0=0,0;1,0=1,0;0,1=0,1;5,5=inf,1", "not finite"),
])
def test_bad_points_are_input_errors(text, message):
    with pytest.raises(InputError, match=message):
        fit_screen(*parse_points(text))


def test_points_fix_the_geometry_without_registration(aimed_up, sim):
    photo, truth, _ = aimed_up
    # four screen positions where the user would measure: the marker centres
    hv = np.array([(h, v) for _, h, v in DEFAULT_LAYOUT.markers])[[0, 4, 5, 9, 2]]
    rows, cols = sim.wall.pixel_of(25 * np.tan(np.radians(hv[:, 0])),
                                   25 * np.tan(np.radians(hv[:, 1])))
    x, y = apply_matrix(np.linalg.inv(truth), cols, rows)
    text = "; ".join(f"{a:.2f},{b:.2f}={h},{v}" for a, b, (h, v) in zip(x, y, hv))
    result = compare_images(photo, sim, CompareOptions(points=text, markers="off"))
    assert result.registration is None and result.geometry.source == "points"
    assert result.geometry.residual_px[0] < 0.02 and result.geometry.sigma_deg < 1e-3
    assert _max_error(result.matrix, truth, photo.shape) < 0.05
    assert result.aim.judgeable
    assert result.aim.cutoff.offset_deg == pytest.approx(0.5, abs=0.05)


# --- markers -------------------------------------------------------------------------------

def test_markers_map_the_screen_within_a_pixel(aimed_up, sim):
    photo, truth, _ = aimed_up
    geo = detect_markers(photo.luminance)
    assert geo is not None and len(geo.details["marker_ids"]) >= 8
    err = _max_error(sim_matrix(geo, sim.frame), truth, photo.shape)
    assert err < 0.5, err                               # simulation px (0.17° each)
    assert geo.residual_deg[0] < 0.1


def test_aim_half_a_degree_high_is_reported_with_its_interval(aimed_up, sim):
    photo, _, _ = aimed_up
    result = compare_images(photo, sim)
    aim = result.aim
    assert aim.geometry == "markers" and aim.judgeable
    cut = aim.cutoff
    assert cut.offset_deg is not None and not cut.blur_at_cap
    assert abs(cut.offset_deg - 0.5) <= cut.interval_deg, (cut.offset_deg, cut.interval_deg)
    assert 0.005 < cut.interval_deg < 0.25
    assert aim.hotspot_dv_deg == pytest.approx(0.5, abs=0.12)
    assert abs(aim.hotspot_dh_deg) < 0.12
    assert result.metrics["cutoff_dv_deg"] == cut.offset_deg


def test_aim_on_target_reads_zero_and_the_test_points_agree(lux, sim, tmp_path):
    photo, _, _ = _marker_photo(lux, tmp_path, "on", rotate_deg=-3, tilt_deg=-6, seed=4)
    aim = compare_images(photo, sim).aim
    cut = aim.cutoff
    assert abs(cut.offset_deg) <= max(cut.interval_deg, 0.03)
    assert aim.normalised_at["point"] == "50R" and not aim.normalised_at["clipped"]
    points = {p.name: p for p in aim.points}
    assert set(points) == {"75R", "50V", "B50L"}
    # bright points: photo and simulation agree relative to 50R (room light adds ~1 %)
    for name in ("75R", "50V"):
        assert points[name].ratio == pytest.approx(1.0, abs=0.05), points[name]
    # B50L is dark: the room light (0.5 lx) dominates it in the photo, as in a real one
    assert points["B50L"].photo_rel > points["B50L"].sim_rel


def test_registration_fallback_says_aim_cannot_be_judged(aimed_up, sim, tmp_path, capsys):
    photo, _, path = aimed_up
    result = compare_images(photo, sim, CompareOptions(markers="off"))
    assert result.registration is not None and not result.aim.judgeable
    assert "cannot be judged" in result.aim.statement
    code, out, _ = _run(["compare", str(path), "--sim", sim.source, "--out",
                         str(tmp_path / "fb"), "--markers", "off"], capsys)
    assert code == 0 and "AIM: aim cannot be judged from this photo" in " ".join(out.split())
    doc = json.loads((tmp_path / "fb" / "comparison.json").read_text())
    assert doc["geometry"]["source"] == "beam registration" and not doc["aim"]["judgeable"]


# --- the printed board ---------------------------------------------------------------------

def test_screen_target_png_is_found_exactly_and_pdf_has_a_page_per_marker(tmp_path, capsys):
    code, _, err = _run(["screen-target", str(tmp_path / "board.png"), "--px-per-m", "60"],
                        capsys)
    assert code == 0, err
    layout = load_layout(tmp_path / "board.layout.json")
    assert layout == DEFAULT_LAYOUT

    img = iio.imread(tmp_path / "board.png").astype(float) / 255
    geo = detect_markers(img ** 2.2, layout)
    assert sorted(geo.details["marker_ids"]) == list(range(10))
    assert geo.residual_px[0] < 0.5
    code, _, err = _run(["screen-target", str(tmp_path / "board.pdf"), "--distance", "10"], capsys)
    assert code == 0, err
    pdf = (tmp_path / "board.pdf").read_bytes()
    assert pdf.startswith(b"%PDF") and pdf.count(b"/Type /Page\n") + pdf.count(
        b"/Type /Page ") + pdf.count(b"/Type /Page>") >= 11
    doc = json.loads((tmp_path / "board.layout.json").read_text())
    assert doc["distance_m"] == 10 and doc["size_m"] == pytest.approx(
        2 * 10 * np.tan(np.radians(0.75)))


def test_screen_target_bad_output_exits_2(tmp_path, capsys):
    code, _, err = _run(["screen-target", str(tmp_path / "board.svg")], capsys)
    assert code == 2 and err.strip().count("\n") == 0 and "png or .pdf" in err
    assert not list(tmp_path.iterdir())


def test_write_target_rejects_a_bad_resolution(tmp_path):
    with pytest.raises(InputError, match="px-per-m"):
        write_target(tmp_path / "b.png", px_per_m=float("nan"))


# --- photo against photo -------------------------------------------------------------------

def _deflected(lux):
    """A deflector that dims everything left of H = −2° by 40 % (soft edge)."""
    h = WallFrame.from_any(FRAME).h_deg()[None, :]
    return lux * (1 - 0.4 / (1 + np.exp((h + 2.0) / 0.2)))


def _pair(lux, folder, layout, texture, ambient, moved=True):
    cam = dict(rotate_deg=2, scale=0.9, size=(1300, 560), tilt_deg=5, blur_px=0.8,
               noise=0.004)
    shots = []
    for name, scene_lux, extra in (
            ("a", lux, dict(seed=1)),
            ("b", _deflected(lux), dict(rotate_deg=3.2 if moved else 2,
                                        shift_px=(9, -6) if moved else (0, 0),
                                        exposure_ev=-0.5, seed=2))):
        scene, _, to_sim = screen_scene(scene_lux, FRAME, layout=layout,
                                        texture_seed=texture, ambient_lx=ambient)
        shot = render_photo(scene, CameraSettings(**{**cam, **extra}))
        path, _ = write_photo(folder / f"{name}.jpg", shot)
        shots.append((path, shot, to_sim))
    return shots


def _points_text(truth):
    hv = np.array([(h, v) for _, h, v in DEFAULT_LAYOUT.markers])[[0, 4, 5, 9, 2, 7]]

    wall = WallFrame.from_any(FRAME)
    rows, cols = wall.pixel_of(25 * np.tan(np.radians(hv[:, 0])),
                               25 * np.tan(np.radians(hv[:, 1])))
    x, y = apply_matrix(np.linalg.inv(truth), cols, rows)
    return "; ".join(f"{a:.3f},{b:.3f}={h},{v}" for a, b, (h, v) in zip(x, y, hv))


def _true_change(lux, name, ambient):
    """(E_B + ambient)/(E_A + ambient) − 1 at a test point: what the camera sees change."""
    g = load_ruleset("r112-b-passing").geometry(name)
    wall = WallFrame.from_any(FRAME)
    r, c = wall.pixel_of(25 * np.tan(np.radians(g.h)), 25 * np.tan(np.radians(g.v)))
    ea, eb = (float(map_coordinates(x, [[r], [c]], order=1)[0]) for x in (lux, _deflected(lux)))
    return (eb + ambient) / (ea + ambient) - 1


def _check_pair(doc, shots, truth_change):
    """B → A within a pixel over the screen (|H| ≤ 10°, −6° ≤ V ≤ 4° seen in A); the
    change at the unclipped test points as the camera sees it."""
    (_, a, to_sim), (_, b, _) = shots
    m = np.array(doc["alignment"]["matrix"])
    a_to_b = np.linalg.inv(b.matrix) @ a.matrix
    # compare B→A maps at A pixels x_a: truth is x_a itself, found is m·(a_to_b·x_a)
    wall = WallFrame.from_any(FRAME)
    yy, xx = np.mgrid[0:560:8, 0:1300:8].astype(float)
    sx, sy = apply_matrix(to_sim @ a.matrix, xx, yy)
    h = np.interp(sx, np.arange(wall.width), wall.h_deg())
    v = np.interp(sy, np.arange(wall.height), wall.v_deg())
    keep = (np.abs(h) <= 10) & (v >= -6) & (v <= 4)
    bx, by = apply_matrix(a_to_b, xx, yy)
    fx, fy = apply_matrix(m, bx, by)
    assert float(np.max(np.hypot(fx - xx, fy - yy)[keep])) < 1.0
    changes = {p["name"]: p["change"] for p in doc["test_points"] if not p["unusable"]}
    for name, want in truth_change.items():
        assert changes[name] == pytest.approx(want, abs=0.05), (name, changes, truth_change)


def test_photo_against_photo_by_static_features(lux, tmp_path, capsys):
    shots = _pair(lux, tmp_path, layout=False, texture=7, ambient=2.0)
    (pa, a, to_sim), (pb, _, _) = shots
    text = _points_text(to_sim @ a.matrix)
    code, out, err = _run(["compare", str(pa), "--against", str(pb), "--points", text,
                           "--out", str(tmp_path / "pair")], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "pair" / "pair.json").read_text())
    assert doc["alignment"]["method"] == "features + ECC" and doc["alignment"]["inliers"] >= 50
    assert doc["exposure"]["source"] == "static scene"
    assert doc["exposure"]["ratio"] == pytest.approx(2 ** 0.5, rel=0.03)
    _check_pair(doc, shots, {n: _true_change(lux, n, 2.0) for n in ("B50L", "75R", "50V", "50L")})
    assert (tmp_path / "pair" / "relative_difference.png").stat().st_size > 10_000
    assert "not by the beams" in out


def test_photo_against_photo_by_markers(lux, tmp_path, capsys):
    shots = _pair(lux, tmp_path, layout=None, texture=None, ambient=0.5)
    code, _, err = _run(["compare", str(shots[0][0]), "--against", str(shots[1][0]),
                         "--out", str(tmp_path / "pm")], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "pm" / "pair.json").read_text())
    assert doc["alignment"]["method"] == "markers" and doc["geometry"]["source"] == "markers"
    _check_pair(doc, shots, {n: _true_change(lux, n, 0.5) for n in ("B50L", "75R", "50V", "50L")})


def test_photo_against_photo_without_a_static_scene_exits_2(lux, tmp_path, capsys):
    shots = _pair(lux, tmp_path, layout=False, texture=None, ambient=0.0)
    code, _, err = _run(["compare", str(shots[0][0]), "--against", str(shots[1][0]),
                         "--out", str(tmp_path / "none")], capsys)
    assert code == 2 and err.count("\n") == 1 and "static" in err
    assert not (tmp_path / "none").exists()


def test_cli_photo_of_a_marker_screen_with_the_lamp_aimed_half_a_degree_up(sim, tmp_path,
                                                                            capsys):

    folder = Path(sim.source).parent
    photo = tmp_path / "up.jpg"
    code, _, err = _run(["photo", str(folder), str(photo), "--markers", "--reaim", "0,0.5",
                         "--rotate", "-4", "--scale", "3", "--size", "1200x500", "--tilt",
                         "-7", "--blur", "1", "--noise", "0.005", "--seed", "5"], capsys)
    assert code == 0, err
    truth = json.loads((tmp_path / "up.truth.json").read_text())
    assert truth["reaim_deg"] == {"dh": 0.0, "dv": 0.5} and truth["screen"]["markers"]
    code, out, err = _run(["compare", str(photo), "--sim", str(folder), "--out",
                           str(tmp_path / "c")], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "c" / "comparison.json").read_text())
    # only three markers of the lower row are in this photo: they do not fix the screen
    # across their row, so the aim is refused, in one line, with the markers named
    assert doc["geometry"]["marker_ids"] == [6, 7, 8]
    assert doc["aim"]["markers"]["found"] == [6, 7, 8]
    assert doc["aim"]["markers"]["missing"] == [0, 1, 2, 3, 4, 5, 9]
    assert not doc["aim"]["judgeable"] and "only 3 marker(s)" in doc["aim"]["refused"]
    assert "markers: 3 of 10 found (ids 6, 7, 8); missing 0, 1, 2, 3, 4, 5, 9" in out
    assert "AIM: aim not read: only 3 marker(s)" in out
    # the photo command's defaults frame the whole marker board: all ten are found, and
    # the aim interval covers the 0.5° re-aim
    photo = tmp_path / "default.jpg"
    code, _, err = _run(["photo", str(folder), str(photo), "--markers", "--reaim", "0,0.5",
                         "--blur", "1", "--noise", "0.005", "--seed", "5"], capsys)
    assert code == 0, err
    code, out, err = _run(["compare", str(photo), "--sim", str(folder), "--out",
                           str(tmp_path / "d")], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "d" / "comparison.json").read_text())
    assert doc["aim"]["markers"]["found"] == list(range(10)) and doc["aim"]["judgeable"]
    cut = doc["aim"]["cutoff"]
    assert abs(cut["offset_deg"] - 0.5) <= cut["interval_deg"]
    assert f"AIM: cut-off {cut['offset_deg']:+.3f}° ± {cut['interval_deg']:.3f}°" in out


def test_photo_against_photo_uses_exif_exposure(lux, sim, tmp_path, capsys):
    """Two raw DNGs of one marker screen, B exposed twice as long (EXIF 1/25 s vs 1/50 s)
    and twice as bright: the exposure ratio comes from EXIF and nothing else changed."""
    scene, _, _ = screen_scene(lux, FRAME)
    shot = render_photo(scene, CameraSettings(**{**CAMERA, "noise": 0.0}))
    a = write_dng(tmp_path / "a.dng", 0.45 * shot.linear)
    b = write_dng(tmp_path / "b.dng", 0.9 * shot.linear,
                  exposure={"exposure_time_s": 1 / 25})
    code, _, err = _run(["compare", str(a), "--against", str(b), "--out",
                         str(tmp_path / "p")], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "p" / "pair.json").read_text())
    assert doc["exposure"]["source"] == "exif" and doc["exposure"]["ratio"] == pytest.approx(0.5)
    assert abs(doc["relative_difference"]["median"]) < 0.01
    code, _, err = _run(["compare", str(a), "--sim", str(Path(sim.source).parent), "--out",
                         str(tmp_path / "s"), "-q"], capsys)
    assert code == 0, err
    phot = json.loads((tmp_path / "s" / "comparison.json").read_text())["photometric"]
    assert phot["relative_exposure"] == pytest.approx(200 / 50 / 2.8**2)
    assert phot["gain_per_relative_exposure"] == pytest.approx(
        phot["gain"] / phot["relative_exposure"])


def test_real_photograph_against_a_moved_darker_copy_aligns_by_the_door(tmp_path, capsys):
    """The shipped real photograph (CC BY 4.0, tests/data/README.md) against itself turned
    1°, moved (7, −4) px and 0.7× as bright, re-encoded as JPEG: the garage door outside
    the beams aligns B onto A within 0.5 px and the exposure ratio is found."""
    real = Path(__file__).parents[1] / "data" / "zoe-lowbeam-garage-door.jpg"
    img = srgb_decode(iio.imread(real).astype(float) / 255)
    h, w = img.shape[:2]
    cx, cy, a = (w - 1) / 2, (h - 1) / 2, math.radians(1.0)
    b_to_a = (np.array([[1, 0, cx + 7], [0, 1, cy - 4], [0, 0, 1.0]])
              @ np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0],
                          [0, 0, 1.0]])
              @ np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1.0]]))
    moved = np.stack([warp(img[..., c], ProjectiveTransform(b_to_a), order=1, mode="edge")
                      for c in range(3)], axis=-1)
    b = tmp_path / "b.jpg"
    iio.imwrite(b, np.round(srgb_encode(0.7 * moved) * 255).astype(np.uint8), quality=92)
    code, _, err = _run(["compare", str(real), "--against", str(b), "--out",
                         str(tmp_path / "p")], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "p" / "pair.json").read_text())
    m = np.array(doc["alignment"]["matrix"])
    yy, xx = np.mgrid[int(0.1 * h):int(0.9 * h):20, int(0.1 * w):int(0.9 * w):20].astype(float)
    tx, ty = apply_matrix(b_to_a, xx, yy)
    fx, fy = apply_matrix(m, xx, yy)
    assert float(np.max(np.hypot(fx - tx, fy - ty))) < 0.5
    assert doc["exposure"]["ratio"] == pytest.approx(1 / 0.7, rel=0.02)


def test_a_single_marker_is_not_trusted(lux, sim, tmp_path):
    """One marker's four corners fix a homography with nothing to check it: not used."""
    one = replace(DEFAULT_LAYOUT, markers=DEFAULT_LAYOUT.markers[2:3])
    scene, _, _ = screen_scene(lux, FRAME, layout=one)
    shot = render_photo(scene, CameraSettings(**CAMERA))
    path, _ = write_photo(tmp_path / "one.jpg", shot)
    photo = read_photo(path)
    assert detect_markers(photo.luminance).details["marker_ids"] == [2]
    result = compare_images(photo, sim, CompareOptions())
    assert result.geometry is None and not result.aim.judgeable
    assert any("only marker 2 found" in w for w in result.photo.info["warnings"])
