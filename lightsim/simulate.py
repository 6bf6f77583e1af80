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
``wall_lux.png``       false colour with a lux colour bar, axes H/V in degrees
``summary.json``       wall frame, energy bookkeeping (lm), error vs time, plan, settings,
                       ``outputs``: the files of this set (moved in last: the run finished)
``error_vs_time.png``  estimated relative error against seconds and photons (log-log)
``checkpoint.json``    only while a run is interrupted: ``--resume DIR`` continues it
=====================  ====================================================================
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim import __version__
from lightsim.engine.config import RunConfig
from lightsim.errors import InputError
from lightsim.io.cad import Tessellation
from lightsim.scene import Scene, load_scene

CHECKPOINT = "checkpoint.json"


@dataclass
class SimulateOptions:
    """Everything a simulation run depends on (stored in checkpoints for ``--resume``)."""

    scene_path: str
    out_dir: str = "lightsim-out"
    photons: int | None = None
    seconds: float | None = None
    target_error: float | None = None
    flux: float | None = None
    emission: str | None = None
    filament: str | None = None
    filament_at: tuple[float, float, float] | None = None
    filament_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    wall_distance: float = 25.0
    wall_size: tuple[float, float] = (30.0, 12.0)
    resolution: tuple[int, int] = (640, 256)
    part_materials: dict[str, str] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    log_scale: bool = False
    workers: int = 0
    address: str | None = None
    regulation: str | None = None
    traffic: str = "right"
    aim: bool = False
    ies: str | None = None
    ldt: str | None = None
    farfield_photons: int = 1_000_000
    mount_height: float = 0.65
    ies_type: str = "auto"
    lamp_set: int | None = None
    aperture: float = 0.15
    spt_points: bool = False
    rayfile: str | None = None
    rayfile_at: tuple[float, float, float] | None = None
    rayfile_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    materials: str | None = None
    cad_linear_tol_mm: float = 0.01
    cad_angular_tol_deg: float = 2.0

    def run_config(self) -> RunConfig:
        """The engine settings (validated); also checks the photometric output names, so
        a misspelt option fails before the run rather than after it."""
        for opt, path, suffixes in (("--ies", self.ies, (".ies",)),
                                    ("--ldt", self.ldt, (".ldt", ".eul"))):
            if path is not None and Path(path).suffix.lower() not in suffixes:
                raise InputError(f"{opt} {path}: the file name must end in "
                                 f"{' or '.join(suffixes)}")
        from lightsim.luminaires.photometric import resolve_ies_type

        resolve_ies_type(self.ies_type, None)  # a misspelt --ies-type fails here
        if self.lamp_set is not None and not self.lamp_set >= 1:
            raise InputError(f"--lamp-set must be ≥ 1, got {self.lamp_set}")
        cfg = dict(self.config)
        if cfg.get("max_radius") == "inf":
            cfg["max_radius"] = math.inf
        if "probe_grid" in cfg:
            cfg["probe_grid"] = tuple(cfg["probe_grid"])
        if "extra_probes" in cfg:
            cfg["extra_probes"] = tuple(tuple(p) for p in cfg["extra_probes"])
        return RunConfig(**cfg)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SimulateOptions:
        d = dict(d)
        for key in ("filament_at", "filament_axis", "wall_size", "resolution", "rayfile_at",
                    "rayfile_axis"):
            if d.get(key) is not None:
                d[key] = tuple(d[key])
        return cls(**d)


@dataclass
class SimulationResult:
    lux: np.ndarray          # (H, W) luminous illuminance, lx
    rgb: np.ndarray | None   # (H, W, 3) for coloured scenes
    summary: dict[str, Any]
    out_dir: Path
    interrupted: bool = False


OUTPUT_FILES = ("wall_lux.exr", "wall_lux.png", "error_vs_time.png", "isolux.png",
                "road.png", "probes.npz", "summary.json")
"""Files a finished run may have left in its folder (an older set's are replaced)."""


def check_out_dir(path: str | os.PathLike) -> Path:
    """Create the output folder and make sure files can be written there.

    The test writes a staging-named empty folder (removed at once; a kill in between leaves
    only what the next run's clean-up removes).
    """
    from lightsim.io.atomic import STAGING_PREFIX

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
    from lightsim.io.atomic import clean_stale, unfinished_set

    notes = clean_stale(out)
    left = unfinished_set(out, OUTPUT_FILES)
    if left:
        notes.append(f"{out}: holds an unfinished run's outputs ({', '.join(left)}; no "
                     "summary.json): this run replaces them")
    return notes


