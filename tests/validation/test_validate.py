"""Analytic validation: the exact answers themselves, the fast suite, and that
its checks can fail. The full study is ``-m slow``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lightsim.cli.main import main
from lightsim.materials import MIRROR, Material, fresnel_dielectric, slab_transmittance
from lightsim.validation import analytic as va
from lightsim.validation.scenes import analytic as an


def _run(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


# ------------------------------------------------------------------------------------------
# The exact answers, checked independently of the tracer
# ------------------------------------------------------------------------------------------

def test_disk_formula_equals_lambert_polygon_integral():
    case = an.lambertian_case(segments=1024)
    lum = case.extra["luminance"]
    rho = np.linspace(0.0, 0.3, 13)
    pts = case.frame.to_world(rho, 0 * rho)
    poly = an.lambert_polygon_lux(lum, case.scene.parts[0].vertices[1:], pts, case.frame.normal)
    disk = an.disk_lux(lum, 0.05, 0.1, rho)
    np.testing.assert_allclose(poly, disk, rtol=2e-5)
    # on the axis: E = (Φ/A) a²/(a² + d²) with L = Φ/(πA)
    area = case.params["area_m2"]
    assert disk[0] == pytest.approx(100.0 / area * 0.05**2 / (0.05**2 + 0.1**2), rel=1e-12)
    assert lum == pytest.approx(100.0 / (math.pi * area), rel=1e-12)


def test_isotropic_lux_integrates_to_the_solid_angle_flux():
    d, half = 2.0, 2.0
    n = 801
    x = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(x, x)
    e = an.isotropic_plane_lux(1000.0, d, np.hypot(xx, yy))
    flux = np.trapezoid(np.trapezoid(e, x, axis=1), x)
    omega = an.rectangle_solid_angle(-half, half, -half, half, d)
    assert flux == pytest.approx(1000.0 * omega / (4 * math.pi), rel=1e-5)
    # a huge rectangle is a half space: 2π sr; a tiny one is A / d²
    assert an.rectangle_solid_angle(-1e6, 1e6, -1e6, 1e6, 1.0) == pytest.approx(2 * math.pi,
                                                                               rel=1e-5)
    assert an.rectangle_solid_angle(0, 1e-3, 0, 1e-3, 1.0) == pytest.approx(1e-6, rel=1e-5)


def test_paraboloid_beam_carries_the_flux_the_mirror_catches():
    f, a, R = 0.1, 0.15, 0.88
    r = np.linspace(0.0, a, 200_001)
    flux = np.trapezoid(an.paraboloid_reflected_lux(1000.0, f, R, r) * 2 * np.pi * r, r)
    psi = 2 * math.atan(a / (2 * f))
    assert flux == pytest.approx(R * 1000.0 * (1 - math.cos(psi)) / 2, rel=1e-8)
    # centre value R Φ/(4π f²); at r = 2f the cos⁴(ψ/2) factor is 1/4
    assert an.paraboloid_reflected_lux(1000.0, f, R, 0.0) == pytest.approx(
        R * 1000 / (4 * math.pi * f * f))
    assert an.paraboloid_reflected_lux(1000.0, f, R, 2 * f) == pytest.approx(
        R * 1000 / (4 * math.pi * f * f) / 4)


@pytest.mark.parametrize("sigma", [0.0, 10.0])
def test_slab_orders_conserve_flux_and_sum_to_the_slab_transmittance(sigma):
    s = an.SlabExact(1000.0, 1.0, 0.02, 1.5, sigma, theta_max=1.2)
    th1 = 0.9
    for k, (rho_k, e_k) in enumerate(s.orders[:3]):
        sel = s.theta <= th1
        flux = np.trapezoid(e_k[sel] * 2 * np.pi * rho_k[sel], rho_k[sel])
        R = s.reflectance(s.theta[sel])
        a = s.absorption(s.theta[sel])
        tk = (1 - R) ** 2 * R ** (2 * k) * a ** (2 * k + 1)
        expect = 500.0 * np.trapezoid(tk * np.sin(s.theta[sel]), s.theta[sel])
        assert flux == pytest.approx(expect, rel=1e-6)
    for deg in (0.0, 20.0, 50.0):
        t = math.radians(deg)
        a = float(s.absorption(t))
        assert s.transmittance(t) == pytest.approx(slab_transmittance(1.5, math.cos(t), a),
                                                   rel=1e-12)
    # the tracer's model (mean R) and the polarised answer agree at normal incidence only
    assert s.transmittance_polarised(0.0) == pytest.approx(s.transmittance(0.0), rel=1e-12)
    assert s.transmittance_polarised(math.radians(60)) > s.transmittance(math.radians(60))


def test_fresnel_matches_the_tracer_kernel():
    for c in (1.0, 0.8, 0.3, 0.01):
        rs, rp = an.fresnel_unpolarised(c, 1.5)
        assert 0.5 * (rs + rp) == pytest.approx(fresnel_dielectric(c, 1.0, 1.5), rel=1e-12)


def test_nephroid_cusp_is_half_the_radius():
    phi = np.linspace(0.0, 1.0, 1001)
    x = an.nephroid_axis_crossing(0.1, phi)
    assert x.min() == pytest.approx(0.05, rel=1e-12) and np.all(x >= 0.05)
    # the same from explicit reflection: ray (1, 0) at height R sin φ, normal to the centre
    for p in (0.05, 0.3, 0.7):
        hit = 0.1 * np.array([math.cos(p), math.sin(p)])
        n = -hit / 0.1
        d = np.array([1.0, 0.0]) - 2 * (np.array([1.0, 0.0]) @ n) * n
        t = -hit[1] / d[1]
        assert hit[0] + t * d[0] == pytest.approx(an.nephroid_axis_crossing(0.1, p), rel=1e-12)


def test_pixel_average_is_exact_for_polynomials():
    case = an.isotropic_case(resolution=(8, 8))
    fn = lambda h, v: 3 * h**4 - v**2 * h + 2  # noqa: E731
    avg = an.pixel_average(fn, case.frame, n=3)
    h, v = case.frame.pixel_centres()
    dh, dv = case.frame.pixel_size_m
    # exact pixel means of h⁴ (h0⁴ + h0² dh²/2 + dh⁴/80) and of v² h (= (v0² + dv²/12) h0)
    hh, vv = np.meshgrid(h, v)
    exact = 3 * (hh**4 + hh**2 * dh**2 / 2 + dh**4 / 80) - (vv**2 + dv**2 / 12) * hh + 2
    np.testing.assert_allclose(avg, exact, rtol=1e-12)


def test_knn_radius_model_on_a_uniform_field():
    """Uniform density n: the disk of radius √(k / (π n)) holds k photons; the blurred
    image of a constant is the constant (away from the detector's edge)."""
    from lightsim.scene import Scene, make_wall

    wall, frame = make_wall(1.0, (4.0, 4.0), resolution=(40, 40))
    case = an.AnalyticScene("uniform", "", Scene([wall], frame), 1.0,
                            lambda h, v: np.full(np.shape(h), 5.0), radial=True)
    cfg = va.RunConfig(estimator="knn", k=64, interleave=4, final="interleaved")
    n_set = 1000.0  # photons per set; density 5 per m² per emitted photon: r_k = 0.064 m
    r, rk = va.estimator_radius(case, cfg, n_set, (0.01, math.inf))
    want = math.sqrt(64 / (math.pi * 5.0 * n_set))
    centre = slice(15, 25)
    np.testing.assert_allclose(rk[centre, centre], want, rtol=0.02)
    assert np.all(r >= 0.01)
    img = va.expected_image(case, cfg, n_set, (0.01, math.inf))
    np.testing.assert_allclose(img[centre, centre], 5.0, rtol=1e-9)
    # 0.05 m from the detector's edge a cap of the disk is empty (~7 % of its area at
    # r ≈ 0.065 m): r_k grows and the blurred estimate drops by about that fraction
    d, rr = 0.05, float(rk[0, 20])
    cap = rr * rr * math.acos(d / rr) - d * math.sqrt(rr * rr - d * d)
    assert rk[0, 20] > 1.01 * want
    unfiltered = va.expected_image(case, cfg.with_(interleave=1), n_set, (0.01, math.inf))
    assert unfiltered[0, 20] == pytest.approx(5.0 * (1 - cap / (math.pi * rr * rr)), rel=0.01)
    assert img[0, 20] > unfiltered[0, 20]  # the M×M filter mixes in rows further inside
    # a max_radius below r_k makes it a fixed-radius count
    r2, _ = va.estimator_radius(case, cfg, n_set, (0.01, 0.03))
    assert np.all(r2 <= 0.03)


def test_student_quantile_is_the_4_sigma_equivalent():
    assert va.student_q(10**6) == pytest.approx(4.0, abs=1e-3)
    assert va.student_q(16) == pytest.approx(5.48, abs=0.01)
    assert math.isinf(va.student_q(1))


# ------------------------------------------------------------------------------------------
# The fast suite (what `lightsim validate` runs), once per session
# ------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def fast_suite():
    return va.run_suite(va.SuiteSettings.fast())


def test_fast_suite_passes(fast_suite):
    failed = [c.to_dict() for c in fast_suite.checks if not c.passed]
    assert not failed, failed
    cases = {c.case.split("/")[0] for c in fast_suite.checks}
    assert {"isotropic", "paraboloid", "slab", "ring", "lambertian"} <= cases
    assert any(c.case.startswith("box") for c in fast_suite.checks)
    # every numeric check carries a finite allowance; profiles have several regions
    for c in fast_suite.checks:
        if c.numeric:
            assert c.uncertainty is not None and math.isfinite(c.uncertainty), c
    assert sum(1 for c in fast_suite.checks if c.case == "isotropic/bin"
               and c.quantity.startswith("E θ")) >= 8


def test_fast_suite_runs_knn_when_available(fast_suite):
    names = {c.case for c in fast_suite.checks}
    assert {"isotropic/knn", "paraboloid/knn", "ring/knn"} <= names
    # the blur allowance is computed, and it is what the kNN paraboloid centre needs
    centre = next(c for c in fast_suite.checks if c.case == "paraboloid/knn"
                  and "r 0–" in c.quantity)
    assert centre.bias > 0 and centre.error is not None
    assert abs(centre.error) <= centre.uncertainty


def test_wrong_reflectance_fails():
    """The profile check must notice a 5 % wrong mirror (R = 0.84 where 0.88 is expected)."""
    case = an.paraboloid_case(resolution=(48, 48))
    mirror = next(p for p in case.scene.parts if p.name == "reflector")
    case.scene = case.scene.replace_part(
        "reflector", material=Material("reflector", MIRROR, np.full(3, 0.84)))
    assert mirror.material.rgb[0] == pytest.approx(0.88)
    checks, _ = va.check_image_case(case, va.RunConfig(estimator="bin", spt=False), 300_000)
    inner = [c for c in checks if c.quantity.startswith("E_refl")]
    assert sum(not c.passed for c in inner) >= len(inner) // 2
    flux = next(c for c in checks if c.quantity == "flux on the wall")
    assert not flux.passed


def test_wrong_glass_index_fails():
    case = an.slab_case(resolution=(48, 48))
    slab = next(p for p in case.scene.parts if p.name == "slab")
    from dataclasses import replace

    case.scene = case.scene.replace_part("slab", material=replace(slab.material, ior=2.2))
    checks, _ = va.check_image_case(case, va.RunConfig(estimator="bin", spt=False), 300_000)
    assert sum(not c.passed for c in checks if c.quantity.startswith("E θ")) >= 3


def test_check_rows_and_verdicts():
    ok = va.Check("c", "q", 1.0, 1.05, "lx", sigma=0.01, q=4.0, bias=0.02)
    assert ok.uncertainty == pytest.approx(0.06) and ok.passed
    bad = va.Check("c", "q", 1.0, 1.07, "lx", sigma=0.01, q=4.0, bias=0.02)
    assert not bad.passed
    nan = va.Check("c", "q", 1.0, math.nan, "lx", sigma=0.01, q=4.0)
    assert not nan.passed
    no_sigma = va.Check("c", "q", 1.0, 1.0, "lx")
    assert not no_sigma.passed  # an allowance must be stated
    row = va.table_rows([bad])[0]
    assert row[-1] == "FAIL" and "(+7.00%)" in row[4]


# ------------------------------------------------------------------------------------------
# The command
# ------------------------------------------------------------------------------------------

def test_validate_cli_prints_table_and_json(tmp_path, capsys):
    out = tmp_path / "v.json"
    code, stdout, err = _run(["validate", "--case", "box", "--json", str(out), "-q"], capsys)
    assert code == 0, err
    header = stdout.splitlines()[1].split()
    assert header == ["case", "quantity", "expected", "measured", "error", "uncertainty",
                      "pass"]
    assert "PASS" in stdout and "FAIL" not in stdout
    doc = json.loads(out.read_text())
    assert doc["passed"] is True and doc["n_failed"] == 0
    assert {c["quantity"] for c in doc["analytic"]["checks"]} >= {"escaped flux",
                                                                 "arrivals per emitted lumen"}


def test_validate_cli_exits_1_when_a_check_fails(monkeypatch, capsys):
    def broken(settings=None, cases=None, progress=None):
        return va.SuiteResult([va.Check("x", "E", 1.0, 2.0, "lx", sigma=0.1, q=4.0)], 0.0,
                              va.SuiteSettings())

    monkeypatch.setattr(va, "run_suite", broken)
    code, stdout, _ = _run(["validate", "-q"], capsys)
    assert code == 1
    assert "FAIL" in stdout and "failed:" in stdout


@pytest.mark.parametrize("argv", [["validate", "--photons", "10"],
                                  ["validate", "--case", "nosuch"]])
def test_validate_cli_bad_input_exits_2(argv, capsys):
    code, _, err = _run(argv, capsys)
    assert code == 2 and err.startswith("lightsim: error:") and len(err.splitlines()) == 1


# ------------------------------------------------------------------------------------------
# The long study
# ------------------------------------------------------------------------------------------

@pytest.mark.slow
def test_full_suite_passes():
    res = va.run_suite(va.SuiteSettings.full_run())
    failed = [c.to_dict() for c in res.checks if not c.passed]
    assert not failed, failed
    assert any(c.case == "slab-absorbing/bin" for c in res.checks)
    assert any(c.case == "lambertian/radius" for c in res.checks)


# ------------------------------------------------------------------------------------------
# Coverage of the regulation points' intervals (validate --coverage)
# ------------------------------------------------------------------------------------------

def test_synthetic_lamp_is_type_a_and_truth_is_the_files_interpolant(tmp_path):
    from lightsim.luminaires.photometric import HVGrid, read_ies, write_ies
    from lightsim.validation.coverage import aperture_truth, lamp_intensity, synthetic_lamp

    grid, p = synthetic_lamp(np.random.default_rng(5))
    # written as Type A (photometric type 3) and read back unchanged by the IES reader
    write_ies(tmp_path / "l.ies", grid)
    back = read_ies(tmp_path / "l.ies")
    assert isinstance(back, HVGrid) and back.photometric_type == "A"
    assert (tmp_path / "l.ies").read_text().splitlines()[8].split()[5] == "3"
    np.testing.assert_allclose(back.candela, grid.candela, rtol=1e-6)
    # at H = 0 the Type A node (0, V) is the wall angle (0, V): the node holds the formula
    j = int(np.argmin(np.abs(grid.h_deg)))
    i = int(np.argmin(np.abs(grid.v_deg + 2.0)))
    assert grid.h_deg[j] == 0.0
    assert grid.candela[j, i] == pytest.approx(
        lamp_intensity(np.array(0.0), np.array(grid.v_deg[i]), p), rel=1e-12)
    # a small aperture inside one bilinear cell returns the interpolant at its centre
    h, v = np.array([0.625]), np.array([-2.05])
    tiny = aperture_truth(back, h, v, 0.01, quad=4)
    assert tiny[0] == pytest.approx(float(back.intensity_hv(h, v)[0]), rel=1e-6)
    # a uniform lamp's aperture mean is its intensity whatever the aperture (exact dΩ)
    flat = HVGrid(grid.h_deg, grid.v_deg, np.full(grid.shape, 1234.0), "A")
    big = aperture_truth(flat, np.array([-20.0, 0.0]), np.array([5.0, 0.0]), 1.5, quad=16)
    np.testing.assert_allclose(big, 1234.0, rtol=1e-6)
    # the 95 % point's neighbourhood: the hot spot is bright, the glare just above the
    # cut-off at least 8× dimmer
    t = aperture_truth(back, np.array([1.15, -3.43]), np.array([-0.57, 0.57]), 0.15)
    below = float(back.intensity_hv(np.array([-3.0]), np.array([p["vc"] - 0.2]))[0])
    above = float(back.intensity_hv(np.array([-3.0]), np.array([p["vc"] + 0.2]))[0])
    assert t[0] > 5 * t[1] > 0 and below > 8 * above > 0


def test_coverage_study_small_within_a_binomial_band():
    from lightsim.validation.coverage import coverage_study

    res = coverage_study(3, 200_000, seed=7, quad=24)
    assert res.evaluations == 3 * 18
    lo, hi = res.band()   # 0.95 ± 3 binomial standard errors for 54 evaluations
    assert lo <= res.rate <= hi, res.to_dict()
    assert abs(res.worst_mean_bias) < 1.0
    # every kind of rule judged against its exact truth, no wrong verdict beyond nominal
    assert {k: c.evaluations > 0 for k, c in res.rules.items()} == dict.fromkeys(
        ("point", "sum", "zone", "relation"), True)
    assert all(c.wrong <= c.allowed() for c in res.rules.values()), res.wrong_examples
    json.dumps(res.to_dict())


@pytest.mark.slow
@pytest.mark.parametrize("photons", [250_000, 1_000_000])
def test_coverage_study_full_93_to_97_percent(photons):
    from lightsim.validation.coverage import COVERAGE_BAND, coverage_study

    res = coverage_study(40, photons)
    assert COVERAGE_BAND[0] <= res.rate <= COVERAGE_BAND[1], res.to_dict()
    for kind, c in res.rules.items():  # wrong verdicts within the nominal α/2 rate
        assert c.wrong <= c.allowed(), (kind, res.wrong_examples)


@pytest.mark.slow
@pytest.mark.parametrize("lamp", ["lowbeam.glb", "headlight.glb"])
def test_shipped_lamps_verdicts_against_a_long_reference(lamp, tmp_path_factory):
    """8 seeds at 250 k and 1 M photons against a 48 M-photon reference (built once per
    session in a temporary folder): no wrong verdict beyond the nominal rate."""
    from pathlib import Path

    from lightsim.validation.coverage import shipped_study

    path = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / lamp
    cache = tmp_path_factory.getbasetemp() / "coverage-reference"
    for photons in (250_000, 1_000_000):
        res = shipped_study(path, photons, 8, cache_dir=cache)
        for kind, c in res.rules.items():
            assert c.wrong <= c.allowed(), (kind, res.wrong_examples)


def test_validate_coverage_cli_bad_input(capsys):
    for argv in (["--lamps", "0"], ["--photons", "10"], ["--aperture", "-1"],
                 ["--counts", "250k,500"], ["--lamp", "no-such.glb"],
                 ["--lamp", "luminaires/examples/lowbeam.glb", "--seeds", "0"],
                 ["--counts", "1M", "--reference-photons", "100k"]):
        code, _, err = _run(["validate", "--coverage", *argv], capsys)
        assert code == 2 and len(err.strip().splitlines()) == 1
