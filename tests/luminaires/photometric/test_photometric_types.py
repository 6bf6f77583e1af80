"""IES Types A and B: LM-63 axes, exact flux, exact sampling (χ²), Type A files in and out."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from scipy.stats import chi2

from lightsim.errors import InputError
from lightsim.io.exr import read_exr
from lightsim.luminaires.photometric import (
    CandelaGrid,
    HVGrid,
    farfield_from_photons,
    hv_directions,
    read_ies,
    sample_directions,
    uniform_axes,
    write_ies,
)
from lightsim.scene import SceneSettings, load_scene

from support import run_cli as _run

# ---- helpers ---------------------------------------------------------------------------


def _seg_cos_moments(v0: float, v1: float) -> tuple[float, float]:
    """∫ (1−t) cos V dV and ∫ t cos V dV over [v0, v1] (radians), t the segment coordinate.

    Closed form from ∫ cos V = sin V and ∫ V cos V = cos V + V sin V.
    """
    d = v1 - v0
    whole = np.sin(v1) - np.sin(v0)
    first = (np.cos(v1) + v1 * np.sin(v1)) - (np.cos(v0) + v0 * np.sin(v0))  # ∫ V cos V
    up = (first - v0 * whole) / d
    return whole - up, up


def exact_type_a_flux(h_deg, v_deg, f_h, g_v) -> float:
    """Flux (lm) of I(H, V) = f(H)·g(V), f and g piecewise linear through the nodes.

    Type A solid angle: dΩ = cos V dV dH; the double integral separates.
    """
    fh = np.trapezoid(f_h, np.radians(h_deg))
    v = np.radians(v_deg)
    gv = 0.0
    for k in range(len(v) - 1):
        a, b = _seg_cos_moments(v[k], v[k + 1])
        gv += g_v[k] * a + g_v[k + 1] * b
    return float(fh * gv)


def type_a_text(h, v, cd, lumens: float, mult: float = 1.0) -> str:
    """An LM-63-2002 Type A file (photometric type 3) built by hand, not by write_ies."""
    rows = "\n".join(" ".join(f"{x:.9g}" for x in row) for row in cd)
    return ("IESNA:LM-63-2002\n[TEST] test lamp\n[MANUFAC] lightsim tests\nTILT=NONE\n"
            f"1 {lumens:.12g} {mult:g} {len(v)} {len(h)} 3 2 0 0 0\n1 1 55\n"
            + " ".join(f"{x:g}" for x in v) + "\n" + " ".join(f"{x:g}" for x in h) + "\n"
            + rows + "\n")


def chi_square_p(grid, n: int = 400_000, seed: int = 11, k: int = 2,
                 dirs: np.ndarray | None = None) -> tuple[float, int]:
    """p-value of sampled directions against the interpolant's exact flux in sub-cells."""
    table = grid.table.refined(k, k)  # the same function, cells split k × k
    if dirs is None:
        rng = np.random.default_rng(seed)
        dirs, _ = sample_directions(grid, rng.random(n), rng.random(n))
    j, _, _, i, _ = table.locate(*table.angles(dirs))
    assert np.all(j >= 0)
    counts = np.bincount(j * (len(table.theta_deg) - 1) + i,
                         minlength=table.cell_flux_matrix().size)
    expect = table.cell_flux_matrix().ravel() / table.total_flux() * len(dirs)
    use = expect >= 5                  # sparse bins are pooled into one
    obs = np.concatenate([counts[use], [counts[~use].sum()]])
    exp = np.concatenate([expect[use], [expect[~use].sum()]])
    keep = exp > 0
    stat = np.sum((obs[keep] - exp[keep]) ** 2 / exp[keep])
    dof = int(keep.sum()) - 1
    return float(chi2.sf(stat, dof)), dof


