"""Far-field photometric files of a run (``--ies``, ``--ldt``): the lamp without its wall,
binned into Type C or Type A grids and written as IES LM-63 or EULUMDAT.

:class:`FarfieldAnalysis` is the :class:`~lightsim.analysis.Analysis` that
``lightsim simulate`` hands to the run; the photons come from
:func:`lightsim.report.escaped_light` (traced by the engine), the grids from
:func:`~lightsim.luminaires.photometric.farfield_from_photons`.

=====================  =====  =========  ==============================================
parameter              unit   default    meaning
=====================  =====  =========  ==============================================
``ies``, ``ldt``       –      None       output files (``.ies``; ``.ldt`` or ``.eul``)
``ies_type``           –      auto       A, C or auto (A for lamp models and Type A
                                         inputs, else C; :func:`resolve_ies_type`)
``photons``            –      10⁶        photons traced without the wall
``step_deg``           deg    1          grid step in C and γ (or H and V)
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

__all__ = ["TYPE_A_OUTSIDE_WARN", "FarfieldAnalysis", "farfield_grid", "farfield_grids",
           "type_a_outside_warning"]

TYPE_A_OUTSIDE_WARN = 0.01
"""Share of the far-field flux outside a written Type A file above which we warn."""


def farfield_grid(scene, photons: int = 1_000_000, seed: int = 1, step_deg: float = 1.0,
                  threads: int | None = None, photometric_type: str = "C"):
    """Far-field intensity (Type C grid, or Type A with ``photometric_type="A"``; cd) from
    photons leaving the lamp (no wall).

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
    """``--ies``/``--ldt``: trace the lamp without its wall after the run and write the
    far-field files (an :class:`~lightsim.analysis.Analysis`).

    A misspelt ``ies_type`` fails at construction, before any work.
    """

    ies: str | None = None
    ldt: str | None = None
    ies_type: str = "auto"
    photons: int = 1_000_000
    name: str = "farfield"

    def __post_init__(self) -> None:
        resolve_ies_type(self.ies_type, None)

    def prepare(self, config: Any, scene: Any) -> Any:
        """Nothing to measure on the wall."""
        return config

    def report(self, run: FinishedRun, out: Path) -> AnalysisReport:
        """Write the requested files; the summary holds the far field's figures."""
        scene = run.session.scene
        src = next((p.distribution for p in scene.parts if p.distribution is not None), None)
        ies_type = resolve_ies_type(self.ies_type, None if src is None
                                    else src.photometric_type)
        wanted = {path: (ies_type if path == self.ies else "C")
                  for path in (self.ies, self.ldt) if path}
        grids = farfield_grids(scene, self.photons, seed=run.session.config.seed,
                               photometric_types=tuple(sorted(set(wanted.values()))))
        grid = grids["C"] if "C" in grids else grids["A"]
        # a Type A grid holds the front hemisphere only: the far field's flux adds what
        # it leaves out, so the figure is the lamp's whatever file type was asked for
        total_lm = float(grid.total_flux()) + (
            0.0 if "C" in grids else float(grid.metadata.get("flux_outside_lm", 0.0)))
        summary: dict[str, Any] = {"photons": self.photons, "total_flux_lm": total_lm,
                                   "max_cd": float(np.max(grid.candela)), "files": [],
                                   "ies_type": ies_type if self.ies else None}
        if "A" in grids:
            out_a = float(grids["A"].metadata.get("flux_outside_lm", 0.0))
            summary["type_a_flux_lm"] = float(grids["A"].total_flux())
            summary["type_a_outside_lm"] = out_a
            if self.ies and ies_type == "A":
                note = type_a_outside_warning(self.ies, float(grids["A"].total_flux()), out_a)
                if note:
                    summary["warning"] = note
        files = []
        for path, kind in wanted.items():
            files.append(write_photometric(path, grids[kind]))
            summary["files"].append(str(path))
        return AnalysisReport(summary, files=files)
