"""FMVSS No. 108 verdicts with the 1/4° re-aim, against a hand-computed table for a Type A
file with known intensities; the measuring conditions refuse what does not apply."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.io.exr import write_exr
from lightsim.io.summary import write_json
from lightsim.luminaires.photometric import read_photometric
from lightsim.luminaires.photometric.hvgrid import HVGrid
from lightsim.luminaires.photometric.ies import write_ies
from lightsim.luminaires.regulations import load_ruleset
from lightsim.luminaires.regulations.conditions import wall_angles
from lightsim.luminaires.regulations.lamp_check import check_lamp, lamp_source
from lightsim.luminaires.regulations.reaim import (
    aperture_points,
    evaluate_reaim,
    reaim_offsets,
    reaim_probes,
    values_from,
)

from support import run_cli

H = np.round(np.arange(-20.0, 20.001, 0.25), 6)
V = np.round(np.arange(-10.0, 10.001, 0.25), 6)


def _table() -> np.ndarray:
    """1000 cd below the horizontal, 100 cd above it, 0 from 9.5U; 200 cd at 2U-4L/4R;
    10 000 cd at 0.5D-1.5R; 14 000 cd at 1.5D-2R with 17 000 cd a quarter degree above
    (so 15 500 cd 1/8° up: passes only re-aimed); 300 cd over the whole re-aim disc of
    1D-6L (fails even re-aimed)."""
    cd = np.where(V[None, :] < 0.25, 1000.0, 100.0) * np.ones((H.size, 1))
    cd[:, V >= 9.5] = 0.0

    def node(h: float, v: float) -> tuple[int, int]:
        return int(np.flatnonzero(np.isclose(H, h))[0]), int(np.flatnonzero(np.isclose(V, v))[0])

    for h in (-4.0, 4.0):
        cd[node(h, 2.0)] = 200.0
    cd[node(1.5, -0.5)] = 10_000.0
    cd[node(2.0, -1.5)] = 14_000.0
    cd[node(2.0, -1.25)] = 17_000.0
    for h in (-6.5, -6.25, -6.0, -5.75, -5.5):
        for v in (-1.5, -1.25, -1.0, -0.75, -0.5):
            cd[node(h, v)] = 300.0
    return cd


# the verdicts an engineer computes by hand from the table above (LB1V, right traffic)
EXPECTED = {
    "4U-8L": ("pass", 100.0), "4U-8R": ("pass", 100.0), "2U-4L": ("pass", 200.0),
    "2U-4R": ("pass", 200.0), "0.5U-1R": ("pass", 100.0), "0.5U-2R": ("pass", 100.0),
    "0.5U-3R": ("pass", 100.0), "0.5D-1.5R": ("pass", 10_000.0), "1D-6L": ("fail", 300.0),
    "1.5D-2R": ("pass", 15_500.0), "1.5D-9L": ("pass", 1000.0), "1.5D-9R": ("pass", 1000.0),
    "2D-15L": ("pass", 1000.0), "2D-15R": ("pass", 1000.0), "4D-4R": ("pass", 1000.0),
}


@pytest.fixture(scope="module")
def lamp_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("lamp") / "known.ies"
    write_ies(path, HVGrid(H, V, _table(), "A"))
    return path


def test_offsets_cover_the_disc() -> None:
    off = reaim_offsets(0.25)
    assert off.shape == (25, 2)
    r = np.hypot(off[:, 0], off[:, 1])
    assert r[0] == 0 and np.allclose(sorted(set(np.round(r, 12))), [0.0, 0.125, 0.25])


def test_goniometer_angles_to_wall_angles() -> None:
    h, v = wall_angles([30.0], [10.0], "azimuth-elevation")
    # (H, V) points along (cos V sin H, sin V, cos V cos H); its wall v is atan(y/z)
    assert h[0] == 30.0
    assert v[0] == pytest.approx(np.degrees(np.arctan(np.tan(np.radians(10)) /
                                                      np.cos(np.radians(30)))))


def test_known_lamp_matches_hand_computed_table(lamp_file: Path) -> None:
    res = check_lamp(lamp_source(lamp_file), "fmvss-lb1v-lower", beam="lower")
    rows = {r["name"]: r for r in res.results}
    for name, (verdict, value) in EXPECTED.items():
        assert rows[name]["verdict"] == verdict, name
        assert rows[name]["value_cd"] == pytest.approx(value, rel=1e-9), name
    assert rows["1.5D-2R"]["after_reaim"] is True
    assert rows["1.5D-2R"]["reaim_offset_deg"] == pytest.approx([0.0, 0.125], abs=1e-12)
    assert rows["1.5D-2R"]["reaim_direction"] == "0.125° U"
    assert not any(rows[n].get("after_reaim") for n in EXPECTED if n != "1.5D-2R")
    assert rows["1D-6L"]["reaim_direction"].startswith("none passes")
    for zone in ("10U-90U", "1U-1.5L to L", "0.5U-1.5L to L", "0.5D-1.5L to L",
                 "1.5U-1R to R"):
        assert rows[zone]["verdict"] == "pass", zone
    assert res.n_sets == 1 and res.beam == "lower"


def test_nominal_reading_is_below_the_limit(lamp_file: Path) -> None:
    """The same lamp read strictly at the aim: 1.5D-2R fails (what the re-aim changed)."""
    rs = load_ruleset("fmvss-lb1v-lower")
    grid = read_photometric(lamp_file)
    rp = reaim_probes(rs)
    rows = {r["name"]: r for r in evaluate_reaim(rs, rp, values_from(grid.intensity_hv, rp))}
    nominal = grid.intensity_hv(*wall_angles([2.0], [-1.5], "azimuth-elevation"))
    assert nominal[0] == pytest.approx(14_000.0)
    assert rows["1.5D-2R"]["verdict"] == "pass" and rows["1.5D-2R"]["after_reaim"]


def test_intervals_from_sets_and_bonferroni(lamp_file: Path) -> None:
    """Per-set values with noise: the re-aimed reading uses the stricter level."""
    rs = load_ruleset("fmvss-lb1v-lower")
    grid = read_photometric(lamp_file)
    rp = reaim_probes(rs)
    base = values_from(grid.intensity_hv, rp)[0]
    rng = np.random.default_rng(5)
    vals = base[None, :] * (1.0 + 0.01 * rng.standard_normal((8, base.size)))
    rows = {r["name"]: r for r in evaluate_reaim(rs, rp, vals)}
    r = rows["1.5D-2R"]
    assert r["verdict"] == "pass" and r["after_reaim"]
    assert r["reaim_confidence"] == pytest.approx(1 - 0.05 / 25)
    lo, hi = r["interval_cd"]
    assert lo > 15_000 and lo < r["value_cd"] < hi


def test_cli_table_json_and_bad_input(lamp_file: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "verdicts.json"
    code, text, err = run_cli(["check", str(lamp_file), "--regulation", "fmvss-lb1v-lower",
                               "--beam", "lower", "--json", str(out)], capsys)
    assert code == 0, err
    assert "after re-aim 0.125° U" in text and "1 only after re-aim" in text
    doc = json.loads(out.read_text())
    assert doc["measurement"]["reaim_deg"] == 0.25
    # an upper-beam rule set does not apply to a lower beam: one line, exit 2, no file
    out2 = tmp_path / "no.json"
    code, text, err = run_cli(["check", str(lamp_file), "--regulation", "fmvss-ub1-upper",
                               "--beam", "lower", "--json", str(out2)], capsys)
    assert code == 2 and "applies to upper beams" in err
    assert len(err.strip().splitlines()) == 1 and not out2.exists()
    code, _, err = run_cli(["check", str(lamp_file), "--regulation", "fmvss-lb1v-lower",
                            "--traffic", "left", "--beam", "lower"], capsys)
    assert code == 2 and "right-hand traffic only" in err


def test_run_wall_too_near(tmp_path: Path) -> None:
    frame = {"centre": [0.0, 0.0, 10.0], "h_axis": [-1.0, 0.0, 0.0],
             "v_axis": [0.0, 1.0, 0.0], "normal": [0.0, 0.0, -1.0],
             "h_range_m": [-6.0, 6.0], "v_range_m": [-2.5, 2.5], "distance_m": 10.0,
             "resolution": [120, 50]}
    run = tmp_path / "run"
    run.mkdir()
    write_exr(run / "wall_lux.exr", {"Y": np.full((50, 120), 50.0)})
    write_json(run / "summary.json", {"wall": frame})
    with pytest.raises(InputError, match=r"18\.3 m or more"):
        check_lamp(lamp_source(run), "fmvss-ub1-upper", beam="upper")


BASE = '''schema = "lightsim-ruleset-1"
id = "m"
title = "t"
version = "1"
source = "s"
traffic = "right"

[[point]]
name = "HV"
h = 0.0
v = 0.0
min = 1

'''


@pytest.mark.parametrize("table, text", [
    ('[measurement]\nreaim = 0.25\n', "unknown key"),
    ('[measurement]\nreaim_deg = -1\n', "reaim_deg"),
    ('[measurement]\nbeam = "dipped"\n', "beam"),
    ('[measurement]\ncertainty = "less-sure"\n', "needs a 'note'"),
    ('[measurement]\nmirror = "no"\n', "mirror"),
])
def test_measurement_table_checked(tmp_path: Path, table: str, text: str) -> None:
    path = tmp_path / "m.toml"
    path.write_text(BASE + table)
    with pytest.raises(InputError, match=text):
        load_ruleset(str(path))


def test_measurement_table_read_and_one_traffic_side() -> None:
    rs = load_ruleset("fmvss-ub1-upper")
    mc = rs.measurement
    assert (mc.reaim_deg, mc.min_distance_m, mc.aim, mc.beam, mc.mirror) == (
        0.25, 18.3, "mechanical", "upper", False)
    assert mc.certainty == "less-sure" and mc.note
    with pytest.raises(InputError, match="right-hand traffic only"):
        rs.for_traffic("left")
    assert all(g.certainty == "less-sure" and "571.108" in g.source for g in rs.geometries)


def test_screen_check_refuses_reaim_sets(tmp_path: Path, capsys) -> None:
    """``simulate --regulation`` reads fixed apertures at screen angles: it refuses a set
    measured with re-aim and goniometer angles before any work, naming ``lightsim check``."""
    out = tmp_path / "out"
    lamp = Path(__file__).resolve().parents[3] / "luminaires" / "examples" / "lowbeam.glb"
    code, _, err = run_cli(["simulate", str(lamp), "-n", "1000",
                            "--regulation", "fmvss-ub1-upper", "--out", str(out)], capsys)
    assert code == 2 and "lightsim check" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_aperture_mean(lamp_file: Path, capsys) -> None:
    """An aperture averages the intensity over its disc: a uniform region keeps its value;
    an aperture straddling the 14 000 → 17 000 cd step gives a value in between."""
    pts = aperture_points(0.5)
    assert np.all(np.hypot(pts[:, 0], pts[:, 1]) <= 0.25 + 1e-12)
    assert abs(pts.mean(axis=0)).max() < 0.02  # centred
    res = check_lamp(lamp_source(lamp_file), "fmvss-lb1v-lower", beam="lower",
                     aperture_deg=0.2)
    rows = {r["name"]: r for r in res.results}
    assert rows["1.5D-9L"]["value_cd"] == pytest.approx(1000.0)
    assert 1000.0 < rows["0.5D-1.5R"]["value_cd"] < 10_000.0  # an isolated node, blurred
    code, _, err = run_cli(["check", str(lamp_file), "--regulation", "fmvss-lb1v-lower",
                            "--beam", "lower", "--aperture", "-1"], capsys)
    assert code == 2 and "--aperture" in err
