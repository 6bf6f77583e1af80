"""Visual/optical aim of a lower beam by its cut-off, applied before the photometry.

A visually/optically aimable lower beam (FMVSS No. 108's "VOA" headlamps, as its aiming
paragraphs were read in secondary sources here) is not measured on its mechanical axis:
the tester aims it by the cut-off first, then reads the test points. lightsim does the
same when a rule set's ``[measurement]`` says ``aim = "visual"``:

1. the cut-off is located on the lamp's wall map by a vertical scan
   (:func:`lightsim.render.cutoff.find_cutoff`) on the standard's line: 2.5° left of V-V
   for a "VOL" lamp, 2.0° right of V-V for a "VOR" lamp (for right-hand traffic; mirrored
   for left); its position is the steepest fall of log10 E going up (the maximum
   gradient), and G = log10 E(β) − log10 E(β + 0.1°) across it;
2. the cut-off must be at least ``WIDTH_DEG`` = 2° wide, centred on that line, and level:
   the scans 1° either side of the line must find it within ``INCLINATION_DEG`` = 0.2° of
   the centre's position (S10.18.9.1.3–4 as cited in a transcription of the standard);
   a lamp whose cut-off is not found, not level over that width, or whose G is below
   ``cutoff_gradient_min``, is **not visually aimable**: no aim is applied and the check
   says so;
3. otherwise the lamp is pitched by ``dv = cutoff_v_deg − v_cutoff`` so that its cut-off
   sits at ``cutoff_v_deg`` (VOL 0.4° D, VOR on H unless the set says otherwise); the
   horizontal aim is kept as built, because such a lamp has no horizontal adjustment;
4. every test point is then read on the pitched lamp: the intensity in direction d is the
   built lamp's intensity in direction R⁻¹·d (R: the pitch about the horizontal axis),
   exactly, not as a shift of the screen angles (:func:`pitched`). The permitted re-aim at
   each test point (:mod:`.reaim`) comes on top of this aim.

Parameters
----------
=======================  =====  ==========  ============================================
name                     unit   default     meaning
=======================  =====  ==========  ============================================
``visual_aim``           –      "VOL"       the side the cut-off is scanned on
``SCAN_H_DEG``           deg    VOL 2.5,    distance of the scan line from V-V
                                VOR 2.0
``cutoff_v_deg``         deg    VOL −0.4,   where the aim puts the cut-off (+ up)
                                VOR 0
``cutoff_gradient_min``  1      0.13        least G for the lamp to be visually aimable
``WIDTH_DEG``            deg    2.0         least width of the cut-off, centred on the line
``INCLINATION_DEG``      deg    0.2         largest offset of the cut-off at the width's
                                            ends from its position on the line
``dv_deg``               deg    –           the pitch applied (+ up)
=======================  =====  ==========  ============================================
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lightsim.render.cutoff import find_cutoff

from .conditions import MeasuringConditions

__all__ = ["INCLINATION_DEG", "SCAN_H_DEG", "WIDTH_DEG", "VisualAim", "find_visual_aim",
           "pitch_back", "pitched"]

WIDTH_DEG = 2.0
"""Least width (deg) of the cut-off, centred on the scan line."""
INCLINATION_DEG = 0.2
"""Largest vertical offset (deg) of the cut-off at the width's ends from its centre."""

SCAN_H_DEG = {"VOL": 2.5, "VOR": 2.0}
"""Distance (deg) from V-V of the line a visual aim scans: 2.5° L (VOL), 2.0° R (VOR)."""

_EDGE_Z = 1e-9
"""Smallest forward component kept: directions pitched past the zenith or nadir are read
at its edge (only the rule sets' 10U-90U type of area reaches there)."""


@dataclass(frozen=True)
class VisualAim:
    """The visual aim of a lamp (see the module docstring); JSON-ready via :meth:`to_dict`.

    Attributes
    ----------
    method : {"VOL", "VOR"}
        Where the cut-off was scanned.
    found : bool
        Whether a cut-off was found.
    v_cutoff_deg : float or None
        The cut-off of the lamp as built (deg, + up).
    target_v_deg : float
        Where the aim puts it (deg).
    sharpness_g : float or None
        Its gradient G.
    gradient_min : float
        The least G of a visually aimable lamp.
    ends_v_deg : list of float or None
        The cut-off found 1° either side of the line (None where not found).
    level : bool
        Both ends found within :data:`INCLINATION_DEG` of the centre.
    aimable : bool
        Found, level, and G ≥ ``gradient_min``.
    applied : bool
        Whether the points are read on the aimed lamp.
    dv_deg : float
        The pitch applied (deg, + up); 0 when not applied.
    message : str
        One line for the report.
    """

    method: str
    found: bool
    v_cutoff_deg: float | None
    target_v_deg: float
    sharpness_g: float | None
    gradient_min: float
    ends_v_deg: list[float | None]
    level: bool
    aimable: bool
    applied: bool
    dv_deg: float
    message: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return asdict(self)


