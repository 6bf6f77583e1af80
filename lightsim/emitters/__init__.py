"""Light sources behind one interface (:class:`~lightsim.emitters.base.Emitter`).

Modules: ``base`` (the protocol, units), ``mesh`` (emissive triangles), ``goniometric`` (a
point source with an intensity table), ``polar`` (the bilinear polar-web intensity table
and its exact sampler), ``rayfile`` (TM-25 / Zemax ray files), ``mixture`` (several sources
by flux), ``registry`` (readers and bulb catalogues that ``lightsim.luminaires`` registers).
"""

from lightsim.emitters.base import Emitter
from lightsim.emitters.goniometric import GoniometricEmitter
from lightsim.emitters.mesh import EMISSION_MODES, MeshEmitter
from lightsim.emitters.mixture import EmitterMix

__all__ = ["EMISSION_MODES", "Emitter", "EmitterMix", "GoniometricEmitter", "MeshEmitter"]
