"""Screen geometry for ``lightsim compare``: control points, markers, aim read off the photo.

Truth comes from the synthetic camera (:mod:`lightsim.validation.synthetic_photo`): a wall
with the default marker board (:func:`screen_scene`), photographed turned, magnified, seen
at an angle, blurred and noisy, written as JPEG and read back. The "real lamp" is the
simulated beam re-aimed by :func:`lightsim.render.cutoff.apply_shift` (a rotation of the
lamp), so the true aim error is known exactly.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import run_cli as _run

from lightsim.errors import InputError
from lightsim.render.cutoff import apply_shift
from lightsim.validation.compare import CompareOptions, compare_images
from lightsim.validation.photo_io import load_simulation, read_photo
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
    write_photo,
    write_result,
)

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
    from lightsim.luminaires.regulations.units import WallFrame

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
    assert 0.01 < cut.interval_deg < 0.25
    assert aim.hotspot_dv_deg == pytest.approx(0.5, abs=0.12)
    assert abs(aim.hotspot_dh_deg) < 0.12
    assert result.metrics["cutoff_dv_deg"] == cut.offset_deg


def test_aim_on_target_reads_zero(lux, sim, tmp_path):
    photo, _, _ = _marker_photo(lux, tmp_path, "on", rotate_deg=-3, tilt_deg=-6, seed=4)
    cut = compare_images(photo, sim).aim.cutoff
    assert abs(cut.offset_deg) <= max(cut.interval_deg, 0.03)


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
    import imageio.v3 as iio

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
