"""The emitter protocol: what the tracer asks of a light source.

An emitter turns sample points into photons. Each photon carries the same share Φ/N of
the emitter's flux Φ (the tracer sets the powers); the emitter only decides where photons
start and where they go, with the density of its own emission, so every emitter is
sampled *exactly*, never by rejection or weights.

==============  =====  =========  =======================================================
member          unit   shape      meaning
==============  =====  =========  =======================================================
``flux_lm``     lm     –          luminous flux Φ of the source
``sample(u)``   –      (n, k)     sample points in [0, 1); k ≥ 2 (the dimensions a source
                                  uses: see its module); returns origins (n, 3) in m and
                                  unit directions (n, 3), world axes (+Z ahead, +Y up)
``describe()``  –      –          one line for ``--explain`` and reports
==============  =====  =========  =======================================================

Sample points must be used so that photon i depends on row i only (the tracer emits in
chunks, in threads, and a lost set is replayed from its indices).

The emitters in the core: :mod:`~lightsim.emitters.mesh` (emissive triangles: filaments,
LEDs modelled as meshes, the sky), :mod:`~lightsim.emitters.goniometric` (a point source
with a measured intensity table), :mod:`~lightsim.emitters.rayfile` (a TM-25 or Zemax ray
file); :mod:`~lightsim.emitters.mixture` draws from several by flux. File formats and bulb
catalogues live in ``lightsim.luminaires``, which builds these objects
(:mod:`~lightsim.emitters.registry`).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Emitter(Protocol):
    """A light source the tracer can sample (see the module docstring)."""

    flux_lm: float

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins (n, 3) m and unit directions (n, 3) for sample points u (n, k)."""
        ...

    def describe(self) -> str:
        """One line naming the source and its flux."""
        ...
