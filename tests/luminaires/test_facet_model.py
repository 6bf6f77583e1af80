"""Footprint model of the design optimiser (``lightsim design --optimiser model``)."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import shift as nd_shift

from lightsim.errors import InputError
from lightsim.luminaires.design import DesignSettings, design_lowbeam
from lightsim.luminaires.design_lamp import (
    Layout,
    facets_for,
    hole_diameter,
    read_design,
    simulate_lamp,
    start_vector,
    write_design,
)
from lightsim.luminaires.facet_model import (
    add_shifted,
    measure_footprints,
    model_terms,
    optimise_shifts,
)

LAYOUT = Layout(rings=1, sectors=4)
RES = (60, 96)
TINY = dict(regulation="r112-b-passing", rings=1, sectors=4, photons=20_000,
            resolution=(80, 32), seed=2, validate_factor=0, optimiser="model",
            model_photons=30_000, model_resolution=(40, 64), sign_share=0.0, foreground=0.0,
            ring_offsets=(0.0,), aim_photons=0, linearity_photons=0)
"""A model design of LAYOUT, small and fast (the ring offset given: no calibration)."""


def test_bilinear_shift_matches_scipy_inside_the_image():
    g = np.random.default_rng(3)
    img = g.random((40, 50))
    for dr, dc in [(0.3, -1.7), (-2.5, 3.2), (0.0, 0.0), (5.9, -0.01), (-60.0, 0.5)]:
        out = np.zeros_like(img)
        add_shifted(out, img, dr, dc)
        ref = nd_shift(img, (dr, dc), order=1, mode="constant", cval=0.0, prefilter=False)
        np.testing.assert_allclose(out[7:-7, 7:-7], ref[7:-7, 7:-7], atol=1e-12)


def test_facet_shifts_move_exactly_the_named_facets():
    hole = hole_diameter(LAYOUT)
    x = start_vector(LAYOUT)
    a = facets_for(x, LAYOUT, hole)
    b = facets_for(x, replace(LAYOUT, facet_shifts_deg=((1, 0.7, -0.3),)), hole)
    assert b[1].h_deg == pytest.approx(a[1].h_deg + 0.7)
    assert b[1].v_deg == pytest.approx(a[1].v_deg - 0.3)
    assert [f for k, f in enumerate(b) if k != 1] == [f for k, f in enumerate(a) if k != 1]
    with pytest.raises(InputError):
        facets_for(x, replace(LAYOUT, facet_shifts_deg=((9, 0.0, 0.0),)), hole)
    with pytest.raises(InputError):
        facets_for(x, replace(LAYOUT, facet_shifts_deg=((0, float("nan"), 0.0),)), hole)


def _simulated(layout) -> np.ndarray:
    """The lamp of ``layout`` at the start vector, simulated as the model's footprints
    were (same photons, wall and seed), lx with NaN as 0."""
    with tempfile.TemporaryDirectory() as tmp:
        glb = Path(tmp) / "lamp.glb"
        write_design(glb, start_vector(LAYOUT), layout)
        _reg, lux, _fr = simulate_lamp(glb, "r112-b-passing", photons=150_000,
                                       resolution=RES, seed=4, aim=False)
    return np.nan_to_num(lux)


@pytest.fixture(scope="module")
def model():
    return measure_footprints(start_vector(LAYOUT), LAYOUT, "r112-b-passing",
                              photons=150_000, resolution=RES, seed=4)


def test_zero_shift_model_is_the_simulated_lamp(model):
    """Base + Σ footprints at zero shift is the whole lamp's simulated map (same seed)."""
    assert model.facets and model.footprints.shape[0] == len(model.facets)
    lux = _simulated(LAYOUT)
    pred = model.lux(np.zeros((len(model.facets), 2)))
    # kNN is not additive where two footprints overlap: a few per cent in total
    assert abs(pred.sum() / lux.sum() - 1) < 0.05
    assert np.abs(pred - lux).sum() / lux.sum() < 0.25


def test_model_predicts_a_shifted_facet_as_the_simulator_sees_it(model):
    k = model.facets[0]
    shifts = np.zeros((len(model.facets), 2))
    shifts[0] = (1.5, 0.8)
    lay = replace(LAYOUT, facet_shifts_deg=((k, 1.5, 0.8),))
    lux = _simulated(lay)
    moved = model.lux(shifts)
    still = model.lux(np.zeros_like(shifts))
    # the shifted model is closer to the simulated shifted lamp than the unshifted one
    err_moved = np.abs(moved - lux).sum()
    err_still = np.abs(still - lux).sum()
    assert err_moved < 0.7 * err_still


