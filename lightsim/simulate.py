"""``simulate`` as an engine function: load, plan, run frames, write results, checkpoint.

The command line (``lightsim simulate``) only parses options into
:class:`SimulateOptions` and shows progress; everything else is here so that scripts
can call :func:`run_simulation` directly.

Outputs in the output folder, written as a set: into a staging folder inside it
(``.lightsim-staging-<pid>-…``), then moved in with ``summary.json`` last — its presence
means the run finished. A run into a folder removes the staging folders and temporary
files that killed runs left there and says so (a warning).

=====================  ====================================================================
file                   content
=====================  ====================================================================
``wall_lux.exr``       float32 OpenEXR, channel ``Y`` = illuminance (lx); ``R``, ``G``,
                       ``B`` too for coloured scenes; metadata: units, wall frame, photons,
                       seed, estimator, lightsim version
``wall_lux.png``       false colour (log scale unless ``--linear``), axes H/V in degrees,
                       lx and cd scales, H-V lines, the first rule set's test points
``isolux.png``         iso-lux plot of the first rule set (``isolux-ID.png`` for each
                       further one); ``road.png`` the road view; every plot captioned
``summary.json``       wall frame, energy bookkeeping (lm), error vs time, plan, settings,
                       ``timings_s``: where the run's time went (load, session, sample,
                       trace, insert, estimate, final_map, outputs; s, wall clock),
                       ``outputs``: the files of this set (moved in last: the run finished)
``error_vs_time.png``  estimated relative error against seconds and photons (log-log)
``checkpoint.json``    only while a run is interrupted: ``--resume DIR`` continues it
``per_source.exr``     ``--per-source``: a channel per emitter group (lx), ``Y`` their sum;
                       ``per_source_var.exr`` their variances (lx²); :mod:`lightsim.persource`
=====================  ====================================================================
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import platform
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import MISSING, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lightsim import __version__, options, report
from lightsim.analysis import Analysis, FinishedRun, StopsRun
from lightsim.engine.config import RunConfig
from lightsim.engine.memory import check_fits
from lightsim.engine.pointstore import store_peak_bytes
from lightsim.engine.server import STOP_ALPHA, Session
from lightsim.errors import ClusterError, InputError, LightsimError
from lightsim.io.atomic import STAGING_PREFIX, OutputSet, clean_stale, unfinished_set
from lightsim.io.cad import Tessellation
from lightsim.io.exr import wall_metadata, write_exr
from lightsim.io.plot_worker import InProcess
from lightsim.io.summary import read_json, write_json
from lightsim.options import option
from lightsim.render.cutoff import cutoff_interval, find_cutoff, scan_sample_points
from lightsim.render.frame import luminous
from lightsim.scene import Scene, SceneSettings, load_scene

CHECKPOINT = "checkpoint.json"
UNTIL_CAP_PHOTONS = 400_000_000
"""Photon cap of ``--until decided`` without ``--photons`` (a rule exactly at its limit
never decides)."""
UNTIL_GUIDE_PHOTONS = 1e18
"""``--until decided --guide points``: a guide target's photon goal, out of reach — an
open rule's apertures draw guided photons until the rule decides."""


