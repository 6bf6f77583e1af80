"""The hand-written package list in pyproject.toml matches the folders.

pyproject maps the four top-level folders onto the one ``lightsim`` namespace
(``[tool.setuptools] package-dir``) and therefore lists every package by hand: a new
subpackage that is not listed would be missing from a wheel (``pip install .``) while
still importing from a checkout. Every folder holding an ``__init__.py`` under a mapped
folder must be listed under its installed name, and every listed package must exist.
"""

from __future__ import annotations

import importlib.util
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _setuptools() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def folder_packages() -> dict[str, Path]:
    """Installed package name → folder, for every folder with an ``__init__.py``."""
    mapping = _setuptools()["package-dir"]
    out: dict[str, Path] = {}
    for pkg, folder in mapping.items():
        base = ROOT / folder
        nested = {other for other, f in mapping.items() if other != pkg
                  and (ROOT / f).resolve().is_relative_to(base.resolve())}
        for init in sorted(base.rglob("__init__.py")):
            rel = init.parent.relative_to(base)
            if "__pycache__" in rel.parts or any(p.startswith(".") for p in rel.parts):
                continue
            name = ".".join([pkg, *rel.parts])
            if not any(name == n or name.startswith(n + ".") for n in nested):
                out[name] = init.parent
    return out


def test_every_package_folder_is_listed():
    listed = set(_setuptools()["packages"])
    found = folder_packages()
    missing = sorted(set(found) - listed)
    assert not missing, f"add to [tool.setuptools] packages in pyproject.toml: {missing}"


def test_every_listed_package_exists():
    found = folder_packages()
    stale = sorted(set(_setuptools()["packages"]) - set(found))
    assert not stale, f"listed in pyproject.toml but no folder with __init__.py: {stale}"


def test_listed_packages_import_from_the_install():
    """The installed (editable) lightsim resolves every listed package to its folder."""
    found = folder_packages()
    for name in _setuptools()["packages"]:
        spec = importlib.util.find_spec(name)
        assert spec is not None and spec.submodule_search_locations, name
        locations = {Path(p).resolve() for p in spec.submodule_search_locations}
        assert found[name].resolve() in locations, (name, locations)
