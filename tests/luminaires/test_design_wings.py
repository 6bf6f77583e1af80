"""The design's wings (main facets re-aimed to the wide foreground beside the car), the
road view's lit extent, and the shipped lamp's regulation table (fast)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.luminaires.design import DesignSettings, design_lowbeam
from lightsim.luminaires.design_lamp import (
    WING_HALF_WIDTH_DEG,
    Layout,
    facet_images,
    facets_for,
    hole_diameter,
    read_design,
    start_vector,
    write_design,
)
from lightsim.render.road import road_illuminance_from

LAY = Layout(rings=3, sectors=16, sign_share=0.03)
WINGS = (0, 8, 14, 15, 16, 24, 32)
LOWBEAM = Path(__file__).parents[2] / "luminaires" / "examples" / "lowbeam.glb"


def test_wing_facets_put_their_image_medians_on_the_wings_and_nothing_else_moves():
    hole = hole_diameter(LAY)
    x = start_vector(LAY)
    plain = facets_for(x, LAY, hole)
    lay = replace(LAY, wing_facets=WINGS, wing_deg=16.5, wing_drop_deg=2.5)
    wide = facets_for(x, lay, hole)
    assert len(wide) == len(plain)
    moved = [k for k, (a, b) in enumerate(zip(plain, wide)) if a != b]
    # only the wing facets (a sliver cut from a wing facet keeps its own aim)
    assert moved == sorted(WINGS)
    for side in (-1, 1):
        # outer rings (small, bright images) nearest V, then by index
        ks = sorted((k for k in WINGS if (plain[k].h_deg >= 0) == (side > 0)),
                    key=lambda k: (-(k // lay.sectors), k))
        assert len(ks) >= 2
        want = side * (16.5 + WING_HALF_WIDTH_DEG * np.linspace(-1, 1, len(ks)))
        for k, th in zip(ks, want):
            img = facet_images([wide[k]], lay, hole)[0]
            assert img.dh.size > 20
            assert abs(np.median(img.dh + wide[k].h_deg) - th) < 0.2
            assert abs(np.median(img.dv + wide[k].v_deg) - (lay.cutoff_v_deg - 2.5)) < 0.2


def test_wing_options_round_trip_and_bad_ones_are_input_errors(tmp_path):
    lay = replace(LAY, wing_facets=WINGS, wing_deg=18.0, wing_drop_deg=3.0)
    write_design(tmp_path / "w.glb", start_vector(lay), lay)
    _x, back, _rec = read_design(tmp_path / "w.glb")
    assert back == lay
    for bad in (dict(wing_facets=(48,)), dict(wing_facets=(3, 3)), dict(wing_deg=math.nan),
                dict(wing_drop_deg=-1.0), dict(wing_deg=40.0)):
        with pytest.raises(InputError):
            replace(LAY, **bad).check()


def test_road_extent_of_a_uniform_lamp_is_the_circle_of_one_lux():
    # I constant: E = I·h / r³ ≥ 1 lx inside r ≤ (I·h)^(1/3), so at distance z the lit
    # stretch is |x| ≤ sqrt((I·h)^(2/3) − h² − z²)
    i_cd, h = 5000.0, 0.65
    road = road_illuminance_from(lambda hh, vv: np.full(np.shape(hh), i_cd), h,
                                 (-15.0, 15.0), (0.0, 30.0), 0.05)
    for z in (5.0, 10.0, 14.0):
        half = math.sqrt((i_cd * h) ** (2 / 3) - h * h - z * z)
        left, right = road.extent_m(z)
        assert left == pytest.approx(-half, abs=0.05) and right == pytest.approx(half, abs=0.05)
    assert road.extent_m(20.0) is None


def test_shipped_lamp_fails_no_rule(tmp_path):
    """The shipped example at 2 M photons (the README demo's wall, unaimed): no rule of
    R112 or R149 class B fails (its interval wholly beyond the limit), the bright points
    pass with their interval, and it is the lamp with wings of ``docs/guides/design.md``."""
    _x, lay, rec = read_design(LOWBEAM)
    assert rec["command"] == "lightsim design"
    assert lay.wing_facets == (0, 8, 14, 15, 16, 24) and lay.sign_share == 0.05
    r = subprocess.run([sys.executable, "-m", "lightsim.cli.main", "simulate", str(LOWBEAM),
                        "--photons", "2000000", "--resolution", "320x128", "--seed", "5",
                        "--regulation", "r112-b-passing,r149-b-passing", "--quiet",
                        "--out", str(tmp_path / "o")], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    rows = {(t["ruleset"], q["name"]): q for t in (s["regulation"],
                                                  s["regulation:r149-b-passing"])
            for q in t["results"] if q["verdict"] != "info"}
    assert len(rows) == 36
    assert not [k for k, q in rows.items() if q["verdict"] == "fail"]
    for name in ("50R", "75R", "I <= 2*I(50R)", "BR"):
        assert rows[("r149-b-passing", name)]["verdict"] == "pass", name


def test_a_design_run_with_wings_is_deterministic_for_a_seed(tmp_path):
    settings = DesignSettings(regulation="r112-b-passing", rings=1, sectors=4,
                              wing_facets=(0,), wing_deg=12.0, photons=20_000,
                              resolution=(80, 32), evaluations=2, rounds=1, seed=4,
                              validate_factor=0, optimiser="simulator", sign_share=0.0,
                              foreground=0.0)
    a = design_lowbeam(settings)
    b = design_lowbeam(settings)
    assert [h["objective"] for h in a.history] == [h["objective"] for h in b.history]
    assert a.x == b.x and a.layout == b.layout and a.layout.wing_facets == (0,)
    write_design(tmp_path / "a.glb", a.x, a.layout)
    write_design(tmp_path / "b.glb", b.x, b.layout)
    assert (tmp_path / "a.glb").read_bytes() == (tmp_path / "b.glb").read_bytes()