def beam_a(h, v):
    """A headlamp-like Type A table: hot spot right of the axis, sharp cut-off at V = 0."""
    H, V = np.meshgrid(h, v, indexing="ij")
    return (30000 * np.exp(-((H - 2.5) / 6) ** 2) * np.where(V <= 0, np.exp(-((V + 1.5)
                                                                            / 2.5) ** 2), 0.02)
            + 50.0)


# ---- axes ------------------------------------------------------------------------------
def test_lm63_axis_definitions():
    # LM-63-2002 §3: Type A photometric horizontal H0 V0, photometric zero (down) H0 V−90;
    # horizontal angles clockwise (seen from above) for Types A and B → H > 0 to the right
    assert np.allclose(hv_directions(0, 0, "A"), [0, 0, 1])
    assert np.allclose(hv_directions(0, -90, "A"), [0, -1, 0])
    assert np.allclose(hv_directions(90, 0, "A"), [-1, 0, 0])    # right = world −X
    assert np.allclose(hv_directions(0, 30, "A"), [0, 0.5, np.cos(np.radians(30))])
    # Type B: photometric zero (down) H0 V0, photometric horizontal H0 V90
    assert np.allclose(hv_directions(0, 0, "B"), [0, -1, 0])
    assert np.allclose(hv_directions(0, 90, "B"), [0, 0, 1])
    assert np.allclose(hv_directions(90, 37, "B"), [-1, 0, 0])   # H = 90: the polar axis
    # Type A = Type C relabelled: C = −H mod 360, γ = 90 + V (same direction)
    from lightsim.luminaires.photometric import directions_from_angles
    h, v = 23.0, -7.0
    assert np.allclose(hv_directions(h, v, "A"), directions_from_angles(-h % 360, 90 + v))
    g = HVGrid([-90.0, 90.0], [-90.0, 90.0], np.ones((2, 2)), "A")
    for kind in ("A", "B"):
        g = HVGrid([-40.0, 0.0, 35.0], [-20.0, 5.0, 60.0], np.arange(9.0).reshape(3, 3), kind)
        d = g.directions(np.array([-40, 12.0]), np.array([60.0, -3.0]))
        assert np.allclose(g.intensity_towards(d), g.intensity([-40, 12.0], [60.0, -3.0]))


# ---- flux ------------------------------------------------------------------------------
def test_type_a_file_comes_back_with_its_header_flux(tmp_path):
    h = np.linspace(-60, 60, 49)
    v = np.linspace(-20, 20, 41)
    f_h = 1000 * np.exp(-(h / 20) ** 2) + 5
    g_v = np.where(v <= 0, 1.0, 0.1) + 0.01 * v
    g_v = np.maximum(g_v, 0)
    cd = np.outer(f_h, g_v)
    phi = exact_type_a_flux(h, v, f_h, g_v)           # closed form, not our integrator
    p = tmp_path / "lamp_a.ies"
    p.write_text(type_a_text(h, v, cd, lumens=phi))
    grid = read_ies(p)
    assert isinstance(grid, HVGrid) and grid.photometric_type == "A"
    assert grid.warnings == () or all("part of the hemisphere" in w for w in grid.warnings)
    assert grid.lamp_lumens == pytest.approx(phi, rel=1e-12)
    assert grid.total_flux() == pytest.approx(phi, rel=1e-8)   # 9 written digits
    print(f"\nType A round trip: header {phi:.9g} lm, read back {grid.total_flux():.9g} lm "
          f"({grid.total_flux() / phi - 1:+.1e})")
    assert grid.node_solid_angles().sum() == pytest.approx(
        np.radians(120) * 2 * np.sin(np.radians(20)), rel=1e-12)
    scene = load_scene(p, SceneSettings(resolution=(8, 8)))
    assert scene.total_flux == pytest.approx(phi, rel=1e-8)
    # the sampler's photons carry Φ/n each: the far field they make holds that flux
    n = 200_000
    rng = np.random.default_rng(5)
    dirs, _ = sample_directions(grid, rng.random(n), rng.random(n))
    ff = farfield_from_photons(dirs, np.full(n, phi / n), n, c_deg=h, gamma_deg=v,
                               photometric_type="A")
    assert ff.total_flux() == pytest.approx(phi, rel=1e-12)
    assert float(ff.metadata["flux_outside_lm"]) == 0.0


