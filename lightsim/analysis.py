"""What a run is checked against: the protocol that regulation tables and photometric files
implement, so the engine calls them without importing them.

``lightsim simulate`` composes a list of analyses from its options (a rule set, IES/LDT
files: :mod:`lightsim.luminaires.analyses`) and hands it to
:func:`lightsim.simulate.run_simulation`. The run calls each one twice:

1. :meth:`Analysis.prepare` before shooting, to add what it needs measured to the run's
   configuration (detector apertures at a rule set's test points, SPT targets);
2. (an analysis that can also stop the run, :class:`StopsRun`: ``--until decided``)
   :meth:`StopsRun.stopping_rule` once the session exists, for the
   :class:`~lightsim.engine.server.StoppingRule` the run is handed;
3. :meth:`Analysis.report` after the last frame, with the :class:`FinishedRun` (the session,
   the lux map, the cut-off found on it), to measure, evaluate and write its files. Its
   :class:`AnalysisReport` goes into ``summary.json`` under :attr:`Analysis.name`.

The engine (``lightsim/``) never imports ``lightsim.luminaires``: the data flows one way,
scene → photons → maps → lux image → analyses.

=================  =====  ========  =========================================================
name               unit   default   meaning
=================  =====  ========  =========================================================
``name``           –      –         the analysis's key in ``summary.json``
``lux``            lx     –         (H, W) luminous wall illuminance of the finished run
``traffic``        –      right     right- or left-hand traffic of the run
``cutoff``         –      –         ``summary.json["cutoff"]`` of the run (position, interval)
``marks``          –      None      rows to mark on the iso-lux plot (name, h/v deg, verdict)
=================  =====  ========  =========================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["Analysis", "AnalysisReport", "FinishedRun", "StopsRun"]


@dataclass(frozen=True)
class FinishedRun:
    """What an analysis may read of a finished run.

    Attributes
    ----------
    session : lightsim.engine.server.Session
        The finished (still open) session: per-set estimates at any wall point
        (``session.probe``), detector apertures, the scene.
    lux : ndarray, shape (H, W)
        Luminous wall illuminance (lx) of the written map.
    traffic : str
        ``right`` or ``left``.
    cutoff : dict
        The run's cut-off summary (``summary.json["cutoff"]``).
    caption : lightsim.io.plots.PlotCaption or None
        What the analyses' plots say of the run (lamp, seed, photons, error figure).
    """

    session: Any
    lux: np.ndarray
    traffic: str = "right"
    cutoff: dict[str, Any] = field(default_factory=dict)
    caption: Any = None

    @property
    def frame(self) -> Any:
        """The wall frame (:class:`lightsim.wall.WallFrame`)."""
        return self.session.scene.wall


@dataclass
class AnalysisReport:
    """An analysis's result.

    Attributes
    ----------
    summary : dict
        JSON-ready figures, stored as ``summary.json[analysis.name]``.
    marks : list of dict or None
        Rows (``name``, ``h_deg``, ``v_deg``, ``verdict``, …) to draw on the iso-lux plot.
    files : list of Path
        Files written (inside or outside the output folder).
    """

    summary: dict[str, Any]
    marks: list[dict[str, Any]] | None = None
    files: list[Path] = field(default_factory=list)


@runtime_checkable
class Analysis(Protocol):
    """A check or product of a run (see the module docstring)."""

    name: str
    # Optional: ``reads_photons`` (str or None), the option that makes the analysis read
    # kNN estimates (``session.probe``) after the run; None: it reads none, so the run
    # may drop its photons. An analysis without it counts as reading them.
    # Optional: ``probe_points(scene)`` → (n, 2) wall points (h, v in m) it reads with
    # ``session.probe`` after the run; known before it, the sets accumulate them frame by
    # frame, so reading them needs no photon kept.

    def prepare(self, config: Any, scene: Any) -> Any:
        """The run's :class:`~lightsim.engine.config.RunConfig` with what this analysis
        needs measured (unchanged if nothing)."""
        ...

    def report(self, run: FinishedRun, out: Path) -> AnalysisReport:
        """Measure and evaluate the finished run; write files into ``out`` (the output
        set being staged) or where the user asked."""
        ...


@runtime_checkable
class StopsRun(Protocol):
    """An analysis that can decide when the run has enough photons (``--until decided``:
    a regulation's verdicts). :func:`lightsim.simulate.run_simulation` hands the run the
    first rule one of its analyses gives."""

    def stopping_rule(self, session: Any, cap_photons: int) -> Any:
        """A :class:`~lightsim.engine.server.StoppingRule` reading ``session`` with the
        run's photon cap, or None (this analysis does not stop the run)."""
        ...

    def stop_summary(self) -> dict[str, Any] | None:
        """After :meth:`Analysis.report`: ``summary.json["until"]`` (None: no rule)."""
        ...

    def stop_progress(self) -> str:
        """One line on how far the rule is (for a progress display; "" without one)."""
        ...
