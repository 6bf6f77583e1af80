"""Build hook: let mkdocstrings find ``lightsim.cli``, ``.luminaires`` and ``.validation``.

The installed package maps four source folders into one namespace (``lightsim/`` is
``lightsim``, ``luminaires/`` is ``lightsim.luminaires`` …, see ``package-dir`` in
``pyproject.toml``). griffe, which reads the sources for the API reference
(``reference/api.md``), looks for sub-packages inside ``lightsim/`` only. For the build,
this hook lays out the package as installed, in a temporary folder of symbolic links
(``lightsim/*`` plus one link per mapped sub-package), and puts that folder first on the
Python handler's search path; it is removed when the build ends.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Any

from mkdocs.plugins import event_priority

import lightsim
import lightsim.cli
import lightsim.luminaires
import lightsim.validation

MAPPED = {"cli": lightsim.cli, "luminaires": lightsim.luminaires,
          "validation": lightsim.validation}
_made: list[Path] = []


def layout(root: Path) -> Path:
    """``root/lightsim``: links to every entry of the engine's folder and to each mapped
    sub-package's folder. Returns ``root``."""
    pkg = root / "lightsim"
    pkg.mkdir()
    for entry in Path(lightsim.__path__[0]).iterdir():
        if entry.name != "__pycache__":
            (pkg / entry.name).symlink_to(entry)
    for name, module in MAPPED.items():
        (pkg / name).symlink_to(Path(module.__path__[0]))
    return root


@event_priority(100)  # before mkdocstrings' own on_config, which starts the handler
def on_config(config: Any, **_: Any) -> Any:
    """mkdocs hook: the linked layout first on mkdocstrings' Python search path."""
    root = layout(Path(tempfile.mkdtemp(prefix="lightsim-api-")))
    _made.append(root)
    plugin = config.plugins.get("mkdocstrings")
    if plugin is not None:
        python = plugin.config.handlers.setdefault("python", {})
        kept = [p for p in python.get("paths", []) if not p.startswith(tempfile.gettempdir())]
        python["paths"] = [str(root), *kept]
    return config


def remove_layouts(**_: Any) -> None:
    """mkdocs hook (after the build, after a failed one, at shutdown): remove the linked
    layouts."""
    while _made:
        shutil.rmtree(_made.pop(), ignore_errors=True)


on_post_build = on_build_error = on_shutdown = remove_layouts