def load(opts: SimulateOptions) -> Scene:
    return load_scene(opts.scene_path, flux=opts.flux, emission=opts.emission,
                      filament=opts.filament, filament_at=opts.filament_at,
                      filament_axis=opts.filament_axis, wall_distance=opts.wall_distance,
                      wall_size=opts.wall_size, resolution=opts.resolution,
                      part_materials=opts.part_materials, lamp_set=opts.lamp_set,
                      rayfile=opts.rayfile,
                      rayfile_at=opts.rayfile_at, rayfile_axis=opts.rayfile_axis,
                      materials=opts.materials,
                      tessellation=Tessellation(opts.cad_linear_tol_mm,
                                                opts.cad_angular_tol_deg))


def run_simulation(opts: SimulateOptions, *, progress: Callable[[Any], None] | None = None,
                   should_stop: Callable[[], bool] | None = None,
                   on_plan: Callable[[Any], None] | None = None,
                   resume: dict[str, Any] | None = None) -> SimulationResult:
    """Run a simulation to its budget and write the outputs (see the module docstring).

    ``should_stop`` is polled between frames; when it returns True the run writes
    ``checkpoint.json`` instead of final outputs and returns with ``interrupted``.
    """
    from lightsim.errors import LightsimError

    created = not Path(opts.out_dir).exists()
    try:
        return _run(opts, progress, should_stop, on_plan, resume)
    except LightsimError:
        if created:  # bad input leaves nothing behind, not even the folder
            with contextlib.suppress(OSError):
                Path(opts.out_dir).rmdir()
        raise


def _run(opts: SimulateOptions, progress, should_stop, on_plan, resume) -> SimulationResult:
    from lightsim.engine.server import Session

    out = check_out_dir(opts.out_dir)
    if opts.photons is not None and opts.photons < 1:
        raise InputError(f"--photons must be at least 1, got {opts.photons}")
    if opts.seconds is not None and not (opts.seconds > 0):
        raise InputError(f"--time must be positive, got {opts.seconds}")
    if opts.target_error is not None and not (0 < opts.target_error < 1):
        raise InputError(f"target error must lie in (0, 1), got {opts.target_error}")
    if opts.traffic not in ("right", "left"):
        raise InputError(f"traffic must be 'right' or 'left', got '{opts.traffic}'")
    if opts.regulation is not None:
        from lightsim.luminaires.regulations import load_ruleset

        load_ruleset(opts.regulation)  # an unknown rule set fails before any work
    if opts.aim and opts.regulation is None:
        raise InputError("--aim aims the pattern for a regulation check: give --regulation")
    scene = load(opts)
    config = opts.run_config()
    if opts.regulation is not None:  # test points counted in detector apertures
        from lightsim.report import aperture_config

        config = aperture_config(config, opts.regulation, opts.traffic, scene.wall,
                                 opts.aperture, opts.aim, opts.spt_points)
    scene.warnings.extend(folder_notes(out))  # printed with the scene's warnings
    session = Session(scene, config, workers=opts.workers, address=opts.address,
                      checkpoint=(resume or {}).get("session"),
                      regulation=opts.regulation, farfield=bool(opts.ies or opts.ldt))
    try:
        if on_plan is not None:
            on_plan(session)
        stopped = {"flag": False}

        def stop() -> bool:
            stopped["flag"] = bool(should_stop and should_stop())
            return stopped["flag"]

        est = session.run(photons=opts.photons, seconds=opts.seconds,
                          target_error=opts.target_error, callback=progress, should_stop=stop,
                          probes=False)  # the outputs read the map and the apertures
        if stopped["flag"]:
            write_checkpoint(out, opts, session)
            return SimulationResult(np.zeros((0, 0)), None, {}, out, interrupted=True)
        result = write_outputs(out, opts, session, est)
        ckpt = out / CHECKPOINT
        if ckpt.exists():
            ckpt.unlink()
        return result
    finally:
        session.close()