def test_type_a_lateral_symmetry_and_photompy(tmp_path):
    h = np.array([0.0, 10.0, 30.0, 90.0])
    v = np.array([-90.0, -10.0, 0.0, 10.0, 90.0])
    cd = np.array([[1, 80, 100, 20, 0], [1, 60, 90, 10, 0], [1, 5, 8, 1, 0], [0, 0, 0, 0, 0.]])
    p = tmp_path / "half.ies"
    p.write_text(type_a_text(h, v, cd, lumens=-1))
    g = read_ies(p)
    assert np.array_equal(g.h_deg, [-90, -30, -10, 0, 10, 30, 90])
    assert g.intensity(-17.0, 4.0) == pytest.approx(g.intensity(17.0, 4.0))
    assert g.warnings == ()
    half = HVGrid(h, v, cd, "A")                     # the listed quarter…
    assert g.total_flux() == pytest.approx(2 * half.total_flux(), rel=1e-12)  # …mirrored
    photompy = pytest.importorskip("photompy")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")               # "Type A not currently supported"
        ies = photompy.IESFile.read(p.read_text())
    phot = ies.photometry
    assert int(phot.photometric_type) == 3
    assert np.allclose(phot.thetas, v) and np.allclose(phot.phis, h)
    assert np.allclose(phot.values, cd)


def test_type_b_flux_against_quadrature(tmp_path):
    h = np.linspace(-90, 90, 19)
    v = np.linspace(-90, 90, 13)
    H, V = np.meshgrid(h, v, indexing="ij")
    cd = 500 * np.exp(-(H / 25) ** 2 - (V / 40) ** 2) + 3 * (V > 0)
    g = HVGrid(h, v, cd, "B")
    # midpoint quadrature of the interpolant with dΩ = cos H dH dV on a 0.1° mesh
    hm = np.arange(-90, 90, 0.1) + 0.05
    vm = np.arange(-90, 90, 0.1) + 0.05
    HH, VV = np.meshgrid(hm, vm, indexing="ij")
    quad = np.sum(g.intensity(HH, VV) * np.cos(np.radians(HH))) * np.radians(0.1) ** 2
    assert g.total_flux() == pytest.approx(quad, rel=1e-5)
    assert g.downward_flux_fraction() == 1.0
    back = read_ies(write_ies(tmp_path / "b.ies", g))
    assert back.photometric_type == "B" and np.allclose(back.candela, cd, rtol=2e-6)


# ---- sampling: χ² against the interpolant ----------------------------------------------
@pytest.mark.parametrize("kind", ["C", "A", "B"])
def test_sampling_chi_square(kind):
    if kind == "C":
        c, gam = uniform_axes(5.0, 2.5)
        C, G = np.meshgrid(c, gam, indexing="ij")
        cs = np.where(C > 180, C - 360, C)
        grid = CandelaGrid(c, gam, 20000 * np.exp(-((G - 92) / 3) ** 2)
                           * np.exp(-((cs + 5) / 20) ** 2) + 40)
    else:
        h = np.linspace(-45, 45, 31)
        v = np.linspace(-15, 15, 21)
        grid = HVGrid(h, v, beam_a(h, v), kind)
    p, dof = chi_square_p(grid)
    print(f"\nType {kind} sampler vs interpolant: chi2 p = {p:.3f} ({dof} dof, 400 000 "
          "photons, 2x2 sub-cells)")
    assert dof > 400
    assert p > 1e-4, f"sampled directions do not follow the interpolant (p = {p:.2g})"


