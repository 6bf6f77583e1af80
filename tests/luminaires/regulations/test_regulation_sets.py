"""`--regulation a,b`: several rule sets checked in one run, each as if run alone."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lightsim.cli.main import main

LOWBEAM = Path(__file__).parents[3] / "luminaires" / "examples" / "lowbeam.glb"
COMMON = ["--photons", "100000", "--frame-photons", "50000", "--resolution", "160x64",
          "--aim", "--quiet", "--seed", "3"]


def _run(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def _values(table):
    return {r["name"]: (r["value_cd"], tuple(r["interval_cd"]), r["verdict"])
            for r in table["results"]}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    both = tmp_path_factory.mktemp("both")
    alone = {rs: tmp_path_factory.mktemp(rs) for rs in ("r112-b-passing", "r149-b-passing")}
    for out, rs in [(both, "r112-b-passing,r149-b-passing"),
                    *((o, rs) for rs, o in alone.items())]:
        with pytest.raises(SystemExit) as exc:
            main(["simulate", str(LOWBEAM), *COMMON, "--regulation", rs, "--out", str(out)])
        assert exc.value.code == 0
    return both, alone


def test_each_set_equals_its_own_run(runs):
    both, alone = runs
    s = json.loads((both / "summary.json").read_text())
    assert [k for k in s if k.startswith("regulation")] == ["regulation",
                                                            "regulation:r149-b-passing"]
    first = json.loads((alone["r112-b-passing"] / "summary.json").read_text())["regulation"]
    second = json.loads((alone["r149-b-passing"] / "summary.json").read_text())["regulation"]
    assert s["regulation"]["ruleset"] == "r112-b-passing"
    assert s["regulation:r149-b-passing"]["ruleset"] == "r149-b-passing"
    # the same photons (seed) counted in each set's own apertures: identical tables
    assert _values(s["regulation"]) == _values(first)
    assert _values(s["regulation:r149-b-passing"]) == _values(second)
    assert (both / "probes.npz").exists() and (both / "probes-r149-b-passing.npz").exists()


def test_report_rechecks_every_set(runs, capsys):
    both, _ = runs
    before = json.loads((both / "summary.json").read_text())
    code, out, err = _run(["report", str(both)], capsys)
    assert code == 0, err
    assert "r112-b-passing" in out and "r149-b-passing" in out
    after = json.loads((both / "summary.json").read_text())
    for key in ("regulation", "regulation:r149-b-passing"):
        assert _values(after[key]) == _values(before[key])
    code, out, err = _run(["report", str(both), "--regulation", "r149-b-passing"], capsys)
    assert code == 0 and "r149-b-passing" in out and "r112-b-passing (" not in out


@pytest.mark.parametrize("value, text", [("r112-b-passing,,r149-b-passing", "empty"),
                                         ("r112-b-passing,nope", "unknown rule set 'nope'")])
def test_bad_lists_get_one_line(value, text, tmp_path, capsys):
    out = tmp_path / "o"
    code, _, err = _run(["simulate", str(LOWBEAM), "--photons", "1000", "--regulation",
                         value, "--out", str(out)], capsys)
    assert code == 2 and text in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
