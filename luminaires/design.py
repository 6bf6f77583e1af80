"""Reflector design to a regulation target: a ring-and-sector multi-facet low beam.

The lamp (:mod:`lightsim.luminaires.design_lamp`) is the parametric headlight with a
``rings × sectors`` multi-facet reflector whose facets are placed by their traced filament
images under the cut-off line; a design vector x (h0, lift, then spread, drop and focal
scale per ring) and per-facet aim shifts define it. :func:`design_lowbeam` runs the design
as named steps, each a function of a few arguments:

1. **Place the facets** (:func:`place_facets`): x from the geometric start (or the given
   one, or a continued lamp's), clipped to the optimiser's bounds.
2. **Calibrate the rings** (:func:`calibrate_rings`): each ring of the start lamp is
   simulated alone (the other rings aimed at the foreground) and shifted by the aim
   correction its cut-off asks for (median of the three annex-9 scans; two steps): the
   bulb glass and the coil's finite size put the real cut-off a few tenths of a degree —
   differently for every ring — from the traced images' tops. The designed lamp then
   needs no aiming.
3. **Optimise**, ``optimiser="model"`` (the default, :func:`optimise_with_model`):
   ``model_rounds`` rounds (:func:`model_round`) of an aim step, measuring every movable
   facet's footprint with the simulator, Powell on the per-facet aim shifts against the
   deterministic footprint model (:mod:`lightsim.luminaires.facet_model`; the shifts go
   into ``Layout.facet_shifts_deg``) and a trust region that keeps a round's shifts only
   if the re-simulated lamp is better; then the final aim steps (:func:`final_aim_steps`).
   ``optimiser="simulator"`` (:func:`optimise_with_simulator`):
   :func:`scipy.optimize.minimize` with ``method="Powell"`` on x (bounded), in ``rounds``
   rounds of at most ``evaluations`` simulations. Within a round every evaluation uses
   the same photon seed (common random numbers: the optimiser sees geometry); every round
   re-draws the noise (seed + round) so that no round's winner is an artefact of one
   noise realisation.
4. **Linearity step** (model optimiser, ``linearity_photons`` > 0,
   :func:`level_cutoff`): the facets that make the cut-off at annex 9's scans are moved
   up or down, each try simulated (:mod:`lightsim.luminaires.linearity`), with one more
   aim step after it.
5. **Validate** (:func:`validate`): the returned lamp is re-simulated with a fresh seed
   and ``validate_factor`` × the photons (:attr:`DesignResult.validation`).

The objective J (minimised) is :mod:`lightsim.luminaires.design_terms`' sum of hinge
penalties on every rule's 95 % interval, the cut-off's sharpness, linearity and aim,
smoothness, road reach and foreground, from a simulation of the written GLB as it stands
(the calibrated lamp needs no aiming; the aim correction ``--aim`` would apply is a term of
its own). Deterministic for a seed.

Parameters: the fields of :class:`DesignSettings`, each declared once with its
:class:`~lightsim.options.Option` record (flag, unit, range, default, help) — that
declaration is this module's parameter table, and ``lightsim design --help`` and the range
checks come from it. Photons are counts; angles in degrees; lengths as the record says.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lightsim import options
from lightsim.engine.config import RunConfig
from lightsim.errors import InputError
from lightsim.options import option
from lightsim.render.cutoff import find_cutoff
from lightsim.simulate import SimulateOptions

from .bulbs import get_bulb
from .design_lamp import (
    TARGET_V_DEG,
    Layout,
    bounds,
    facet_images,
    facets_for,
    hole_diameter,
    read_design,
    shift_all,
    simulate_lamp,
    start_vector,
    with_shifts,
    write_design,
)
from .design_terms import Term, objective_terms, rule_terms
from .facet_model import (
    NOISE_CD,
    NOISE_PHOTONS,
    FootprintModel,
    ShiftResult,
    measure_footprints,
    model_terms,
    optimise_shifts,
)
from .linearity import LinearitySettings, linearity_step
from .regulations import load_ruleset

__all__ = ["DesignResult", "DesignRun", "DesignSettings", "DesignStart", "Layout", "Term",
           "design_lowbeam", "design_start", "facet_images", "facets_for", "objective_terms",
           "read_design", "regulation_ids", "start_vector", "write_design"]

CALIBRATION_STEPS = 2
"""Calibration passes over the rings (the second corrects what the first moved)."""


def _declared(cls: type, name: str) -> Any:
    """A field carrying another settings class's record ``name`` (the same option, declared
    once: ``--seed`` is :class:`RunConfig`'s, ``--traffic`` :class:`SimulateOptions`')."""
    opt = options.lookup(cls, name)
    return field(default=opt.default, metadata={"option": opt})


_LIST = "comma-separated"


@dataclass(frozen=True, kw_only=True)
class DesignSettings:
    """Everything one ``lightsim design`` run depends on.

    Every field is declared once with its :class:`~lightsim.options.Option` record: the
    command's options, their help (unit, range, default) and the range checks (one
    :class:`~lightsim.errors.InputError` line naming the flag) come from here. Fields given
    as comma-separated lists (``start``, ``ring_offsets``, ``wing_facets``,
    ``restart_seeds``) accept the command line's text or a sequence and hold tuples.
    """

    bulb: str = option("H4", "Bulb: H4 (its passing filament and shield cup) or a preset "
                       "name.", flag=("--bulb",))
    regulation: str = option(MISSING, "Rule set target, e.g. r112-b-passing, or several, "
                             "comma-separated (each one's rules are terms of J).",
                             flag=("--regulation",), metavar="RULES")
    rings: int = option(3, "Facet rings (radial).", flag=("--rings",), low=1, high=8)
    sectors: int = option(8, "Facet sectors (azimuthal): rings × sectors facets.",
                          flag=("--sectors",), low=2, high=32)
    focal_length: float = option(25.0, "Common (base) focal length of the facets.",
                                 unit="mm", flag=("--focal-length",), low=0, low_open=True)
    opening: float = option(160.0, "Lamp opening (reflector rim diameter).", unit="mm",
                            flag=("--opening",), low=0, low_open=True)
    evaluations: int = option(30, "Powell function evaluations per round (each one "
                              "simulation; --optimiser simulator).", flag=("--evaluations",),
                              low=1)
    rounds: int = option(2, "Optimisation rounds; each round re-draws the photon noise "
                         "(seed + round; --optimiser simulator).", flag=("--rounds",), low=1)
    photons: int = option(300_000, "Photons per evaluation (and per ring calibration run).",
                          flag=("--photons", "-n"), low=1)
    resolution: tuple[int, int] = option((80, 256), "Wall pixels WxH of every evaluation "
                                         "(0.1° vertical: the cut-off's sharpness needs it).",
                                         unit="px", flag=("--resolution",), kind="pair",
                                         low=8, high=4096)
    validate_factor: int = option(4, "The best lamp is re-simulated with a fresh seed and "
                                  "this many times the photons (0: not).",
                                  flag=("--validate-factor",), low=0)
    check_photons: int = option(0, "Photons of a final full-resolution check run of the "
                                "written lamp with the regulation's detector apertures "
                                "(0: none).", flag=("--check-photons",), low=0)
    seed: int = _declared(RunConfig, "seed")
    safety: float = option(0.10, "Relative margin asked beyond every limit.",
                           flag=("--safety",), low=0, high=1, high_open=True)
    reach: float = option(25.0, "1 lx road reach asked for (lamp 0.65 m high): the "
                          "intensity along the road line this far ahead is asked for 1 lx.",
                          unit="m", flag=("--reach",), low=0, low_open=True)
    reach_weight: float = option(1.0, "Weight of the reach term in J (its hinge² × this; 1: "
                                 "as every rule).", flag=("--reach-weight",), low=0)
    traffic: str = _declared(SimulateOptions, "traffic")
    check_dir: str = option("design-check", "Folder of the final check run.",
                            flag=("--out",), kind="dir")
    start: tuple[float, ...] | None = option(
        None, f"Start vector x, {_LIST} (h0, lift, then spread, drop, scale per ring).",
        flag=("--start",), cast=str, metavar="X,…", default_text="the geometric start")
    sign_share: float = option(0.03, "Share of a lit vertex-ring facet's azimuth given to "
                               "each overhead-sign sliver (dim light above the cut-off: "
                               "points 1-8); 0: none.", flag=("--sign-share",), low=0)
    optimiser: str = option("model", "model: Powell on per-facet aim shifts against a "
                            "footprint model measured once per round with the simulator "
                            "(deterministic); simulator: Powell on the start vector with a "
                            "simulation per evaluation.", flag=("--optimiser",),
                            choices=("model", "simulator"))
    model_rounds: int = option(1, "Footprint-model rounds (each re-measures the footprints "
                               "at the new aims).", flag=("--model-rounds",), low=0)
    model_photons: int = option(1_000_000, "Photons per footprint run (one run per lit "
                                "facet, plus the base).", flag=("--model-photons",), low=1)
    model_resolution: tuple[int, int] = option((200, 256), "Wall pixels WxH of the "
                                               "footprint maps.", unit="px",
                                               flag=("--model-resolution",), kind="pair",
                                               low=8, high=4096)
    model_evaluations: int = option(3000, "Powell evaluations of the model per round.",
                                    flag=("--model-evaluations",), low=1)
    interval_photons: int = option(12_000_000, "The model asks every point for the margin "
                                   "of the 95 % interval a check run with this many "
                                   "photons shows (0: none).", flag=("--interval-photons",),
                                   low=0)
    model_safety: float = option(0.05, "Relative margin the model asks beyond every limit "
                                 "(on top of the interval).", flag=("--model-safety",),
                                 low=0, high=1, high_open=True)
    ring_offsets: tuple[float, ...] | None = option(
        None, f"Calibrated ring offsets, {_LIST}, one per ring: skip the calibration.",
        unit="deg", flag=("--ring-offsets",), cast=str, metavar="DV,…",
        default_text="calibrated")
    continue_from: str | None = option(
        None, "A lamp written by lightsim design: start from its x, layout and facet shifts "
        "(no calibration) and run --model-rounds more rounds (their seeds follow the rounds "
        "it has).", flag=("--continue-from",), kind="file")
    foreground: float = option(5.0, "Ask for 1 lx on the road at ±this/2 and ±this to the "
                               "side 10 m ahead and at ±this/2 15 m ahead (0: no foreground "
                               "term).", unit="m",
                               flag=("--foreground",), low=0)
    shaded_spread: float = option(0.0, "Extra horizontal spread (× cos φ) of the cup's edge "
                                  "facets, which then light the foreground (0: they stay "
                                  "8° down).", unit="deg", flag=("--shaded-spread",), low=0,
                                  high=30)
    foreground_share: float = option(0.0, "Share of a lit second-ring facet per foreground "
                                     "sliver (× its weight; 0: none): light at 14–28° L/R, "
                                     "2.6–3.9° D.", flag=("--foreground-share",), low=0,
                                     high=0.9, high_open=True)
    shaded_drop: float = option(8.0, "How far under the cut-off the cup's edge facets are "
                                "aimed (with --shaded-spread).", unit="deg",
                                flag=("--shaded-drop",), low=0, high=20)
    wing_facets: tuple[int, ...] = option(
        "", f"Main facets (indices, ring-major, {_LIST}) re-aimed to the wide foreground "
        "beside the car (the wings).", flag=("--wing-facets",), cast=str, metavar="K,…",
        default_text="none")
    wing_deg: float = option(16.5, "The wings' image medians lie at ±(this ± 2.5°), on each "
                             "facet's side of V.", unit="deg", flag=("--wing",), low=0,
                             high=28)
    wing_drop: float = option(2.5, "How far under the cut-off level v0 the wings' image "
                              "medians lie.", unit="deg", flag=("--wing-drop",), low=0,
                              high=10)
    aim_photons: int = option(4_000_000, "Photons of the aim step (before each model round "
                              "and twice at the end: every facet moves by the aim correction "
                              "a 320x128 run's cut-off asks for, so the lamp needs no --aim; "
                              "0: no aim step).", flag=("--aim-photons",), low=0)
    linearity_photons: int = option(4_000_000, "Photons of every simulated try of the "
                                    "linearity step (after the final aim steps, model "
                                    "optimiser: the facets that make the cut-off at annex "
                                    "9's 1.5°/2.5°/3.5° scans are moved up or down until the "
                                    "scans' inflections lie within 0.12°; 0: no linearity "
                                    "step).", flag=("--linearity-photons",), low=0)
    aim_rounds: bool = option(True, "Aim step also before each model round (--no-aim-rounds: "
                              "only the two final ones; the rounds keep the model finder's "
                              "own cut-off).", flag=("--aim-rounds/--no-aim-rounds",),
                              kind="onoff")
    remeasure: bool = option(True, "Re-simulate each model round's lamp and keep its shifts "
                             "(halved up to twice) only if J got better.",
                             flag=("--remeasure/--no-remeasure",), kind="onoff")
    model_smooth: float = option(0.0, "σ of a Gaussian applied to every footprint (0: none).",
                                 unit="px", flag=("--model-smooth",), low=0, high=20)
    restarts: int = option(1, "Design this many lamps (seeds SEED, SEED+1, …), check each "
                           "with the README demo's run (--restart-photons at every "
                           "--restart-seeds; every rule and annex 9's linearity) and keep the "
                           "one that passes best: fewest rows not passing, then the largest "
                           "smallest margin, then the lowest J (1: one design, no check).",
                           flag=("--restarts",), low=1)
    restart_photons: int = option(32_000_000, "Photons of each restart check run.",
                                  flag=("--restart-photons",), low=1)
    restart_resolution: tuple[int, int] = option((320, 128), "Wall pixels WxH of the restart "
                                                 "check runs.", unit="px",
                                                 flag=("--restart-resolution",), kind="pair",
                                                 low=8, high=4096)
    restart_seeds: tuple[int, ...] = option("1,2,3", f"Photon seeds of the restart check "
                                            f"runs, {_LIST}.", flag=("--restart-seeds",),
                                            cast=str, metavar="S,…", default_text="1,2,3")
    until: str | None = option(None, "decided: every check run that reads verdicts "
                               "(--restarts, --check-photons) stops as soon as all its "
                               "verdicts are decided, as simulate --until decided does; "
                               "--restart-photons and --check-photons are then the caps.",
                               flag=("--until",), choices=(None, "decided"),
                               default_text="the check runs' photons")
    smooth_max: float = option(2.0, "Largest allowed lux / Gaussian-smoothed lux (σ 1°).",
                               low=0, low_open=True, internal="fixed by the design")
    aim_resolution: tuple[int, int] = option((320, 128), "Wall pixels WxH of the aim and "
                                             "linearity steps (the README demo's wall).",
                                             unit="px", kind="pair", low=8, high=4096,
                                             internal="fixed by the design")

    def __post_init__(self) -> None:
        for name, cast in (("start", float), ("ring_offsets", float), ("wing_facets", int),
                           ("restart_seeds", int)):
            object.__setattr__(self, name, _numbers(self, name, cast))
        options.check_fields(self)
        if self.ring_offsets is not None and (len(self.ring_offsets) != self.rings or not all(
                map(math.isfinite, self.ring_offsets))):
            raise InputError(f"--ring-offsets needs {self.rings} finite numbers")
        if self.start is not None and not all(map(math.isfinite, self.start)):
            raise InputError("--start needs finite numbers")
        if not self.restart_seeds or min(self.restart_seeds) < 0:
            raise InputError(f"--restart-seeds must be integers ≥ 0, got {self.restart_seeds}")

    def layout(self) -> Layout:
        """The lamp's :class:`~lightsim.luminaires.design_lamp.Layout` (sizes in m; the bulb
        preset by name: ``H4`` is the H4's passing filament with its cup)."""
        name = "H4-low" if self.bulb.strip().upper() == "H4" else get_bulb(self.bulb).name
        return Layout(rings=self.rings, sectors=self.sectors,
                      focal_length_m=self.focal_length * 1e-3, aperture_m=self.opening * 1e-3,
                      bulb=name, traffic=self.traffic, sign_share=self.sign_share,
                      ring_offsets_deg=self.ring_offsets or (),
                      shaded_spread_deg=self.shaded_spread, shaded_drop_deg=self.shaded_drop,
                      foreground_share=self.foreground_share, wing_facets=self.wing_facets,
                      wing_deg=self.wing_deg, wing_drop_deg=self.wing_drop)

    def objective_kw(self) -> dict[str, Any]:
        """Keyword arguments of :func:`~lightsim.luminaires.design_terms.objective_terms`
        for a simulated lamp."""
        return dict(safety=self.safety, reach_m=self.reach, smooth_max=self.smooth_max,
                    foreground_m=self.foreground, reach_weight=self.reach_weight)

    @property
    def noise_cd(self) -> float:
        """Relative half-width × √I (√cd) of the 95 % interval a check run of
        ``interval_photons`` is expected to show at a test point (0: none)."""
        return (NOISE_CD * math.sqrt(NOISE_PHOTONS / self.interval_photons)
                if self.interval_photons > 0 else 0.0)

    def model_kw(self) -> dict[str, Any]:
        """Keyword arguments of :func:`~lightsim.luminaires.design_terms.map_terms` for the
        footprint model and the linearity step: the model's margin and the interval a
        check run of ``interval_photons`` is expected to show."""
        return dict(safety=self.model_safety, reach_m=self.reach, smooth_max=self.smooth_max,
                    reach_weight=self.reach_weight, noise_cd=self.noise_cd,
                    foreground_m=self.foreground)


