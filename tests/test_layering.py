"""The house's import rules, checked on the source with :mod:`ast`.

* The engine (``lightsim/``) never imports ``luminaires/``, ``validation/`` or ``cli/``;
  the four folders import one way: ``lightsim`` ← ``luminaires`` ← ``validation`` ← ``cli``.
* No import cycle between modules, counting imports inside functions too.
* Imports sit at the top of a module; inside a function only for the heavy or optional
  libraries in :data:`LAZY_OK` (each loads in 0.1–1.3 s and only some commands need it).
* No private name (``_x``) of one module is imported by another.

pyproject maps the four folders onto one namespace (``[tool.setuptools] package-dir``:
``lightsim.cli`` = ``cli/``, ``lightsim.luminaires`` = ``luminaires/``, …), so an import
can be spelt absolutely (``lightsim.luminaires.x``), relatively (``from ..luminaires import
x``), by the folder name (``import luminaires``) or as ``importlib.import_module("…")``
with a literal name; every spelling is resolved.
"""

from __future__ import annotations

import ast
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENGINE = "lightsim"
#: the folders' order: a folder may import those before it, never those after it
ORDER = ("lightsim", "lightsim.luminaires", "lightsim.validation", "lightsim.cli")
#: libraries a function may import where it needs them: optional extras (OpenCASCADE,
#: Mitsuba, the web stack, Playwright, MkDocs, the photometric reference readers) and heavy
#: ones only some commands or inputs use (Ray 0.6 s, matplotlib 0.3–0.7 s, OpenCV, LibRaw,
#: scipy.optimize 0.6 s, trimesh 0.8 s: only OBJ/STL/PLY scenes, scipy.spatial: only
#: runs with registered estimate points)
LAZY_OK = ("ray", "matplotlib", "OCP", "cascadio", "mitsuba", "drjit", "starlette", "uvicorn",
           "websockets", "playwright", "cv2", "rawpy", "scipy.optimize", "scipy.spatial",
           "mkdocs",
           "photompy", "eulumdat", "trimesh")


@dataclass(frozen=True)
class Import:
    """One import statement (or ``import_module`` call) of a module."""

    module: str          # the importing module
    line: int
    target: str          # the absolute name imported (module, or module.attribute)
    names: tuple[str, ...]  # the names taken from it (``from x import a, b``)
    in_function: bool
    base: str            # the module the names come from
    by_name: bool = False  # ``importlib.import_module("…")``: a plug-in loaded by name


def package_dirs() -> dict[str, Path]:
    """Installed package name → folder, from pyproject's package-dir."""
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    return {pkg: ROOT / folder for pkg, folder in cfg["tool"]["setuptools"]["package-dir"].items()}


def modules(dirs: dict[str, Path] | None = None) -> dict[str, Path]:
    """Every module of the four folders: absolute name → file."""
    dirs = package_dirs() if dirs is None else dirs
    out = {}
    for pkg, folder in dirs.items():
        for path in sorted(folder.rglob("*.py")):
            rel = path.relative_to(folder).with_suffix("")
            parts = [*pkg.split("."), *rel.parts]
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def _folder_spelling(dirs: dict[str, Path]) -> dict[str, str]:
    """``import luminaires`` → ``lightsim.luminaires`` (a folder name used as a package)."""
    return {folder.name: pkg for pkg, folder in dirs.items() if pkg != ENGINE}


