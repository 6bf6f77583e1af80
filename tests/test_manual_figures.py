"""Every picture the manual shows is made by ``docs/make_figures.py`` from a real run."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _make_figures():
    spec = importlib.util.spec_from_file_location("make_figures", ROOT / "docs" / "make_figures.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("make_figures", mod)  # its dataclasses look their module up
    spec.loader.exec_module(sys.modules["make_figures"])
    mod = sys.modules["make_figures"]
    return mod


def test_every_manual_picture_has_a_run() -> None:
    shown = set()
    for page in (ROOT / "docs").rglob("*.md"):
        shown |= set(re.findall(r"img/([\w.-]+)\.png", page.read_text(encoding="utf-8")))
    made = {p for run in _make_figures().RUNS for p in run.pictures}
    assert "road-right-250" in shown
    assert shown <= made, f"pictures without a run in make_figures.py: {sorted(shown - made)}"


def test_road_run_selected_by_name() -> None:
    mf = _make_figures()
    [(run, keep)] = mf.selected(["road"])
    assert run.name == "road" and keep == ("road-right-250",)