def test_model_optimiser_is_deterministic_and_does_not_get_worse(model):
    kw = dict(safety=0.1, reach_m=25.0, smooth_max=2.0, evaluations=60)
    a = optimise_shifts(model, ("r112-b-passing",), "right", **kw)
    b = optimise_shifts(model, ("r112-b-passing",), "right", **kw)
    np.testing.assert_array_equal(a.shifts_deg, b.shifts_deg)
    assert a.objective == b.objective <= a.start_objective
    terms = model_terms(model, a.shifts_deg, ("r112-b-passing", "r149-b-passing"), "right",
                        safety=0.1, reach_m=25.0, smooth_max=2.0)
    names = {t.name for t in terms}
    assert {"75R", "III", "IV (r149-b-passing)", "shift size"} <= names
    assert "smoothness" not in names  # noise-set on the model map: checked on the lamp


def test_reach_weight_scales_only_the_reach_term(model):
    z = np.zeros((len(model.facets), 2))
    kw = dict(safety=0.1, reach_m=500.0, smooth_max=2.0)  # 500 m: the term is short
    one, three = (model_terms(model, z, ("r112-b-passing",), "right", reach_weight=w, **kw)
                  for w in (1.0, 3.0))
    r1, r3 = ({t.name: t.penalty for t in terms} for terms in (one, three))
    assert r1["reach 1 lx"] > 0 and r3["reach 1 lx"] == pytest.approx(3 * r1["reach 1 lx"])
    assert {k: v for k, v in r1.items() if k != "reach 1 lx"} == \
        {k: v for k, v in r3.items() if k != "reach 1 lx"}
    with pytest.raises(InputError, match="--reach-weight"):
        DesignSettings(**{**TINY, "reach_weight": -1.0})


def test_design_with_the_model_optimiser_writes_the_shifts(tmp_path):
    out = design_lowbeam(DesignSettings(**{**TINY, "model_evaluations": 30,
                                            "regulation": "r112-b-passing,r149-b-passing"}))
    m = out.model[0]
    assert len(out.model) == 1 and m["evaluations"] >= 1
    assert m["objective"] <= m["start_objective"]
    # the round's shifts are kept (possibly halved) only if the re-simulated lamp is better
    # than the round's start; otherwise the lamp stays as it was
    assert m["remeasured"] and m["remeasured"][0]["step"] == 1.0
    moved = {k for k, _dh, _dv in out.layout.facet_shifts_deg}
    if m["accepted_step"] > 0:
        kept = next(t for t in m["remeasured"] if t["step"] == m["accepted_step"])
        assert kept["objective"] < m["start_objective"] and out.objective == kept["objective"]
        assert moved and moved <= set(range(LAYOUT.rings * LAYOUT.sectors))
    else:
        assert all(t["objective"] >= m["start_objective"] for t in m["remeasured"])
        assert not moved
    with pytest.raises(InputError, match="--optimiser"):
        DesignSettings(**{**TINY, "optimiser": "annealing"})


@pytest.mark.parametrize("aim_rounds", [True, False])
def test_aim_rounds_off_aims_only_at_the_end(aim_rounds):
    out = design_lowbeam(DesignSettings(**{**TINY, "model_evaluations": 20,
                                            "aim_photons": 40_000, "aim_resolution": (80, 32),
                                            "aim_rounds": aim_rounds}))
    rounds = [m for m in out.model if m["round"] != "aim"]
    finals = [m for m in out.model if m["round"] == "aim"]
    assert len(rounds) == 1 and 1 <= len(finals) <= 2
    # the round's own aim step happens only with aim_rounds; the final ones always
    assert (rounds[0]["aim_step_deg"] is not None) == aim_rounds
    assert all(np.isfinite(m["aim_step_deg"]) for m in finals)


def test_linearity_step_runs_in_the_design_and_its_record_is_written(tmp_path):
    out = design_lowbeam(DesignSettings(**{**TINY, "model_evaluations": 20,
                                            "aim_photons": 40_000, "aim_resolution": (80, 32),
                                            "aim_rounds": False,
                                            "linearity_photons": 40_000}))
    lin = [m for m in out.model if m["round"] == "linearity"]
    assert len(lin) == 1
    assert lin[0]["spread_before_deg"] is None or np.isfinite(lin[0]["spread_before_deg"])
    # the record (NaN-free: a GLB's extras take none) goes into the written lamp
    write_design(tmp_path / "lin.glb", out.x, out.layout, {"model": out.model})
    assert (tmp_path / "lin.glb").stat().st_size > 0


def test_design_record_round_trips_through_the_glb(tmp_path):
    lay = replace(LAYOUT, ring_offsets_deg=(-0.3,), facet_shifts_deg=((2, 0.25, -0.5),))
    x = start_vector(lay)
    write_design(tmp_path / "a.glb", x, lay, {"model": [{"round": 0}]})
    x2, lay2, rec = read_design(tmp_path / "a.glb")
    np.testing.assert_array_equal(x2, x)
    assert lay2 == lay and rec["model"] == [{"round": 0}]
    (tmp_path / "b.glb").write_bytes(b"glTF\x02\x00\x00\x00garbage")
    for bad in (tmp_path / "b.glb", tmp_path / "missing.glb"):
        with pytest.raises(InputError):
            read_design(bad)
