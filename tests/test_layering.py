"""Imports point one way: the engine (``lightsim/``) never imports ``luminaires/``,
``validation/`` or ``cli/``.

pyproject maps the four folders onto one namespace (``[tool.setuptools] package-dir``:
``lightsim.cli`` = ``cli/``, ``lightsim.luminaires`` = ``luminaires/``, …), so a forbidden
import can be spelt absolutely (``lightsim.luminaires.x``), relatively from the engine's
own top (``from .luminaires import x``, ``from . import cli``) or by the folder name
(``import luminaires``). Every module under ``lightsim/`` is parsed with :mod:`ast`,
including imports inside functions and ``importlib.import_module("…")`` calls with a
literal name.
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENGINE = "lightsim"
FORBIDDEN = ("lightsim.luminaires", "lightsim.validation", "lightsim.cli")

def _engine_dir() -> Path:
    """The folder installed as ``lightsim`` (from pyproject's package-dir)."""
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return ROOT / cfg["tool"]["setuptools"]["package-dir"][ENGINE]


def _folder_names() -> dict[str, str]:
    """Top-level folder → the package it installs as, for the forbidden packages."""
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    dirs = cfg["tool"]["setuptools"]["package-dir"]
    return {Path(folder).parts[0]: pkg for pkg, folder in dirs.items() if pkg in FORBIDDEN}


def _module_name(path: Path, engine: Path) -> str:
    rel = path.relative_to(engine).with_suffix("")
    parts = [ENGINE, *rel.parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _resolve(module: str, node: ast.ImportFrom) -> list[str]:
    """Absolute names an ``ImportFrom`` in ``module`` refers to (module and module.name)."""
    if node.level == 0:
        base = node.module or ""
    else:
        pkg = module.split(".")  # "a.b.c": level 1 is package a.b, level 2 is a
        base = ".".join(pkg[:len(pkg) - node.level] + ([node.module] if node.module else []))
    return [base] + [f"{base}.{a.name}" for a in node.names]


def imported_names(path: Path, engine: Path, folders: dict[str, str]
                   ) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file at ``path``; ``folders``
    maps folder spellings to package names."""
    module = _module_name(path, engine)
    if path.name == "__init__.py":
        module += ".__init__"  # so that level-1 relative imports resolve to the package
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = _resolve(module, node)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute | ast.Name)
              and (getattr(node.func, "attr", None) or getattr(node.func, "id", None))
              in ("import_module", "__import__")
              and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)):
            names = [node.args[0].value]
        for name in names:
            top = name.split(".")[0]
            if top in folders:  # the folder spelling: `import luminaires.x`
                name = folders[top] + name[len(top):]
            out.append((node.lineno, name))
    return out


def violations(engine: Path, folders: dict[str, str] | None = None
               ) -> list[tuple[str, int, str]]:
    """(file, line, name) of every forbidden import under ``engine``."""
    folders = _folder_names() if folders is None else folders
    found = []
    for path in sorted(engine.rglob("*.py")):
        rel = path.relative_to(engine.parent).as_posix()
        for line, name in imported_names(path, engine, folders):
            if any(name == f or name.startswith(f + ".") for f in FORBIDDEN):
                found.append((rel, line, name))
    return found


def test_engine_imports_point_one_way():
    engine = _engine_dir()
    assert (engine / "__init__.py").is_file()
    bad = [f"{f}:{line}: imports {name}" for f, line, name in violations(engine)]
    assert not bad, "the engine must not import luminaires/validation/cli:\n" + "\n".join(bad)


@pytest.mark.parametrize("source, expected", [
    ("from lightsim.luminaires.regulations import units\n", "lightsim.luminaires.regulations"),
    ("def f():\n    import lightsim.cli.main\n", "lightsim.cli.main"),
    ("from .. import validation\n", "lightsim.validation"),
    ("from ..luminaires import bulbs\n", "lightsim.luminaires"),
    ("import luminaires.photometric\n", "lightsim.luminaires.photometric"),
    ("import importlib\nimportlib.import_module('lightsim.cli.view')\n", "lightsim.cli.view"),
])
def test_every_spelling_is_caught(tmp_path, source, expected):
    """The checker sees absolute, relative, folder and importlib spellings, in functions."""
    engine = tmp_path / "lightsim"
    (engine / "render").mkdir(parents=True)
    (engine / "__init__.py").write_text("")
    (engine / "render" / "__init__.py").write_text("")
    (engine / "render" / "x.py").write_text(source)
    names = [n for _, _, n in violations(engine, _folder_names())]
    assert any(n == expected or n.startswith(expected + ".") for n in names), names


def test_clean_module_passes(tmp_path):
    engine = tmp_path / "lightsim"
    engine.mkdir()
    (engine / "__init__.py").write_text("")
    (engine / "ok.py").write_text("import numpy\nfrom lightsim.wall import WallFrame\n"
                                  "from . import wall\n")
    assert violations(engine) == []
