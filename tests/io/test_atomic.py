"""Atomic files and output sets: staging, publication order, clean-up after kills."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from lightsim.io.atomic import (
    STAGING_PREFIX,
    OutputSet,
    atomic_path,
    clean_stale,
    unfinished_set,
    write_text,
)


def test_output_set_publishes_marker_last_and_drops_the_old_set(tmp_path, monkeypatch):
    for name, text in (("a.txt", "old a"), ("old-only.txt", "old"), ("summary.json", "old"),
                       ("notes.md", "user file")):
        (tmp_path / name).write_text(text)
    order = []
    real = os.replace

    def spy(src, dst):
        order.append(os.path.basename(dst))
        # while files move, the folder never shows a finished run
        if os.path.basename(dst) != "summary.json":
            assert not (tmp_path / "summary.json").exists()
        real(src, dst)

    with OutputSet(tmp_path, "summary.json", previous={"a.txt", "old-only.txt"}) as out:
        assert out.dir.parent == tmp_path and out.dir.name.startswith(STAGING_PREFIX)
        write_text(out.dir / "summary.json", "new")
        write_text(out.dir / "a.txt", "new a")
        write_text(out.dir / "b.txt", "new b")
        monkeypatch.setattr(os, "replace", spy)
        out.commit()
    monkeypatch.undo()
    assert order == ["a.txt", "b.txt", "summary.json"]
    assert (tmp_path / "a.txt").read_text() == "new a"
    assert (tmp_path / "summary.json").read_text() == "new"
    assert not (tmp_path / "old-only.txt").exists()          # the old set does not mix in
    assert (tmp_path / "notes.md").read_text() == "user file"  # not ours: kept
    assert not list(tmp_path.glob(STAGING_PREFIX + "*"))


def test_output_set_discards_on_error(tmp_path):
    (tmp_path / "summary.json").write_text("old")
    with pytest.raises(RuntimeError), OutputSet(tmp_path) as out:
        write_text(out.dir / "a.txt", "x")
        raise RuntimeError("boom")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]
    assert (tmp_path / "summary.json").read_text() == "old"


def test_clean_stale_removes_dead_writers_only(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f"{STAGING_PREFIX}{dead.pid}-abc"
    stale.mkdir()
    (stale / ".wall_lux.x1.tmp.png").write_bytes(b"")
    live = tmp_path / f"{STAGING_PREFIX}{os.getppid()}-def"  # a running process
    live.mkdir()
    mine = tmp_path / f"{STAGING_PREFIX}{os.getpid()}-ghi"
    mine.mkdir()
    old_tmp = tmp_path / ".isolux.k2j3.tmp.png"
    old_tmp.write_bytes(b"")
    os.utime(old_tmp, (time.time() - 3600, time.time() - 3600))
    new_tmp = tmp_path / ".road.a8.tmp.png"  # a write in progress right now
    new_tmp.write_bytes(b"")
    (tmp_path / "wall_lux.png").write_bytes(b"png")
    notes = clean_stale(tmp_path)
    assert not stale.exists() and live.exists() and mine.exists()
    assert not old_tmp.exists() and new_tmp.exists()
    assert len(notes) == 2 and all(str(tmp_path) in n for n in notes)
    assert unfinished_set(tmp_path, ["wall_lux.png", "summary.json"]) == ["wall_lux.png"]
    (tmp_path / "summary.json").write_text("{}")
    assert unfinished_set(tmp_path, ["wall_lux.png", "summary.json"]) == []
    assert clean_stale(tmp_path / "missing") == []


def test_atomic_path_leaves_nothing_on_error(tmp_path):
    with pytest.raises(ValueError), atomic_path(tmp_path / "x.png") as tmp:
        tmp.write_bytes(b"half")
        raise ValueError
    assert not list(tmp_path.iterdir())


def test_crash_in_the_middle_of_publishing_leaves_an_unfinished_set(tmp_path, monkeypatch):
    """A kill between two moves of the commit: no summary.json, reported, then replaced."""
    for name in ("a.txt", "b.txt", "summary.json"):
        (tmp_path / name).write_text("old")
    real = os.replace
    moves = []

    def dies_after_one(src, dst):
        if moves:
            raise KeyboardInterrupt  # stands for the SIGKILL: nothing after this runs
        moves.append(dst)
        real(src, dst)

    out = OutputSet(tmp_path, previous={"a.txt", "b.txt"})
    for name in ("a.txt", "b.txt", "summary.json"):
        write_text(out.dir / name, "new")
    monkeypatch.setattr(os, "replace", dies_after_one)
    with pytest.raises(KeyboardInterrupt):
        out.commit()
    monkeypatch.undo()
    assert not (tmp_path / "summary.json").exists()  # the folder does not claim a finished run
    assert unfinished_set(tmp_path, ["a.txt", "b.txt", "summary.json"]) == ["a.txt", "b.txt"]
    with OutputSet(tmp_path, previous={"a.txt", "b.txt"}) as again:
        write_text(again.dir / "a.txt", "newer")
        write_text(again.dir / "summary.json", "newer")
        again.commit()
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == [
        "a.txt", "summary.json"]
    assert (tmp_path / "a.txt").read_text() == "newer"