def _numbers(settings: DesignSettings, name: str, cast: type) -> tuple | None:
    """Field ``name`` as a tuple of ``cast``: from the command line's comma-separated text
    (empty items skipped) or a sequence; None stays None."""
    value = getattr(settings, name)
    if value is None:
        return None
    items = [t for t in value.split(",") if t.strip()] if isinstance(value, str) else value
    try:
        return tuple(cast(t) for t in items)
    except (TypeError, ValueError):
        label = options.lookup(DesignSettings, name).label
        what = "integers" if cast is int else "numbers"
        raise InputError(f"{label} must be comma-separated {what}, got {value!r}") from None


def regulation_ids(text: str) -> tuple[str, ...]:
    """The rule set ids of ``--regulation`` (comma-separated), each loaded once to check it
    exists (:class:`InputError` otherwise)."""
    regs = tuple(t.strip() for t in str(text).split(",") if t.strip())
    if not regs:
        raise InputError("--regulation: give at least one rule set id")
    for r in regs:
        load_ruleset(r)
    return regs


@dataclass(frozen=True)
class DesignStart:
    """Where a design run starts (:func:`design_start`).

    Attributes
    ----------
    layout : Layout
        The lamp's layout before calibration (a continued lamp's, with its facet shifts).
    regulations : tuple of str
        Rule set ids; the first is the target, the others add their rules to J.
    x : tuple of float or None
        Start vector (None: :func:`~lightsim.luminaires.design_lamp.start_vector`).
    calibrate : bool
        Calibrate the rings (not when their offsets are given or the lamp is continued).
    first_round : int
        Index of the first model round (a continued lamp's rounds so far).
    previous : tuple of dict
        The continued lamp's model record (empty for a new lamp).
    """

    layout: Layout
    regulations: tuple[str, ...]
    x: tuple[float, ...] | None = None
    calibrate: bool = True
    first_round: int = 0
    previous: tuple[dict[str, Any], ...] = ()


