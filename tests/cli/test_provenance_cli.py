"""simulate --provenance and lightsim report --provenance on the shipped lamps."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lightsim.io.caption import read_caption

from support import run_cli

EXAMPLES = Path(__file__).parents[2] / "luminaires" / "examples"


def _simulate(out: Path, lamp: str, photons: int, capsys, *extra: str) -> dict:
    code, _, err = run_cli(["simulate", str(EXAMPLES / lamp), "--photons", str(photons),
                            "--regulation", "r112-b-passing,r149-b-passing", "--provenance",
                            "--resolution", "160x64", "--outputs", "json", "--out", str(out),
                            "--quiet", *extra], capsys)
    assert code == 0, err
    return json.loads((out / "summary.json").read_text())


def _adds_up(summary: dict) -> int:
    """Every rule of both rule sets: the classes add up to the table's value (the same
    photons split) and so lie within its interval. Returns the rules checked."""
    n = 0
    for key in ("regulation", "regulation:r149-b-passing"):
        table = {r["name"]: r for r in summary[key]["results"]}
        rules = summary["provenance"]["rulesets"][summary[key]["ruleset"]]
        for name, b in rules.items():
            row = table[name]
            assert b["sum_cd"] == pytest.approx(row["value_cd"], rel=1e-9, abs=1e-9), name
            lo, hi = row["interval_cd"]
            assert lo - 1e-9 <= b["sum_cd"] <= hi + 1e-9, name
            assert sum(c["value_cd"] for c in b["classes"]) == pytest.approx(
                b["sum_cd"], rel=1e-9, abs=1e-9)
            n += 1
        points = [r for r in summary[key]["results"] if r["kind"] in ("point", "zone", "sum")]
        assert len(rules) >= len(points) - len(summary[key].get("unevaluated", []))
    return n


def test_lowbeam_classes_add_up_at_every_point_and_report_prints_them(tmp_path, capsys):
    s = _simulate(tmp_path, "lowbeam.glb", 200_000, capsys, "--aim")  # shifted apertures
    assert s["regulation"]["aim"]["aperture_dv_deg"] != 0
    assert _adds_up(s) > 30
    p50r = s["provenance"]["rulesets"]["r112-b-passing"]["50R"]  # bright: photons at 200 k
    assert p50r["classes"] and all(c["interval_cd"][0] <= c["value_cd"] <= c["interval_cd"][1]
                                   for c in p50r["classes"])
    assert any("reflector facet" in c["class"] for c in p50r["classes"])
    before = {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    code, out, err = run_cli(["report", "--provenance", "B50L", str(tmp_path)], capsys)
    assert code == 0, err
    assert "B50L" in out and "path class" in out and "share" in out
    code, out, _ = run_cli(["report", "--provenance", "50R", "--part", "reflector",
                            str(tmp_path)], capsys)
    assert code == 0 and "50R" in out
    # the lamp pictures: the rule's light lands on the lamp (a real PNG, read back)
    import matplotlib.image as mpimg
    img = mpimg.imread(tmp_path / "provenance-50R.png")
    assert img.ndim == 3 and img.shape[0] > 100
    assert (tmp_path / "provenance-r149-b-passing-50R.png").exists()
    assert (tmp_path / "provenance-B50L.png").exists()
    for p in tmp_path.glob("provenance-*.png"):  # each says which run and rule set it shows
        cap = read_caption(p)
        assert cap is not None and "photons" in cap and "lightsim" in cap, (p.name, cap)
    for p in tmp_path.glob("provenance-*.png"):
        p.unlink()
    assert {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()} == before
    # bad input: one line, exit 2, nothing written
    for argv, words in ((["report", "--provenance", "B99X", str(tmp_path)], "no rule"),
                        (["report", "--provenance", "B50L", "--part", "nosuch",
                          str(tmp_path)], "no part")):
        code, out, err = run_cli(argv, capsys)
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err
    assert {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()} == before


def test_report_provenance_on_a_run_without_it_and_bad_simulate_options(tmp_path, capsys):
    code, _, err = run_cli(["simulate", str(EXAMPLES / "lowbeam.glb"), "--photons", "50000",
                            "--regulation", "r112-b-passing", "--resolution", "80x32",
                            "--outputs", "json", "--out", str(tmp_path / "plain"), "--quiet"],
                           capsys)
    assert code == 0, err
    code, _, err = run_cli(["report", "--provenance", "B50L", str(tmp_path / "plain")],
                           capsys)
    assert code == 2 and "without --provenance" in err
    for extra, words in ((["--aperture", "0", "--regulation", "r112-b-passing"], "aperture"),
                         ([], "--regulation")):
        out = tmp_path / f"bad{len(extra)}"
        code, _, err = run_cli(["simulate", str(EXAMPLES / "lowbeam.glb"), "--photons", "1000",
                                "--provenance", "--out", str(out), "--quiet", *extra], capsys)
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists()


@pytest.mark.slow
@pytest.mark.parametrize("lamp", ["headlight.glb", "projector.glb", "matrix.glb"])
def test_every_shipped_lamp_adds_up_at_every_point(tmp_path, capsys, lamp):
    assert _adds_up(_simulate(tmp_path, lamp, 200_000, capsys)) > 30


def test_path_map_holds_its_class_and_all_classes_hold_the_wall_flux(tmp_path, capsys):
    """--provenance-map: every class names the emitter, so its map is all the wall's flux
    (read back from the EXR); a part's map is part of it; a text no class can hold is
    refused before the run."""
    from lightsim.io.exr import read_exr

    s = _simulate(tmp_path / "all", "lowbeam.glb", 50_000, capsys, "--provenance-map",
                  "filament")
    ch, _ = read_exr(tmp_path / "all" / "provenance-map.exr")
    w = s["wall"]
    area = ((w["h_range_m"][1] - w["h_range_m"][0]) / w["resolution"][0]
            * (w["v_range_m"][1] - w["v_range_m"][0]) / w["resolution"][1])
    assert float(ch["Y"].astype(float).sum()) * area == pytest.approx(
        s["energy_lm"]["wall"], rel=1e-4)
    cap = read_caption(tmp_path / "all" / "provenance-map.png")
    assert cap is not None and "lowbeam.glb" in cap and "r112-b-passing" in cap, cap
    s2 = _simulate(tmp_path / "shield", "lowbeam.glb", 50_000, capsys, "--provenance-map",
                   "shield (diffuse)")
    ch2, _ = read_exr(tmp_path / "shield" / "provenance-map.exr")
    part = float(ch2["Y"].astype(float).sum()) * area
    assert 0 < part < 0.5 * s2["energy_lm"]["wall"]
    code, _, err = run_cli(["simulate", str(EXAMPLES / "lowbeam.glb"), "--photons", "1000",
                            "--regulation", "r112-b-passing", "--provenance",
                            "--provenance-map", "housing", "--out", str(tmp_path / "bad"),
                            "--quiet"], capsys)
    assert code == 2 and "housing" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "bad").exists()


def test_provenance_keeps_no_photon_and_reads_as_a_keep_all_run(tmp_path, capsys):
    """The class counts are accumulated per frame: a --provenance run keeps no photon, and
    its tables equal a --keep-photons run's."""
    plain = _simulate(tmp_path / "plain", "lowbeam.glb", 200_000, capsys)
    kept = _simulate(tmp_path / "kept", "lowbeam.glb", 200_000, capsys, "--keep-photons")
    assert plain["config"]["keep_photons"] is False and kept["config"]["keep_photons"]
    for summary in (plain, kept):
        summary["provenance"].pop("seconds", None)
    assert plain["provenance"] == kept["provenance"]
    assert plain["regulation"]["results"] == kept["regulation"]["results"]
