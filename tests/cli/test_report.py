"""simulate --regulation/--aim/--ies/--ldt and lightsim report on the shipped headlight."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lightsim.cli.main import main
from lightsim.luminaires.photometric import read_photometric

HEADLIGHT = Path(__file__).parents[2] / "luminaires" / "examples" / "headlight.glb"


def _run(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("h4")
    argv = ["simulate", str(HEADLIGHT), "--photons", "300000", "--frame-photons", "150000",
            "--resolution", "320x128", "--regulation", "r112-b-passing", "--aim",
            "--ies", str(out / "lamp.ies"), "--ldt", str(out / "lamp.ldt"),
            "--farfield-photons", "100000", "--out", str(out), "--quiet",
            "--aperture", "0"]  # kNN probes: 0.15° apertures are too sparse at 300 k
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    return out


def test_regulation_table_with_intervals(result):
    s = json.loads((result / "summary.json").read_text())
    reg = s["regulation"]
    assert reg["ruleset"] == "r112-b-passing" and reg["aim"]["applied"]
    assert reg["aim"]["dv_deg"] == pytest.approx(s["cutoff"]["aim_dv_deg"])
    points = {r["name"]: r for r in reg["results"]}
    for name in ("B50L", "BR", "75R", "75L", "50L", "50R", "50V", "25L", "25R"):
        r = points[name]
        assert set(r) >= {"name", "h_deg", "v_deg", "value_cd", "interval_cd", "limit",
                          "verdict"}
        lo, hi = r["interval_cd"]
        assert lo <= r["value_cd"] <= hi and hi > lo
        assert r["verdict"] in ("pass", "fail", "uncertain")
    assert points["75R"]["h_deg"] == pytest.approx(1.15) and points["75R"]["v_deg"] == -0.57
    # the hot spot of a passing beam lies below H-H: 50V is far brighter than B50L
    assert points["50V"]["value_cd"] > 5 * points["B50L"]["value_cd"]
    assert (result / "probes.npz").exists() and (result / "isolux.png").exists()
    assert (result / "road.png").exists()


def test_far_field_files_hold_the_escaping_flux(result):
    s = json.loads((result / "summary.json").read_text())
    ies = read_photometric(result / "lamp.ies")
    ldt = read_photometric(result / "lamp.ldt")
    leaving = s["farfield"]["total_flux_lm"]
    # flux that leaves the lamp = what reached the wall + what missed it (main run)
    e = s["energy_lm"]
    assert leaving == pytest.approx(e["wall"] + e["escaped"], rel=0.03)
    # a headlamp's --ies is Type A (front hemisphere): it holds the flux heading forwards
    ff = s["farfield"]
    assert ff["ies_type"] == "A" and ies.photometric_type == "A"
    assert ies.total_flux() == pytest.approx(ff["type_a_flux_lm"], rel=1e-4)
    assert ff["type_a_flux_lm"] + ff["type_a_outside_lm"] == pytest.approx(leaving, rel=1e-9)
    assert ldt.total_flux() == pytest.approx(leaving, rel=1e-3)
    # straight ahead (H = V = 0°) is bright; straight up is dark
    i_ahead = float(ies.intensity_hv(0.0, 0.0))
    i_up = float(ies.intensity_towards(np.array([0.0, 1.0, 0.0])))
    assert i_ahead > 100 * max(i_up, 1e-9)


def test_report_regenerates_plots_and_table(result, capsys):
    (result / "isolux.png").unlink()
    before = json.loads((result / "summary.json").read_text())["regulation"]["results"]
    code, out, err = _run(["report", str(result)], capsys)
    assert code == 0, err
    assert (result / "isolux.png").exists()
    after = json.loads((result / "summary.json").read_text())["regulation"]["results"]
    assert [r["value_cd"] for r in after] == pytest.approx([r["value_cd"] for r in before])
    assert "B50L" in out
    code, _, err = _run(["report", str(result), "--regulation", "sae-j1383-low"], capsys)
    assert code == 2 and "probes of 'r112-b-passing'" in err