def design_start(settings: DesignSettings) -> DesignStart:
    """Check the settings' rule sets and lamp and say where the run starts: the settings'
    lamp, or (``continue_from``) a written lamp's x, layout and facet shifts with this
    run's sliver and wing options."""
    regs = regulation_ids(settings.regulation)
    layout = settings.layout()
    if settings.continue_from is None:
        start = DesignStart(layout, regs, settings.start, settings.ring_offsets is None)
    else:
        x_prev, stored, rec = read_design(settings.continue_from)
        layout = replace(stored, shaded_spread_deg=settings.shaded_spread,
                         shaded_drop_deg=settings.shaded_drop,
                         foreground_share=settings.foreground_share,
                         sign_share=settings.sign_share, wing_facets=settings.wing_facets,
                         wing_deg=settings.wing_deg, wing_drop_deg=settings.wing_drop)
        previous = tuple(rec.get("model") or [])
        start = DesignStart(layout, regs, tuple(float(t) for t in x_prev), False,
                            len(previous), previous)
    start.layout.check()
    if start.x is not None and len(start.x) != start.layout.n_params:
        raise InputError(f"--start needs {start.layout.n_params} finite numbers for "
                         f"{start.layout.rings} rings, got {len(start.x)}")
    return start


@dataclass
class DesignResult:
    """Outcome of :func:`design_lowbeam`.

    Attributes
    ----------
    x : list of float
        Best design vector (:mod:`lightsim.luminaires.design_lamp`).
    objective : float
        J at ``x`` in the round that found it.
    layout : Layout
    history : list of dict
        Per evaluation: ``round``, ``x``, ``objective``, ``failing`` (terms with a negative
        margin), ``seconds``.
    terms : list of Term
        J's terms at ``x`` (in the round that found it).
    validation : list of Term
        The terms of ``x`` re-simulated with a fresh seed and more photons (empty when
        ``validate_factor`` is 0).
    validation_objective : float
    calibration_deg : list of list of float
        Per calibration step, the correction of every ring (deg);
        ``layout.ring_offsets_deg`` holds their sums.
    seconds : float
        Wall-clock time, s.
    """

    x: list[float]
    objective: float
    layout: Layout
    history: list[dict[str, Any]] = field(default_factory=list)
    terms: list[Term] = field(default_factory=list)
    validation: list[Term] = field(default_factory=list)
    validation_objective: float = math.nan
    calibration_deg: list[list[float]] = field(default_factory=list)
    seconds: float = 0.0
    model: list[dict[str, Any]] = field(default_factory=list)
    """Per footprint-model round: J at the start and end, evaluations, footprint time."""


