"""Candela grids, far fields from photons, IES/LDT round trips, the shipped IES file, sampling."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.luminaires.photometric import (
    SAMPLE_IES,
    CandelaGrid,
    angles_from_directions,
    direction_from_hv,
    directions_from_angles,
    farfield_from_photons,
    hv_from_directions,
    read_ies,
    read_ldt,
    read_photometric,
    sample_directions,
    uniform_axes,
    write_ies,
    write_ldt,
    write_photometric,
)

REL_ROUNDING = 2e-6  # 7 significant digits written


def headlamp_grid(lumens: float | None = 1500.0) -> CandelaGrid:
    """An asymmetric, beam-like distribution on a 5° × 2.5° Type C grid."""
    c, g = uniform_axes(5.0, 2.5)
    C, G = np.meshgrid(c, g, indexing="ij")
    cs = np.where(C > 180, C - 360, C)  # signed C: + towards the driver's left
    beam = 20000 * np.exp(-((G - 92) / 3) ** 2) * np.exp(-((cs + 5) / 20) ** 2)
    return CandelaGrid(c, g, beam + 40 + 10 * np.cos(np.radians(G)) ** 2,
                       lamp_lumens=lumens, metadata={"luminaire": "test lamp",
                                                     "manufacturer": "lightsim tests"})


# ---- axes ------------------------------------------------------------------------------
def test_axes_convention():
    ahead = directions_from_angles(0.0, 90.0)
    assert np.allclose(ahead, [0, 0, 1])                      # C=0, γ=90: straight ahead
    assert np.allclose(directions_from_angles(0.0, 0.0), [0, -1, 0])     # nadir
    assert np.allclose(directions_from_angles(90.0, 90.0), [1, 0, 0])    # +X: driver's left
    assert np.allclose(directions_from_angles(270.0, 90.0), [-1, 0, 0])  # -X: right (H > 0)
    assert np.allclose(direction_from_hv(10.0, 0.0), directions_from_angles(350.0, 90.0))
    d = direction_from_hv(np.array([3.0, -7.0]), np.array([-1.0, 2.0]))
    h, v = hv_from_directions(d)
    assert np.allclose(h, [3, -7]) and np.allclose(v, [-1, 2])
    c, g = angles_from_directions(directions_from_angles([0, 45, 300], [10, 90, 170]))
    assert np.allclose(c, [0, 45, 300]) and np.allclose(g, [10, 90, 170])


def test_grid_validation():
    with pytest.raises(InputError, match="shape"):
        CandelaGrid([0.0], [0.0, 90.0], np.ones((2, 2)))
    with pytest.raises(InputError, match="increase"):
        CandelaGrid([0.0, 0.0], [0.0, 90.0], np.ones((2, 2)))
    with pytest.raises(InputError, match="≥ 0"):
        CandelaGrid([0.0], [0.0, 90.0], -np.ones((1, 2)))


def test_isotropic_flux_and_interpolation():
    c, g = uniform_axes(10.0, 5.0)
    grid = CandelaGrid(c, g, np.full((len(c), len(g)), 100.0))
    assert grid.total_flux() == pytest.approx(400 * np.pi, rel=1e-12)  # 4π · 100 cd
    assert grid.solid_angles().sum() == pytest.approx(4 * np.pi, rel=1e-12)
    assert grid.downward_flux_fraction() == pytest.approx(0.5, rel=1e-12)
    lin = CandelaGrid(c, g, np.tile(g, (len(c), 1)))  # I = γ (cd): bilinear is exact
    assert lin.intensity(123.0, 47.5) == pytest.approx(47.5)
    assert lin.intensity(359.0, 47.5) == pytest.approx(47.5)  # across the C wrap
    axial = CandelaGrid([0.0], [0.0, 90.0], [[10.0, 0.0]])    # downlight: zero above 90°
    assert axial.intensity(77.0, 45.0) == pytest.approx(5.0)
    assert axial.intensity(77.0, 120.0) == 0.0
    # flux of the interpolant I = 10·(1 − γ/90°): 2π·10·∫(1 − 2θ/π) sin θ dθ = 20π − 40
    assert axial.total_flux() == pytest.approx(20 * np.pi - 40, rel=1e-13)
    assert axial.node_solid_angles().sum() == pytest.approx(2 * np.pi, rel=1e-13)


# ---- far field ---------------------------------------------------------------------------
def test_farfield_isotropic_and_conserves_flux():
    rng = np.random.default_rng(1)
    n = 400_000
    d = rng.normal(size=(n, 3))
    phi = 1000.0
    grid, err = farfield_from_photons(d, np.full(n, phi / n), n, dc_deg=10.0,
                                      dgamma_deg=10.0, return_error=True)
    assert grid.total_flux() == pytest.approx(phi, rel=1e-12)   # lumens conserved
    expected = phi / (4 * np.pi)                                 # 79.58 cd everywhere
    z = (grid.candela - expected) / err
    assert np.all(np.abs(z) < 5)
    # the error estimate matches the actual scatter: z-scores have unit variance
    assert np.mean(z[:, 1:-1] ** 2) == pytest.approx(1.0, abs=0.15)
    rings = grid.candela[:, 3:16].mean(axis=0)                   # 36 cells per ring: ±2 %
    assert np.allclose(rings, expected, rtol=0.02)
    assert np.ptp(grid.candela[:, 0]) == 0  # one value at the nadir for every C-plane


def test_farfield_escaped_subset_and_direction():
    # 1000 photons emitted, 10 escape straight ahead carrying 2 lm each
    d = np.tile([0.0, 0.0, 1.0], (10, 1))
    grid = farfield_from_photons(d, np.full(10, 2.0), 1000, dc_deg=2.0, dgamma_deg=2.0)
    assert grid.total_flux() == pytest.approx(20.0)
    j, i = np.unravel_index(np.argmax(grid.candela), grid.shape)
    assert (grid.c_deg[j], grid.gamma_deg[i]) == (0.0, 90.0)
    assert grid.metadata["photons_emitted"] == "1000"
    with pytest.raises(InputError, match="n_emitted"):
        farfield_from_photons(d, np.ones(10), 5)
    with pytest.raises(InputError, match="0 to 180"):
        farfield_from_photons(d, np.ones(10), 10, gamma_deg=[0.0, 90.0])


# ---- file formats ------------------------------------------------------------------------
@pytest.mark.parametrize("lumens", [1500.0, None])
def test_ies_round_trip(tmp_path, lumens):
    grid = headlamp_grid(lumens)
    p = write_ies(tmp_path / "lamp.ies", grid)
    text = p.read_bytes().decode("ascii")
    assert text.startswith("IESNA:LM-63-2002\r\n") and "TILT=NONE" in text
    assert max(len(line) for line in text.split("\r\n")) <= 256
    back = read_ies(p)
    assert np.allclose(back.candela, grid.candela, rtol=REL_ROUNDING, atol=0)
    assert np.array_equal(back.c_deg, grid.c_deg)
    assert np.array_equal(back.gamma_deg, grid.gamma_deg)
    assert back.lamp_lumens == lumens
    assert back.metadata["luminaire"] == "test lamp"
    assert back.total_flux() == pytest.approx(grid.total_flux(), rel=REL_ROUNDING)


def test_ies_cross_read_by_photompy(tmp_path):
    photompy = pytest.importorskip("photompy")
    grid = headlamp_grid()
    p = write_ies(tmp_path / "lamp.ies", grid)
    ies = photompy.IESFile.read(str(p))
    phot = ies.photometry
    assert np.allclose(phot.thetas, grid.gamma_deg)
    assert np.allclose(phot.phis[:-1], grid.c_deg) and phot.phis[-1] == 360.0
    assert np.allclose(phot.values[:-1], grid.candela, rtol=REL_ROUNDING)
    assert phot.total_optical_power() == pytest.approx(grid.total_flux(), rel=1e-4)


def test_ldt_round_trip_and_cross_read(tmp_path):
    grid = headlamp_grid(1500.0)
    p = write_ldt(tmp_path / "lamp.ldt", grid)
    back = read_ldt(p)
    assert np.allclose(back.candela, grid.candela, rtol=REL_ROUNDING, atol=0)
    assert np.array_equal(back.c_deg, grid.c_deg) and back.lamp_lumens == 1500.0
    assert float(back.metadata["lorl_percent"]) == pytest.approx(
        100 * grid.total_flux() / 1500.0, rel=1e-6)
    assert float(back.metadata["dff_percent"]) == pytest.approx(
        100 * grid.downward_flux_fraction(), rel=1e-6)
    pyldt = pytest.importorskip("pyldt")
    ldt = pyldt.LdtReader.read(p)
    assert ldt.header.mc == grid.shape[0] and ldt.header.ng == grid.shape[1]
    assert ldt.header.lamp_flux == [1500.0]
    cd = np.asarray(ldt.intensities) * 1500.0 / 1000.0   # cd/klm -> cd
    assert np.allclose(cd, grid.candela, rtol=REL_ROUNDING)
    photompy = pytest.importorskip("photompy")
    lf = photompy.LDTFile.read(str(p))
    assert np.allclose(lf.photometry.values, grid.candela, rtol=REL_ROUNDING)


def test_ldt_absolute_photometry_and_axial(tmp_path):
    grid = headlamp_grid(None)
    back = read_ldt(write_ldt(tmp_path / "abs.ldt", grid))
    assert back.lamp_lumens == pytest.approx(grid.total_flux(), rel=1e-6)
    assert np.allclose(back.candela, grid.candela, rtol=REL_ROUNDING)
    axial = CandelaGrid([0.0], [0.0, 30.0, 60.0, 90.0], [[1000.0, 800.0, 300.0, 0.0]], 500.0)
    back = read_photometric(write_photometric(tmp_path / "axial.ldt", axial))
    assert back.shape == (1, 4) and np.allclose(back.candela, axial.candela)
    back = read_photometric(write_photometric(tmp_path / "axial.ies", axial))
    assert back.shape == (1, 4) and np.allclose(back.candela, axial.candela)


def test_ldt_symmetry_expansion(tmp_path):
    # Isym 2 (symmetric about C0-C180), Mc = 4 (0, 90, 180, 270), Ng = 3, 1000 lm lamp
    lines = ["co", "3", "2", "4", "90", "3", "45", "r", "lum", "n", "f", "d"] + ["0"] * 9
    lines += ["50", "100", "1", "0", "1", "1", "LED", "1000", "", "", "10"] + ["0"] * 10
    lines += ["0", "90", "180", "270", "0", "45", "90"]
    lines += ["100", "50", "10", "200", "60", "20", "300", "70", "30"]  # C0, C90, C180
    p = tmp_path / "sym.ldt"
    p.write_text("\n".join(lines) + "\n", encoding="latin-1")
    g = read_ldt(p)
    assert np.array_equal(g.c_deg, [0, 90, 180, 270])
    assert np.allclose(g.candela[3], g.candela[1])            # C270 mirrors C90
    assert np.allclose(g.candela[2], [300, 70, 30])


def test_ies_symmetry_expansion_and_multiplier(tmp_path):
    text = ("IESNA:LM-63-2002\n[TEST] q\nTILT=NONE\n1 1000 2 3 3 1 2 0 0 0\n1.5 1 10\n"
            "0, 45, 90\n0 45 90\n10 20 30\n40 50 60\n70 80 90\n")
    p = tmp_path / "quad.ies"
    p.write_text(text)
    g = read_ies(p)      # quadrant symmetric: planes 0..315 every 45°
    assert np.array_equal(g.c_deg, np.arange(0, 360, 45))
    assert np.allclose(g.candela[0], [30, 60, 90])            # × multiplier 2 × ballast 1.5
    assert np.allclose(g.candela[3], g.candela[1])            # C135 mirrors C45
    assert np.allclose(g.candela[6], g.candela[2])            # C270 mirrors C90
    assert g.lamp_lumens == 1000.0


@pytest.mark.parametrize("text, fragment", [
    ("IESNA:LM-63-2002\nTILT=NONE\n1 1000 1 3 1 2 2 0 0 0\n1 1 0\n0 45 90\n0\n1 2 3\n",
     "two horizontal angles"),  # Type B with one horizontal angle: no LM-63 layout
    ("IESNA:LM-63-2002\nTILT=NONE\n1 1000 1 3 1 1 2 0 0 0\n1 1 0\n0 45 90\n0\n1 2\n",
     "need 7 numbers"),
    ("IESNA:LM-63-2002\nTILT=NONE\n1 1000 1 3 1 1 2 0 0 0\n1 1 0\n0 45 x\n0\n1 2 3\n",
     "'x'"),
    ("IESNA:LM-63-2002\n[TEST] no tilt\n", "no TILT"),
])
def test_ies_errors(tmp_path, text, fragment):
    p = tmp_path / "bad.ies"
    p.write_text(text)
    with pytest.raises(InputError) as exc:
        read_ies(p)
    assert fragment in str(exc.value)


# ---- the published file ------------------------------------------------------------------
def test_published_ies_file_known_total():
    g = read_ies(SAMPLE_IES)
    assert g.shape == (1, 361) and g.lamp_lumens is None    # absolute photometry (-1)
    assert g.metadata["manufac"] == "Interlight"
    assert "5300LM" in g.metadata["luminaire"]
    assert g.metadata["candela_multiplier"] == "0.4597"
    assert g.candela[0, 0] == pytest.approx(4170.2998 * 0.4597)
    # the manufacturer states 5 300 lm; integrating the table gives 5 300.8 lm
    assert g.total_flux() == pytest.approx(5300.0, rel=0.002)
    assert g.max_candela() == pytest.approx(1917.087, rel=1e-6)


def test_published_ies_file_cross_read():
    photompy = pytest.importorskip("photompy")
    text = SAMPLE_IES.read_bytes().decode("latin-1")  # photompy reads UTF-8 files only
    ies = photompy.IESFile.read(text)
    ours = read_ies(SAMPLE_IES)
    assert np.allclose(ies.photometry.values[0], ours.candela[0])
    # photompy integrates with the midpoint-cell rule; ours is the bilinear interpolant's
    # exact integral: the same rule agrees to 1e-6, the two rules within 1e-5 at 0.5° steps
    assert ies.photometry.total_optical_power() == pytest.approx(ours.cell_flux(), rel=1e-6)
    assert ies.photometry.total_optical_power() == pytest.approx(ours.total_flux(), rel=1e-5)


# ---- sampling ----------------------------------------------------------------------------
def test_sampled_directions_reproduce_the_grid():
    grid = headlamp_grid()
    n = 300_000
    rng = np.random.default_rng(7)
    dirs, pdf = sample_directions(grid, rng.random(n), rng.random(n))
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
    phi = grid.total_flux()
    ff = farfield_from_photons(dirs, np.full(n, phi / n), n, c_deg=grid.c_deg,
                               gamma_deg=grid.gamma_deg)
    assert ff.total_flux() == pytest.approx(phi, rel=1e-12)   # total flux = the file's
    # pdf = the interpolated intensity towards each direction / Φ
    assert np.allclose(pdf * phi, grid.intensity_towards(dirs), rtol=1e-9, atol=1e-9)


def test_sampling_published_file_band_fluxes():
    grid = read_ies(SAMPLE_IES)                     # axial, 0.5° steps
    n = 200_000
    rng = np.random.default_rng(3)
    dirs, pdf = sample_directions(grid, rng.random(n), rng.random(n))
    phi = grid.total_flux()
    assert phi == pytest.approx(5300.8, rel=1e-4)
    _, g = angles_from_directions(dirs)
    # exact flux of the interpolant in 5° γ bands (band edges are file nodes)
    cells = grid.table.cell_flux_matrix()[0]        # one φ cell (axial), 360 γ cells
    p_band = cells.reshape(36, 10).sum(axis=1) / phi
    assert p_band.sum() == pytest.approx(1.0, rel=1e-12)
    counts = np.histogram(g, bins=np.arange(0.0, 180.1, 5.0))[0]
    sigma = np.sqrt(n * p_band * (1 - p_band)) + 1e-9
    assert np.all(np.abs(counts - n * p_band) < 5 * sigma)
    assert np.all(pdf > 0)
    with pytest.raises(InputError):
        sample_directions(grid, [0.5], [1.5])


def test_wall_lux_of_a_grid():
    c, g = uniform_axes(5.0, 5.0)
    grid = CandelaGrid(c, g, np.full((len(c), len(g)), 625.0))
    frame = {"distance_m": 25.0, "h_range_m": [-1.0, 1.0], "v_range_m": [-1.0, 1.0],
             "resolution": [2, 2]}
    lux = grid.wall_lux(frame)
    # 625 cd at (±0.5, ±0.5) m: E = 625·25 / (625.5)^1.5
    assert np.allclose(lux, 625 * 25 / 625.5**1.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert grid.summary()["total_flux_lm"] == pytest.approx(625 * 4 * np.pi)