def test_chi_square_rejects_a_constant_per_cell_sampler():
    """The test has power: the old sampler (uniform within midpoint cells) fails it."""
    h = np.linspace(-45, 45, 31)
    v = np.linspace(-15, 15, 21)
    grid = HVGrid(h, v, beam_a(h, v), "A")
    hc = np.concatenate([[h[0]], 0.5 * (h[1:] + h[:-1]), [h[-1]]])
    vc = np.concatenate([[v[0]], 0.5 * (v[1:] + v[:-1]), [v[-1]]])
    sv = np.sin(np.radians(vc))
    w = grid.candela * np.diff(np.radians(hc))[:, None] * np.diff(sv)[None, :]
    n = 400_000
    rng = np.random.default_rng(2)
    cell = rng.choice(w.size, size=n, p=(w / w.sum()).ravel())
    ci, vi = np.unravel_index(cell, w.shape)
    hh = hc[ci] + rng.random(n) * (hc[ci + 1] - hc[ci])
    vv = np.degrees(np.arcsin(sv[vi] + rng.random(n) * (sv[vi + 1] - sv[vi])))
    p, dof = chi_square_p(grid, dirs=hv_directions(hh, vv, "A"))
    print(f"\nconstant-per-cell sampler: chi2 p = {p:.2g} ({dof} dof)")
    assert p < 1e-6


def test_pdf_is_the_interpolated_intensity():
    h = np.linspace(-45, 45, 31)
    v = np.linspace(-15, 15, 21)
    for kind in ("A", "B"):
        g = HVGrid(h, v, beam_a(h, v), kind)
        rng = np.random.default_rng(1)
        d, pdf = sample_directions(g, rng.random(20000), rng.random(20000))
        assert np.allclose(pdf * g.total_flux(), g.intensity_towards(d), rtol=1e-9)
    with pytest.raises(InputError, match="no flux"):
        sample_directions(HVGrid(h, v, np.zeros((31, 21)), "A"), [0.5], [0.5])


# ---- lightsim simulate: the light goes where the file says -----------------------------
@pytest.mark.parametrize("kind", ["A", "C"])
def test_asymmetric_type_a_lamp_lands_on_the_right(tmp_path, capsys, kind):
    """Light only at H = +4…+12° (right of the axis), V = −3…−1°: the wall's right side.

    Type C: the same lamp as C = 348…356° (C = −H), γ = 87…89° (γ = 90° + V).
    """
    h = np.array([-20.0, 3.0, 4.0, 12.0, 13.0, 20.0])
    v = np.array([-10.0, -4.0, -3.0, -1.0, 0.0, 10.0])
    cd = np.zeros((6, 6))
    cd[2:4, 2:4] = 10000.0
    p = tmp_path / "right.ies"
    if kind == "A":
        p.write_text(type_a_text(h, v, cd, lumens=-1))
    else:
        c = np.array([0.0, 340.0, 347.0, 348.0, 356.0, 357.0])
        gam = np.array([0.0, 86.0, 87.0, 89.0, 90.0, 180.0])
        cdc = np.zeros((6, 6))
        cdc[3:5, 2:4] = 10000.0
        write_ies(p, CandelaGrid(c, gam, cdc))
    out = tmp_path / "run"
    code, _, err = _run(["simulate", str(p), "--photons", "60000", "--wall-distance", "25",
                         "--wall-size", "24x8", "--resolution", "48x16", "--estimator", "bin",
                         "--frame-photons", "30000", "--out", str(out), "--quiet"], capsys)
    assert code == 0, err
    lux = read_exr(out / "wall_lux.exr")[0]["Y"]
    wall = json.loads((out / "summary.json").read_text())["wall"]
    W = wall["resolution"][0]
    h_m = np.linspace(*wall["h_range_m"], W + 1)
    h_c = 0.5 * (h_m[1:] + h_m[:-1])
    col = lux.sum(axis=0)
    right = col[h_c > 0].sum()
    assert right > 0.999 * col.sum()                      # all on the driver's right
    centre_h = np.degrees(np.arctan(np.sum(col * h_c) / col.sum() / 25.0))
    print(f"\nType {kind} lamp lit at H +4…+12°: {100 * right / col.sum():.3f} % of the wall "
          f"lux at h > 0, centroid H = {centre_h:+.2f}°")
    assert 4.0 < centre_h < 12.0
    rows = lux.sum(axis=1)                                # row 0 is the top
    v_m = np.linspace(wall["v_range_m"][1], wall["v_range_m"][0], lux.shape[0] + 1)
    v_c = 0.5 * (v_m[1:] + v_m[:-1])
    assert rows[v_c < 0].sum() > 0.999 * rows.sum()       # below the horizon


