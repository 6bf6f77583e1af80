"""Visual/optical aim applied before the photometry: a Type A lamp aimed 1.4° too high (its
cut-off at 1° U) is pitched to put the cut-off at 0.4° D, and its FMVSS LB1V table then
matches the one computed by hand for the aimed lamp."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.luminaires.photometric.hvgrid import HVGrid
from lightsim.luminaires.photometric.ies import write_ies
from lightsim.luminaires.regulations import load_ruleset
from lightsim.luminaires.regulations.conditions import CUTOFF_V_DEG
from lightsim.luminaires.regulations.lamp_check import check_lamp, lamp_source
from lightsim.luminaires.regulations.reaim import reaim_probes
from lightsim.luminaires.regulations.visual_aim import pitch_back, pitched
from lightsim.wall import WallFrame

from support import run_cli

CUT = 1.0  # the built lamp's cut-off (deg U): 1.4° above where a VOL aim puts it
H = np.round(np.arange(-20.0, 20.001, 0.25), 6)
V = np.round(np.arange(-12.0, 15.001, 0.05), 6)


def _table() -> np.ndarray:
    """200 cd from the cut-off up, 0 cd from 11° U; 16 000 cd in the 3° below the cut-off
    (the step is one 0.05° cell), 5 000 cd lower down."""
    row = np.where(V >= CUT - 1e-9, 200.0, np.where(V >= CUT - 3.0 - 1e-9, 16_000.0, 5_000.0))
    row[V >= 11.0 - 1e-9] = 0.0
    return np.repeat(row[None, :], H.size, axis=0)


@pytest.fixture(scope="module")
def high_lamp(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("aim") / "high.ies"
    write_ies(path, HVGrid(H, V, _table(), "A"))
    return path


# by hand, for the lamp pitched 1.4° down (cut-off at 0.4° D): a point at V reads the built
# lamp 1.4° higher: from 0.4° D up → 200 cd (0 cd from 9.6° U), 0.4° D … 3.4° D → 16 000 cd,
# below → 5 000 cd (Table XIX-a LB1V, point values)
AIMED = {
    "10U-90U": ("pass", 0.0), "4U-8L": ("pass", 200.0), "4U-8R": ("pass", 200.0),
    "2U-4L": ("pass", 200.0), "1.5U-1R to 3R": ("pass", 200.0),
    "1.5U-1R to R": ("pass", 200.0), "1U-1.5L to L": ("pass", 200.0),
    "0.5U-1.5L to L": ("pass", 200.0), "0.5U-1R to 3R (min)": ("fail", 200.0),
    "0.5U-1R to 3R (max)": ("pass", 200.0), "H-V": ("pass", 200.0),
    "H-4L": ("pass", 200.0), "H-8L": ("pass", 200.0), "0.6D-1.3R": ("pass", 16_000.0),
    "0.86D-V": ("pass", 16_000.0), "0.86D-3.5L": ("fail", 16_000.0),
    "1.5D-2R": ("pass", 16_000.0), "2D-9L": ("pass", 16_000.0), "2D-9R": ("pass", 16_000.0),
    "2D-15L": ("pass", 16_000.0), "2D-15R": ("pass", 16_000.0), "4D-V": ("pass", 5_000.0),
    "4D-4R": ("pass", 5_000.0), "4D-20L": ("pass", 5_000.0), "4D-20R": ("pass", 5_000.0),
}


def test_pitch_back_is_the_inverse_rotation() -> None:
    h, v = pitch_back([0.0], [2.0], -1.4)
    assert h[0] == pytest.approx(0.0) and v[0] == pytest.approx(3.4)
    # off the vertical plane: rotate the direction vector by hand
    hh, vv, dv = 15.0, -2.0, 0.7
    d = np.array([np.tan(np.radians(hh)), np.tan(np.radians(vv)), 1.0])
    a = np.radians(dv)
    r = np.array([[1, 0, 0], [0, np.cos(a), np.sin(a)], [0, -np.sin(a), np.cos(a)]])
    x, y, z = r.T @ d
    h0, v0 = pitch_back([hh], [vv], dv)
    assert h0[0] == pytest.approx(np.degrees(np.arctan2(x, z)), abs=1e-12)
    assert v0[0] == pytest.approx(np.degrees(np.arctan2(y, z)), abs=1e-12)
    # pitching there and back is the identity; a pitch of 0 returns the same function
    f = pitched(lambda hd, vd: np.asarray(vd, dtype=float), 0.7)
    assert f(np.array([0.0]), np.array([1.0]))[0] == pytest.approx(0.3)
    g = lambda hd, vd: vd  # noqa: E731
    assert pitched(g, 0.0) is g


def test_lamp_with_known_offset_is_aimed_then_read(high_lamp: Path) -> None:
    res = check_lamp(lamp_source(high_lamp), "fmvss-lb1v-lower", beam="lower",
                     aperture_deg=0.0)
    aim = res.aim
    assert aim["applied"] and aim["aimable"] and aim["level"] and aim["method"] == "VOL"
    assert aim["target_v_deg"] == CUTOFF_V_DEG["VOL"] == -0.4
    assert aim["v_cutoff_deg"] == pytest.approx(CUT, abs=0.05)
    assert aim["dv_deg"] == pytest.approx(-0.4 - CUT, abs=0.05)
    rows = {r["name"]: r for r in res.results}
    assert set(rows) == set(AIMED)
    for name, (verdict, value) in AIMED.items():
        assert rows[name]["verdict"] == verdict, name
        assert rows[name]["value_cd"] == pytest.approx(value, rel=1e-9, abs=1e-9), name
    assert not any(r.get("after_reaim") for r in res.results)
    assert rows["0.86D-3.5L"]["reaim_direction"].startswith("none passes")  # 16 000 > 12 000
    assert any("pitched -1.4" in n for n in res.notes)


def test_without_the_aim_the_high_lamp_glares(high_lamp: Path) -> None:
    """The same lamp read at its aim as built: the points above H sit in the bright part."""
    res = check_lamp(lamp_source(high_lamp), "fmvss-lb1v-lower", beam="lower",
                     visual_aim=False, aperture_deg=0.0)
    rows = {r["name"]: r for r in res.results}
    assert not res.aim["applied"] and res.aim["dv_deg"] == 0.0 and res.aim["aimable"]
    assert rows["H-V"]["verdict"] == "fail" and rows["H-V"]["value_cd"] == 16_000.0
    assert rows["0.5U-1R to 3R (max)"]["verdict"] == "fail"
    assert rows["0.5U-1R to 3R (max)"]["value_cd"] == 16_000.0
    assert rows["10U-90U"]["verdict"] == "fail"  # 200 cd up to 11° U


def test_vor_aim_puts_the_cutoff_on_h(high_lamp: Path, tmp_path: Path) -> None:
    rs = tmp_path / "vor.toml"
    rs.write_text('schema = "lightsim-ruleset-1"\nid = "vor"\ntitle = "t"\nversion = "1"\n'
                  'source = "test"\ntraffic = "right"\n[measurement]\naim = "visual"\n'
                  'visual_aim = "VOR"\nbeam = "lower"\n'
                  '[[point]]\nname = "0.5U-V"\nh = 0.0\nv = 0.5\nmax = 1000\n'
                  '[[point]]\nname = "0.5D-V"\nh = 0.0\nv = -0.5\nmax = 1000\n')
    res = check_lamp(lamp_source(high_lamp), str(rs), beam="lower")
    assert res.aim["method"] == "VOR" and "right of V-V" in res.aim["message"]
    assert res.aim["dv_deg"] == pytest.approx(-CUT, abs=0.05)
    rows = {r["name"]: r for r in res.results}
    # the cut-off now on H: 0.5° above it is dark, 0.5° below it bright
    assert rows["0.5U-V"]["verdict"] == "pass" and rows["0.5U-V"]["value_cd"] == 200.0
    assert rows["0.5D-V"]["verdict"] == "fail" and rows["0.5D-V"]["value_cd"] == 16_000.0


def test_visual_mark_vor_on_a_v_column(high_lamp: Path, capsys) -> None:
    """A VOR lamp checked against LB1V: scanned 2.0° R and put on H-H, not at 0.4° D."""
    res = check_lamp(lamp_source(high_lamp), "fmvss-lb1v-lower", beam="lower",
                     aperture_deg=0.0, visual_mark="VOR")
    assert res.aim["method"] == "VOR" and res.aim["target_v_deg"] == 0.0
    assert res.aim["dv_deg"] == pytest.approx(-CUT, abs=0.05)
    code, _, err = run_cli(["check", str(high_lamp), "--regulation", "fmvss-lb1v-lower",
                            "--beam", "lower", "--visual-mark", "VOX"], capsys)
    assert code == 2 and "--visual-mark" in err


def test_a_lamp_without_cutoff_is_not_aimable(tmp_path: Path) -> None:
    path = tmp_path / "flat.ies"
    write_ies(path, HVGrid(H, V, np.full((H.size, V.size), 1000.0), "A"))
    res = check_lamp(lamp_source(path), "fmvss-lb1v-lower", beam="lower", aperture_deg=0.0)
    assert not res.aim["aimable"] and not res.aim["applied"] and res.aim["dv_deg"] == 0.0
    assert "NOT visually aimable" in res.aim["message"]
    assert {r["name"]: r for r in res.results}["H-V"]["value_cd"] == 1000.0


def test_the_wall_is_judged_on_the_aimed_lamp() -> None:
    """A run's wall covering ±3° V: 2U-4L reads the built lamp at 3.4° U when aimed 1.4° down,
    off the wall, so it is dropped; unaimed it stays."""
    frame = WallFrame.from_any({"centre": [0.0, 0.0, 25.0], "h_axis": [-1.0, 0.0, 0.0],
                                "v_axis": [0.0, 1.0, 0.0], "normal": [0.0, 0.0, -1.0],
                                "h_range_m": [-12.0, 12.0], "v_range_m": [-1.31, 1.31],
                                "distance_m": 25.0, "resolution": [480, 52]})
    rs = load_ruleset("fmvss-lb1v-lower")
    plain = reaim_probes(rs, frame=frame)
    aimed = reaim_probes(rs, frame=frame, aim_dv_deg=-1.4)
    assert "2U-4L" in plain.base.labels and "2U-4L" in plain.points
    assert "2U-4L" not in aimed.base.labels and "2U-4L" in aimed.base.dropped


def test_cli_reports_the_aim(high_lamp: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "v.json"
    code, text, err = run_cli(["check", str(high_lamp), "--regulation", "fmvss-lb1v-lower",
                               "--beam", "lower", "--aperture", "0", "--json", str(out)],
                              capsys)
    assert code == 0, err
    assert "lamp pitched -1.4" in text
    doc = json.loads(out.read_text())
    assert doc["visual_aim"]["applied"] is True
    assert doc["measurement"]["visual_aim"] == "VOL"
    assert doc["measurement"]["cutoff_v_deg"] == -0.4


@pytest.mark.parametrize(("key", "value", "text"), [
    ("visual_aim", '"VOX"', "'visual_aim' must be one of VOL, VOR"),
    ("cutoff_v_deg", "5.0", "'cutoff_v_deg' must be a number"),
    ("aperture_deg", "-1", "'aperture_deg' must be a number"),
])
def test_new_measurement_keys_checked(tmp_path: Path, key: str, value: str, text: str) -> None:
    rs = tmp_path / "bad.toml"
    rs.write_text('schema = "lightsim-ruleset-1"\nid = "bad"\ntitle = "t"\nversion = "1"\n'
                  f'source = "test"\ntraffic = "right"\n[measurement]\n{key} = {value}\n'
                  '[[point]]\nname = "H-V"\nh = 0.0\nv = 0.0\nmax = 1000\n')
    with pytest.raises(InputError, match=text):
        load_ruleset(str(rs))


def test_rule_set_aperture_is_the_default(high_lamp: Path, tmp_path: Path) -> None:
    """A set's aperture applies unless one is given: H-V, 0.4° above the aimed cut-off, keeps
    200 cd over the whole 0.516° disc; 0.6D-1.3R, 0.2° below it, is blurred. Every shipped
    FMVSS set states the standard's 0.516° (0.009 × the distance across)."""
    for col in ("lb1m", "lb1v", "lb2m", "lb2v", "lb3m", "lb3v", "lb4m", "lb4v", "lb5m"):
        assert load_ruleset(f"fmvss-{col}-lower").measurement.aperture_deg == 0.516
    for n in range(1, 7):
        assert load_ruleset(f"fmvss-ub{n}-upper").measurement.aperture_deg == 0.516
    rs = tmp_path / "two.toml"
    rs.write_text('schema = "lightsim-ruleset-1"\nid = "two"\ntitle = "t"\nversion = "1"\n'
                  'source = "test"\ntraffic = "right"\n[measurement]\naim = "visual"\n'
                  'beam = "lower"\nangles = "azimuth-elevation"\naperture_deg = 0.516\n'
                  '[[point]]\nname = "H-V"\nh = 0.0\nv = 0.0\nmax = 5000\n'
                  '[[point]]\nname = "0.6D-1.3R"\nh = 1.3\nv = -0.6\nmin = 10000\n')
    res = check_lamp(lamp_source(high_lamp), str(rs), beam="lower")
    assert res.aperture_deg == pytest.approx(0.516)
    rows = {r["name"]: r for r in res.results}
    assert rows["H-V"]["value_cd"] == pytest.approx(200.0)
    assert 200.0 < rows["0.6D-1.3R"]["value_cd"] < 16_000.0
    point = check_lamp(lamp_source(high_lamp), str(rs), beam="lower", aperture_deg=0.0)
    assert {r["name"]: r for r in point.results}["0.6D-1.3R"]["value_cd"] == 16_000.0