@dataclass
class DesignRun:
    """What every step of one design run shares.

    Attributes
    ----------
    settings : DesignSettings
    regulations : tuple of str
        Rule set ids (the first is the target).
    glb : Path
        The candidate lamp, rewritten by every simulated step.
    note, progress : callable or None
        Progress text (one line); and ``progress(count, entry)`` per evaluation.
    history : list of dict
        Every evaluation (:attr:`DesignResult.history`).
    t0 : float
        Start (``time.perf_counter``), s.
    """

    settings: DesignSettings
    regulations: tuple[str, ...]
    glb: Path
    note: Callable[[str], None] | None = None
    progress: Callable[[int, dict[str, Any]], None] | None = None
    history: list[dict[str, Any]] = field(default_factory=list)
    t0: float = field(default_factory=time.perf_counter)

    def say(self, text: str) -> None:
        if self.note is not None:
            self.note(text)

    def log(self, entry: dict[str, Any]) -> None:
        """Record one evaluation and report it."""
        self.history.append(entry)
        if self.progress is not None:
            self.progress(len(self.history), entry)

    def simulate(self, x: np.ndarray, layout: Layout, *, photons: int,
                 resolution: tuple[int, int], seed: int, also: tuple[str, ...] = (),
                 only_ring: int | None = None) -> tuple[dict[str, Any], np.ndarray, Any]:
        """Write the lamp of ``x`` and ``layout`` (``only_ring``: that ring alone) and
        simulate it unaimed against the target rule set (``also``: further rule sets on
        the same run); (regulation dict, lux map, wall frame)."""
        write_design(self.glb, x, layout, only_ring=only_ring)
        return simulate_lamp(self.glb, self.regulations[0], photons=photons,
                             resolution=resolution, seed=seed, traffic=layout.traffic,
                             aim=False, also=also)


