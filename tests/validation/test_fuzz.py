"""The input-error promise under fuzzing, and simulate's output set under SIGKILL.

A seeded corpus of mutated GLB/glTF, IES, LDT and photo files is generated here (from
inputs the repository builds or ships) and run through the real command line in a worker
process (:mod:`lightsim.validation.fuzz`): every case must exit 0 with finite, closed
results or exit 2 with exactly one stderr line, no traceback and nothing in ``--out``.
The default run takes a few dozen cases; ``-m slow`` runs the 300-case study (with the
shipped headlight) and 32 kill points.
"""

from __future__ import annotations

import json

import pytest

from lightsim.cli.main import main
from lightsim.validation.fuzz import (
    SIM_OUTPUTS,
    CorpusFiles,
    FuzzCase,
    build_corpus,
    case_argv,
    inspect_output,
    judge,
    kill_during_write,
    kill_study,
    run_fuzz,
    small_scene_glb,
)

from support import run_cli

# half of the default cases are meshes (the loader is the largest surface)
DEFAULT_KINDS = ("glb", "ies", "glb", "ldt", "glb", "photo")


def _failures(report, kinds):
    return [r.describe() for r in report.failures if r.case.kind in kinds]


@pytest.fixture(scope="module")
def default_report(tmp_path_factory):
    return run_fuzz(24, seed=13, kinds=DEFAULT_KINDS, command=main, photons=5000,
                    resolution="32x16", timeout_s=120, workdir=tmp_path_factory.mktemp("fuzz"))


def test_fuzz_meshes_keep_the_promise(default_report):
    glb = [r for r in default_report.results if r.case.kind == "glb"]
    assert len(glb) == 12
    assert not _failures(default_report, {"glb"}), "\n".join(_failures(default_report,
                                                                        {"glb"}))
    # the corpus exercises both outcomes
    assert {r.verdict for r in glb} >= {"ran", "rejected"}


def test_fuzz_photometric_and_photos_keep_the_promise(default_report):
    kinds = {"ies", "ldt", "photo"}
    assert sum(r.case.kind in kinds for r in default_report.results) == 12
    assert not _failures(default_report, kinds), "\n".join(_failures(default_report, kinds))


def test_fuzz_corpus_is_reproducible(tmp_path):
    a, _ = build_corpus(8, 5, tmp_path / "a", kinds=("glb", "ies"))
    b, _ = build_corpus(8, 5, tmp_path / "b", kinds=("glb", "ies"))
    assert [c.data for c in a] == [c.data for c in b]
    assert [c.mutation for c in a] == [c.mutation for c in b]
    c, _ = build_corpus(8, 6, tmp_path / "c", kinds=("glb", "ies"))
    assert [x.data for x in c] != [x.data for x in a]


def test_fuzz_judge_catches_broken_promises(tmp_path):
    """The judge is not a rubber stamp: each broken promise gets its class."""
    case = FuzzCase(0, "glb", "test", "x.glb", b"")
    out = tmp_path / "out"
    out.mkdir()
    assert judge(case, 2, ["lightsim: error: bad"], out) == ("rejected", "")
    assert judge(case, 2, ["Traceback (most recent call last):", "x"], out)[0] == "traceback"
    assert judge(case, 2, ["warn", "lightsim: error: bad"], out)[0] == "lines"
    assert judge(case, 1, ["lightsim: error: bad"], out)[0] == "exit"
    (out / "wall_lux.exr").write_bytes(b"x")
    assert judge(case, 2, ["lightsim: error: bad"], out)[0] == "leftover"
    assert judge(case, 0, [], out)[0] == "incomplete"
    assert judge(case, 0, ["numpy RuntimeWarning"], out)[0] == "stray"


def test_fuzz_command_prints_the_table(tmp_path, capsys):
    code, out, err = run_cli(["fuzz", "2", "--kind", "glb", "--photons", "2000",
                              "--resolution", "16x8", "--json", str(tmp_path / "f.json")],
                             capsys)
    assert code == 0, out + err
    assert "total" in out and "glb" in out
    doc = json.loads((tmp_path / "f.json").read_text())
    assert len(doc["cases"]) == 2 and doc["counts"]["total"]


