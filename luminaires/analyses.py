"""The analyses a run's options ask for: the rule set's table, the far-field files.

``lightsim simulate`` (and everything that runs a simulation the same way: ``lightsim
design``, the tolerance study, ``lightsim view``'s save) turns its options into this list
and passes it to :func:`lightsim.simulate.run_simulation`; the engine calls them through
the :class:`lightsim.analysis.Analysis` protocol without importing this package.

==================  =====  ==========================================================
option              unit   analysis
==================  =====  ==========================================================
``regulation``      –      :class:`~.regulations.check.RegulationAnalysis` per rule set
                           of the comma list (with ``traffic``, ``aim``, ``aperture``
                           deg, ``spt_points``; ``until`` = decided: one shared
                           :class:`~.regulations.sequential.VerdictRule`; with
                           ``--guide points`` also :class:`~.regulations.sequential.
                           GuideTargets`)
``ies``, ``ldt``    –      :class:`~.photometric.analysis.FarfieldAnalysis` (with
                           ``ies_type``, ``farfield_photons``, ``ies_step``,
                           ``ldt_step`` deg)
``provenance``      –      :class:`~.provenance_report.ProvenanceAnalysis` of the rule
                           sets (path classes per rule)
``road``            –      :class:`lightsim.road_evaluation.RoadAnalysis` (with
                           ``mount_height`` m, ``traffic``)
==================  =====  ==========================================================
"""

from __future__ import annotations

from typing import Any

from lightsim.analysis import Analysis
from lightsim.errors import InputError
from lightsim.road_evaluation import RoadAnalysis, RoadSettings

from .photometric import resolve_ies_type
from .photometric.analysis import FarfieldAnalysis
from .photometric.gridding import check_step
from .provenance_report import ProvenanceAnalysis
from .regulations.check import RegulationAnalysis, split_rulesets
from .regulations.conditions import refuse_screen_check
from .regulations.sequential import GuideTargets, VerdictRule

__all__ = ["for_options"]


def for_options(opts: Any) -> list[Analysis]:
    """The analyses of a :class:`~lightsim.simulate.SimulateOptions`, in report order.

    Building them checks their options (an unknown rule set, a misspelt ``--ies-type``
    raise :class:`~lightsim.errors.InputError` before any work).
    """
    resolve_ies_type(opts.ies_type, None)  # a misspelt --ies-type fails even without --ies
    for step, kind, flag in ((opts.ies_step, "ies", "--ies-step"),
                             (opts.ldt_step, "ldt", "--ldt-step")):
        if step is not None:
            check_step(step, kind, flag)
    out: list[Analysis] = []
    if opts.regulation is not None:
        # --until decided/verdict: one stopping rule over every rule set's verdicts
        until = VerdictRule(stop=opts.until) if opts.until is not None else None
        # `a,b`: one table per rule set, the first named "regulation"
        for i, rs in enumerate(split_rulesets(opts.regulation)):
            analysis = RegulationAnalysis(rs, opts.traffic, opts.aim, opts.aperture,
                                          opts.spt_points,
                                          name="regulation" if i == 0 else f"regulation:{rs}",
                                          until=until)
            refuse_screen_check(analysis.rules)  # re-aim etc.: `lightsim check` instead
            out.append(analysis)
        if opts.run_config().guide == "points":  # one guide target per point or zone
            out.append(GuideTargets(tuple(split_rulesets(opts.regulation)), opts.traffic))
    if getattr(opts, "provenance", False):
        regs = [a for a in out if isinstance(a, RegulationAnalysis)]
        if not regs:
            raise InputError("--provenance breaks regulation rules down: give --regulation")
        if not opts.aperture:
            raise InputError("--provenance splits the detector apertures' photons: give "
                             "--aperture > 0")
        out.append(ProvenanceAnalysis(regs, map_text=opts.provenance_map or ""))
    elif getattr(opts, "provenance_map", None):
        raise InputError("--provenance-map needs --provenance")
    if opts.ies or opts.ldt:
        out.append(FarfieldAnalysis(opts.ies, opts.ldt, opts.ies_type, opts.farfield_photons,
                                    opts.ies_step, opts.ldt_step))
    if getattr(opts, "road", False):
        out.append(RoadAnalysis(RoadSettings(mount_height=opts.mount_height,
                                             traffic=opts.traffic)))
    return out
