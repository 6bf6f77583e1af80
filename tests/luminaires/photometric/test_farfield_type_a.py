"""``simulate --ies`` as Type A: a warning when the file leaves out flux behind the lamp."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lightsim.cli.main import main
from lightsim.luminaires.photometric import CandelaGrid, read_photometric, write_ies
from lightsim.luminaires.photometric.analysis import type_a_outside_warning


def _simulate(scene, out, capsys, *extra):
    argv = ["simulate", str(scene), "--photons", "20000", "--resolution", "40x16",
            "--farfield-photons", "40000", "--ies", str(out / "far.ies"), "--out", str(out),
            "--quiet", *extra]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 0, err
    return json.loads((out / "summary.json").read_text()), err


def test_warning_line_threshold_and_degenerate_input():
    assert type_a_outside_warning("a.ies", 423.0, 22.0).count("\n") == 0
    line = type_a_outside_warning("out/a.ies", 423.0, 22.0)
    assert "a.ies" in line and "4.9%" in line and "22 lm" in line and "445 lm" in line
    assert "--ies-type C" in line
    assert type_a_outside_warning("a.ies", 995.0, 5.0) is None      # 0.5 % ≤ 1 %
    assert type_a_outside_warning("a.ies", 989.0, 11.0) is not None  # 1.1 % > 1 %
    for inside, outside in ((0.0, 0.0), (float("nan"), 1.0), (1.0, float("inf"))):
        assert type_a_outside_warning("a.ies", inside, outside) is None


def test_isotropic_lamp_as_type_a_warns_once_with_the_missing_share(tmp_path, capsys):
    """An isotropic point source sends half its flux backwards: a Type A file lacks it."""
    lamp = tmp_path / "iso.ies"
    write_ies(lamp, CandelaGrid(np.array([0.0]), np.array([0.0, 90.0, 180.0]),
                                np.full((1, 3), 100.0), None, {}))
    s, err = _simulate(lamp, tmp_path / "a", capsys, "--ies-type", "A")
    ff = s["farfield"]
    share = ff["type_a_outside_lm"] / (ff["type_a_flux_lm"] + ff["type_a_outside_lm"])
    assert share == pytest.approx(0.5, abs=0.02)  # exact: half the sphere
    lines = [ln for ln in err.splitlines() if "Type A" in ln]
    assert len(lines) == 1 and lines[0].startswith("lightsim: warning: far.ies (Type A)")
    assert f"({share:.1%})" in lines[0] and "--ies-type C" in lines[0]
    assert ff["warning"] in lines[0]
    # the file really holds only the front: its flux is the summary's inside share
    grid = read_photometric(tmp_path / "a" / "far.ies")
    assert grid.photometric_type == "A"
    assert grid.total_flux() == pytest.approx(ff["type_a_flux_lm"], rel=1e-4)
    # Type C keeps everything: no warning
    s, err = _simulate(lamp, tmp_path / "c", capsys, "--ies-type", "C")
    assert "Type A" not in err and "warning" not in s["farfield"]


def test_forward_lamp_as_type_a_does_not_warn(tmp_path, capsys):
    from lightsim.validation.coverage import synthetic_lamp

    lamp = tmp_path / "beam.ies"
    write_ies(lamp, synthetic_lamp(np.random.default_rng(3))[0])  # front hemisphere only
    s, err = _simulate(lamp, tmp_path / "a", capsys)
    assert s["farfield"]["ies_type"] == "A" and s["farfield"]["type_a_outside_lm"] == 0.0
    assert "Type A" not in err and "warning" not in s["farfield"]
