"""Check a lamp — a finished run or a photometric file — against a rule set with its
measuring conditions (re-aim, aim, test distance, beam type): ``lightsim check``.

The lamp's intensity comes from

* a run folder: its written wall map (``wall_lux.exr``, read as intensity through
  :meth:`lightsim.wall.WallFrame.sample`), and every interleave set's map
  (``wall_sets.npz``, stored by ``simulate --road``) for intervals; or
* an ``.ies``/``.ldt`` file: its exact (bilinear) intensity, one "set", no interval.

Before any verdict the rule set's ``[measurement]`` table is checked against the lamp
(:mod:`.conditions`): a rule set for upper beams does not apply to a lower beam (the beam
is given, or a lower beam is recognised by its cut-off on the wall), a right-hand-only set
does not apply to left-hand traffic, a run's wall nearer than the least test distance is
refused; each is one line. A visually/optically aimed set needs a cut-off whose gradient
G (R112 annex 9 scan at 2.5°) reaches ``cutoff_gradient_min``; the points are read at the
lamp's aim. Then :mod:`.reaim` gives the verdicts.

Parameters
----------
===============  =====  ========  ========================================================
name             unit   default   meaning
===============  =====  ========  ========================================================
``source``       –      –         run folder or ``.ies``/``.ldt`` file
``ruleset``      –      –         rule-set id or file
``beam``         –      auto      "lower" or "upper"; auto: lower when a cut-off is found
``traffic``      –      right     traffic side
``confidence``   1      0.95      two-sided level
``aperture_deg`` deg    0         photometer aperture's angular diameter (0: point values)
``FILE_WALL``    –      25 m      the wall a photometric file is drawn on to find its
                                  cut-off (±15 m × ±6 m, 640 × 256 pixels)
===============  =====  ========  ========================================================
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from numpy.typing import NDArray

from lightsim.errors import InputError
from lightsim.render.cutoff import find_cutoff
from lightsim.road_evaluation import load_far_field
from lightsim.wall import WallFrame

from ..photometric import read_photometric
from .evaluate import unevaluated_rules
from .reaim import evaluate_reaim, reaim_probes, values_from
from .ruleset import RuleSet, load_ruleset

__all__ = ["FILE_WALL", "LampCheck", "LampSource", "check_lamp", "lamp_source", "verdict_counts"]

FILE_WALL = {"centre": [0.0, 0.0, 25.0], "h_axis": [-1.0, 0.0, 0.0],
             "v_axis": [0.0, 1.0, 0.0], "normal": [0.0, 0.0, -1.0],
             "h_range_m": [-15.0, 15.0], "v_range_m": [-6.0, 6.0], "distance_m": 25.0,
             "resolution": [640, 256]}


@dataclass(frozen=True)
class LampSource:
    """A lamp's intensity as a rule set reads it.

    Attributes
    ----------
    name : str
        The run folder or file.
    intensity : callable
        ``I(h_deg, v_deg)`` in cd at wall angles (NaN where unknown).
    set_intensity : callable or None
        Every interleave set's ``I_s``, shape (S, …); None: no error estimate.
    frame : WallFrame or None
        The wall the intensities are read on (the per-set maps' when there are; None for
        a photometric file: every direction is known).
    lux : ndarray
        A wall map of the lamp (the run's, or the file drawn on :data:`FILE_WALL`).
    lux_frame : WallFrame
        The frame of ``lux``.
    n_sets : int
        Interleave sets (1 for a file or a run without per-set maps).
    """

    name: str
    intensity: Callable[[NDArray, NDArray], NDArray]
    set_intensity: Callable[[NDArray, NDArray], NDArray] | None
    frame: WallFrame | None
    lux: NDArray
    lux_frame: WallFrame
    n_sets: int = 1


def lamp_source(path: str | Path) -> LampSource:
    """Read a run folder or an ``.ies``/``.ldt`` file (one line on bad input)."""
    p = Path(path)
    if p.is_dir():
        far = load_far_field(p)
        if far.n_sets > 1:  # the per-set maps (every 2nd pixel) span a little less
            return LampSource(str(p), far.intensity, far.set_intensity, far.sets_frame,
                              far.lux, far.frame, far.n_sets)
        return LampSource(str(p), far.intensity, None, far.frame, far.lux, far.frame)
    if not p.is_file():
        raise InputError(f"check: {p} is neither a run folder nor a photometric file")
    grid = read_photometric(p)
    frame = WallFrame.from_any(FILE_WALL)
    return LampSource(str(p), grid.intensity_hv, None, None, grid.wall_lux(frame), frame)


@dataclass
class LampCheck:
    """The outcome of :func:`check_lamp` (JSON-ready via :meth:`to_dict`)."""

    ruleset: RuleSet
    results: list[dict[str, Any]]
    unevaluated: list[dict[str, str]]
    beam: str
    beam_from: str
    cutoff: dict[str, Any]
    n_sets: int
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        mc = self.ruleset.measurement
        return {"ruleset": self.ruleset.id, "title": self.ruleset.title,
                "version": self.ruleset.version, "source": self.ruleset.source,
                "measurement": None if mc is None else mc.to_dict(), "beam": self.beam,
                "beam_from": self.beam_from, "cutoff": self.cutoff,
                "interleave_sets": self.n_sets, "error_estimate": self.n_sets > 1,
                "results": self.results, "unevaluated": self.unevaluated,
                "notes": self.notes}


def _beam(src: LampSource, beam: str | None, traffic: str) -> tuple[str, str, dict[str, Any]]:
    res = find_cutoff(src.lux, src.lux_frame.to_dict(), traffic)
    cut = {"found": bool(res.found), "v_cutoff_deg": res.v_cutoff_deg,
           "sharpness_g": res.sharpness_g, "message": res.message}
    if beam is not None:
        if beam not in ("lower", "upper"):
            raise InputError(f"--beam must be lower or upper, got {beam!r}")
        return beam, "given", cut
    if res.found:
        return "lower", f"a cut-off was found at {res.v_cutoff_deg:+.2f}°", cut
    return "upper", "no cut-off was found", cut


def check_lamp(src: LampSource, ruleset: str, beam: str | None = None,
               traffic: str = "right", confidence: float = 0.95,
               aperture_deg: float = 0.0) -> LampCheck:
    """Verdicts of ``ruleset`` for the lamp ``src`` (see the module docstring).

    Raises
    ------
    InputError
        The rule set does not apply (beam type, traffic side, test distance), the lamp's
        data miss a test point, a bad confidence level.
    """
    if not 0.0 < confidence < 1.0:
        raise InputError(f"--confidence must lie in (0, 1), got {confidence}")
    rs = load_ruleset(ruleset)
    mc = rs.measurement
    kind, why, cut = _beam(src, beam, traffic)
    notes: list[str] = []
    if mc is not None:
        if mc.beam is not None and mc.beam != kind:
            raise InputError(f"rule set {rs.id} applies to {mc.beam} beams; {src.name} is a "
                             f"{kind} beam ({why}): give --beam {mc.beam} if it is not")
        if not mc.mirror and traffic != rs.traffic:
            raise InputError(f"rule set {rs.id} applies to {rs.traffic}-hand traffic only; "
                             f"--traffic {traffic} does not apply")
        if src.frame is not None and src.frame.distance_m < mc.min_distance_m:
            raise InputError(f"rule set {rs.id} measures at {mc.min_distance_m:g} m or more; "
                             f"the run's wall is at {src.frame.distance_m:g} m")
        if mc.aim == "visual":
            g = cut["sharpness_g"] if cut["found"] else None
            ok = g is not None and g >= mc.cutoff_gradient_min
            cut["gradient_min"] = mc.cutoff_gradient_min
            cut["visually_aimable"] = bool(ok)
            if g is None:
                notes.append("visual/optical aim by the cut-off: no cut-off found: NOT "
                             "visually aimable")
            else:
                notes.append(f"visual/optical aim by the cut-off: gradient G = {g:.3f} "
                             f"{'≥' if ok else '<'} {mc.cutoff_gradient_min:g}"
                             + ("" if ok else ": NOT visually aimable"))
        if mc.reaim_deg > 0:
            notes.append(f"re-aim up to {mc.reaim_deg:g}° permitted at every test point")
    rp = reaim_probes(rs, traffic, 0.25, src.frame, aperture_deg)
    if aperture_deg > 0:
        notes.append(f"photometer aperture {aperture_deg:g}° (mean over its disc)")
    fn = src.set_intensity if src.set_intensity is not None else src.intensity
    values = values_from(fn, rp)
    results = evaluate_reaim(rs, rp, values, confidence)
    return LampCheck(rs, results, unevaluated_rules(rs, rp.base), kind, why, cut,
                     int(values.shape[0]), notes)


def verdict_counts(results: list[dict[str, Any]]) -> dict[str, int]:
    """How many rules pass (and of those, only after re-aim), fail, are uncertain."""
    out = {"pass": 0, "after_reaim": 0, "fail": 0, "uncertain": 0}
    for r in results:
        out[r["verdict"]] = out.get(r["verdict"], 0) + 1
        out["after_reaim"] += bool(r.get("after_reaim"))
    return out

