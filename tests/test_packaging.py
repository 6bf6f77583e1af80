"""The hand-written package list in pyproject.toml matches the folders that hold code.

pyproject maps the design card's top-level folders (``lightsim/``, ``cli/``,
``luminaires/``, ``validation/``) onto one ``lightsim`` namespace, so setuptools cannot
discover subpackages by itself: a folder with an ``__init__.py`` that is missing from the
list would be left out of a wheel (and of a non-editable install) without any error.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def _packages_on_disk(package_dir: dict[str, str]) -> set[str]:
    found: set[str] = set()
    for name, folder in package_dir.items():
        base = ROOT / folder
        for init in base.rglob("__init__.py"):
            rel = init.parent.relative_to(base)
            if any(part.startswith(".") or part == "__pycache__" for part in rel.parts):
                continue
            found.add(".".join((name, *rel.parts)) if rel.parts else name)
    return found


def test_package_list_matches_folders() -> None:
    setup = _pyproject()["tool"]["setuptools"]
    listed = set(setup["packages"])
    on_disk = _packages_on_disk(setup["package-dir"])
    missing, extra = on_disk - listed, listed - on_disk
    assert not missing, f"folders with __init__.py missing from pyproject: {sorted(missing)}"
    assert not extra, f"pyproject lists packages with no folder: {sorted(extra)}"


def test_console_script_points_at_the_cli() -> None:
    scripts = _pyproject()["project"]["scripts"]
    assert scripts["lightsim"] == "lightsim.cli.main:main"
    from lightsim.cli.main import main

    assert callable(main)