@dataclass
class SimulateOptions:
    """Everything a simulation run depends on (stored in checkpoints for ``--resume``).

    Every field is declared once with its :class:`~lightsim.options.Option` record (flag,
    unit, default, range, help): ``lightsim simulate``'s options, the range checks and the
    checkpoint come from these declarations and :class:`~lightsim.engine.config.RunConfig`'s
    (``config`` holds RunConfig settings by name, ``{}`` = all defaults).
    """
    scene_path: str = option(MISSING, "GLB/glTF/OBJ/STL/PLY, STEP/IGES or a photometric or ray "
                             "file to simulate.", internal="the SCENE_FILE argument")
    photons: int | None = option(None, "Photons to shoot in total.", flag=("--photons", "-n"),
                                 low=1, default_text="1 frame", resume=True)
    seconds: float | None = option(None, "Stop after this much time.", unit="s",
                                   flag=("--time",), low=0, low_open=True, resume=True)
    target_error: float | None = option(
        None, "Stop when the relative error over the lit region is at most this at "
        f"{1 - STOP_ALPHA:.0%} confidence (the error figure's upper bound).",
        flag=("--target-error",), low=0, high=1, low_open=True, high_open=True, resume=True)
    until: str | None = option(
        None, "decided: stop as soon as every rule of every --regulation rule set is pass "
        "or fail at its confidence, with a sequential rule that keeps wrong verdicts at "
        "their nominal rate however often it looks; verdict: stop as soon as the lamp's "
        "verdict is decided (a rule surely fails, or every rule is decided; rules still "
        "open read uncertain); --photons (default "
        f"{UNTIL_CAP_PHOTONS:,}) and --time cap the run, which then reports what is still "
        "undecided.", flag=("--until",), choices=(None, "decided", "verdict"), resume=True,
        default_text="the photon or time budget")
    out_dir: str = option("lightsim-out", "Output folder.", flag=("--out",), kind="dir")
    resolution: tuple[int, int] = option((640, 256), "Wall pixels WxH.", unit="px",
                                         flag=("--resolution",), kind="pair", low=1)
    wall_distance: float = option(25.0, "Distance of the added wall, if the file has none.",
                                  unit="m", flag=("--wall-distance",), low=0, low_open=True)
    wall_size: tuple[float, float] = option(
        (30.0, 12.0), "Size WxH of the added wall, centred on H-V.", unit="m",
        flag=("--wall-size",), kind="pair", low=0, low_open=True)
    flux: float | None = option(None, "Luminous flux of the emitter(s).", unit="lm",
                                flag=("--flux",), low=0, low_open=True,
                                default_text="the scene's")
    emission: str | None = option(None, "Angular emission of the emitters (overrides the "
                                  "file's).", flag=("--emission",),
                                  choices=(None, "isotropic", "lambertian"),
                                  default_text="the file's, else isotropic")
    filament: str | None = option(None, "Bulb preset for a mesh without emitter (e.g. H7).",
                                  flag=("--filament",))
    filament_at: tuple[float, float, float] | None = option(
        None, "Filament centre X,Y,Z.", unit="m", flag=("--filament-at",), kind="triple")
    filament_axis: tuple[float, float, float] = option(
        (0.0, 0.0, 1.0), "Filament axis X,Y,Z.", flag=("--filament-axis",), kind="triple")
    rayfile: str | None = option(
        None, "LED/bulb ray file (IES TM-25 .tm25ray or Zemax binary .dat/.ray) as the "
        "light source, replacing the scene's emitters.", flag=("--rayfile",), kind="file")
    rayfile_at: tuple[float, float, float] | None = option(
        None, "Where the ray file's origin goes, X,Y,Z.", unit="m", flag=("--rayfile-at",),
        kind="triple")
    rayfile_axis: tuple[float, float, float] = option(
        (0.0, 0.0, 1.0), "Where the ray file's +Z points, X,Y,Z.", flag=("--rayfile-axis",),
        kind="triple")
    materials: str | None = option(
        None, "Material map (TOML): part-name pattern → mirror/glass/diffuse/emitter/"
        "ignore, for CAD files without optics (`lightsim luminaire parts FILE` lists the "
        "part and face names).", flag=("--materials",), kind="file")
    cad_linear_tol_mm: float = option(
        0.01, "STEP/IGES tessellation: largest facet-to-surface distance.", unit="mm",
        flag=("--cad-linear-tol",), low=0, low_open=True)
    cad_angular_tol_deg: float = option(
        2.0, "STEP/IGES tessellation: largest angle between facet normals.", unit="deg",
        flag=("--cad-angular-tol",), low=0, high=90, low_open=True, high_open=True)
    cad_time_limit_s: float = option(
        600.0, "STEP/IGES: processor time the CAD reader may use (a damaged file can make "
        "it loop).", unit="s", flag=("--cad-time-limit",), low=0, low_open=True)
    part_materials: dict[str, str] = option(  # noqa: RUF009 - a dataclasses.field
        help="NAME=mirror[:R]|glass[:n]|diffuse[:ρ]|wall|ignore (repeatable).",
        default_factory=dict, flag=("--part-material",), kind="assign",
        metavar="NAME=KIND[:VALUE]")
    config: dict[str, Any] = field(default_factory=dict)
    regulation: str | None = option(
        None, "Rule set to check, e.g. r112-b-passing, or several: "
        "r112-b-passing,r149-b-passing (see `lightsim report --list-rulesets`).",
        flag=("--regulation",))
    traffic: str = option("right", "Traffic side of the regulation check and cut-off.",
                          flag=("--traffic",), choices=("right", "left"))
    aim: bool = option(False, "Aim the cut-off at 0.57° D before checking.",
                       flag=("--aim",), kind="flag")
    aperture: float = option(
        0.15, "Side of the square detector aperture each regulation test point counts "
        "photons in (0.15° ≈ 65 mm at 25 m); 0 = kNN estimate instead.", unit="deg",
        flag=("--aperture",), low=0, high=2)
    provenance: bool = option(
        False, "Break every regulation rule's light down by the path it took (emitter, "
        "parts and reflector facets met, reflection/refraction/TIR/diffuse at each): "
        "summary.json's provenance, a table for failing and uncertain rules, lightsim "
        "report --provenance RULE.", flag=("--provenance",), kind="flag")
    provenance_map: str | None = option(
        None, "With --provenance: the wall map of one path class — the photons whose class "
        "name holds this text (a part, a facet, 'TIR', 'Fresnel reflection', 'diffuse') — "
        "as provenance-map.exr (lx) and provenance-map.png.", flag=("--provenance-map",),
        metavar="CLASS")
    keep_all_photons: bool = option(
        False, "Keep every photon for kNN estimates anywhere after the run (memory grows "
        "with --photons). Without it the run keeps none: the estimates its outputs read "
        "are accumulated per frame.", flag=("--keep-photons",), kind="flag")
    spt_points: bool = option(False, "Aim Selective Photon Tracing at the regulation's "
                              "test points.", flag=("--spt-points/--no-spt-points",),
                              kind="onoff")
    ies: str | None = option(None, "Write the far-field intensity as IES LM-63-2002.",
                             flag=("--ies",), kind="file", suffixes=(".ies",))
    ldt: str | None = option(None, "Write the far-field intensity as EULUMDAT.",
                             flag=("--ldt",), kind="file", suffixes=(".ldt", ".eul"))
    ies_type: str = option(
        "auto", "Photometric type of --ies: A (vehicle lamps: H right, V up), C; auto = A "
        "for lamp models and Type A inputs, else C.", flag=("--ies-type",),
        choices=("auto", "A", "C"))
    ies_step: float | None = option(
        None, "Angle step of --ies, in H and V (Type A) or C and γ (Type C); auto = uneven "
        "angles, fine where the beam changes fast (cut-off, hot spot), coarse elsewhere.",
        unit="deg", flag=("--ies-step",), low=0.1, high=90, default_text="auto")
    ldt_step: float | None = option(
        None, "Angle step of --ldt in C and γ (EULUMDAT: at most 721 C-planes and 361 γ "
        "angles); auto = uneven angles, fine where the beam changes fast.", unit="deg",
        flag=("--ldt-step",), low=0.5, high=90, default_text="auto")
    lamp_set: int | None = option(
        None, "EULUMDAT scene file: which lamp set (1-based) scales the intensities.",
        flag=("--lamp-set",), low=1, metavar="N",
        default_text="the first, with a warning when there are several")
    farfield_photons: int = option(1_000_000, "Photons of the far-field (IES/LDT) run.",
                                   flag=("--farfield-photons",), low=1)
    mount_height: float = option(0.65, "Lamp height above the road for the road view.",
                                 unit="m", flag=("--mount-height",), low=0, low_open=True)
    road: bool = option(False, "Road evaluation after the run (lightsim road): reach at the "
                        "road edges and glare on a straight road and 150/250 m curves, with "
                        "intervals from the interleave sets; writes road.json, "
                        "road_<approach>.png and wall_sets.npz.", flag=("--road",),
                        kind="flag")
    per_source: bool = option(
        False, "Also write a map per emitter group (glTF extras lightsim.group, else the part "
        "name) from the same photons: per_source.exr (a channel per group, Y = their sum, "
        "lx) and per_source_var.exr (variances, lx²), each group's error in summary.json; "
        "costs groups × pixels × 16 bytes of memory.", flag=("--per-source",), kind="flag")
    outputs: tuple[str, ...] = option(
        ("exr", "png", "error_vs_time", "isolux", "road", "json"),
        "Files to write, comma-separated: exr (wall_lux.exr), png (wall_lux.png), "
        "error_vs_time, isolux, road (their .png), json (summary.json, always written: it "
        "marks a finished run); all = every one.", flag=("--outputs",), kind="names",
        choices=("exr", "png", "error_vs_time", "isolux", "road", "json"), resume=True,
        default_text="all")
    log_scale: bool = option(True, "Colour scale of wall_lux.png: logarithmic (three "
                             "decades below the maximum) or linear.",
                             flag=("--log/--linear",), kind="onoff")
    workers: int = option(0, "0: in-process; N: N Ray actors on this machine.",
                          flag=("--workers",), low=0, resume=True)
    address: str | None = option(None, "Ray cluster address HOST:PORT.",
                                 flag=("--address",), envvar="RAY_ADDRESS", resume=True)

    def __post_init__(self) -> None:
        options.check_fields(self)

    def run_config(self) -> RunConfig:
        """The engine settings (validated)."""
        return RunConfig.from_dict(self.config)

    def to_json(self) -> dict[str, Any]:
        return options.to_json(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SimulateOptions:
        return cls(**options.from_json(cls, d))

    @classmethod
    def from_command_line(cls, scene_path: str, values: dict[str, Any]) -> SimulateOptions:
        """Options from the click values of :func:`lightsim.options.click_options`
        (SimulateOptions and RunConfig fields by name; text forms not yet parsed)."""
        sim, run = _split(values)
        return cls(scene_path=scene_path, config=run, **sim)

    def resumed(self, values: dict[str, Any], where: str) -> SimulateOptions:
        """These (a checkpoint's) options with the command line's ``values`` (the options
        given explicitly) applied: budgets and workers may change; any other option that
        differs from the checkpoint is refused in one line."""
        sim, run = _split(values)
        stored_run = RunConfig.from_dict(self.config)
        conflicts = []
        for name, value in sim.items():
            opt = options.lookup(SimulateOptions, name)
            if not opt.resume and value != getattr(self, name):
                conflicts.append(f"{opt.label} {_text(getattr(self, name))} (not {_text(value)})")
        for name, value in run.items():
            opt = options.lookup(RunConfig, name)
            if value != getattr(stored_run, name):
                conflicts.append(f"{opt.label} {_text(getattr(stored_run, name))} "
                                 f"(not {_text(value)})")
        if conflicts:
            raise InputError(f"--resume {where}: the checkpoint was run with "
                             f"{', '.join(conflicts)}: leave those options out or start a "
                             "new run")
        return replace(self, **{n: v for n, v in sim.items()
                                if options.lookup(SimulateOptions, n).resume})


def _split(values: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Click values → parsed (SimulateOptions fields, RunConfig fields)."""
    sim_names = {o.name: o for o in options.table(SimulateOptions)}
    run_names = {o.name: o for o in options.table(RunConfig)}
    sim, run = {}, {}
    for name, raw in values.items():
        if name in sim_names:
            sim[name] = sim_names[name].parse(raw)
        elif name in run_names:
            run[name] = run_names[name].parse(raw)
        else:
            raise KeyError(f"not a run option: {name}")
    return sim, run


def _text(value: Any) -> str:
    if isinstance(value, tuple):
        return ",".join(str(v) for v in value)
    return "none" if value is None else str(value)


@dataclass
class SimulationResult:
    lux: np.ndarray          # (H, W) luminous illuminance, lx
    rgb: np.ndarray | None   # (H, W, 3) for coloured scenes
    summary: dict[str, Any]
    out_dir: Path
    interrupted: bool = False


OUTPUT_FILES = ("wall_lux.exr", "wall_lux.png", "error_vs_time.png", "isolux.png",
                "road.png", "probes.npz", "per_source.exr", "per_source_var.exr",
                "summary.json")
"""Files a finished run may have left in its folder (an older set's are replaced)."""


def check_out_dir(path: str | os.PathLike) -> Path:
    """Create the output folder and make sure files can be written there.

    The test writes a staging-named empty folder (removed at once; a kill in between leaves
    only what the next run's clean-up removes).
    """
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
        os.rmdir(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}-", dir=out))
    except OSError as exc:
        raise InputError(f"output directory {out} is not writable "
                         f"({exc.strerror or exc})") from None
    return out


def folder_notes(out: Path) -> list[str]:
    """Clean what killed runs left in ``out``; warnings saying what was found or done."""
    notes = clean_stale(out)
    left = unfinished_set(out, OUTPUT_FILES)
    if left:
        notes.append(f"{out}: holds an unfinished run's outputs ({', '.join(left)}; no "
                     "summary.json): this run replaces them")
    return notes


def load(opts: SimulateOptions) -> Scene:

    return load_scene(opts.scene_path, SceneSettings(flux=opts.flux, emission=opts.emission,
                      filament=opts.filament, filament_at=opts.filament_at,
                      filament_axis=opts.filament_axis, wall_distance=opts.wall_distance,
                      wall_size=opts.wall_size, resolution=opts.resolution,
                      part_materials=opts.part_materials, lamp_set=opts.lamp_set,
                      rayfile=opts.rayfile,
                      rayfile_at=opts.rayfile_at, rayfile_axis=opts.rayfile_axis,
                      materials=opts.materials,
                      tessellation=Tessellation(opts.cad_linear_tol_mm,
                                                opts.cad_angular_tol_deg,
                                                opts.cad_time_limit_s)))


def run_simulation(opts: SimulateOptions, *, progress: Callable[[Any], None] | None = None,
                   should_stop: Callable[[], bool] | None = None,
                   on_plan: Callable[[Any], None] | None = None,
                   resume: dict[str, Any] | None = None,
                   analyses: Sequence[Analysis] | None = None,
                   plots: Any = None) -> SimulationResult:
    """Run a simulation to its budget and write the outputs (see the module docstring).

    ``should_stop`` is polled between frames; when it returns True the run writes
    ``checkpoint.json`` instead of final outputs and returns with ``interrupted``.
    ``analyses`` (:class:`~lightsim.analysis.Analysis`) prepare the run and report on it:
    what ``opts.regulation``/``ies``/``ldt`` ask for, built by
    :func:`lightsim.luminaires.analyses.for_options`. ``plots`` draws the plots
    (:func:`lightsim.io.plot_worker.start`: a plot process started before the run;
    default: here, after the map).
    """
    analyses = list(analyses or ())
    if not analyses and (opts.regulation is not None or opts.ies or opts.ldt or opts.road):
        raise LightsimError("run_simulation: the options ask for a regulation check or "
                            "far-field files but no analyses were given (build them with "
                            "lightsim.luminaires.analyses.for_options)")
    created = not Path(opts.out_dir).exists()
    try:
        return _run(opts, progress, should_stop, on_plan, resume, analyses, plots)
    except LightsimError:
        if created:  # bad input leaves nothing behind, not even the folder
            with contextlib.suppress(OSError):
                Path(opts.out_dir).rmdir()
        raise


def _run(opts: SimulateOptions, progress, should_stop, on_plan, resume,
         analyses: Sequence[Analysis], plots: Any = None) -> SimulationResult:

    clock = {"t0": time.perf_counter()}
    out = check_out_dir(opts.out_dir)  # the options were checked when they were made
    if opts.aim and opts.regulation is None:
        raise InputError("--aim aims the pattern for a regulation check: give --regulation")
    scene = load(opts)
    clock["load"] = time.perf_counter()
    config = opts.run_config()
    check_until(opts, config)
    keeper = photon_keeper(opts, config, analyses)
    config = config.with_(keep_photons=keeper is not None)
    # the kNN estimates read after the run: the cut-off scans and the analyses' points
    # (e.g. --road's per-set maps), accumulated per frame there when no photon is kept
    extra = np.vstack([cutoff_points(scene.wall, opts.traffic, config)]
                      + analysis_points(analyses, scene, config))
    channels = scene.channels or 3
    points = len(extra)  # the stores' points (the error grid reads the ICI lattice)
    estimate = check_fits(opts.photons, scene.wall.resolution, config, channels,  # pre-flight
                          keeper=keeper or "--keep-photons",
                          point_bytes=config.n_sets * store_peak_bytes(points, config.k,
                                                                       channels))
    for analysis in analyses:  # e.g. test points counted in detector apertures
        config = analysis.prepare(config, scene)
    if opts.until is not None and config.guide == "points":
        # the verdicts steer the guide: a target closes when its rules decide, not at a
        # photon count (luminaires.regulations.sequential.VerdictRule.steer)
        config = config.with_(guide_photons=UNTIL_GUIDE_PHOTONS)
    if resume is not None:  # the photons are replayed with the settings they were shot with
        config = resumed_config(resume, config, out)
    scene.warnings.extend(folder_notes(out))  # printed with the scene's warnings
    session = Session(scene, config, workers=opts.workers, address=opts.address,
                      checkpoint=(resume or {}).get("session"),
                      regulation=opts.regulation, farfield=bool(opts.ies or opts.ldt),
                      per_source=opts.per_source, extra_probes=extra)
    session.memory_estimate = estimate
    clock["session"] = time.perf_counter()
    try:
        if on_plan is not None:
            on_plan(session)
        stopped = {"flag": False}

        def stop() -> bool:
            stopped["flag"] = bool(should_stop and should_stop())
            return stopped["flag"]

        photons, rule = opts.photons, None
        if opts.until is not None:  # the verdicts stop the run; the photons cap it
            photons = opts.photons if opts.photons is not None else UNTIL_CAP_PHOTONS
            rule = stopping_rule(analyses, session, photons)
        try:
            est = session.run(photons=photons, seconds=opts.seconds,
                              target_error=opts.target_error, callback=progress,
                              should_stop=stop, probes=False,  # outputs read map + apertures
                              rule=rule)
            if stopped["flag"]:
                write_checkpoint(out, opts, session)
                return SimulationResult(np.zeros((0, 0)), None, {}, out, interrupted=True)
            clock["run"] = time.perf_counter()
            result = write_outputs(out, opts, session, est, analyses, clock=clock,
                                   plots=plots)
        except ClusterError as exc:
            if not getattr(session.backend, "head_lost", False):
                raise
            # the frames shot so far are known here: the run continues from them
            write_checkpoint(out, opts, session)
            raise ClusterError(f"{exc}: checkpoint written to {out / CHECKPOINT} — continue "
                               f"with: lightsim simulate --resume {out} (with the cluster "
                               "back, or --address/--workers anew)") from None
        ckpt = out / CHECKPOINT
        if ckpt.exists():
            ckpt.unlink()
        return result
    finally:
        session.close()


def photon_keeper(opts: SimulateOptions, config: RunConfig,
                  analyses: Sequence[Analysis]) -> str | None:
    """The option that makes the run keep every photon, or None: the run's outputs read
    its kNN estimates only at points known before it (the cut-off scans), so the sets
    accumulate those per frame and drop the photons (memory that does not grow with
    ``--photons``). Kept for ``--keep-photons``, a written map by the ``knn`` bandwidth,
    the ``radius`` estimator or ``--final interleaved`` (every pixel reads the photons),
    and an analysis that
    reads estimates anywhere (its ``reads_photons``: the option that makes it)."""
    if config.estimator == "bin":
        return None  # bins, no photon map at all
    if opts.keep_all_photons:
        return "--keep-photons"
    if config.estimator != "knn":
        return f"--estimator {config.estimator}"
    if not config.uses_ici:
        return f"--bandwidth {config.bandwidth}"
    if config.final != "pooled":  # the sets' sub-images are kNN estimates at every pixel
        return f"--final {config.final}"
    for analysis in analyses:
        reads = getattr(analysis, "reads_photons", f"the {analysis.name} analysis")
        if reads:
            return str(reads)
    return None


def cutoff_points(frame: Any, traffic: str, config: RunConfig) -> np.ndarray:
    """Wall points (h, v in m) of the cut-off scans every set estimates after the run
    (:func:`_cutoff`; none with a single set, which has no spread)."""
    if config.n_sets < 2:
        return np.zeros((0, 2))
    hv, _, _ = scan_sample_points(frame.to_dict(), traffic)
    return np.asarray(hv, dtype=np.float64).reshape(-1, 2)


def analysis_points(analyses: Sequence[Analysis], scene: Scene, config: RunConfig
                    ) -> list[np.ndarray]:
    """The wall points (h, v in m, (n, 2) each) the analyses read after the run (their
    optional ``probe_points``; none with a single set, which has no spread to read)."""
    if config.n_sets < 2:
        return []
    return [np.asarray(a.probe_points(scene), dtype=np.float64).reshape(-1, 2)
            for a in analyses if hasattr(a, "probe_points")]


def check_until(opts: SimulateOptions, config: RunConfig) -> None:
    """``--until decided`` needs verdicts to decide, one stopping rule and the sets'
    spread (one clear line otherwise)."""
    if opts.until is None:
        return
    if opts.regulation is None:
        raise InputError("--until decided stops when the regulation's verdicts are decided: "
                         "give --regulation")
    if opts.target_error is not None:
        raise InputError("--until decided and --target-error are two stopping rules: give "
                         "one of them")
    if config.n_sets < 2:
        raise InputError("--until decided needs at least 2 interleave sets (-M 2 or more): "
                         "the verdicts' intervals come from their spread")


def stopping_rule(analyses: Sequence[Analysis], session, cap_photons: int) -> Any:
    """The first stopping rule an analysis gives (:class:`~lightsim.analysis.StopsRun`),
    bound to ``session`` with the photon cap; None if none does."""
    for analysis in analyses:
        if isinstance(analysis, StopsRun):
            rule = analysis.stopping_rule(session, cap_photons)
            if rule is not None:
                return rule
    return None


def until_summary(opts: SimulateOptions, session, summary: dict[str, Any],
                  analyses: Sequence[Analysis]) -> dict[str, Any] | None:
    """``summary.json["until"]``: the stopping rule's record (after the analyses reported)
    and what ended the run — ``decided``, or the cap that came first: ``memory``,
    ``time`` or ``photons``."""
    for analysis in analyses:
        if isinstance(analysis, StopsRun) and (rec := analysis.stop_summary()) is not None:
            if rec.get("stopped") in ("decided", "verdict"):
                why = str(rec["stopped"])
            elif session.memory_stop is not None:
                why = "memory"
            elif opts.seconds is not None and summary["seconds"] >= opts.seconds:
                why = "time"
            else:
                why = "photons"
            return {**rec, "stopped_by": why}
    return None


def write_checkpoint(out: Path, opts: SimulateOptions, session) -> Path:
    """Write ``checkpoint.json`` into ``out`` (atomically); a disk that cannot take it
    is one line (:class:`~lightsim.errors.LightsimError`), any earlier checkpoint kept."""
    path = out / CHECKPOINT
    try:
        write_json(path, {"lightsim_version": __version__, "options": opts.to_json(),
                          "session": session.checkpoint()})
    except OSError as exc:
        why = write_failure(out, exc, had_set=False).split(";", 1)[0]
        raise LightsimError(f"{why.replace('the outputs', 'the checkpoint')}: the run "
                            "cannot be resumed (free space and run again)") from None
    return path


def read_checkpoint(out_dir: str | os.PathLike) -> tuple[SimulateOptions, dict[str, Any]]:

    path = Path(out_dir) / CHECKPOINT
    if not path.exists():
        raise InputError(f"{out_dir}: no {CHECKPOINT} to resume (finished or never interrupted)")
    doc = read_json(path)
    try:
        opts = SimulateOptions.from_json(doc["options"])
        session = doc["session"]
        session["counters"] = {int(k): int(v) for k, v in session["counters"].items()}
        RunConfig.from_dict(session["config"])
    except (KeyError, TypeError, ValueError, InputError) as exc:
        raise InputError(f"{path}: corrupt checkpoint ({exc})") from None
    return opts, {"session": session, "lightsim_version": doc.get("lightsim_version")}


def resumed_config(resume: dict[str, Any], config: RunConfig, out: Path) -> RunConfig:
    """The checkpoint's engine settings, after checking that the stored options still give
    them (a lightsim of other defaults would replay different photons: refused)."""
    stored = RunConfig.from_dict(resume["session"]["config"])
    if stored != config:
        diff = [f"{o.label} {getattr(stored, o.name)!r} (now {getattr(config, o.name)!r})"
                for o in options.table(RunConfig)
                if getattr(stored, o.name) != getattr(config, o.name)]
        raise InputError(f"{out / CHECKPOINT}: written by lightsim "
                         f"{resume.get('lightsim_version') or '?'} with other settings than "
                         f"its options give now ({'; '.join(diff)}): start a new run")
    return stored


def _lux_stats(lux: np.ndarray, frame) -> dict[str, Any]:
    if lux.size == 0 or not np.any(lux > 0):
        return {"max_lx": 0.0, "max_at_deg": None, "lit_mean_lx": 0.0}
    r, c = np.unravel_index(int(np.argmax(lux)), lux.shape)
    h_c, v_c = frame.pixel_centres()
    hd, vd = frame.degrees(h_c[c], v_c[r])
    lit = lux >= 0.1 * lux.max()
    dh, dv = frame.pixel_size_m
    return {"max_lx": float(lux.max()), "max_at_deg": [float(hd), float(vd)],
            "lit_mean_lx": float(lux[lit].mean()),
            "flux_on_map_lm": float(lux.sum() * dh * dv)}


def write_outputs(out: Path, opts: SimulateOptions, session, est,
                  analyses: Sequence[Analysis] = (), clock: dict[str, float] | None = None,
                  plots: Any = None) -> SimulationResult:
    """Write wall_lux.exr, wall_lux.png, error_vs_time.png, the engineering outputs and
    summary.json as one set (staged inside ``out``, summary.json published last); only
    the files ``opts.outputs`` names, and summary.json always. ``plots``: where the plots
    are drawn (:mod:`lightsim.io.plot_worker`; default here, one after the other)."""
    previous = set(OUTPUT_FILES)
    if (out / "summary.json").is_file():  # the files an earlier run recorded as its set
        with contextlib.suppress(Exception):
            listed = read_json(out / "summary.json").get("outputs")
            if isinstance(listed, list):
                previous |= {str(n) for n in listed if "/" not in str(n)}
    plots = plots if plots is not None else InProcess()
    had_set = (out / "summary.json").is_file()
    try:
        with OutputSet(out, "summary.json", previous) as staged:
            try:
                result = _write_set(staged.dir, opts, session, est, analyses, clock, plots)
            except BaseException:
                plots.abandon()  # no plot may land in the set being given up
                raise
            staged.commit()
    except OSError as exc:  # a full disk, a quota, a folder gone read-only
        raise LightsimError(write_failure(out, exc, had_set)) from None
    result.out_dir = out
    return result


def write_failure(out: Path, exc: OSError, had_set: bool) -> str:
    """One line for outputs that could not be written: why, and what the folder holds
    now (the staged set was dropped, so an earlier complete set is untouched)."""
    why = {errno.ENOSPC: "no space left on the device",
           errno.EDQUOT: "the disk quota is exceeded",
           errno.EROFS: "the file system is read-only"}.get(exc.errno or 0,
                                                          exc.strerror or str(exc))
    if had_set and (out / "summary.json").is_file():
        kept = "the previous complete set of outputs there is kept, unchanged"
    elif had_set:
        kept = "the previous set there is incomplete (no summary.json)"
    else:
        kept = "nothing was written there"
    return (f"could not write the outputs to {out}: {why}; {kept} (free space and run "
            "again)")


def _write_set(out: Path, opts: SimulateOptions, session, est,
               analyses: Sequence[Analysis], clock: dict[str, float] | None,
               plots: Any) -> SimulationResult:
    """Write every output file into ``out`` (the staging folder), summary.json last; the
    plots are handed to ``plots`` first, so a plot process draws them while the map,
    the cut-off and the analyses are written here."""
    scene = session.scene
    frame = scene.wall
    lux = luminous(est.lux)
    rgb = est.lux if est.lux.shape[-1] == 3 else None
    energy = session.energy()
    parts = {k: v for k, v in energy.items() if k != "emitted"}
    placement = getattr(session.backend, "placement", None)  # Ray runs: where actors ran
    closure = (abs(sum(parts.values()) - energy["emitted"]) / energy["emitted"]
               if energy["emitted"] else 0.0)
    cfg = session.config
    photons = int(est.photons)
    wall = frame.to_dict()
    summary: dict[str, Any] = {
        "lightsim_version": __version__,
        "scene": {"source": str(opts.scene_path), "triangles": scene.n_triangles,
                  "parts": scene.describe(), "warnings": scene.warnings,
                  "flux_lm": scene.total_flux},
        "wall": wall,
        "units": {"illuminance": "lx", "flux": "lm", "length": "m", "angle": "deg"},
        "photons": photons,
        "seed": cfg.seed,
        "frames": session.frames,
        "seconds": float(est.seconds),
        # set when a time or error budget would have outgrown the memory (engine/server.py)
        "memory_stop": (None if session.memory_stop is None
                        else {**session.memory_stop.to_json(),
                              "message": session.memory_stop.message()}),
        "rel_error": est.rel_error,
        "rel_noise": None if est.error is None else est.error.noise,
        "rel_bias": None if est.error is None else est.error.bias,
        "rel_bias_upper": None if est.error is None else est.error.bias_upper,
        # the figure's upper bound, √(noise² + rel_bias_upper²) (a target-error stop reads
        # its own bound at the look's confidence: stop_level in engine/server.py)
        "rel_error_upper": None if est.error is None else est.error.upper,
        "error_text": None if est.error is None else est.error.describe()
        + ("" if cfg.error_region == "lit" else f" over the {cfg.error_region}"),
        "error_region": cfg.error_region,  # the pixels the figure covers (render/region.py)
        "estimator": {"name": cfg.estimator, "k": cfg.k, "kernel": cfg.kernel,
                      "interleave": cfg.interleave, "filter": cfg.filter_n,
                      "structure": cfg.structure,
                      "min_radius_m": session.radii_m[0],
                      "max_radius_m": (None if math.isinf(session.radii_m[1])
                                       else session.radii_m[1])},
        "energy_lm": {**energy, "sum_of_parts": sum(parts.values()),
                      "closure_relative": closure},
        "caustic_yield": session.caustic_yield(),
        "lux": _lux_stats(lux, frame),
        "error_vs_time": [e for e in session.log if "photons" in e],
        "plan": session.plan.to_dict(),
        "config": cfg.to_dict(),
        "workers": opts.workers,
        **({"cluster": placement()} if placement is not None else {}),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
    }
    meta = wall_metadata(wall, units="lx", quantity="illuminance",
                         photons=photons, seed=int(cfg.seed), estimator=cfg.estimator,
                         lightsim_version=__version__, source=Path(opts.scene_path).name)
    channels = {"Y": lux.astype(np.float32)}
    if rgb is not None:
        for i, ch in enumerate("RGB"):
            channels[ch] = rgb[..., i].astype(np.float32)
    wanted = set(opts.outputs)
    drawn = []  # matplotlib is imported only where a plot is asked
    if "exr" in wanted:
        write_exr(out / "wall_lux.exr", channels, meta)
    if opts.per_source and (maps := session.per_source()) is not None:
        summary["per_source"] = maps.write(out, {"source": Path(opts.scene_path).name,
                                                 "lightsim_version": __version__})
    _engineering_outputs(out, opts, session, lux, summary, analyses, plots)
    if "error_vs_time" in wanted:  # after the analyses: its caption names the rule sets
        caption = report.plot_caption(summary)
        drawn.append(plots.draw("error_vs_time", out / "error_vs_time.png",
                                summary["error_vs_time"],
                                caption=None if caption is None else caption.text()))
    for p in drawn:
        p.result()
    summary["outputs"] = sorted([p.name for p in out.iterdir() if p.is_file()
                                 and not p.name.startswith(".")] + ["summary.json"])
    summary["timings_s"] = _timings(session, est, clock)
    write_json(out / "summary.json", summary)
    return SimulationResult(lux, rgb, summary, out)


def _timings(session, est, clock: dict[str, float] | None) -> dict[str, float] | None:
    """Where this process's run time went (s, wall clock; see docs/explanation/benchmarks.md):
    loading the scene, the session (plan, pilot, embree, numba), the frames' sample points, tracing
    and insertion, the error estimates, the final map, and the outputs up to summary.json.
    ``clock``: perf_counter stamps t0, load, session, run of :func:`_run`; None when the
    run was not timed (outputs written by a script)."""
    if not clock or "run" not in clock:
        return None
    tot = session.shoot_totals
    final = float(est.timings.get("render", 0.0) + est.timings.get("assemble", 0.0))
    run = clock["run"] - clock["session"]
    return {"load": clock["load"] - clock["t0"], "session": clock["session"] - clock["load"],
            "sample": tot.sample_s, "trace": tot.trace_s,
            "insert": tot.seconds - tot.sample_s - tot.trace_s,
            "estimate": max(run - tot.seconds - final, 0.0), "final_map": final,
            "outputs": time.perf_counter() - clock["run"]}


def _engineering_outputs(out: Path, opts: SimulateOptions, session, lux: np.ndarray,
                         summary: dict[str, Any], analyses: Sequence[Analysis],
                         plots: Any = None) -> None:
    """Cut-off, the analyses (regulation table, far-field files), isolux and road plots."""
    frame = session.scene.wall
    summary["cutoff"] = _cutoff(lux, frame, opts.traffic, session)
    run = FinishedRun(session, lux, opts.traffic, summary["cutoff"],
                      caption=report.plot_caption(summary))
    marks: list[dict[str, Any]] | None = None
    for analysis in analyses:
        result = analysis.report(run, out)
        summary[analysis.name] = result.summary
        if result.marks is not None:  # several rule sets: every set's points, once each
            seen = {(m["name"], m.get("h_deg"), m.get("v_deg")) for m in marks or ()}
            marks = (marks or []) + [m for m in result.marks if (
                m["name"], m.get("h_deg"), m.get("v_deg")) not in seen]
    until = until_summary(opts, session, summary, analyses)
    if until is not None:  # --until decided: its looks and what is still open
        summary["until"] = until
    drawn = {"png": "wall_lux", "isolux": "isolux", "road": "road"}
    report.engineering_plots(out, lux, frame, marks, opts.mount_height, summary=summary,
                             which=tuple(v for k, v in drawn.items() if k in opts.outputs),
                             plots=plots, log=opts.log_scale)


def _cutoff(lux: np.ndarray, frame, traffic: str, session=None) -> dict[str, Any]:
    res = find_cutoff(lux, frame.to_dict(), traffic)
    out = {"found": res.found, "message": res.message, "v_cutoff_deg": res.v_cutoff_deg,
           "sharpness_g": res.sharpness_g, "linear": res.linear,
           # annex 9's scans: where each found its inflection and how far apart they are
           "spread_deg": res.spread_deg,
           "scans": [{"h_deg": s.h_deg, "v_inflection_deg": s.v_inflection_deg,
                      "sharpness_g": s.sharpness_g} for s in res.scans],
           "aim_dv_deg": res.aim_dv_deg}
    if res.found and session is not None and session.config.n_sets > 1:
        # every set scans its own estimate: their spread is the position's interval
        hv, _, _ = scan_sample_points(frame.to_dict(), traffic)
        ci = cutoff_interval(luminous(session.probe(hv).values), frame.to_dict(),
                             res.v_cutoff_deg, traffic)
        out["v_cutoff_interval_deg"] = (None if ci.interval_deg is None
                                        else list(ci.interval_deg))
        out["interval"] = ci.to_dict()
    return out

