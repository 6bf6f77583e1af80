"""lightsim — photon-mapping simulator of headlight beam patterns in photometric units.

The engine follows Günther, Wald & Slusallek, "Realtime Caustics Using Distributed Photon
Mapping" (EGSR 2004): photons are traced with embree, stored per interleave set in
unbalanced kd-trees, and turned into illuminance (lux) on a measurement wall by exact
k-nearest-neighbour density estimation, interleaved sampling and an O(1) box filter.

Data flows one way: scene → photons → photon maps → images → reports.
"""

__version__ = "0.1.0"
