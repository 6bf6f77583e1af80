"""Where the core finds the readers that turn files and bulb names into emitters.

The core knows no file format of photometry and no bulb catalogue: ``lightsim.luminaires``
holds both and registers them here when it is imported, or when the registry first
needs them, through the ``lightsim.sources`` entry point (:data:`ENTRY_POINT_GROUP`:
the standard plug-in mechanism, so the core names no package of the outer layers). The
scene loader then asks this registry for a reader by file suffix, or for the filament of a bulb, and
builds core emitters (:mod:`~lightsim.emitters.goniometric`, :mod:`~lightsim.emitters.mesh`)
from what they return. A registry rather than an argument threaded through
``load_scene``: its twenty callers (CLI, validation, view, benches) stay unchanged, and
another catalogue can register without touching the core.

=============================  ===========================================================
registered function            returns
=============================  ===========================================================
photometric reader             ``reader(path, lamp_set=None)`` → a grid with ``.table``
                               (:class:`~lightsim.emitters.polar.PolarTable`, cd),
                               ``.total_flux()`` (lm), ``.scaled(f)``, ``.warnings``
filament factory               ``factory(bulb, at (m), axis)`` → (vertices (n, 3) m,
                               faces (m, 3), flux lm, name)
=============================  ===========================================================
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any

from lightsim.errors import InputError

_READERS: dict[str, Callable[..., Any]] = {}
_FILAMENTS: list[Callable[..., tuple]] = []
_PLUGINS_LOADED = False

#: entry-point group of the packages that register readers and catalogues (lightsim's own
#: ``lightsim.luminaires`` declares itself in pyproject.toml); loaded on first need, so a
#: script that calls ``load_scene("lamp.ies")`` without importing them still works
ENTRY_POINT_GROUP = "lightsim.sources"

_HINT = ("no package registered under the 'lightsim.sources' entry point provides it "
         "(is lightsim installed with pip?)")


def _load_plugins() -> None:
    """Call every registered entry point once (each registers its readers/factories)."""
    global _PLUGINS_LOADED
    if _PLUGINS_LOADED:
        return
    _PLUGINS_LOADED = True
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        ep.load()()


def register_photometric_reader(suffixes: tuple[str, ...], reader: Callable[..., Any]) -> None:
    """Use ``reader`` for files ending in any of ``suffixes`` (e.g. ``(".ies",)``)."""
    for s in suffixes:
        _READERS[s.lower()] = reader


def photometric_reader(suffix: str) -> Callable[..., Any]:
    """The reader registered for ``suffix``; InputError (one line) if there is none."""
    if suffix.lower() not in _READERS:
        _load_plugins()
    reader = _READERS.get(suffix.lower())
    if reader is None:
        raise InputError(f"no photometric reader for '{suffix}' files is registered: {_HINT}")
    return reader


def register_filament_factory(factory: Callable[..., tuple]) -> None:
    """Use ``factory`` to build bulb filaments (the last one registered wins)."""
    if factory not in _FILAMENTS:
        _FILAMENTS.append(factory)


def filament_factory() -> Callable[..., tuple]:
    """The registered filament factory; InputError (one line) if there is none."""
    if not _FILAMENTS:
        _load_plugins()
    if not _FILAMENTS:
        raise InputError(f"no bulb catalogue is registered: {_HINT}")
    return _FILAMENTS[-1]