def write_checkpoint(out: Path, opts: SimulateOptions, session) -> Path:
    from lightsim.io.summary import write_json

    path = out / CHECKPOINT
    write_json(path, {"lightsim_version": __version__, "options": opts.to_json(),
                      "session": session.checkpoint()})
    return path


def read_checkpoint(out_dir: str | os.PathLike) -> tuple[SimulateOptions, dict[str, Any]]:
    from lightsim.io.summary import read_json

    path = Path(out_dir) / CHECKPOINT
    if not path.exists():
        raise InputError(f"{out_dir}: no {CHECKPOINT} to resume (finished or never interrupted)")
    doc = read_json(path)
    try:
        opts = SimulateOptions.from_json(doc["options"])
        session = doc["session"]
        session["counters"] = {int(k): int(v) for k, v in session["counters"].items()}
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: corrupt checkpoint ({exc})") from None
    return opts, {"session": session}


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


def write_outputs(out: Path, opts: SimulateOptions, session, est) -> SimulationResult:
    """Write wall_lux.exr, wall_lux.png, error_vs_time.png, the engineering outputs and
    summary.json as one set (staged inside ``out``, summary.json published last)."""
    from lightsim.io.atomic import OutputSet
    from lightsim.io.summary import read_json

    previous = set(OUTPUT_FILES)
    if (out / "summary.json").is_file():  # the files an earlier run recorded as its set
        with contextlib.suppress(Exception):
            listed = read_json(out / "summary.json").get("outputs")
            if isinstance(listed, list):
                previous |= {str(n) for n in listed if "/" not in str(n)}
    with OutputSet(out, "summary.json", previous) as staged:
        result = _write_set(staged.dir, opts, session, est)
        staged.commit()
    result.out_dir = out
    return result


def _write_set(out: Path, opts: SimulateOptions, session, est) -> SimulationResult:
    """Write every output file into ``out`` (the staging folder), summary.json last."""
    from lightsim.io.errorplot import error_vs_time_plot
    from lightsim.io.exr import wall_metadata, write_exr
    from lightsim.io.png import write_lux_png
    from lightsim.io.summary import write_json
    from lightsim.render.frame import luminous

    scene = session.scene
    frame = scene.wall
    lux = luminous(est.lux)
    rgb = est.lux if est.lux.shape[-1] == 3 else None
    energy = session.energy()
    parts = {k: v for k, v in energy.items() if k != "emitted"}
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
        "rel_error": est.rel_error,
        "rel_noise": None if est.error is None else est.error.noise,
        "rel_bias": None if est.error is None else est.error.bias,
        "rel_bias_upper": None if est.error is None else est.error.bias_upper,
        "error_text": None if est.error is None else est.error.describe(),
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
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
    }
    meta = wall_metadata(wall, units="lx", quantity="illuminance",
                         photons=photons, seed=int(cfg.seed), estimator=cfg.estimator,
                         lightsim_version=__version__, source=Path(opts.scene_path).name)
    channels = {"Y": lux.astype(np.float32)}
    if rgb is not None:
        for i, ch in enumerate("RGB"):
            channels[ch] = rgb[..., i].astype(np.float32)
    write_exr(out / "wall_lux.exr", channels, meta)
    write_lux_png(out / "wall_lux.png", lux, wall, log=opts.log_scale,
                  title=f"{Path(opts.scene_path).name}: {photons:,} photons")
    error_vs_time_plot(out / "error_vs_time.png", summary["error_vs_time"])
    _engineering_outputs(out, opts, session, lux, summary)
    summary["outputs"] = sorted([p.name for p in out.iterdir() if p.is_file()
                                 and not p.name.startswith(".")] + ["summary.json"])
    write_json(out / "summary.json", summary)
    return SimulationResult(lux, rgb, summary, out)