# ---------------------------------------------------------------------------------------
# the steps
# ---------------------------------------------------------------------------------------


def place_facets(start: DesignStart) -> np.ndarray:
    """The start vector x (facets placed by their filament images under the cut-off line:
    the geometric start, or the given one), clipped to the optimiser's bounds."""
    lo, hi = (np.array(b) for b in zip(*bounds(start.layout)))
    x0 = start_vector(start.layout) if start.x is None else start.x
    return np.clip(np.asarray(x0, float), lo, hi)


def calibrate_rings(run: DesignRun, x: np.ndarray, layout: Layout, steps: int
                    ) -> tuple[Layout, list[list[float]]]:
    """Shift every ring until its cut-off sits at 0.57° D (``steps`` passes): the bulb
    glass and the coil's finite size move each ring's real cut-off from where the traced
    images put it, by different amounts (two rings off by different amounts make two
    edges). Each ring is simulated alone (the others aimed away, the vertex ring not
    lifted). Returns the layout with the ring offsets and every pass's corrections (deg)."""
    s = run.settings
    calibration = []
    x_flat = x.copy()
    x_flat[1] = 0.0  # without the lifted vertex ring
    offsets = list(layout.ring_offsets_deg) or [0.0] * layout.rings
    for _ in range(steps):
        step = []
        for r in range(layout.rings):
            layout = replace(layout, ring_offsets_deg=tuple(offsets))
            reg, _lux, _fr = run.simulate(x_flat, layout, photons=s.photons,
                                          resolution=s.resolution, seed=s.seed, only_ring=r)
            found = [sc["v_inflection_deg"] for sc in
                     reg["aim"]["cutoff"].get("scans", []) if sc.get("found")]
            # the median of the three annex-9 scans: one may lock on a weaker edge
            dv = (float(np.clip(TARGET_V_DEG - np.median(found), -1.0, 1.0))
                  if found else 0.0)
            offsets[r] += dv
            step.append(dv)
        calibration.append(step)
        if max(abs(d) for d in step) < 0.05:
            break
    return replace(layout, ring_offsets_deg=tuple(offsets)), calibration


