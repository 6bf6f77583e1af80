"""lightsim adb (lightsim.luminaires.adb): traffic files, the R149 ADB limits, the masks of
the linear programme, verdicts with intervals, the residual light, agreement of a masked
composition with a direct simulation of the dimmed lamp, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lightsim.io.caption import read_caption
from lightsim.io.exr import read_exr
from lightsim.luminaires.adb import (
    AdbComposer,
    AdbLimits,
    AdbSettings,
    ScreenMaps,
    choose_levels,
    choose_levels_batch,
    read_traffic,
    run_adb,
)
from lightsim.luminaires.matrix import write_matrix
from lightsim.persource import read_per_source
from lightsim.scene import SceneSettings, load_scene
from lightsim.simulate import SimulateOptions, run_simulation

from support import run_cli

MATRIX = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "matrix.glb"
RES = (128, 48)
PHOTONS = 200_000

APPROACH = """
[road]
mount_height_m = 0.65
lane_width_m = 3.5

[[vehicle]]
name = "oncoming car"
kind = "oncoming"
approach_m = [400.0, 30.0]
frames = 40

[[vehicle]]
name = "car ahead"
kind = "preceding"
distance_m = 80.0
"""


def _run(scene: Path, out: Path) -> Path:
    run_simulation(SimulateOptions(scene_path=str(scene), photons=PHOTONS, out_dir=str(out),
                                   resolution=RES, per_source=True, outputs=("exr", "json")))
    return out


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    return _run(MATRIX, tmp_path_factory.mktemp("adb") / "run")


@pytest.fixture()
def approach(tmp_path) -> Path:
    p = tmp_path / "approach.toml"
    p.write_text(APPROACH)
    return p


def test_limits_come_from_the_rule_set():
    lim = AdbLimits.load()
    assert lim.for_user("oncoming", 30.0).max_cd == 625  # nearer than 50 m: the 50 m line
    assert lim.for_user("oncoming", 150.0).max_cd == 1750  # the stricter neighbour
    assert lim.for_user("oncoming", 400.0).max_cd == 5450
    assert lim.for_user("preceding", 100.0).max_cd == 5300
    line = lim.for_user("preceding", 250.0)
    assert line.max_cd == 16000 and "Table 7" in line.source and line.certainty == "less-sure"


def test_traffic_file_places_the_road_users(approach, tmp_path):
    tr = read_traffic(approach)
    assert len(tr.frames) == 40
    first, last = tr.frames[0], tr.frames[-1]
    oncoming = next(u for u in first if u.kind == "oncoming")
    assert oncoming.distance_m == 400.0 and oncoming.lateral_m == -3.5
    assert next(u for u in last if u.kind == "oncoming").distance_m == 30.0
    assert all(u.distance_m == 80.0 for f in tr.frames for u in f if u.kind == "preceding")
    left = tmp_path / "left.toml"
    left.write_text(APPROACH.replace('lane_width_m = 3.5', 'lane_width_m = 3.5\nside = "left"'))
    on = next(u for u in read_traffic(left).frames[0] if u.kind == "oncoming")
    assert on.lateral_m == 3.5 and on.points[0][1] == -0.4  # mirrored


def test_levels_solve_a_known_programme():
    """A fractional knapsack: three segments cost 1, 2, 3 cd of a 3.5 cd limit per unit
    level, each gives 1 lm; the optimum is 1, 1, 0.5/3."""
    a = np.array([[1.0, 2.0, 3.0]])
    w, ok = choose_levels(a, np.array([3.5]), np.ones(3), {})
    assert ok
    np.testing.assert_allclose(w, [1.0, 1.0, 0.5 / 3], atol=1e-6)
    # the batch of independent frames gives each frame its own optimum
    batch, oks = choose_levels_batch([(a, np.array([3.5])), (a, np.array([100.0])),
                                      (a, np.array([1.0]))], np.ones(3), {})
    np.testing.assert_allclose(batch, [[1, 1, 0.5 / 3], [1, 1, 1], [1, 0, 0]], atol=1e-6)
    assert oks.all()
    # a fixed segment keeps its level; a limit it alone breaks cannot be met
    w, ok = choose_levels(a, np.array([2.0]), np.ones(3), {2: 1.0})
    assert not ok and w[2] == 1.0 and w[0] == w[1] == 0.0


def test_masks_keep_every_position_within_its_limit(run_dir, approach):
    maps = read_per_source(run_dir)
    result = run_adb(maps, read_traffic(approach))
    assert len(result.frames) == 40
    for f in result.frames:
        assert f.feasible
        assert np.all((f.levels >= 0) & (f.levels <= 1))
        for p in f.positions:
            assert p["verdict"] == "pass"
            assert p["interval_cd"][1] <= p["max_cd"] * (1 + 1e-6)
            assert p["interval_cd"][0] <= p["cd"] <= p["interval_cd"][1]
    # the mask dims only what it must: at 400 m the oncoming car's eyes need less dimming
    # than at 30 m, and the far-right stripe stays full
    assert result.frames[0].levels.sum() > result.frames[-1].levels.sum()
    assert result.frames[-1].levels[maps.index("led_15")] == 1.0
    for r in result.frames[-1].residual:  # residual light: not zero, below all-on
        assert 0 < r["mean_cd"] < r["all_on_mean_cd"]
        assert r["interval_cd"][0] <= r["mean_cd"] <= r["interval_cd"][1]


def test_composition_is_the_weighted_sum(run_dir):
    maps = read_per_source(run_dir)
    tr = read_traffic_text(run_dir.parent / "one.toml",
                           '[[vehicle]]\nkind = "oncoming"\ndistance_m = 60.0\n')
    comp = AdbComposer(maps, tr)
    assert np.array_equal(comp.composed(np.ones(len(maps.names))), maps.all_on())
    w = np.linspace(0, 1, len(maps.names))
    expect = np.zeros(maps.lux.shape[1:], np.float32)
    for g in range(len(w)):
        expect += np.float32(w[g]) * maps.lux[g]
    assert np.array_equal(comp.composed(w), expect)


def read_traffic_text(path: Path, text: str):
    path.write_text(text)
    return read_traffic(path)


def test_masked_composition_agrees_with_a_direct_simulation(run_dir, tmp_path):
    """The lamp built with three segments dimmed, simulated directly, against the per-source
    maps of the all-on run composed with those levels: equal within their intervals at
    the R149 driving-beam points."""
    maps = read_per_source(run_dir)
    levels = np.ones(16)
    levels[[5, 6, 9]] = [0.0, 0.3, 0.5]
    glb = tmp_path / "dimmed.glb"
    write_matrix(glb, levels=list(levels))
    direct = read_per_source(_run(glb, tmp_path / "direct"))
    w = np.array([levels[int(n[4:])] for n in maps.names])
    s_all, s_dir = ScreenMaps(maps), ScreenMaps(direct)
    h = np.array([-5.0, -2.5, 0.0, 2.5, 5.0])  # H-5L, H-2.5L, HV, H-2.5R, H-5R
    half = 0.25
    a1, v1, _ = s_all.means(h - half, h + half, -half + 0 * h, half + 0 * h)
    a2, v2, _ = s_dir.means(h - half, h + half, -half + 0 * h, half + 0 * h)
    composed, var_c = a1 @ w, v1 @ (w * w)
    measured, var_d = a2.sum(axis=1), v2.sum(axis=1)
    z = np.abs(composed - measured) / np.sqrt(var_c + var_d)
    assert np.all(z < 3.5), (composed, measured, z)
    assert composed[1] < 0.6 * a1[1].sum()  # H-2.5L was dimmed: the check has teeth


def test_cli_writes_the_set(run_dir, approach, capsys, tmp_path):
    out = tmp_path / "adb"
    code, text, err = run_cli(["adb", str(run_dir), "--traffic", str(approach), "--out",
                               str(out)], capsys)
    assert code == 0, err
    assert "40 frame(s) of 16 segments" in text and "residual" in text
    names = sorted(p.name for p in out.iterdir())
    assert names == ["adb.json", "adb_composed.exr", "adb_isolux.png", "adb_levels.png",
                     "adb_road.png"]
    doc = json.loads((out / "adb.json").read_text())
    assert len(doc["frames"]) == 40 and doc["limits"][0]["source"]
    ch, _meta = read_exr(out / "adb_composed.exr")
    maps = read_per_source(run_dir)
    w = np.array([doc["frames"][-1]["levels"][n] for n in maps.names])
    assert np.array_equal(ch["Y"], AdbComposer(maps, read_traffic(approach)).composed(w))
    for png in ("adb_isolux.png", "adb_levels.png", "adb_road.png"):  # said what they show
        cap = read_caption(out / png)
        assert cap is not None and "photons" in cap and "r149-adb" in cap, (png, cap)


@pytest.mark.parametrize("body, why", [
    ("this is = = not toml", "not a TOML traffic file"),
    ('[[vehicle]]\nkind = "oncoming"\ndistance_m = -20.0\n', "behind the lamp"),
    ('[segments]\nled_99 = 0.5\n[[vehicle]]\nkind = "oncoming"\ndistance_m = 50.0\n',
     "no emitter group 'led_99'"),
    ('[segments]\nled_03 = 1.5\n[[vehicle]]\nkind = "oncoming"\ndistance_m = 50.0\n',
     "must be from 0 to 1"),
    ('[[vehicle]]\nkind = "truck"\ndistance_m = 50.0\n', "kind must be oncoming or preceding"),
])
def test_bad_traffic_is_one_line_and_writes_nothing(run_dir, tmp_path, capsys, body, why):
    bad = tmp_path / "bad.toml"
    bad.write_text(body)
    out = tmp_path / "out"
    code, _, err = run_cli(["adb", str(run_dir), "--traffic", str(bad), "--out", str(out)],
                           capsys)
    assert code == 2 and why in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_run_without_per_source_maps_is_refused(tmp_path, approach, capsys):
    plain = tmp_path / "plain"
    run_simulation(SimulateOptions(scene_path=str(MATRIX), photons=20_000, out_dir=str(plain),
                                   resolution=(32, 16), outputs=("json",)))
    code, _, err = run_cli(["adb", str(plain), "--traffic", str(approach)], capsys)
    assert code == 2 and "no per-source maps" in err
    assert not (plain / "adb").exists()


def test_settings_are_checked():
    with pytest.raises(Exception, match="confidence"):
        AdbSettings(confidence=1.5)


def test_matrix_levels_on_the_command_line(tmp_path, capsys):
    out = tmp_path / "dimmed.glb"
    levels = ["1"] * 16
    levels[5], levels[6] = "0", "0.3"
    code, _, err = run_cli(["luminaire", "matrix", str(out), "--levels", ",".join(levels)],
                           capsys)
    assert code == 0, err
    scene = load_scene(str(out), SceneSettings(resolution=(8, 8)))
    flux = {p.name: p.flux_lm for p in scene.emitters}
    assert "led_05" not in flux and len(flux) == 15
    full = load_scene(str(MATRIX), SceneSettings(resolution=(8, 8)))
    assert flux["led_06"] == pytest.approx(0.3 * next(
        p.flux_lm for p in full.emitters if p.name == "led_06"), rel=1e-12)
    for bad in ("1,1,0.5", ",".join(["1"] * 15 + ["2"]), "1,x"):
        code, _, err = run_cli(["luminaire", "matrix", str(tmp_path / "b.glb"), "--levels",
                                bad], capsys)
        assert code == 2 and len(err.strip().splitlines()) == 1
        assert not (tmp_path / "b.glb").exists()