def imports(name: str, path: Path, folders: dict[str, str]) -> Iterator[Import]:
    """Every import of the module ``name`` stored at ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    stack: list[tuple[ast.AST, bool]] = [(tree, False)]
    while stack:
        node, in_fn = stack.pop()
        here = in_fn or isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)
        if isinstance(node, ast.Import):
            for a in node.names:
                yield Import(name, node.lineno, _spell(a.name, folders), (), in_fn,
                             _spell(a.name, folders))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                parts = parts[:len(parts) - node.level + 1]
                base = ".".join(parts + ([node.module] if node.module else []))
            else:
                base = _spell(node.module or "", folders)
            names = tuple(a.name for a in node.names)
            yield Import(name, node.lineno, base, names, in_fn, base)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute | ast.Name)
              and (getattr(node.func, "attr", None) or getattr(node.func, "id", None))
              in ("import_module", "__import__")
              and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)):
            target = _spell(node.args[0].value, folders)
            yield Import(name, node.lineno, target, (), in_fn, target, by_name=True)
        for child in ast.iter_child_nodes(node):
            stack.append((child, here))


def _spell(name: str, folders: dict[str, str]) -> str:
    top, _, rest = name.partition(".")
    return folders[top] + ("." + rest if rest else "") if top in folders else name


def all_imports(dirs: dict[str, Path] | None = None) -> list[Import]:
    dirs = package_dirs() if dirs is None else dirs
    folders = _folder_spelling(dirs)
    return [imp for name, path in modules(dirs).items()
            for imp in imports(name, path, folders)]


def folder_of(module: str) -> str:
    """The folder package a module belongs to (the longest of :data:`ORDER` it starts with)."""
    best = ENGINE
    for f in ORDER:
        if (module == f or module.startswith(f + ".")) and len(f) > len(best):
            best = f
    return best


def edges(imps: list[Import], mods: dict[str, Path]) -> dict[str, set[str]]:
    """Module → the project modules it imports (a package's ``from p import m`` is p.m)."""
    out: dict[str, set[str]] = {m: set() for m in mods}
    for imp in imps:
        targets = [f"{imp.base}.{n}" for n in imp.names if f"{imp.base}.{n}" in mods]
        if len(targets) < len(imp.names) or not imp.names:
            targets.append(imp.base)
        for t in targets:
            while t and t not in mods:
                t = t.rpartition(".")[0]
            if t and t != imp.module:
                out[imp.module].add(t)
    return out


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in graph:
                    continue
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        found.append(sorted(comp))
    return found


# -- the rules --------------------------------------------------------------------------------
def test_folders_import_one_way():
    bad = []
    for imp in all_imports():
        src, dst = folder_of(imp.module), folder_of(imp.base)
        if dst in ORDER and ORDER.index(dst) > ORDER.index(src):
            bad.append(f"{imp.module}:{imp.line} ({src}) imports {imp.base} ({dst})")
    assert not bad, "folders import one way (lightsim ← luminaires ← validation ← cli):\n" + \
        "\n".join(bad)


def test_no_import_cycles():
    mods = modules()
    found = cycles(edges(all_imports(), mods))
    assert not found, "import cycles:\n" + "\n".join(" ↔ ".join(c) for c in found)


def _lazy_ok(target: str) -> bool:
    return any(target == m or target.startswith(m + ".") for m in LAZY_OK)


def test_imports_at_the_top():
    bad = [f"{i.module}:{i.line} imports {i.base} inside a function"
           for i in all_imports() if i.in_function and not _lazy_ok(i.base)
           and not i.by_name]  # plug-ins and the command group's commands, loaded by name
    assert not bad, ("imports belong at the top of the module (inside a function only for "
                     f"{', '.join(LAZY_OK)}):\n" + "\n".join(bad))


def test_no_private_names_across_modules():
    mods = modules()
    bad = []
    for imp in all_imports():
        if not imp.base.startswith(ENGINE):
            continue
        for n in imp.names:
            if n.startswith("_") and not n.startswith("__") and f"{imp.base}.{n}" not in mods:
                bad.append(f"{imp.module}:{imp.line} imports {imp.base}.{n}")
    assert not bad, "private names imported across modules:\n" + "\n".join(bad)


# -- the checker sees what it must ------------------------------------------------------------
def _tree(tmp_path: Path, files: dict[str, str]) -> dict[str, Path]:
    dirs = {"lightsim": tmp_path / "lightsim", "lightsim.luminaires": tmp_path / "luminaires"}
    for rel, text in files.items():
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    for d in dirs.values():
        d.mkdir(exist_ok=True)
        (d / "__init__.py").touch()
    return dirs


@pytest.mark.parametrize("source, expected", [
    ("from lightsim.luminaires.regulations import units\n", "lightsim.luminaires.regulations"),
    ("def f():\n    import lightsim.luminaires.x\n", "lightsim.luminaires.x"),
    ("from .. import luminaires\n", "lightsim"),
    ("import luminaires.photometric\n", "lightsim.luminaires.photometric"),
    ("import importlib\nimportlib.import_module('lightsim.luminaires.y')\n",
     "lightsim.luminaires.y"),
])
def test_every_spelling_is_resolved(tmp_path, source, expected):
    dirs = _tree(tmp_path, {"lightsim/render/__init__.py": "", "lightsim/render/x.py": source})
    got = [i.base for i in all_imports(dirs)]
    assert expected in got, got


def test_a_cycle_through_a_function_import_is_found(tmp_path):
    dirs = _tree(tmp_path, {"lightsim/a.py": "from lightsim import b\n",
                            "lightsim/b.py": "def f():\n    from lightsim.a import g\n"})
    found = cycles(edges(all_imports(dirs), modules(dirs)))
    assert found == [["lightsim.a", "lightsim.b"]]
    assert any(i.in_function for i in all_imports(dirs))


def test_a_clean_tree_has_no_cycle(tmp_path):
    dirs = _tree(tmp_path, {"lightsim/a.py": "import numpy\nfrom lightsim import b\n",
                            "lightsim/b.py": "import math\n"})
    assert cycles(edges(all_imports(dirs), modules(dirs))) == []