def evaluate_lamp(run: DesignRun, x: np.ndarray, layout: Layout, seed: int, photons: int
                  ) -> tuple[float, list[Term]]:
    """J and its terms of the lamp of ``x`` simulated with ``photons`` at ``seed`` (every
    rule set's rules; a lamp that cannot be built costs 1000)."""
    s = run.settings
    try:
        write_design(run.glb, x, layout)
    except InputError:
        return 1e3, [Term("geometry", -10.0, 1e3)]
    # unaimed: the calibrated lamp needs no aiming, and the probes then move smoothly with
    # the geometry (an aim re-estimated per candidate would not)
    reg, lux, frame = simulate_lamp(run.glb, run.regulations[0], photons=photons,
                                    resolution=s.resolution, seed=seed,
                                    traffic=layout.traffic, aim=False,
                                    also=run.regulations[1:])
    terms = objective_terms(reg, lux, frame, **s.objective_kw())
    for extra in reg["also"]:
        terms += [replace(t, name=f"{t.name} ({extra['ruleset']})")
                  for t in rule_terms(extra["results"], s.safety)]
    return float(sum(t.penalty for t in terms)), terms


def optimise_with_simulator(run: DesignRun, x: np.ndarray, layout: Layout
                            ) -> dict[str, Any]:
    """Powell on x with a simulation per evaluation, ``rounds`` rounds (seed + round);
    the last round's best ``{"j", "x", "terms"}`` (rounds are compared at their own noise:
    the last round's winner has survived every re-draw)."""
    from scipy.optimize import minimize

    s = run.settings
    box = bounds(layout)
    best: dict[str, Any] = {"j": math.inf}
    for rnd in range(s.rounds):
        s_round = s.seed + rnd
        round_best: dict[str, Any] = {"j": math.inf}

        def evaluate(xv: np.ndarray, rnd: int = rnd, s_round: int = s_round,
                     round_best: dict[str, Any] = round_best) -> float:
            t1 = time.perf_counter()
            j, terms = evaluate_lamp(run, np.asarray(xv, float), layout, s_round, s.photons)
            entry = {"round": rnd, "x": [float(t) for t in xv], "objective": j,
                     "failing": [t.name for t in terms if t.margin < 0],
                     "seconds": time.perf_counter() - t1}
            if j < round_best["j"]:
                round_best.update(j=j, x=entry["x"], terms=terms)
            run.log(entry)
            return j

        minimize(evaluate, x, method="Powell", bounds=box,
                 options={"maxfev": int(s.evaluations), "xtol": 0.05, "ftol": 1e-3})
        x = np.array(round_best["x"])
        best = {"j": round_best["j"], "x": round_best["x"], "terms": round_best["terms"]}
    return best


def aim_step(run: DesignRun, x: np.ndarray, layout: Layout) -> tuple[Layout, float]:
    """Simulate the lamp as the check run does (``aim_resolution``, unaimed) and lower or
    raise every facet by the aim correction its cut-off asks for (deg, at most ±0.5°)."""
    s = run.settings
    reg, _l, _f = run.simulate(x, layout, photons=s.aim_photons, resolution=s.aim_resolution,
                               seed=s.seed + 500)
    cut = reg["aim"]["cutoff"]
    dv = (float(np.clip(cut.get("aim_dv_deg") or 0.0, -0.5, 0.5))
          if cut.get("found", True) else 0.0)
    n_all = len(facets_for(x, layout, hole_diameter(layout)))
    return shift_all(layout, n_all, dv), dv


