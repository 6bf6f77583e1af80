"""A rule set's measuring conditions: the ``[measurement]`` table and what it asks of a run.

Most rule sets are a list of test points on the 25 m screen. Some regulations add rules
about *how* the points are measured; FMVSS No. 108 (49 CFR 571.108) is the example (its
measuring paragraphs S14.2.5 as read in transcriptions here, not in the CFR text itself —
the shipped sets mark them less sure):

* its angles are goniometer angles (left/right in plan view, up/down from the horizontal
  plane), i.e. azimuth H and elevation V; the screen's wall angles of lightsim are
  h = H and v = atan(tan V / cos H) (:func:`wall_angles`);
* a 1/4° re-aim is permitted in any direction at any test point (:mod:`.reaim`);
* the photometer is at least 18.3 m (60 ft) from the lamp;
* mechanically aimed lamps are measured on their own axis; a visually/optically aimed
  lower beam is aimed by its cut-off, which must be sharp enough (a least gradient, 0.13
  as in R112 annex 9 by default);
* the tables are written for right-hand traffic only.

A rule set states these in an optional ``[measurement]`` table (format in ``README.md``
beside this module); :func:`parse_conditions` checks it strictly;
:mod:`.lamp_check` refuses a lamp the conditions do not allow (beam type, traffic side,
test distance) and :func:`refuse_screen_check` a screen check that cannot honour them.
The photometer's aperture is not part of the table (its FMVSS size was not confirmed):
``lightsim check --aperture DEG`` averages every reading over a disc of that diameter.

Parameters
----------
=======================  =====  ==========  ==============================================
key                      unit   default     meaning
=======================  =====  ==========  ==============================================
``angles``               –      "screen"    "screen" (wall angles) or "azimuth-elevation"
                                            (goniometer H, V; converted to wall angles)
``reaim_deg``            deg    0           permitted re-aim at every test point
``min_distance_m``       m      0           the photometer's least distance
``aim``                  –      "screen"    "screen" (as the run is, or ``--aim``),
                                            "mechanical" (the lamp's axis, no aim) or
                                            "visual" (by the cut-off)
``beam``                 –      none        "lower" or "upper": the lamps it applies to
``cutoff_gradient_min``  1      0.13        least cut-off gradient of a visual aim
``mirror``               –      true        false: the set has one traffic side only
``certainty``, ``note``,
``source``                                  as for every rule
=======================  =====  ==========  ==============================================
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lightsim.errors import InputError

__all__ = [
    "AIMS",
    "ANGLES",
    "BEAMS",
    "MeasuringConditions",
    "parse_conditions",
    "refuse_screen_check",
    "wall_angles",
]

ANGLES = ("screen", "azimuth-elevation")
AIMS = ("screen", "mechanical", "visual")
BEAMS = ("lower", "upper")
_KEYS = {"angles", "reaim_deg", "min_distance_m", "aim", "beam",
         "cutoff_gradient_min", "mirror", "certainty", "note", "source"}


@dataclass(frozen=True)
class MeasuringConditions:
    """How a rule set's points are measured (see the module docstring).

    Attributes
    ----------
    angles : {"screen", "azimuth-elevation"}
        The coordinates the rule set's positions are written in.
    reaim_deg : float
        Re-aim permitted at every test point (deg); 0 = none.
    min_distance_m : float
        Least lamp → photometer distance (m).
    aim : {"screen", "mechanical", "visual"}
        How the lamp is aimed before the points are read.
    beam : {"lower", "upper"} or None
        The beams the rule set applies to (None: any).
    cutoff_gradient_min : float
        Least gradient G of the cut-off of a visual aim.
    mirror : bool
        False when the positions may not be mirrored for the other traffic side.
    certainty, note, source : str
        How sure these conditions are and where they come from.
    """

    angles: str = "screen"
    reaim_deg: float = 0.0
    min_distance_m: float = 0.0
    aim: str = "screen"
    beam: str | None = None
    cutoff_gradient_min: float = 0.13
    mirror: bool = True
    certainty: str = "sure"
    note: str = ""
    source: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"angles": self.angles, "reaim_deg": self.reaim_deg,
                "min_distance_m": self.min_distance_m,
                "aim": self.aim,
                "beam": self.beam, "cutoff_gradient_min": self.cutoff_gradient_min,
                "mirror": self.mirror, "certainty": self.certainty, "note": self.note,
                "source": self.source}


def _number(fail, key: str, value: Any, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(
            value) or not low <= value <= high:
        raise fail(f"[measurement]: '{key}' must be a number in [{low:g}, {high:g}], "
                   f"got {value!r}")
    return float(value)


def _choice(fail, key: str, value: Any, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise fail(f"[measurement]: '{key}' must be one of {', '.join(choices)}, got {value!r}")
    return str(value)


def parse_conditions(table: Any, fail, default_source: str) -> MeasuringConditions:
    """Check a rule set's ``[measurement]`` table.

    Parameters
    ----------
    table : mapping
        The table as read from the file.
    fail : callable
        Makes the loader's one-line error from a message (``str -> InputError``).
    default_source : str
        The rule set's ``source`` (used when the table has none).

    Raises
    ------
    InputError
        Through ``fail``: unknown keys, values out of range, a less-sure table without a
        note.
    """
    if not isinstance(table, Mapping):
        raise fail("'measurement' must be a table ([measurement])")
    extra = sorted(set(table) - _KEYS)
    if extra:
        raise fail(f"[measurement]: unknown key(s) {', '.join(extra)} "
                   f"(allowed: {', '.join(sorted(_KEYS))})")
    out: dict[str, Any] = {}
    if "angles" in table:
        out["angles"] = _choice(fail, "angles", table["angles"], ANGLES)
    if "aim" in table:
        out["aim"] = _choice(fail, "aim", table["aim"], AIMS)
    if "beam" in table:
        out["beam"] = _choice(fail, "beam", table["beam"], BEAMS)
    for key, low, high in (("reaim_deg", 0.0, 2.0), ("min_distance_m", 0.0, 1000.0),
                           ("cutoff_gradient_min", 0.0, 5.0)):
        if key in table:
            out[key] = _number(fail, key, table[key], low, high)
    if "mirror" in table:
        if not isinstance(table["mirror"], bool):
            raise fail("[measurement]: 'mirror' must be true or false")
        out["mirror"] = table["mirror"]
    for key in ("certainty", "note", "source"):
        if key in table and not isinstance(table[key], str):
            raise fail(f"[measurement]: '{key}' must be text")
    certainty = table.get("certainty", "sure")
    if certainty not in ("sure", "less-sure"):
        raise fail("[measurement]: 'certainty' must be one of sure, less-sure")
    if certainty == "less-sure" and not table.get("note"):
        raise fail("[measurement]: a 'less-sure' table needs a 'note' saying why")
    return MeasuringConditions(**out, certainty=certainty, note=table.get("note", ""),
                               source=table.get("source", default_source))


def refuse_screen_check(ruleset: Any) -> None:
    """Refuse a rule set whose measuring conditions the screen check (``simulate
    --regulation``: fixed apertures at screen angles) cannot honour — a re-aim, goniometer
    angles or a visual aim — and name ``lightsim check``, which does."""
    mc = getattr(ruleset, "measurement", None)
    if mc is None:
        return
    needs = [what for what, flag in (("a re-aim at every test point", mc.reaim_deg > 0),
                                     ("goniometer angles", mc.angles != "screen"),
                                     ("an aim by the cut-off", mc.aim == "visual")) if flag]
    if needs:
        raise InputError(f"rule set {ruleset.id} is measured with {' and '.join(needs)}: "
                         "simulate with --road (it stores the per-set maps), then "
                         f"lightsim check RUN_DIR --regulation {ruleset.id}")


def wall_angles(h_deg: ArrayLike, v_deg: ArrayLike, angles: str = "screen"
                ) -> tuple[NDArray, NDArray]:
    """Positions in a rule set's ``angles`` → lightsim's wall angles (deg).

    Goniometer angles (azimuth H about the vertical axis, then elevation V) point along
    ``(cos V sin H, sin V, cos V cos H)`` (right, up, ahead); the wall angles of that
    direction are ``h = atan(x/z) = H`` and ``v = atan(y/z) = atan(tan V / cos H)``.
    Screen angles are returned as they are.
    """
    h = np.asarray(h_deg, dtype=float)
    v = np.asarray(v_deg, dtype=float)
    if angles == "screen":
        return h, v
    hr = np.radians(h)
    return h.copy(), np.degrees(np.arctan2(np.tan(np.radians(v)), np.cos(hr)))
