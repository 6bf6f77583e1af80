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
    """Goniometer (Type A) nodes: 1000 cd up to H, 100 cd from 0.25° U, 0 from 9.5U; 200 cd
    at 2U-4L; 250 cd along 1.5U from 1R to 3R; 600 cd along 0.5U from 1R to 3R; 12 000 cd
    on the four nodes around 0.6D-1.3R; 5 000 cd at 0.75D and 1D on V; 2 000 cd at 0.75D and
    1D on 3.5L; 14 000 cd at 1.5D-2R with 17 000 cd a quarter degree above (so 15 500 cd 1/8°
    up: passes only re-aimed); 300 cd over the whole re-aim disc of 2D-9L (fails even
    re-aimed); 1 500 cd at 2D-9R."""
    cd = np.where(V[None, :] < 0.25, 1000.0, 100.0) * np.ones((H.size, 1))
    cd[:, V >= 9.5] = 0.0

    def node(h: float, v: float) -> tuple[int, int]:
        return int(np.flatnonzero(np.isclose(H, h))[0]), int(np.flatnonzero(np.isclose(V, v))[0])

    cd[node(-4.0, 2.0)] = 200.0
    for h in np.arange(1.0, 3.001, 0.25):
        cd[node(h, 1.5)] = 250.0
        cd[node(h, 0.5)] = 600.0
    for h in (1.25, 1.5):
        for v in (-0.5, -0.75):
            cd[node(h, v)] = 12_000.0
    for v in (-0.75, -1.0):
        cd[node(0.0, v)] = 5_000.0
        cd[node(-3.5, v)] = 2_000.0
    cd[node(2.0, -1.5)] = 14_000.0
    cd[node(2.0, -1.25)] = 17_000.0
    for h in (-9.5, -9.25, -9.0, -8.75, -8.5):
        for v in (-2.5, -2.25, -2.0, -1.75, -1.5):
            cd[node(h, v)] = 300.0
    cd[node(9.0, -2.0)] = 1_500.0
    return cd


# the verdicts an engineer computes by hand from the table above (Table XIX-a LB1V, right
# traffic, point values at the lamp's aim as built): every row class — point minimum,
# maximum and range, line minimum and maximum, a line range split in two, the 10U-90U area
EXPECTED = {
    "4U-8L": ("pass", 100.0), "4U-8R": ("pass", 100.0), "2U-4L": ("pass", 200.0),
    "H-V": ("pass", 1000.0), "H-4L": ("pass", 1000.0), "H-8L": ("pass", 1000.0),
    "0.6D-1.3R": ("pass", 12_000.0), "0.86D-V": ("pass", 5_000.0),
    "0.86D-3.5L": ("pass", 2_000.0), "1.5D-2R": ("pass", 15_500.0),
    "2D-9L": ("fail", 300.0), "2D-9R": ("pass", 1_500.0), "2D-15L": ("pass", 1000.0),
    "2D-15R": ("pass", 1000.0), "4D-V": ("pass", 1000.0), "4D-4R": ("pass", 1000.0),
    "4D-20L": ("pass", 1000.0), "4D-20R": ("pass", 1000.0),
    "10U-90U": ("pass", 0.0), "1.5U-1R to 3R": ("pass", 250.0),
    "0.5U-1R to 3R (min)": ("pass", 600.0), "0.5U-1R to 3R (max)": ("pass", 600.0),
}
LINES = ("1.5U-1R to R", "1U-1.5L to L", "0.5U-1.5L to L")


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
    """Point values read at the lamp's aim as built (no visual aim, no aperture: the table
    is written for it)."""
    res = check_lamp(lamp_source(lamp_file), "fmvss-lb1v-lower", beam="lower",
                     visual_aim=False, aperture_deg=0.0)
    rows = {r["name"]: r for r in res.results}
    assert set(rows) == set(EXPECTED) | set(LINES)
    for name, (verdict, value) in EXPECTED.items():
        assert rows[name]["verdict"] == verdict, name
        assert rows[name]["value_cd"] == pytest.approx(value, rel=1e-9, abs=1e-9), name
    assert rows["1.5D-2R"]["after_reaim"] is True
    assert rows["1.5D-2R"]["reaim_offset_deg"] == pytest.approx([0.0, 0.125], abs=1e-12)
    assert rows["1.5D-2R"]["reaim_direction"] == "0.125° U"
    assert not any(rows[n].get("after_reaim") for n in EXPECTED if n != "1.5D-2R")
    assert rows["2D-9L"]["reaim_direction"].startswith("none passes")
    for zone in LINES:  # 100 cd or less along them (250 cd on 1.5U up to 3R)
        assert rows[zone]["verdict"] == "pass", zone
    assert rows["1.5U-1R to R"]["value_cd"] == pytest.approx(250.0)
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
                               "--beam", "lower", "--no-visual-aim", "--aperture", "0",
                               "--json", str(out)], capsys)
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


def test_aperture_mean(lamp_file: Path, tmp_path: Path, capsys) -> None:
    """An aperture averages the intensity over its disc: a uniform region keeps its value;
    an aperture straddling the 14 000 → 17 000 cd step gives a value in between."""
    pts = aperture_points(0.5)
    assert np.all(np.hypot(pts[:, 0], pts[:, 1]) <= 0.25 + 1e-12)
    assert abs(pts.mean(axis=0)).max() < 0.02  # centred
    two = tmp_path / "two.toml"  # two LB1V rows (the whole set's 10U-90U area is slow here)
    two.write_text('schema = "lightsim-ruleset-1"\nid = "two"\ntitle = "t"\nversion = "1"\n'
                   'source = "test"\ntraffic = "right"\n[measurement]\n'
                   'angles = "azimuth-elevation"\nreaim_deg = 0.25\n'
                   '[[point]]\nname = "4D-V"\nh = 0.0\nv = -4.0\nmax = 10000\n'
                   '[[point]]\nname = "0.6D-1.3R"\nh = 1.3\nv = -0.6\nmin = 10000\n')
    res = check_lamp(lamp_source(lamp_file), str(two), beam="lower", aperture_deg=0.2)
    rows = {r["name"]: r for r in res.results}
    assert rows["4D-V"]["value_cd"] == pytest.approx(1000.0)
    assert 1000.0 < rows["0.6D-1.3R"]["value_cd"] < 12_000.0  # a 2 × 2 node block, blurred
    # the rule set's own aperture (0.516°: 0.009 × the distance across) is the default
    dflt = check_lamp(lamp_source(lamp_file), "fmvss-ub2-upper", beam="upper")
    assert dflt.aperture_deg == pytest.approx(0.516)
    assert any("aperture 0.516°" in n for n in dflt.notes)
    code, _, err = run_cli(["check", str(lamp_file), "--regulation", "fmvss-lb1v-lower",
                            "--beam", "lower", "--aperture", "-1"], capsys)
    assert code == 2 and "--aperture" in err
