"""``docs/make_benchmarks.py --only NAME`` replaces that benchmark's section of the page and
nothing else."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _make_benchmarks():
    spec = importlib.util.spec_from_file_location("make_benchmarks",
                                                  ROOT / "docs" / "make_benchmarks.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("make_benchmarks", mod)  # its dataclasses look their module up
    spec.loader.exec_module(sys.modules["make_benchmarks"])
    return sys.modules["make_benchmarks"]


PAGE = """# Benchmarks

- **generated**: then

## tracer

old tracer table

## memory

old memory table

## peer

old peer table
"""


def test_only_replaces_the_named_sections() -> None:
    mb = _make_benchmarks()
    new = mb.replace_sections(PAGE, {"memory": "## memory\n\nnew memory table\n"})
    assert new == PAGE.replace("old memory table", "new memory table")
    last = mb.replace_sections(PAGE, {"peer": "## peer\n\nnew peer table\n"})
    assert last == PAGE.replace("old peer table", "new peer table")
    with pytest.raises(SystemExit, match="no section road"):
        mb.replace_sections(PAGE, {"road": "## road\n\nx\n"})


def test_every_benchmark_has_a_section_on_the_page() -> None:
    mb = _make_benchmarks()
    page = (ROOT / "docs" / "benchmarks.md").read_text(encoding="utf-8")
    for bench in mb.BENCHES:
        assert f"\n## {bench.name}\n" in page, bench.name