def test_type_a_far_field_written_and_read(tmp_path):
    h = np.linspace(-45, 45, 31)
    v = np.linspace(-15, 15, 21)
    g = HVGrid(h, v, beam_a(h, v), "A", metadata={"luminaire": "test lamp"})
    n = 300_000
    rng = np.random.default_rng(9)
    d, _ = sample_directions(g, rng.random(n), rng.random(n))
    phi = g.total_flux()
    ff = farfield_from_photons(d, np.full(n, phi / n), n, dc_deg=1.0, dgamma_deg=1.0,
                               photometric_type="A")
    assert ff.shape == (181, 181) and ff.total_flux() == pytest.approx(phi, rel=1e-12)
    p = write_ies(tmp_path / "ff.ies", ff)
    text = p.read_bytes().decode("ascii")
    assert "\r\n1 -1 1 181 181 3 2 " in text                    # photometric type 3
    back = read_ies(p)
    assert back.photometric_type == "A"
    assert back.total_flux() == pytest.approx(phi, rel=1e-5)
    # a node estimates the file's intensity averaged with its bilinear "hat" (±1°): check
    # the bright nodes against that average by quadrature (statistical error ≈ 1 %)
    x = np.linspace(-1, 1, 201)
    X, Y = np.meshgrid(x, x, indexing="ij")
    for h0, v0 in ((2.0, -2.0), (3.0, -1.0), (-4.0, -2.0)):
        w = (1 - abs(X)) * (1 - abs(Y)) * np.cos(np.radians(v0 + Y))
        hat = np.sum(w * g.intensity(h0 + X, v0 + Y)) / np.sum(w)
        assert back.intensity(h0, v0) == pytest.approx(hat, rel=0.04)
    assert back.intensity(-30.0, 10.0) < 0.01 * g.max_candela()
    photompy = pytest.importorskip("photompy")     # a maintained reader parses our Type A
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        phot = photompy.IESFile.read(text).photometry
    assert int(phot.photometric_type) == 3
    assert np.allclose(phot.phis, back.h_deg) and np.allclose(phot.thetas, back.v_deg)
    assert np.allclose(phot.values, back.candela)


@pytest.mark.parametrize("text, fragment", [
    ("1 -1 1 2 1 3 2 0 0 0\n1 1 0\n-10 10\n0\n1 2\n", "two horizontal angles"),
    ("1 -1 1 2 2 3 2 0 0 0\n1 1 0\n-10 100\n-5 5\n1 2 3 4\n", "must lie in"),
    ("1 -1 1 2 2 3 2 0 0 0\n1 1 0\n-10 10\n5 -5\n1 2 3 4\n", "increase strictly"),
    ("1 -1 1 2 2 4 2 0 0 0\n1 1 0\n-10 10\n-5 5\n1 2 3 4\n", "photometric type"),
])
def test_type_ab_layout_errors(tmp_path, text, fragment):
    p = tmp_path / "bad.ies"
    p.write_text("IESNA:LM-63-2002\nTILT=NONE\n" + text)
    with pytest.raises(InputError, match=fragment):
        read_ies(p)
