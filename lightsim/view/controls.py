"""The controls of ``lightsim view``: what an engineer changes while looking.

=====================  ======  ==========  ==============  =================================
control                unit    default     range           meaning
=====================  ======  ==========  ==============  =================================
``filament_x_mm``      mm      0           −5 … 5          filament offset along world X
``filament_y_mm``      mm      0           −5 … 5          … along Y (up)
``filament_z_mm``      mm      0           −5 … 5          … along Z (the lamp's axis)
``filament_tilt_deg``  deg     0           −30 … 30        filament axis tilted about world X
                                                           through the filament centre
``bulb``               –       the file's  bulb presets    replaces the filament (mesh and
                                                           flux) by a preset's, same focus
``flux_lm``            lm      the file's  1 … 10⁵         total emitter flux
``aim_h_deg``          deg     0           −10 … 10        lamp turned right (pattern moves
                                                           to +H)
``aim_v_deg``          deg     0           −5 … 5          lamp tilted up (pattern moves up)
``wall_distance_m``    m       the file's  2 … 100         measuring wall distance; the wall
                                                           keeps its angular size
``k``                  –       64          1 … 1024        photons per kNN estimate
``interleave``         –       4           1 … 8           M (M×M interleave sets)
``frame_photons``      –       20 000      1 000 … 10⁷     photons per frame (all sets)
=====================  ======  ==========  ==============  =================================

The last three change the engine's run configuration: the session is rebuilt (its
photons are discarded anyway, as after every change).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from lightsim.errors import InputError


@dataclass(frozen=True)
class ControlSpec:
    """One numeric control: name, unit, range and slider step (what the page draws)."""

    name: str
    label: str
    unit: str
    lo: float
    hi: float
    step: float
    integer: bool = False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


SPECS: tuple[ControlSpec, ...] = (
    ControlSpec("filament_x_mm", "filament x", "mm", -5.0, 5.0, 0.05),
    ControlSpec("filament_y_mm", "filament y", "mm", -5.0, 5.0, 0.05),
    ControlSpec("filament_z_mm", "filament z", "mm", -5.0, 5.0, 0.05),
    ControlSpec("filament_tilt_deg", "filament tilt", "deg", -30.0, 30.0, 0.5),
    ControlSpec("flux_lm", "flux", "lm", 1.0, 1e5, 10.0),
    ControlSpec("aim_h_deg", "aim H", "deg", -10.0, 10.0, 0.1),
    ControlSpec("aim_v_deg", "aim V", "deg", -5.0, 5.0, 0.05),
    ControlSpec("wall_distance_m", "wall distance", "m", 2.0, 100.0, 0.5),
    ControlSpec("k", "k (kNN)", "", 1, 1024, 1, integer=True),
    ControlSpec("interleave", "interleave M", "", 1, 8, 1, integer=True),
    ControlSpec("frame_photons", "photons / frame", "", 1000, 10_000_000, 1000, integer=True),
)
SPEC_BY_NAME = {s.name: s for s in SPECS}
CONFIG_CONTROLS = ("k", "interleave", "frame_photons")
POSE_CONTROLS = frozenset({"filament_x_mm", "filament_y_mm", "filament_z_mm",
                           "filament_tilt_deg"})  # move the emitters only
AIM_CONTROLS = frozenset({"aim_h_deg", "aim_v_deg"})  # move the wall (or the lamp)


@dataclass(frozen=True)
class Controls:
    """Current values of every control (units in the module docstring)."""

    filament_x_mm: float = 0.0
    filament_y_mm: float = 0.0
    filament_z_mm: float = 0.0
    filament_tilt_deg: float = 0.0
    bulb: str = ""
    flux_lm: float = 1000.0
    aim_h_deg: float = 0.0
    aim_v_deg: float = 0.0
    wall_distance_m: float = 25.0
    k: int = 64
    interleave: int = 4
    frame_photons: int = 20_000

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def changed(self, other: Controls) -> set[str]:
        """Names of the controls whose values differ from ``other``."""
        return {f.name for f in fields(self) if getattr(self, f.name) != getattr(other, f.name)}

    def with_changes(self, changes: dict[str, Any], bulbs: tuple[str, ...] = ()) -> Controls:
        """A copy with ``changes`` applied, each validated.

        Raises
        ------
        InputError
            Unknown control, a value that is not a finite number, out of range, or an
            unknown bulb — one line naming the control (shown on the page).
        """
        if not isinstance(changes, dict):
            raise InputError("changes must be an object of control: value")
        out: dict[str, Any] = {}
        for name, value in changes.items():
            if name == "bulb":
                if not isinstance(value, str) or (bulbs and value not in bulbs):
                    raise InputError(f"unknown bulb {value!r}; known: {', '.join(bulbs)}")
                out[name] = value
                continue
            spec = SPEC_BY_NAME.get(name)
            if spec is None:
                raise InputError(f"unknown control {name!r}")
            out[name] = check_value(spec, value)
        return replace(self, **out)

    @classmethod
    def from_dict(cls, d: dict[str, Any], bulbs: tuple[str, ...] = ()) -> Controls:
        base = cls(bulb=str(d.get("bulb", "")))
        return base.with_changes({k: v for k, v in d.items() if k != "bulb"}, bulbs)


def check_value(spec: ControlSpec, value: Any) -> float | int:
    """``value`` as a number inside the control's range, else :class:`InputError`."""
    if isinstance(value, bool):
        raise InputError(f"{spec.label}: {value!r} is not a number")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{spec.label}: {value!r} is not a number") from None
    if not math.isfinite(x):
        raise InputError(f"{spec.label}: {value!r} is not a finite number")
    if not spec.lo <= x <= spec.hi:
        unit = f" {spec.unit}" if spec.unit else ""
        raise InputError(f"{spec.label}: {x:g}{unit} is outside {spec.lo:g} … {spec.hi:g}{unit}")
    if spec.integer:
        if x != round(x):
            raise InputError(f"{spec.label}: {x:g} is not a whole number")
        return round(x)
    return x