def model_aim_offset(model: FootprintModel, layout: Layout) -> float | None:
    """Check-run minus model-finder aim on the model's reference lamp (deg): after an aim
    step the check run's cut-off sits at 0.57° D, and the model's aim term asks to keep it
    there in the model finder's terms."""
    c0 = find_cutoff(model.lux(np.zeros((len(model.facets), 2))), model.frame,
                     layout.traffic)
    return None if c0.aim_dv_deg is None else -float(c0.aim_dv_deg)


def remeasure(run: DesignRun, x: np.ndarray, layout: Layout, model: FootprintModel,
              shifts: np.ndarray, seed: int, aim_offset: float | None
              ) -> tuple[float, list[Term]]:
    """J of the lamp with ``shifts`` simulated on the model's wall (the whole lamp, the
    model's reference photons and ``seed``)."""
    s = run.settings
    _r, lux, _f = run.simulate(x, with_shifts(layout, model.facets, shifts),
                               photons=4 * s.model_photons, resolution=s.model_resolution,
                               seed=seed)
    terms = model_terms(model, shifts, run.regulations, layout.traffic,
                        lux=np.nan_to_num(lux), **s.model_kw(), aim_offset_deg=aim_offset)
    return float(sum(t.penalty for t in terms)), terms


def trust_region(run: DesignRun, x: np.ndarray, layout: Layout, model: FootprintModel,
                 res: ShiftResult, rnd: int, aim_offset: float | None
                 ) -> tuple[float, float, list[Term], list[dict[str, float]]]:
    """Keep a model round's shifts (× 1, ½, ¼) only if the re-simulated lamp (the model's
    reference seed and photons, so the comparison is noise-fair) is better than the
    round's start; (accepted step, its J, its terms, every try)."""
    s = run.settings
    tried = []
    accepted = 0.0
    j_acc, terms_acc = res.start_objective, res.terms
    for t in (1.0, 0.5, 0.25) if s.remeasure else ():
        jr, tr = remeasure(run, x, layout, model, t * res.shifts_deg, s.seed + rnd,
                           aim_offset)
        tried.append({"step": t, "objective": jr})
        if run.note is not None:
            mt = {q.name: q.penalty for q in res.terms}
            diff = sorted(tr, key=lambda q: -abs(q.penalty - mt.get(q.name, 0.0)))
            run.say(f"round {rnd}: shifts × {t:g} re-measured J {jr:.4f} (model "
                    f"{res.objective:.4f} at × 1, start {res.start_objective:.4f}); "
                    "model vs lamp: " + ", ".join(
                        f"{q.name} {mt.get(q.name, 0.0):.3f}/{q.penalty:.3f}"
                        for q in diff[:4]))
        if jr < res.start_objective:
            accepted, j_acc, terms_acc = t, jr, tr
            break
    if not s.remeasure:
        accepted, j_acc = 1.0, res.objective
    return accepted, j_acc, terms_acc, tried


def model_round(run: DesignRun, x: np.ndarray, layout: Layout, rnd: int
                ) -> tuple[Layout, dict[str, Any], dict[str, Any]]:
    """One footprint-model round: aim step, footprints, Powell on the facet shifts against
    the model, trust region; (layout with the kept shifts, best ``{"j", "x", "terms"}``,
    the round's record)."""
    s = run.settings
    aim_dv = math.nan
    aiming = s.aim_photons > 0 and s.aim_rounds
    if aiming:
        layout, aim_dv = aim_step(run, x, layout)
        run.say(f"round {rnd}: aim step {aim_dv:+.3f}° (every facet)")
    model = measure_footprints(x, layout, run.regulations[0], photons=s.model_photons,
                               resolution=s.model_resolution, seed=s.seed + rnd,
                               residual_factor=4, progress=run.note, smooth_px=s.model_smooth)
    aim_off = model_aim_offset(model, layout) if aiming else None

    def shown(i: int, j: float, terms: list[Term]) -> None:
        run.log({"round": rnd, "x": [float(t) for t in x], "objective": j,
                 "failing": [t.name for t in terms if t.margin < 0],
                 "seconds": time.perf_counter() - run.t0, "model_evaluation": i})

    res = optimise_shifts(model, run.regulations, layout.traffic, safety=s.model_safety,
                          reach_m=s.reach, smooth_max=s.smooth_max,
                          evaluations=s.model_evaluations, progress=shown,
                          noise_cd=s.noise_cd, foreground_m=s.foreground,
                          aim_offset_deg=aim_off, reach_weight=s.reach_weight)
    accepted, j_acc, terms_acc, tried = trust_region(run, x, layout, model, res, rnd, aim_off)
    layout = with_shifts(layout, model.facets, accepted * res.shifts_deg)
    best = {"j": j_acc, "x": [float(t) for t in x], "terms": terms_acc}
    record = {"round": rnd, "start_objective": res.start_objective, "objective": res.objective,
              "remeasured": tried, "accepted_step": accepted,
              "aim_step_deg": aim_dv if math.isfinite(aim_dv) else None,
              "evaluations": res.evaluations, "footprint_seconds": model.seconds,
              "facets": len(model.facets)}
    return layout, best, record


