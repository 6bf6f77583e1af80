"""Luminaires: filament emitters, bulb presets, the parametric headlight, GLB writing.

Modules (imported lazily, so ``lightsim.luminaires.photometric`` and friends stay cheap):

* :mod:`~lightsim.luminaires.gltf_writer` — :class:`GltfMaterial`, :class:`GltfPart`,
  :func:`write_glb`: a small binary glTF 2.0 writer following ``docs/reference/conventions.md``;
* :mod:`~lightsim.luminaires.bulbs` — :data:`BULBS`, :func:`get_bulb`: H1, H3, H4 (driving
  and passing filament), H7 presets with flux sources and stated dimension assumptions;
* :mod:`~lightsim.luminaires.filament` — :func:`filament_mesh`, :func:`filament_part`;
* :mod:`~lightsim.luminaires.headlight` — :func:`build_headlight`, :func:`write_headlight`.

Units: metres and lumens; glTF axes (+Y up, the lamp shines along +Z).
"""

from __future__ import annotations

import importlib
from typing import Any

# the core's emitter registry learns the photometric readers and the bulb catalogue
from lightsim.luminaires import sources as _sources  # noqa: F401

_EXPORTS = {
    "GltfMaterial": "gltf_writer",
    "GltfPart": "gltf_writer",
    "write_glb": "gltf_writer",
    "BULBS": "bulbs",
    "BulbSpec": "bulbs",
    "get_bulb": "bulbs",
    "filament_mesh": "filament",
    "filament_part": "filament",
    "build_headlight": "headlight",
    "write_headlight": "headlight",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)