def find_visual_aim(lux: ArrayLike, frame: Any, mc: MeasuringConditions,
                    traffic: str = "right", apply: bool = True) -> VisualAim:
    """The aim that puts the lamp's cut-off where ``mc`` asks (see the module docstring).

    Parameters
    ----------
    lux : array_like, shape (H, W)
        The lamp's wall map (lx).
    frame : WallFrame or mapping
        Its wall frame.
    mc : MeasuringConditions
        The rule set's conditions (``visual_aim``, ``cutoff_v_deg``,
        ``cutoff_gradient_min``).
    traffic : {"right", "left"}
        Traffic side; a VOL lamp is scanned on the side away from the kerb step of right-hand
        traffic (left of V-V), mirrored for left-hand traffic.
    apply : bool
        False: report the aim but read the points at the lamp's aim as built.
    """
    # find_cutoff scans left of V-V for "right" and right of it for "left"
    scan_left = (mc.visual_aim == "VOL") == (traffic == "right")
    line = SCAN_H_DEG[mc.visual_aim]
    half = 0.5 * WIDTH_DEG
    res = find_cutoff(lux, frame, "right" if scan_left else "left",
                      scan_h_deg=(line - half, line, line + half),
                      target_v_deg=mc.cutoff_target_deg)
    target = float(mc.cutoff_target_deg)
    side = f"{mc.visual_aim}, scanned {line:g}° {'left' if scan_left else 'right'} of V-V"
    centre = res.scans[1]
    ends = [float(e.v_inflection_deg) if e.found else None for e in (res.scans[0],
                                                                       res.scans[2])]

    def aim(found: bool, v_cut: float | None, g: float | None, level: bool, aimable: bool,
            dv: float, message: str) -> VisualAim:
        return VisualAim(mc.visual_aim, found, v_cut, target, g, mc.cutoff_gradient_min,
                         ends, level, aimable, dv != 0.0 or (aimable and apply), dv, message)

    as_built = "points read at the lamp's aim as built"
    if not centre.found:
        return aim(False, None, None, False, False, 0.0,
                   f"visual/optical aim ({side}): no cut-off ({centre.message}): NOT visually "
                   f"aimable; {as_built}")
    v_cut = float(centre.v_inflection_deg)
    g = float(centre.sharpness_g)
    level = all(e is not None and abs(e - v_cut) <= INCLINATION_DEG + 1e-9 for e in ends)
    where = f"cut-off at {v_cut:+.2f}°, G = {g:.3f}"
    if g < mc.cutoff_gradient_min:
        return aim(True, v_cut, g, level, False, 0.0,
                   f"visual/optical aim ({side}): {where} < {mc.cutoff_gradient_min:g}: NOT "
                   f"visually aimable; {as_built}")
    if not level:
        at = ", ".join("none" if e is None else f"{e:+.2f}°" for e in ends)
        return aim(True, v_cut, g, False, False, 0.0,
                   f"visual/optical aim ({side}): {where}, but not level over "
                   f"{WIDTH_DEG:g}° (1° either side: {at}; at most {INCLINATION_DEG:g}° off): "
                   f"NOT visually aimable; {as_built}")
    dv = target - v_cut
    where = f"{where} ≥ {mc.cutoff_gradient_min:g}, level over {WIDTH_DEG:g}°"
    if not apply:
        return aim(True, v_cut, g, True, True, 0.0,
                   f"visual/optical aim ({side}): {where}; NOT applied ({as_built}; the aim "
                   f"would pitch it {dv:+.2f}°)")
    return aim(True, v_cut, g, True, True, float(dv),
               f"visual/optical aim ({side}): {where}; lamp pitched {dv:+.2f}° to put it at "
               f"{target:+.2f}° (horizontal aim as built)")


def pitch_back(h_deg: ArrayLike, v_deg: ArrayLike, dv_deg: float) -> tuple[NDArray, NDArray]:
    """Wall angles (deg) of the built lamp's direction that a lamp pitched by ``dv_deg``
    (+ up) sends along wall angles (``h_deg``, ``v_deg``): ``R⁻¹·d``, R the pitch about
    the horizontal axis."""
    h = np.radians(np.asarray(h_deg, dtype=float))
    v = np.radians(np.asarray(v_deg, dtype=float))
    x, y, z = np.tan(h), np.tan(v), np.ones_like(h + v)
    a = np.radians(float(dv_deg))
    y0 = np.cos(a) * y - np.sin(a) * z
    z0 = np.maximum(np.sin(a) * y + np.cos(a) * z, _EDGE_Z)
    return np.degrees(np.arctan2(x, z0)), np.degrees(np.arctan2(y0, z0))


def pitched(intensity: Callable[[NDArray, NDArray], NDArray], dv_deg: float
            ) -> Callable[[NDArray, NDArray], NDArray]:
    """``intensity(h_deg, v_deg)`` (cd, wall angles; any leading set axis) of the lamp
    pitched by ``dv_deg`` (+ up)."""
    if dv_deg == 0.0:
        return intensity

    def aimed(h_deg: NDArray, v_deg: NDArray) -> NDArray:
        return intensity(*pitch_back(h_deg, v_deg, dv_deg))

    return aimed
