"""Halogen bulb presets (UN R37 categories H1, H3, H4, H7) and LED presets as data.

Each preset gives the luminous flux with its source, the filament (coil envelope) size, the
filament position relative to the reflector focus, the filament axis, the glass envelope and
whether the bulb carries a shield cup (H4 passing beam) or an opaque tip cap.

Axes and units follow ``docs/reference/conventions.md``: metres, lumens; lamp axes with +Y up
and the lamp shining along +Z, the reflector focus at the origin of the offsets. "Ahead of the
focus" is +Z (further from the reflector vertex).

Flux sources (UN R37 and published bulb ratings):

* H1: UN R37, 1 550 lm ±15 % at the 13.2 V test voltage (US rating 1 410 lm at 12.8 V).
* H3: UN R37, 1 450 lm ±15 % at 13.2 V.
* H4: 1 650 lm (driving beam) / 1 000 lm (passing beam) at 13.2 V are the *commonly cited*
  values; not verified against the R37 data sheet.
* H7: 1 500 lm, the upper end of the published figures (1 350–1 500 lm), which disagree.

Filament dimensions — ASSUMPTIONS. The R37 data sheets (which define the distance e from the
reference plane to the filament centre, the filament length f and a lateral position box)
were not available from reachable sources. The values below are engineering estimates for
55/60 W halogen coils, chosen to give plausible beams; replace them when the sheets are at
hand:

* coil envelope diameter 1.4 mm (H7: 1.3 mm);
* H1 5.0 mm, H3 5.0 mm (transverse, along X), H4 driving 5.0 mm, H4 passing 4.5 mm,
  H7 4.1 mm long;
* H1/H3/H7 are centred on the focus, on the axis;
* H4 (one bulb, two filaments, both on presets "H4-high" and "H4-low"): the passing
  filament lies entirely ahead of the focus — from 1.25 mm to 5.75 mm, centre 3.5 mm — and
  0.7 mm above the axis, so that all the light the upper reflector half returns goes below
  the horizontal (the "Bilux" principle); its shield cup (:class:`ShieldCupSpec`, Ø 6 mm,
  rims 6° and 21° below the horizontal) shades the lower reflector half. The driving
  filament sits on the axis 0.75 mm behind it, from −4.5 mm to +0.5 mm (centre 2.0 mm
  behind the focus): the focus lies on the driving filament, near its front end. Both
  filaments cannot be centred near the focus in one bulb; a passing filament starting
  further ahead (e.g. behind a driving filament centred exactly on the focus) gives a plain
  paraboloid a passing beam whose hot spot sits 4–5° below the horizontal, which is why the
  focus was put near the front of the driving filament (compared by a mirror-only ray
  trace while building ``luminaires/examples/headlight.glb``);
* glass envelopes: quartz, Ø 11 mm (H4) / Ø 9 mm (others), 0.8 mm wall, hemispherical
  dome whose apex lies 9.5 mm (H4) / 8.5 mm (others) in front of the front filament end, so
  that an opaque tip cap shades only directions that would leave the lamp without
  touching a reflector of the default size.

LED presets (:data:`LEDS`): rows of square 1 mm² dies, each a flat Lambertian emitter,
with 300 lm per die — typical of automotive headlamp LEDs at 1 A (about 95 Mcd/m²),
an assumption rather than one product's data sheet. Used by the LED projector module
(:mod:`lightsim.luminaires.projector`).

Tip caps: UN R37 sheet H7/2 (note 7, as amended by ECE/TRANS/WP.29/2006/81) prescribes an
obscuration covering at least the bulb top down to its cylindrical part; H4 bulbs carry such
a black cap too (assumed here, not checked against sheet H4); H1 and H3 are modelled without.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from lightsim.errors import InputError

__all__ = [
    "BULBS",
    "LEDS",
    "BulbSpec",
    "EnvelopeSpec",
    "LedSpec",
    "ShieldCupSpec",
    "bulb_names",
    "check_flux",
    "get_bulb",
    "get_led",
]

MM = 1e-3  # metres per millimetre


@dataclass(frozen=True)
class EnvelopeSpec:
    """The quartz glass envelope of a bulb.

    Attributes
    ----------
    outer_diameter_m : float
        Outer diameter of the cylindrical part in m.
    wall_m : float
        Wall thickness in m.
    apex_z_m : float
        Position of the dome apex along the lamp axis relative to the focus, in m.
    tip_cap : bool
        Whether the dome carries an opaque black obscuration (tip cap).
    ior : float
        Refractive index of the glass (fused quartz ≈ 1.46 in the visible).
    """

    outer_diameter_m: float
    wall_m: float
    apex_z_m: float
    tip_cap: bool
    ior: float = 1.46


@dataclass(frozen=True)
class ShieldCupSpec:
    """The shield cup under an H4 passing-beam filament.

    The cup is a trough — a cylindrical sheet around an axis parallel to the lamp axis
    through ``centre_m`` — closed by flat end plates. Seen from the front, its cross-section
    is an arc below the filament. The rim on the non-traffic side sits ``rim_drop_deg`` below
    the horizontal through the cup axis, the rim on the traffic side ``step_deg`` lower
    still. The cup thus shades the lower reflector half except a strip next to the horizontal
    — whose light still goes slightly down, because the filament lies above the axis — and,
    on the traffic side, a wedge ``step_deg`` wider whose light is returned upwards on the
    opposite side: the step-up of the cut-off on the traffic side.

    Attributes
    ----------
    centre_m : tuple of 3 float
        Point on the cup axis relative to the focus (the filament centre), in m.
    length_m : float
        Trough length along the lamp axis in m (centred on ``centre_m``).
    radius_m : float
        Radius of the trough sheet in m.
    rim_drop_deg : float
        Angle of the non-traffic rim below the horizontal, in degrees.
    step_deg : float
        Extra drop of the traffic-side rim, in degrees (the 15° of UN R112).
    """

    centre_m: tuple[float, float, float]
    length_m: float
    radius_m: float
    rim_drop_deg: float
    step_deg: float = 15.0


@dataclass(frozen=True)
class BulbSpec:
    """One bulb preset (one lit filament).

    Attributes
    ----------
    name : str
        Preset name (``"H4-low"``); also written to the emitter's ``extras.lightsim.bulb``.
    category : str
        UN R37 category (``"H4"``).
    flux_lm : float
        Objective luminous flux in lm at ``test_voltage_v``.
    flux_source : str
        Where the flux comes from and how sure it is.
    power_w : float
        Rated power in W (at 12 V).
    test_voltage_v : float
        Voltage at which the flux is specified, in V.
    filament_length_m, filament_diameter_m : float
        Coil envelope length and outer diameter in m (assumptions, see module docstring).
    filament_offset_m : tuple of 3 float
        Filament centre relative to the reflector focus in m (lamp axes).
    filament_axis : tuple of 3 float
        Unit vector of the filament axis (axial: ``(0, 0, 1)``).
    envelope : EnvelopeSpec
        Glass envelope.
    shield : ShieldCupSpec or None
        Shield cup, if the bulb has one.
    cap : str
        Lamp cap (IEC 60061 designation).
    """

    name: str
    category: str
    flux_lm: float
    flux_source: str
    power_w: float
    test_voltage_v: float
    filament_length_m: float
    filament_diameter_m: float
    filament_offset_m: tuple[float, float, float]
    filament_axis: tuple[float, float, float]
    envelope: EnvelopeSpec
    shield: ShieldCupSpec | None
    cap: str

    @property
    def shield_cup(self) -> bool:
        """Whether a shield cup is used."""
        return self.shield is not None

    def with_flux(self, flux_lm: float) -> BulbSpec:
        """A copy with another luminous flux (``--flux``), in lm (> 0)."""
        return replace(self, flux_lm=check_flux(flux_lm),
                       flux_source="given by the user (--flux)")


def check_flux(flux_lm: float) -> float:
    """``flux_lm`` as a float luminous flux in lm; :class:`InputError` unless finite and > 0."""
    try:
        flux = float(flux_lm)
    except (TypeError, ValueError):
        flux = math.nan
    if not (math.isfinite(flux) and flux > 0):
        raise InputError(f"luminous flux must be > 0 lm, got {flux_lm!r}")
    return flux


_AXIAL = (0.0, 0.0, 1.0)
_TRANSVERSE = (1.0, 0.0, 0.0)

# --- H4 geometry (assumptions, see module docstring) ------------------------------------
_H4_DRIVING_LENGTH = 5.0 * MM
_H4_PASSING_LENGTH = 4.5 * MM
_H4_GAP = 0.75 * MM  # driving filament front end → passing filament rear end (cup plate)
_H4_PASSING_REAR = 1.25 * MM  # the passing filament starts this far ahead of the focus
_H4_PASSING_Z = _H4_PASSING_REAR + 0.5 * _H4_PASSING_LENGTH  # 3.5 mm
_H4_DRIVING_Z = _H4_PASSING_REAR - _H4_GAP - 0.5 * _H4_DRIVING_LENGTH  # −2.0 mm
_H4_PASSING_Y = 0.7 * MM  # above the axis: upper-half light is returned below H–H
_H4_ENVELOPE = EnvelopeSpec(
    outer_diameter_m=11.0 * MM,
    wall_m=0.8 * MM,
    apex_z_m=_H4_PASSING_Z + 0.5 * _H4_PASSING_LENGTH + 9.5 * MM,
    tip_cap=True,  # H4 bulbs carry a black top cap (assumption, see module docstring)
)
_H4_SHIELD = ShieldCupSpec(
    centre_m=(0.0, _H4_PASSING_Y, _H4_PASSING_Z),
    # overhangs the coil by 0.35 mm at both ends; clears the driving filament by 0.4 mm
    length_m=_H4_PASSING_LENGTH + 0.7 * MM,
    radius_m=3.0 * MM,
    rim_drop_deg=6.0,
)
_H4_DIAMETER = 1.4 * MM

_FLUX_H4 = (
    "commonly cited H4 value (1 650 lm driving / 1 000 lm passing at 13.2 V); "
    "not verified against the UN R37 data sheet"
)


def _h4(name: str, flux_lm: float, power_w: float, length_m: float,
        offset_m: tuple[float, float, float]) -> BulbSpec:
    """One filament of the H4 bulb; both share the envelope and the shield cup (the same
    bulb: the passing beam's cup stays in place for the driving beam)."""
    return BulbSpec(
        name=name,
        category="H4",
        flux_lm=flux_lm,
        flux_source=_FLUX_H4,
        power_w=power_w,
        test_voltage_v=13.2,
        filament_length_m=length_m,
        filament_diameter_m=_H4_DIAMETER,
        filament_offset_m=offset_m,
        filament_axis=_AXIAL,
        envelope=_H4_ENVELOPE,
        shield=_H4_SHIELD,
        cap="P43t",
    )


def _single(
    name: str,
    flux_lm: float,
    flux_source: str,
    length_mm: float,
    diameter_mm: float,
    axis: tuple[float, float, float],
    tip_cap: bool,
    cap: str,
    power_w: float = 55.0,
) -> BulbSpec:
    """A single-filament bulb centred on the focus with a Ø 9 mm envelope."""
    return BulbSpec(
        name=name,
        category=name,
        flux_lm=flux_lm,
        flux_source=flux_source,
        power_w=power_w,
        test_voltage_v=13.2,
        filament_length_m=length_mm * MM,
        filament_diameter_m=diameter_mm * MM,
        filament_offset_m=(0.0, 0.0, 0.0),
        filament_axis=axis,
        envelope=EnvelopeSpec(
            outer_diameter_m=9.0 * MM,
            wall_m=0.8 * MM,
            # a transverse coil reaches only its radius forward
            apex_z_m=(0.5 * length_mm if axis == _AXIAL else 0.5 * diameter_mm) * MM
            + 8.5 * MM,
            tip_cap=tip_cap,
        ),
        shield=None,
        cap=cap,
    )


#: All presets by name.
BULBS: dict[str, BulbSpec] = {
    "H1": _single(
        "H1", 1550.0, "UN R37: 1 550 lm ±15 % at 13.2 V (US rating 1 410 lm at 12.8 V)",
        5.0, 1.4, _AXIAL, tip_cap=False, cap="P14.5s",
    ),
    "H3": _single(
        "H3", 1450.0, "UN R37: 1 450 lm ±15 % at 13.2 V",
        5.0, 1.4, _TRANSVERSE, tip_cap=False, cap="PK22s",
    ),
    "H4-high": _h4("H4-high", 1650.0, 60.0, _H4_DRIVING_LENGTH, (0.0, 0.0, _H4_DRIVING_Z)),
    "H4-low": _h4("H4-low", 1000.0, 55.0, _H4_PASSING_LENGTH,
                  (0.0, _H4_PASSING_Y, _H4_PASSING_Z)),
    "H7": _single(
        "H7", 1500.0,
        "1 500 lm at 13.2 V, the upper end of published values (1 350–1 500 lm)",
        4.1, 1.3, _AXIAL, tip_cap=True, cap="PX26d",
    ),
}  # fmt: skip


def bulb_names() -> list[str]:
    """Names of the presets, in table order."""
    return list(BULBS)


def get_bulb(name: str) -> BulbSpec:
    """The preset called ``name`` (case-insensitive).

    Raises
    ------
    InputError
        Unknown name (the message lists the known ones).
    """
    key = {k.lower(): k for k in BULBS}.get(str(name).strip().lower())
    if key is None:
        raise InputError(f"unknown bulb {name!r}; known bulbs: {', '.join(BULBS)}")
    return BULBS[key]


@dataclass(frozen=True)
class LedSpec:
    """An LED light source: a row of square dies, each a flat Lambertian emitter.

    Attributes
    ----------
    name : str
        Preset name (``"LED-2x1"``); written to each die's ``extras.lightsim.led``.
    dies : int
        Number of dies in the row (along the lamp's X axis).
    die_side_m : float
        Edge of one square die in m.
    pitch_m : float
        Centre distance of neighbouring dies in m.
    flux_lm : float
        Luminous flux of all dies together, in lm (shared equally).
    flux_source : str
        Where the flux comes from and how sure it is.
    """

    name: str
    dies: int
    die_side_m: float
    pitch_m: float
    flux_lm: float
    flux_source: str

    @property
    def luminance_cd_m2(self) -> float:
        """Luminance of the lit dies, L = Φ / (π A), in cd/m² (a Lambertian emitter)."""
        return self.flux_lm / (math.pi * self.dies * self.die_side_m ** 2)

    def with_flux(self, flux_lm: float) -> LedSpec:
        """A copy with another luminous flux, in lm (> 0)."""
        return replace(self, flux_lm=check_flux(flux_lm),
                       flux_source="given by the user (--flux)")


#: LED presets by name. Die sizes and fluxes are typical of automotive headlamp LEDs
#: (1 mm² dies in rows of 1 to 4, 250–300 lm per die at 1 A); stated assumptions, not the
#: data sheet of one product.
LEDS: dict[str, LedSpec] = {
    "LED-1x1": LedSpec(
        "LED-1x1", 1, 1.0 * MM, 1.1 * MM, 300.0,
        "assumption: one 1 mm² die at 300 lm, typical of automotive headlamp LEDs at 1 A "
        "(not one product's data sheet)",
    ),
    "LED-2x1": LedSpec(
        "LED-2x1", 2, 1.0 * MM, 1.1 * MM, 600.0,
        "assumption: two 1 mm² dies at 300 lm each, typical of automotive headlamp LEDs "
        "at 1 A (not one product's data sheet)",
    ),
}


def get_led(name: str) -> LedSpec:
    """The LED preset called ``name`` (case-insensitive).

    Raises
    ------
    InputError
        Unknown name (the message lists the known ones).
    """
    key = {k.lower(): k for k in LEDS}.get(str(name).strip().lower())
    if key is None:
        raise InputError(f"unknown LED {name!r}; known LEDs: {', '.join(LEDS)}")
    return LEDS[key]
