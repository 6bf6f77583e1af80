"""What ``lightsim.luminaires`` gives the core's emitter registry: file readers, bulbs.

Registered on import of ``lightsim.luminaires`` (see :mod:`lightsim.emitters.registry`):
IES LM-63 and EULUMDAT files become goniometric point sources, bulb presets (H1, H4, H7,
…) become filament meshes with the bulb's flux.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lightsim.emitters.registry import register_filament_factory, register_photometric_reader
from lightsim.luminaires.bulbs import get_bulb
from lightsim.luminaires.filament import filament_mesh
from lightsim.luminaires.photometric import read_photometric


def read_photometric_file(path: Any, lamp_set: int | None = None) -> Any:
    """An IES or EULUMDAT file as a grid (its ``.table`` is the core's polar table)."""
    return read_photometric(path, lamp_set=lamp_set)


def bulb_filament(bulb: str, at: np.ndarray, axis: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, float, str]:
    """The filament mesh (m) of a bulb preset at ``at`` along unit ``axis``, its flux (lm)
    and name."""
    spec = get_bulb(bulb)
    verts, faces = filament_mesh(spec.filament_length_m, spec.filament_diameter_m, at, axis)
    return np.asarray(verts, float), np.asarray(faces, np.int64), float(spec.flux_lm), spec.name


def register() -> None:
    register_photometric_reader((".ies", ".ldt"), read_photometric_file)
    register_filament_factory(bulb_filament)


register()
