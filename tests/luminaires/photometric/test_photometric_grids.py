"""Far-field files that keep the beam: histopolated bins, auto angle lists, the deposit on
a file's angles, step options and the format limits (EULUMDAT's 721 × 361)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.luminaires.analyses import for_options
from lightsim.luminaires.photometric import CandelaGrid, read_photometric, write_photometric
from lightsim.luminaires.photometric.gridding import (
    LDT_MAX_GAMMA,
    LDT_MAX_PLANES,
    auto_axes,
    check_step,
    regrid,
    select_nodes,
    step_axes,
)
from lightsim.luminaires.photometric.reproduce import (
    aperture_means,
    position_text,
    reproduction,
)
from lightsim.luminaires.photometric.runfield import RunField, bin_averages, histopolate
from lightsim.simulate import SimulateOptions
from lightsim.wall import WallFrame


def cutoff_field(c_step: float = 0.25, g_step: float = 0.05) -> RunField:
    """A low-beam-like field: a hot spot below a cut-off that rises within 0.2°."""
    c = np.arange(0.0, 360.0, c_step)
    g = np.unique(np.round(np.concatenate([np.arange(0.0, 180.0001, 1.0),
                                           np.arange(85.0, 95.0001, g_step)]), 6))
    cc, gg = np.meshgrid(c, g, indexing="ij")
    h = -np.where(cc > 180, cc - 360, cc)
    v = gg - 90.0
    edge = 0.5 * (1.0 - np.tanh((v + 0.57) / 0.08))  # 0.2° from 90 % to 10 %
    beam = 40000.0 * np.exp(-((h - 2.0) / 6.0) ** 2 - ((v + 1.5) / 1.2) ** 2) * edge
    cd = beam + 20.0 * (np.abs(h) < 90)
    return RunField(CandelaGrid(c, g, cd), np.zeros(cd.shape, np.int8), None, 1.0)


def test_histopolated_nodes_give_the_bins_back():
    rng = np.random.default_rng(1)
    means = 1000.0 + 200.0 * rng.standard_normal((30, 40))
    means[10:, :] *= 0.01                                  # a cut-off between two rows
    nodes = histopolate(means)
    assert nodes.shape == (61, 81) and nodes.min() >= 0
    assert np.allclose(bin_averages(nodes), means, rtol=1e-12)
    # smooth data give a smooth surface: a plane's nodes are the plane
    x, y = np.meshgrid(np.arange(30.0), np.arange(40.0), indexing="ij")
    plane = histopolate(500.0 + 3.0 * x + 2.0 * y)
    xx, yy = np.meshgrid(np.arange(61) / 2 - 0.5, np.arange(81) / 2 - 0.5, indexing="ij")
    inner = (slice(2, -2), slice(2, -2))
    assert np.allclose(plane[inner], (500.0 + 3.0 * xx + 2.0 * yy)[inner])
    # an isolated photon stays in its own bin, with its flux
    lone = np.zeros((9, 9))
    lone[4, 4] = 150.0
    kept = histopolate(lone)
    assert np.allclose(bin_averages(kept), lone) and kept[:7, :].sum() == 0
    assert np.count_nonzero(kept) == 1


def test_select_nodes_refines_the_cut_off_only():
    v = np.linspace(-10.0, 10.0, 2001)                     # 0.01° candidates
    profile = 0.5 * (1.0 - np.tanh((v + 0.57) / 0.08))     # a cut-off at 0.57° D
    values = np.vstack([profile, 0.5 * profile]) * 1e4 + 10.0
    tol = np.maximum(0.01 * values, 1.0)
    keep, left = select_nodes(v, values, tol, np.isin(v, (-10.0, 10.0)), budget=500,
                              max_gap=5.0)
    assert left <= 1.0
    kv = v[keep]
    assert kv[0] == -10.0 and kv[-1] == 10.0 and np.diff(kv).max() <= 5.0 + 1e-9
    near = np.abs(kv + 0.57) < 0.3
    assert near.sum() >= 10 and (~near).sum() <= 12   # dense at the edge, sparse elsewhere
    line = np.interp(v, kv, values[0][keep])
    assert np.all(np.abs(line - values[0]) <= tol[0] * (1 + 1e-9))
    few, left = select_nodes(v, values, tol, np.isin(v, (-10.0, 10.0)), budget=8,
                             max_gap=5.0)
    assert len(few) == 8 and left > 1.0


def test_auto_axes_keep_the_beam_within_eulumdat_limits(tmp_path):
    field = cutoff_field()
    c, g, converged = auto_axes(field, "C", (LDT_MAX_PLANES, LDT_MAX_GAMMA))
    assert converged
    assert len(c) <= LDT_MAX_PLANES and len(g) <= LDT_MAX_GAMMA
    assert {0.0, 90.0, 180.0, 270.0} <= set(np.round(c, 9)) and g[0] == 0 and g[-1] == 180
    assert np.diff(g).min() < 0.1 < 2.0 < np.diff(g).max()   # uneven: fine at the cut-off
    grid = regrid(field, "C", c, g, lamp_lumens=1000.0, sample=True)
    assert grid.total_flux() == pytest.approx(field.grid.total_flux(), rel=1e-9)
    probe_h, probe_v = np.meshgrid([-3.0, 0.0, 2.0, 6.0], [-2.0, -0.8, -0.57, -0.4, 1.0])
    want = field.grid.intensity_hv(probe_h, probe_v)
    got = grid.intensity_hv(probe_h, probe_v)
    assert np.all(np.abs(got - want) <= 0.03 * want + 0.001 * want.max())
    # EULUMDAT without symmetry, uneven C and γ: Dc = Dg = 0; other readers agree
    path = write_photometric(tmp_path / "beam.ldt", grid)
    back = read_photometric(path)
    assert back.metadata["dc_deg"] == "0" and back.metadata["dg_deg"] == "0"
    assert np.allclose(back.candela, grid.candela, rtol=1e-6)
    pyldt = pytest.importorskip("pyldt")
    ldt = pyldt.LdtReader.read(path)
    assert (ldt.header.mc, ldt.header.ng) == grid.shape and ldt.header.dc == 0.0
    assert np.allclose(np.asarray(ldt.intensities) * 1000.0 / 1000.0, grid.candela, rtol=1e-6)
    photompy = pytest.importorskip("photompy")
    assert np.allclose(photompy.LDTFile.read(str(path)).photometry.values, grid.candela,
                       rtol=1e-6)


def test_type_a_auto_file_and_its_outside_flux(tmp_path):
    field = cutoff_field()
    h, v, _ = auto_axes(field, "A", (1441, 721))
    assert h[0] == -90.0 and h[-1] == 90.0 and v[0] == -90.0 and v[-1] == 90.0
    grid = regrid(field, "A", h, v, lamp_lumens=1000.0, metadata={"luminaire": "beam"},
                  sample=True)
    outside = float(grid.metadata["flux_outside_lm"])
    assert grid.total_flux() + outside == pytest.approx(field.grid.total_flux(), rel=1e-9)
    assert outside == pytest.approx(0.0, abs=1e-9)      # nothing behind this lamp
    assert "photons_escaped" not in grid.metadata        # the deposit's own count is dropped
    path = write_photometric(tmp_path / "beam.ies", grid)
    photompy = pytest.importorskip("photompy")
    phot = photompy.IESFile.read(str(path)).photometry
    assert np.allclose(phot.values, grid.candela, rtol=1e-6)
    assert np.allclose(phot.thetas, v) and np.allclose(phot.phis, h)


def test_equal_steps_and_their_checks():
    h, v = step_axes("A", 0.5)
    assert len(h) == len(v) == 361 and h[0] == -90.0
    c, g = step_axes("C", 0.5)
    assert len(c) == 720 <= LDT_MAX_PLANES and len(g) == 361 <= LDT_MAX_GAMMA
    check_step(0.25, "ies", "--ies-step")
    with pytest.raises(InputError, match="--ldt-step must divide 90° into equal steps"):
        check_step(0.7, "ldt", "--ldt-step")
    with pytest.raises(InputError, match="--ies-step"):
        check_step(7.0, "ies", "--ies-step")
    # checked with the options, before any work, even without --ies
    base = {"scene_path": "lamp.glb"}
    with pytest.raises(InputError, match="--ies-step"):
        for_options(SimulateOptions(**base, ies_step=0.7))
    with pytest.raises(InputError, match="--ldt-step"):
        SimulateOptions(**base, ldt_step=0.2)          # below EULUMDAT's 0.5°: the range
    ff = for_options(SimulateOptions(**base, ies="a.ies", ies_step=0.25, ldt="a.ldt"))[0]
    assert (ff.ies_step, ff.ldt_step) == (0.25, None)


def test_aperture_means_of_a_constant_and_a_ramp():
    frame = WallFrame.from_any({"distance_m": 25.0, "h_range_m": [-15, 15],
                                "v_range_m": [-6, 6], "resolution": [64, 32]})
    c, g = step_axes("C", 1.0)
    cc, gg = np.meshgrid(c, g, indexing="ij")
    flat = CandelaGrid(c, g, np.full(cc.shape, 500.0))
    got = aperture_means(flat, frame, np.array([0.0, 10.0]), np.array([0.0, -3.0]), 0.15, 0.15)
    assert np.allclose(got, 500.0)
    ramp = CandelaGrid(c, g, 1000.0 + 10.0 * (gg - 90.0))
    got = aperture_means(ramp, frame, np.array([0.0]), np.array([-0.57]), 0.15, 0.15)
    assert got[0] == pytest.approx(1000.0 - 5.7, rel=1e-4)
    assert position_text(1.15, -0.57) == "0.57D 1.15R" and position_text(0, 0) == "H-V"
    assert position_text(-8.0, 0.0) == "H 8L"


def test_a_coarse_file_is_flagged_in_one_line():
    frame = WallFrame.from_any({"distance_m": 25.0, "h_range_m": [-15, 15],
                                "v_range_m": [-6, 6], "resolution": [64, 32]})
    field = cutoff_field()
    cols = np.arange(-5.0, 5.0, 0.15) + 0.075
    vs = np.arange(-4.0, 1.0, 0.15) + 0.075
    cg, vg = np.meshgrid(cols, vs, indexing="ij")
    tiles = aperture_means(field.grid, frame, cg.ravel(), vg.ravel(), 0.15, 0.15)
    tiles = tiles.reshape(cg.shape)
    rng = np.random.default_rng(2)
    per_set = tiles[None] * (1 + 0.01 * rng.standard_normal((16, *tiles.shape)))
    bins = SimpleNamespace(tiles=per_set, h_deg=cols, v_deg=vs, tile_v_deg=vs,
                           width_deg=0.15, height_deg=0.15)
    session = SimpleNamespace(scene=SimpleNamespace(wall=frame),
                              config=SimpleNamespace(apertures=(), aperture_deg=0.15))
    fine = regrid(field, "A", *auto_axes(field, "A", (1441, 721))[:2], sample=True)
    assert reproduction(fine, "fine.ies", session, bins).warning is None
    coarse = regrid(field, "A", *step_axes("A", 1.0))
    note = reproduction(coarse, "coarse.ies", session, bins, "use a finer step").warning
    assert note is not None and "\n" not in note
    assert note.startswith("coarse.ies does not reproduce the run: peak ")
    assert note.endswith("; use a finer step")
