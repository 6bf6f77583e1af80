"""``lightsim bench verdicts``: both emissions per lamp in one run, side by side."""

from __future__ import annotations

import json

import pytest

from lightsim.errors import InputError
from lightsim.validation.bench.verdicts import bench_verdicts

from support import run_cli


def test_uniform_and_guided_rows_side_by_side(tmp_path, capsys):
    path = tmp_path / "v.json"
    code, out, err = run_cli(["bench", "verdicts", "--lamp", "typeA", "--photons", "400000",
                              "--resolution", "80x32", "--json", str(path)], capsys)
    assert code in (0, None), err
    rows = json.loads(path.read_text())["rows"]
    assert [(r["lamp"], r["emission"]) for r in rows] == [("typeA", "uniform"),
                                                          ("typeA", "guided")]
    for r in rows:
        assert 0 < r["photons"] <= 400_000 and r["seconds"] > 0 and r["looks"] >= 1
        assert r["decided"] == (r["open"] == 0) and len(r["open_rules"]) == r["open"]
    assert rows[0]["ratio"] == 1.0
    assert rows[1]["ratio"] == pytest.approx(rows[1]["seconds"] / rows[0]["seconds"])
    assert "guided" in out and "uniform" in out


def test_unknown_lamp_and_bad_cap_are_refused():
    with pytest.raises(InputError, match="unknown lamp"):
        bench_verdicts(["nolamp"])
    with pytest.raises(InputError, match="photons"):
        bench_verdicts(["typeA"], cap_photons=0)