def final_aim_steps(run: DesignRun, x: np.ndarray, layout: Layout
                    ) -> tuple[Layout, list[dict[str, Any]]]:
    """Up to two aim steps (none without ``aim_photons``), so that the lamp needs no
    ``--aim``; the layout and their records."""
    out = []
    for _ in range(2 if run.settings.aim_photons > 0 else 0):
        layout, aim_dv = aim_step(run, x, layout)
        run.say(f"final aim step {aim_dv:+.3f}° (every facet)")
        out.append({"round": "aim", "aim_step_deg": aim_dv})
        if abs(aim_dv) < 0.01:
            break
    return layout, out


def level_cutoff(run: DesignRun, x: np.ndarray, layout: Layout
                 ) -> tuple[Layout, list[dict[str, Any]]]:
    """The linearity step (:func:`~lightsim.luminaires.linearity.linearity_step`) on the
    aim step's wall, and an aim step after it when it moved facets (the level at 2.5° may
    have moved); the layout and the records."""
    s = run.settings
    level = LinearitySettings(photons=s.linearity_photons,
                              footprint_photons=max(s.linearity_photons // 8, 1),
                              resolution=s.aim_resolution, seed=s.seed + 600)
    layout, lin = linearity_step(x, layout, run.regulations, level, terms_kw=s.model_kw(),
                                 note=run.note)
    out = [{"round": "linearity", **lin.to_dict()}]
    if lin.shifts_deg and s.aim_photons > 0:
        layout, aim_dv = aim_step(run, x, layout)
        run.say(f"aim step after the linearity step {aim_dv:+.3f}° (every facet)")
        out.append({"round": "aim", "aim_step_deg": aim_dv})
    return layout, out


def optimise_with_model(run: DesignRun, x: np.ndarray, layout: Layout, first_round: int
                        ) -> tuple[Layout, dict[str, Any], list[dict[str, Any]]]:
    """``model_rounds`` model rounds from ``first_round``, then the final aim steps; the
    layout, the best ``{"j", "x", "terms"}`` and every round's record."""
    best: dict[str, Any] = {"j": math.nan, "x": [float(t) for t in x], "terms": []}
    records = []
    for rnd in range(first_round, first_round + run.settings.model_rounds):
        layout, best, record = model_round(run, x, layout, rnd)
        records.append(record)
    layout, aims = final_aim_steps(run, x, layout)
    return layout, best, records + aims


def validate(run: DesignRun, x: list[float], layout: Layout) -> tuple[float, list[Term]]:
    """J and terms of the lamp re-simulated with a fresh seed and ``validate_factor`` ×
    the photons (NaN and none when the factor is 0)."""
    s = run.settings
    if not s.validate_factor:
        return math.nan, []
    return evaluate_lamp(run, np.array(x), layout, s.seed + 1000,
                         s.photons * s.validate_factor)


def design_lowbeam(settings: DesignSettings, start: DesignStart | None = None, *,
                   progress: Callable[[int, dict[str, Any]], None] | None = None,
                   note: Callable[[str], None] | None = None) -> DesignResult:
    """Design the lamp of ``settings`` (see the module docstring for the steps).

    Parameters
    ----------
    settings : DesignSettings
    start : DesignStart, optional
        Where to start (default: :func:`design_start` of ``settings``).
    progress : callable, optional
        ``progress(count, entry)`` after every evaluation (:attr:`DesignResult.history`).
    note : callable, optional
        One line of progress text per step.
    """
    start = design_start(settings) if start is None else start
    with tempfile.TemporaryDirectory(prefix="lightsim-design-") as tmp:
        run = DesignRun(settings, start.regulations, Path(tmp) / "candidate.glb", note,
                        progress)
        x = place_facets(start)
        layout, calibration = calibrate_rings(run, x, start.layout,
                                              CALIBRATION_STEPS if start.calibrate else 0)
        records: list[dict[str, Any]] = []
        if settings.optimiser == "model":
            layout, best, records = optimise_with_model(run, x, layout, start.first_round)
            if settings.linearity_photons > 0:
                layout, steps = level_cutoff(run, x, layout)
                records += steps
        else:
            best = optimise_with_simulator(run, x, layout)
        vj, validation = validate(run, best["x"], layout)
    return DesignResult(x=best["x"], objective=best["j"], layout=layout, history=run.history,
                        terms=best["terms"], validation=validation, validation_objective=vj,
                        calibration_deg=calibration, seconds=time.perf_counter() - run.t0,
                        model=records)
