"""A damaged STEP or IGES file that crashes OpenCASCADE's reader (a segmentation fault in
its parser) or keeps it reading gives one line and exit 2: the reader runs in a child
process with a time limit."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import pytest

from lightsim.errors import InputError
from lightsim.io.cad import Tessellation, read_cad
from lightsim.io.cad_xcaf import have_ocp
from lightsim.luminaires.cad_example import write_example

from support import run_cli


@pytest.mark.skipif(not have_ocp(), reason="needs cadquery-ocp")
def test_a_step_file_that_crashes_the_reader_is_one_line(tmp_path, capsys):
    mmap = write_example(tmp_path / "lamp.step")
    lines = (tmp_path / "lamp.step").read_text(encoding="latin-1").splitlines()
    # line 96 of the example: its entity number 33 made 3 (a segmentation fault in
    # OpenCASCADE's STEP reader, found by lightsim fuzz --kind step, seed 1, case 32)
    assert "33" in lines[95]
    lines[95] = lines[95].replace("33", "3", 1)
    bad = tmp_path / "bad.step"
    bad.write_text("\n".join(lines) + "\n", encoding="latin-1")
    out = tmp_path / "out"
    code, _, err = run_cli(["simulate", str(bad), "--materials", str(mmap), "--photons",
                            "2000", "--resolution", "16x8", "-q", "--out", str(out)], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "lightsim: error:" in err
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.skipif(not have_ocp(), reason="needs cadquery-ocp")
def test_a_cad_read_over_its_time_limit_is_one_line(tmp_path, capsys, monkeypatch):
    """A read that does not end (a damaged file can make OpenCASCADE's reader loop) is
    given up after --cad-time-limit: the child is killed, one line, exit 2, no output."""
    mmap = write_example(tmp_path / "lamp.step")
    out = tmp_path / "out"
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    code, _, err = run_cli(["simulate", str(tmp_path / "lamp.step"), "--materials",
                            str(mmap), "--cad-time-limit", "0.05", "--photons", "2000",
                            "--resolution", "16x8", "-q", "--out", str(out)], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "did not finish reading the file within 0.05 s of processor time" in err
    assert "--cad-time-limit" in err
    assert not out.exists() or not any(out.iterdir())
    # the killed child's result file is removed
    assert not list(scratch.iterdir())


def test_cad_time_limit_must_be_positive():
    with pytest.raises(InputError, match="time limit"):
        Tessellation(time_limit_s=0.0)
    with pytest.raises(InputError, match="time limit"):
        Tessellation(time_limit_s=math.nan)
    with pytest.raises(InputError, match="time limit"):
        read_cad(Path("x.step"), Tessellation(time_limit_s=-1.0))


def test_simulate_help_names_the_parts_lister(capsys):
    """A CAD lamp needs a material map by part name: simulate's help says where the
    names come from (the no-emitter error says it too, tests/io/test_cad_names.py)."""
    code, out, _ = run_cli(["simulate", "--help"], capsys)
    assert code == 0
    assert "luminaire parts FILE" in " ".join(out.split())