def test_a_tilted_cutoff_is_not_level(tmp_path: Path) -> None:
    """The cut-off rises 0.3° per degree to the right: 1° either side of 2.5° L it is 0.3°
    off the centre's position, more than 0.2°: not visually aimable, no aim applied."""
    cut = 0.3 * (H[:, None] + 2.5)  # on H at 2.5° L
    cd = np.where(V[None, :] >= cut - 1e-9, 200.0, 16_000.0)
    path = tmp_path / "tilted.ies"
    write_ies(path, HVGrid(H, V, cd, "A"))
    res = check_lamp(lamp_source(path), "fmvss-lb1v-lower", beam="lower", aperture_deg=0.0)
    aim = res.aim
    # positions to within the step's cell and the scan band; the ends 0.3° either way
    v0 = aim["v_cutoff_deg"]
    assert aim["found"] and v0 == pytest.approx(0.0, abs=0.1)
    assert aim["ends_v_deg"][0] - v0 == pytest.approx(0.3, abs=0.05)  # 1.5° L
    assert aim["ends_v_deg"][1] - v0 == pytest.approx(-0.3, abs=0.05)  # 3.5° L
    assert not aim["level"] and not aim["aimable"] and not aim["applied"]
    assert "not level over 2°" in aim["message"] and aim["dv_deg"] == 0.0
