"""Far-field photometric files of a run (``--ies``, ``--ldt``): the lamp's intensity over
the sphere written as IES LM-63 (Type A or C) or EULUMDAT.

:class:`FarfieldAnalysis` is the :class:`~lightsim.analysis.Analysis` that
``lightsim simulate`` hands to the run. Where the wall is, the intensities are the run's
own photons — beam bins counted as they were inserted, and the wall map
(:mod:`~.runfield`); elsewhere a far-field trace of the lamp without its wall
(:func:`lightsim.report.escaped_light`). The file's angles are auto (uneven, fine where
the beam changes fast) or equal steps (:mod:`~.gridding`); each file is compared with the
run's apertures and a one-line warning says when it cannot reproduce the run
(:mod:`~.reproduce`).

=====================  =====  =========  ==============================================
parameter              unit   default    meaning
=====================  =====  =========  ==============================================
``ies``, ``ldt``       –      None       output files (``.ies``; ``.ldt`` or ``.eul``)
``ies_type``           –      auto       A, C or auto (A for lamp models and Type A
                                         inputs, else C; :func:`resolve_ies_type`)
``photons``            –      10⁶        photons of the far-field trace (no wall)
``ies_step``           deg    auto       equal angle step of the IES file (None: auto)
``ldt_step``           deg    auto       equal angle step of the EULUMDAT file
``step_deg``           deg    1          grid step of :func:`farfield_grid`
``TYPE_A_OUTSIDE_WARN`` –     0.01       share of the flux outside a Type A file (behind
                                         the lamp) above which the run warns
=====================  =====  =========  ==============================================
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.analysis import AnalysisReport, FinishedRun
from lightsim.report import escaped_light

from . import farfield_from_photons, resolve_ies_type, write_photometric
from .gridding import (
    IES_MAX_PLANES,
    IES_MAX_POLAR,
    LDT_MAX_GAMMA,
    LDT_MAX_PLANES,
    check_step,
    file_axes,
    regrid,
)
from .reproduce import reproduction
from .runfield import beam_bins, beam_raster_config, run_field

__all__ = ["TYPE_A_OUTSIDE_WARN", "FarfieldAnalysis", "farfield_grid", "farfield_grids",
           "type_a_outside_warning"]

TYPE_A_OUTSIDE_WARN = 0.01
"""Share of the far-field flux outside a written Type A file above which we warn."""


def farfield_grid(scene, photons: int = 1_000_000, seed: int = 1, step_deg: float = 1.0,
                  threads: int | None = None, photometric_type: str = "C"):
    """Far-field intensity (Type C grid, or Type A with ``photometric_type="A"``; cd) from
    a far-field trace alone: photons leaving the lamp without its wall.

    Photons are traced through the luminaire alone; those escaping to infinity are
    binned by direction (I = ΔΦ/ΔΩ).
    """
    return farfield_grids(scene, photons, seed, step_deg, threads,
                          (photometric_type,))[photometric_type]


def farfield_grids(scene, photons: int = 1_000_000, seed: int = 1, step_deg: float = 1.0,
                   threads: int | None = None, photometric_types: tuple[str, ...] = ("C",)):
    """:func:`farfield_grid` for several photometric types from one set of traced photons."""
    light = escaped_light(scene, photons, seed, threads)
    meta = {"luminaire": light.luminaire, "test": f"lightsim far field, {photons} photons"}
    return {t: farfield_from_photons(light.directions, light.power_lm, light.photons,
                                     dc_deg=step_deg, dgamma_deg=step_deg,
                                     lamp_lumens=light.lamp_lumens, metadata=meta,
                                     photometric_type=t)
            for t in photometric_types}


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


@dataclass
class FarfieldAnalysis:
    """``--ies``/``--ldt``: the run's intensity over the sphere written as far-field files
    (an :class:`~lightsim.analysis.Analysis`).

    Before the run it asks for the beam bins (:func:`~.runfield.beam_raster_config`);
    after it, the wall photons (bins and map) and a far-field trace of ``photons`` photons
    for the rest of the sphere make one table (:func:`~.runfield.run_field`), written on
    auto or equal-step angles (:mod:`~.gridding`) and compared with the run's apertures
    (:mod:`~.reproduce`). A misspelt ``ies_type`` or a step that does not divide the
    sphere fails at construction, before any work.
    """

    ies: str | None = None
    ldt: str | None = None
    ies_type: str = "auto"
    photons: int = 1_000_000
    ies_step: float | None = None
    ldt_step: float | None = None
    name: str = "farfield"

    #: the far field reads the beam bins, apertures and counters, no kNN estimate
    reads_photons = None

    def __post_init__(self) -> None:
        resolve_ies_type(self.ies_type, None)
        if self.ies_step is not None:
            check_step(self.ies_step, "ies", "--ies-step")
        if self.ldt_step is not None:
            check_step(self.ldt_step, "ldt", "--ldt-step")

    def prepare(self, config: Any, scene: Any) -> Any:
        """The beam bins the files are made from (kept as they are if a rule set counts
        its test points in apertures)."""
        return beam_raster_config(config, scene.wall)

    def report(self, run: FinishedRun, out: Path) -> AnalysisReport:
        """Write the requested files; the summary holds the far field's figures and how
        each file reproduces the run."""
        session = run.session
        scene = session.scene
        src = next((p.distribution for p in scene.parts if p.distribution is not None), None)
        ies_type = resolve_ies_type(self.ies_type, None if src is None
                                    else src.photometric_type)
        light = escaped_light(scene, self.photons, seed=session.config.seed)
        bins = beam_bins(session)
        field = run_field(scene.wall, run.lux, bins, light.directions, light.power_lm,
                          light.photons)
        run_photons = int(sum(session.emitted_per_set().values()))
        meta = {"luminaire": light.luminaire,
                "test": f"lightsim simulation: {run_photons} photons (wall), far field "
                        f"{self.photons} photons",
                "photons_emitted": str(run_photons), "farfield_photons": str(self.photons)}
        total_lm = float(field.grid.total_flux())
        summary: dict[str, Any] = {"photons": self.photons, "total_flux_lm": total_lm,
                                   "max_cd": float(np.max(field.grid.candela)),
                                   "files": [], "ies_type": ies_type if self.ies else None,
                                   "beam_bins": None if bins is None else {
                                       "h_deg": [float(bins.h_deg[0]), float(bins.h_deg[-1])],
                                       "v_deg": [float(bins.v_deg[0]), float(bins.v_deg[-1])],
                                       "size_deg": [bins.width_deg, bins.height_deg]},
                                   "checks": {}}
        wanted = []
        if self.ies:
            wanted.append((self.ies, ies_type, self.ies_step, (IES_MAX_PLANES, IES_MAX_POLAR),
                           "--ies-step"))
        if self.ldt:
            wanted.append((self.ldt, "C", self.ldt_step, (LDT_MAX_PLANES, LDT_MAX_GAMMA),
                           "--ldt-step"))
        notes, files = [], []
        for path, kind, step, budget, flag in wanted:
            planes, polar, sample = file_axes(field, kind, step, budget)
            grid = regrid(field, kind, planes, polar, lamp_lumens=light.lamp_lumens,
                          metadata=meta, sample=sample)
            if kind == "A":
                out_a = float(grid.metadata.get("flux_outside_lm", 0.0))
                summary["type_a_flux_lm"] = float(grid.total_flux())
                summary["type_a_outside_lm"] = out_a
                if path == self.ies:
                    note = type_a_outside_warning(path, float(grid.total_flux()), out_a)
                    if note:
                        notes.append(note)
            files.append(write_photometric(path, grid))
            hint = (f"{flag} {step:g}° is too coarse (auto angles keep the beam)"
                    if step is not None else "")
            check = reproduction(grid, Path(path).name, session, bins, hint)
            if check.warning:
                notes.append(check.warning)
            summary["files"].append(str(path))
            summary["checks"][str(path)] = {
                "type": kind, "step_deg": step, "angles": [len(planes), len(polar)],
                "max_cd": float(np.max(grid.candela)), "flux_lm": float(grid.total_flux()),
                **check.to_dict()}
        if notes:  # one line for the command line, each note for scripts
            summary["warnings"] = notes
            summary["warning"] = "; ".join(notes)
        return AnalysisReport(summary, files=files)