def test_fuzz_bad_options_are_one_line(capsys):
    code, _, err = run_cli(["fuzz", "0"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err


# -- SIGKILL during the write phase -------------------------------------------------------

def test_sigkill_in_the_write_phase_leaves_a_complete_or_unfinished_set(tmp_path, capsys):
    scene = tmp_path / "scene.glb"
    scene.write_bytes(small_scene_glb())
    first = tmp_path / "first"
    argv = ["simulate", str(scene), "--photons", "5000", "--frame-photons", "5000",
            "--resolution", "32x16", "--quiet"]
    code, _, err = run_cli([*argv, "--out", str(first)], capsys)
    assert code == 0, err
    results = []
    for i, delay in enumerate((0.0, 0.4)):
        out = tmp_path / f"kill{i}"
        out.mkdir()
        for f in first.iterdir():  # a finished run (seed 1) the killed one (seed 2) replaces
            (out / f.name).write_bytes(f.read_bytes())
        results.append(kill_during_write(scene, out, delay, photons=5000, resolution="32x16",
                                         timeout_s=120))
    assert all(r.ok for r in results), [r.problems for r in results]
    assert all(r.state in ("complete", "unfinished") for r in results)
    # the next run into a killed folder cleans up, says so if there was anything, finishes
    out = tmp_path / "kill0"
    code, _, err = run_cli([*argv, "--seed", "3", "--out", str(out)], capsys)
    assert code == 0, err
    assert all(ln.startswith("lightsim: warning: ") for ln in err.splitlines() if ln.strip())
    state, top, problems = inspect_output(out)
    assert state == "complete" and not problems and set(top) == SIM_OUTPUTS
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    assert json.loads((out / "summary.json").read_text())["seed"] == 3


@pytest.mark.slow
def test_fuzz_study(tmp_path):
    """The 300-case study: all kinds, the shipped headlight too."""
    report = run_fuzz(300, seed=1, command=main, headlight=True, workdir=tmp_path)
    print("\n".join(report.table()))
    assert not report.failures, "\n".join(r.describe() for r in report.failures)


@pytest.mark.slow
def test_kill_study(tmp_path):
    results = kill_study(32, tmp_path)
    states = [r.state for r in results]
    print({s: states.count(s) for s in set(states)},
          sum(r.in_write_phase for r in results), "kills in the write phase")
    assert all(r.ok for r in results), [(r.delay_s, r.problems) for r in results if not r.ok]


def test_fuzz_new_kinds_keep_the_promise(tmp_path):
    """Material maps, TM-25 and Zemax ray files, --points strings and the view's
    state.json: each case exits 0 with closed results or 2 with one line."""
    kinds = ("materials", "tm25", "zemax", "points", "state")
    report = run_fuzz(10, seed=3, kinds=kinds, command=main, photons=5000,
                      resolution="32x16", timeout_s=240, workdir=tmp_path)
    assert len(report.results) == 10
    assert not report.failures, "\n".join(r.describe() for r in report.failures)
    assert {r.verdict for r in report.results} >= {"ran", "rejected"}


def test_fuzz_corpus_of_every_kind_is_built(tmp_path):
    cases, files = build_corpus(12, 2, tmp_path, kinds=("tm25", "zemax", "points",
                                                        "materials", "state", "ws"))
    assert [c.kind for c in cases[:6]] == ["tm25", "zemax", "points", "materials",
                                          "state", "ws"]
    assert files.lamp.is_file() and files.photo.is_file() and files.sim.is_dir()
    assert all(c.data for c in cases if c.kind != "points")


def test_cad_cases_give_the_reader_its_own_limit(tmp_path):
    """A STEP/IGES case's reader is stopped (one line, exit 2) well within the case's own
    time limit, so a file that keeps OpenCASCADE reading is judged, not timed out."""
    case = FuzzCase(0, "step", "test", "x.step", b"")
    files = CorpusFiles(tmp_path, cad_maps={"step": tmp_path / "m.toml"})
    argv = case_argv(case, tmp_path / "x.step", tmp_path / "out", files, 1000, "16x8",
                     cad_time_limit_s=90.0)
    assert argv[argv.index("--cad-time-limit") + 1] == "90"
    assert argv[:2] == ["simulate", str(tmp_path / "x.step")]