def _engineering_outputs(out: Path, opts: SimulateOptions, session, lux: np.ndarray,
                         summary: dict[str, Any]) -> None:
    """Regulation check, isolux and road plots, far-field files (see lightsim.report)."""
    from lightsim import report

    frame = session.scene.wall
    results = None
    if opts.regulation is not None:
        reg = report.regulation_check(session, lux, opts.regulation, opts.traffic, opts.aim)
        report.save_probes(out, reg)
        summary["regulation"] = report.public(reg)
        results = reg["results"]
    summary["cutoff"] = _cutoff(lux, frame, opts.traffic, session)
    if results is not None and summary["regulation"].get("aim", {}).get("applied"):
        summary["regulation"]["aim"]["cutoff_interval_deg"] = summary["cutoff"].get(
            "v_cutoff_interval_deg")
    report.engineering_plots(out, lux, frame, results, opts.mount_height,
                            summary=summary)
    if opts.ies or opts.ldt:
        from lightsim.luminaires.photometric import resolve_ies_type, write_photometric

        src = next((p.distribution for p in session.scene.parts
                    if p.distribution is not None), None)
        ies_type = resolve_ies_type(opts.ies_type, None if src is None
                                    else src.photometric_type)
        wanted = {path: (ies_type if path == opts.ies else "C")
                  for path in (opts.ies, opts.ldt) if path}
        grids = report.farfield_grids(session.scene, opts.farfield_photons,
                                      seed=session.config.seed,
                                      photometric_types=tuple(sorted(set(wanted.values()))))
        grid = grids["C"] if "C" in grids else grids["A"]
        # a Type A grid holds the front hemisphere only: the far field's flux adds what
        # it leaves out, so the figure is the lamp's whatever file type was asked for
        total_lm = float(grid.total_flux()) + (
            0.0 if "C" in grids else float(grid.metadata.get("flux_outside_lm", 0.0)))
        summary["farfield"] = {"photons": opts.farfield_photons,
                               "total_flux_lm": total_lm,
                               "max_cd": float(np.max(grid.candela)), "files": [],
                               "ies_type": ies_type if opts.ies else None}
        if "A" in grids:
            out_a = float(grids["A"].metadata.get("flux_outside_lm", 0.0))
            summary["farfield"]["type_a_flux_lm"] = float(grids["A"].total_flux())
            summary["farfield"]["type_a_outside_lm"] = out_a
            if opts.ies and ies_type == "A":
                note = type_a_outside_warning(opts.ies, float(grids["A"].total_flux()), out_a)
                if note:
                    summary["farfield"]["warning"] = note
        for path, kind in wanted.items():
            write_photometric(path, grids[kind])
            summary["farfield"]["files"].append(str(path))


TYPE_A_OUTSIDE_WARN = 0.01
"""Share of the far-field flux outside a written Type A file above which we warn."""


def type_a_outside_warning(path: str | os.PathLike, inside_lm: float, outside_lm: float,
                           threshold: float = TYPE_A_OUTSIDE_WARN) -> str | None:
    """One line when more than ``threshold`` of the far-field flux (lm) is not in the Type A
    file at ``path`` (it holds only the front hemisphere, H and V within ±90°); else None."""
    total = inside_lm + outside_lm
    if not (total > 0 and math.isfinite(total)) or outside_lm <= threshold * total:
        return None
    return (f"{Path(path).name} (Type A) holds only the front hemisphere: {outside_lm:.3g} lm "
            f"of the far field's {total:.4g} lm ({outside_lm / total:.1%}) leaves behind the "
            "lamp and is not in it; --ies-type C keeps all of it")


def _cutoff(lux: np.ndarray, frame, traffic: str, session=None) -> dict[str, Any]:
    from lightsim.render.cutoff import cutoff_interval, find_cutoff, scan_sample_points

    res = find_cutoff(lux, frame.to_dict(), traffic)
    out = {"found": res.found, "message": res.message, "v_cutoff_deg": res.v_cutoff_deg,
           "sharpness_g": res.sharpness_g, "linear": res.linear,
           "aim_dv_deg": res.aim_dv_deg}
    if res.found and session is not None and session.config.n_sets > 1:
        # every set scans its own estimate: their spread is the position's interval
        hv, _, _ = scan_sample_points(frame.to_dict(), traffic)
        from lightsim.render.frame import luminous

        ci = cutoff_interval(luminous(session.probe(hv).values), frame.to_dict(),
                             res.v_cutoff_deg, traffic)
        out["v_cutoff_interval_deg"] = (None if ci.interval_deg is None
                                        else list(ci.interval_deg))
        out["interval"] = ci.to_dict()
    return out


def describe_options(opts: SimulateOptions) -> str:
    return json.dumps(opts.to_json(), default=str)
