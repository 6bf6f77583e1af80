"""The regulations' units on the measuring wall: H/V degrees, metres at 25 m, lux ↔ cd.

UN R112/R149 give test points as angles from H-V (U/D = up/down, L/R = left/right) on a
screen 25 m ahead and limits in candela. The wall frame and the conversions themselves are
the engine's (:mod:`lightsim.wall`: one frame for the pixel grid, metres, degrees and
lux ↔ cd, used by the renderer, the plots and these rule sets alike); this module names
them for the rule-set code and keeps the old import path working.

=================  ======  =========  ============================================
name               unit    default    meaning
=================  ======  =========  ============================================
DEFAULT_DISTANCE_M m       25.0       the regulations' measuring distance
=================  ======  =========  ============================================
"""

from __future__ import annotations

from lightsim.wall import (
    DEFAULT_DISTANCE_M,
    WallFrame,
    candela_from_lux,
    deg_from_wall_m,
    lux_from_candela,
    sample_wall,
    wall_m_from_deg,
)

__all__ = [
    "DEFAULT_DISTANCE_M",
    "WallFrame",
    "candela_from_lux",
    "deg_from_wall_m",
    "lux_from_candela",
    "sample_wall",
    "wall_m_from_deg",
]
