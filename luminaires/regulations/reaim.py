"""Verdicts with a permitted re-aim at every test point (FMVSS No. 108 style).

Some regulations let the lamp be re-aimed by a small angle before each test point is
read: FMVSS No. 108 (49 CFR 571.108) permits a re-aim of up to 1/4° in any direction at
any test point. A point then passes when *some* aim within that disc meets its limit. A
rule set states the angle as ``reaim_deg`` in its ``[measurement]`` table
(:mod:`.conditions`).

How a point is judged (every other rule, zones included, as :func:`.evaluate.evaluate`
judges it, at the aim the lamp has):

1. at its nominal position, as usual; a pass there is a plain **pass**;
2. otherwise at n re-aimed positions (the centre, 8 directions at half the re-aim angle,
   16 at the full angle): each with its interval at the Bonferroni level α/n, so that
   choosing the best of n positions keeps the verdict's error at most α/2. If one of them
   passes, the point **passes only after re-aim** (the row names the re-aim, e.g.
   ``0.25° U``); if all of them fail it **fails** even re-aimed; else it is
   **uncertain**. The disc is sampled at those n positions, as zones are sampled on a
   grid.

Positions in the rule set's ``angles`` (``azimuth-elevation``: goniometer angles, H about
the vertical axis then V; converted to lightsim's wall angles to be read,
:func:`.conditions.wall_angles`); the re-aim offsets are taken in the same angles.

Parameters
----------
================  =====  =======  =========================================================
name              unit   default  meaning
================  =====  =======  =========================================================
``reaim_deg``     deg    –        permitted re-aim (the rule set's ``[measurement]``)
``RINGS``         –      see →    (fraction of ``reaim_deg``, directions): (0.5, 8), (1, 16)
``confidence``    1      0.95     two-sided level of the verdicts
``spacing_deg``   deg    0.25     zone sampling step
``aperture_deg``  deg    0        photometer aperture (angular diameter); the mean over
                                  ``APERTURE_POINTS`` = 32 directions of the disc
                                  (0: point values)
================  =====  =======  =========================================================
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rich.table import Table

from lightsim.errors import InputError
from lightsim.wall import WallFrame

from .conditions import wall_angles
from .evaluate import Probes, evaluate, format_position, format_table, probe_points
from .ruleset import Geometry, RuleSet

__all__ = ["APERTURE_POINTS", "RINGS", "ReaimProbes", "aperture_points", "evaluate_reaim",
           "format_reaim_table", "reaim_offsets", "reaim_probes", "values_from"]

RINGS = ((0.5, 8), (1.0, 16))
"""Re-aimed positions: (fraction of the re-aim angle, number of directions) per ring."""
APERTURE_POINTS = 32
"""Directions averaged over a photometer aperture."""


def reaim_offsets(reaim_deg: float) -> NDArray:
    """(n, 2) offsets (dh, dv) in degrees: the centre, then the rings of :data:`RINGS`."""
    out = [(0.0, 0.0)]
    if reaim_deg > 0:
        for frac, n in RINGS:
            a = 2.0 * np.pi * np.arange(n) / n
            r = frac * reaim_deg
            out.extend(zip(r * np.cos(a), r * np.sin(a), strict=True))
    return np.asarray(out, dtype=float)


@dataclass(frozen=True)
class ReaimProbes:
    """Every direction a re-aim evaluation reads.

    Attributes
    ----------
    base : Probes
        The rule set's own probes (points, zone samples), in the rule set's angles.
    points : tuple of str
        The limited points that get re-aimed positions.
    offsets : ndarray, shape (n, 2)
        The re-aim offsets (deg), the same for every point.
    h_deg, v_deg : ndarray, shape (P,)
        All positions in the rule set's angles: ``base`` first, then n per point.
    wall_h_deg, wall_v_deg : ndarray, shape (P,)
        The same positions as lightsim's wall angles.
    aperture_deg : float
        Angular diameter of the photometer's aperture (deg; 0: point values).
    """

    base: Probes
    points: tuple[str, ...]
    offsets: NDArray
    h_deg: NDArray
    v_deg: NDArray
    wall_h_deg: NDArray
    wall_v_deg: NDArray
    aperture_deg: float = 0.0

    def __len__(self) -> int:
        return len(self.h_deg)

    def point_slice(self, k: int) -> slice:
        """Where point ``points[k]``'s re-aimed positions sit in the arrays."""
        start = len(self.base) + k * len(self.offsets)
        return slice(start, start + len(self.offsets))


def _reaim_deg(rs: RuleSet) -> float:
    mc = rs.measurement
    return 0.0 if mc is None else float(mc.reaim_deg)


def _span(frame: WallFrame) -> tuple[float, float, float, float]:
    """Wall angles spanned by the pixel centres (deg): what a map can be read at."""
    h, v = frame.h_deg(), frame.v_deg()
    return float(h.min()), float(h.max()), float(v.min()), float(v.max())


def _inside_wall(base: Probes, frame: WallFrame, angles: str, margin: float = 0.0) -> Probes:
    """``base`` without the probes whose wall angles (after conversion), widened by
    ``margin`` deg, leave the wall."""
    h0, h1, v0, v1 = _span(frame)
    h0, h1, v0, v1 = h0 + margin, h1 - margin, v0 + margin, v1 - margin
    wh, wv = wall_angles(base.h_deg, base.v_deg, angles)
    ok = (wh >= h0) & (wh <= h1) & (wv >= v0) & (wv <= v1)
    if ok.all():
        return base
    labels = np.asarray(base.labels, dtype=object)
    dropped = dict(base.dropped)
    clipped = dict(base.clipped)
    ext = f"the wall covers H {h0:.2f}..{h1:.2f}°, V {v0:.2f}..{v1:.2f}°"
    for name in dict.fromkeys(base.labels):
        mine = labels == name
        if not ok[mine].any():
            dropped[name] = f"outside the wall ({ext})"
            clipped.pop(name, None)
        elif not ok[mine].all():
            clipped[name] = clipped.get(name, 0) + int((~ok[mine]).sum())
    return Probes(base.h_deg[ok], base.v_deg[ok], tuple(labels[ok]), base.ruleset_id,
                  base.traffic, base.spacing_deg, dropped, clipped)


def reaim_probes(rs: RuleSet, traffic: str = "right", spacing_deg: float = 0.25,
                 frame: Any = None, aperture_deg: float = 0.0) -> ReaimProbes:
    """The rule set's probes plus the re-aimed positions of every limited point.

    ``frame`` (a wall frame) drops what the wall does not cover, as
    :func:`.evaluate.probe_points` does (a point's re-aim disc and every aperture must fit
    too). ``aperture_deg``: the photometer's angular diameter (0: point values)."""
    if not (np.isfinite(aperture_deg) and 0.0 <= aperture_deg <= 5.0):
        raise InputError(f"--aperture must lie in [0, 5] deg, got {aperture_deg!r}")
    angles = rs.measurement.angles if rs.measurement is not None else "screen"
    base = probe_points(rs, traffic, spacing_deg, frame)
    if frame is not None and (angles != "screen" or aperture_deg > 0):
        base = _inside_wall(base, WallFrame.from_any(frame), angles, 0.5 * aperture_deg)
    reaim = _reaim_deg(rs)
    off = reaim_offsets(reaim)
    rs_t = rs.for_traffic(traffic)
    present = set(base.labels)
    pts = tuple(g.name for g in rs_t.geometries
                if g.kind == "point" and g.has_limits and g.complete and g.name in present)
    if frame is not None and reaim > 0:
        # a point's whole re-aim disc must lie on the wall
        h0, h1, v0, v1 = _span(WallFrame.from_any(frame))
        m = 0.5 * aperture_deg
        h0, h1, v0, v1 = h0 + m, h1 - m, v0 + m, v1 - m
        off = reaim_offsets(reaim)
        keep = []
        for n in pts:
            g = rs_t.geometry(n)
            wh, wv = wall_angles(g.h + off[:, 0], g.v + off[:, 1], angles)
            if (wh.min() >= h0) and (wh.max() <= h1) and (wv.min() >= v0) and (wv.max() <= v1):
                keep.append(n)
        pts = tuple(keep)
    hs, vs = [base.h_deg], [base.v_deg]
    for name in pts:
        g = rs_t.geometry(name)
        hs.append(g.h + off[:, 0])
        vs.append(g.v + off[:, 1])
    h = np.concatenate(hs)
    v = np.concatenate(vs)
    wh, wv = wall_angles(h, v, angles)
    return ReaimProbes(base, pts, off, h, v, wh, wv, float(aperture_deg))


def aperture_points(aperture_deg: float, n: int = APERTURE_POINTS) -> NDArray:
    """(n, 2) offsets (deg) spread evenly over a disc of diameter ``aperture_deg`` (a
    sunflower pattern: equal areas), whose mean is the aperture's mean intensity."""
    i = np.arange(n) + 0.5
    r = 0.5 * aperture_deg * np.sqrt(i / n)
    a = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def values_from(intensity: Callable[[NDArray, NDArray], NDArray], rp: ReaimProbes
                ) -> NDArray:
    """(S, P) intensities (cd) of ``intensity(h_deg, v_deg)`` (wall angles; a leading set
    axis or none) at every position of ``rp``: point values, or with
    ``rp.aperture_deg`` > 0 the mean over the photometer's aperture (a disc in wall
    angles, :func:`aperture_points`).

    Raises
    ------
    InputError
        A position the source does not cover (NaN): the lamp's data miss a test point.
    """
    if rp.aperture_deg > 0:
        off = aperture_points(rp.aperture_deg)
        h = (rp.wall_h_deg[:, None] + off[None, :, 0]).ravel()
        v = (rp.wall_v_deg[:, None] + off[None, :, 1]).ravel()
        raw = np.asarray(intensity(h, v), dtype=float)
        vals = raw.reshape(*raw.shape[:-1], len(rp), len(off)).mean(axis=-1)
    else:
        vals = np.asarray(intensity(rp.wall_h_deg, rp.wall_v_deg), dtype=float)
    if vals.ndim == 1:
        vals = vals[None, :]
    bad = ~np.isfinite(vals).all(axis=0)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"the lamp's data do not cover {format_position(rp.h_deg[k], rp.v_deg[k])}"
                         f" (wall H {rp.wall_h_deg[k]:.2f}°, V {rp.wall_v_deg[k]:.2f}°): "
                         "simulate a wider wall")
    return vals


def _direction(dh: float, dv: float) -> str:
    parts = []
    if abs(dv) > 1e-9:
        parts.append(f"{abs(dv):.3g}° {'U' if dv > 0 else 'D'}")
    if abs(dh) > 1e-9:
        parts.append(f"{abs(dh):.3g}° {'R' if dh > 0 else 'L'}")
    return " ".join(parts) or "none"


def evaluate_reaim(rs: RuleSet, rp: ReaimProbes, values_cd: NDArray,
                   confidence: float = 0.95) -> list[dict[str, Any]]:
    """Verdicts of ``rs`` with its permitted re-aim (see the module docstring).

    Parameters
    ----------
    rs : RuleSet
        The rule set.
    rp : ReaimProbes
        From :func:`reaim_probes`.
    values_cd : ndarray, shape (S, P) or (P,)
        Intensities (cd) at every position of ``rp``, one row per interleave set.
    confidence : float
        Two-sided level.

    Returns
    -------
    list of dict
        :func:`.evaluate.evaluate`'s rows; every re-aimed point's row adds
        ``after_reaim`` (True when it passes only re-aimed), ``reaim_deg``,
        ``reaim_offset_deg`` [dh, dv] and ``reaim_direction`` (e.g. ``"0.25° U"``), and
        its verdict, value and interval become those of the re-aimed reading.
    """
    vals = np.asarray(values_cd, dtype=float)
    if vals.ndim == 1:
        vals = vals[None, :]
    if vals.ndim != 2 or vals.shape[1] != len(rp):
        raise InputError(f"values_cd must have shape (sets, {len(rp)}), got {vals.shape}")
    nb = len(rp.base)
    rows = evaluate(rs, rp.base, vals[:, :nb], confidence=confidence)
    reaim = _reaim_deg(rs)
    if reaim <= 0:
        return rows
    rs_t = rs.for_traffic(rp.base.traffic)
    n = len(rp.offsets)
    level = 1.0 - (1.0 - confidence) / n  # Bonferroni over the n positions
    for row in rows:
        if row.get("kind") != "point" or row["name"] not in rp.points:
            continue
        row["after_reaim"] = False
        row["reaim_deg"] = reaim
        if row["verdict"] == "pass":
            continue
        k = rp.points.index(row["name"])
        g = rs_t.geometry(row["name"])
        sl = rp.point_slice(k)
        names = tuple(f"{g.name}@{i}" for i in range(n))
        sub = RuleSet(id=f"{rs.id}:reaim", title="", version="", source="",
                      traffic=rp.base.traffic,
                      geometries=tuple(Geometry(nm, "point", float(h), float(v), min=g.min,
                                                max=g.max) for nm, h, v in
                                       zip(names, rp.h_deg[sl], rp.v_deg[sl], strict=True)))
        probes = Probes(rp.h_deg[sl], rp.v_deg[sl], names, sub.id, rp.base.traffic,
                        rp.base.spacing_deg)
        res = evaluate(sub, probes, vals[:, sl], confidence=level)
        verdicts = [r["verdict"] for r in res]
        if "pass" in verdicts:
            i = verdicts.index("pass")  # the smallest re-aim first (centre, inner ring)
            dh, dv = (float(x) for x in rp.offsets[i])
            best = res[i]
            row.update(verdict="pass", after_reaim=True, value_cd=best["value_cd"],
                       interval_cd=best["interval_cd"], reaim_offset_deg=[dh, dv],
                       reaim_direction=_direction(dh, dv), reaim_confidence=level)
        elif all(v == "fail" for v in verdicts):
            row.update(verdict="fail", reaim_direction="none passes within "
                       f"{reaim:g}°", reaim_confidence=level)
        else:
            row.update(verdict="uncertain", reaim_direction=f"uncertain within {reaim:g}°",
                       reaim_confidence=level)
    return rows


def format_reaim_table(rows: Sequence[Mapping[str, Any]], title: str | None = None,
                       unevaluated: Sequence[Mapping[str, str]] | None = None) -> Table:
    """:func:`.evaluate.format_table` with every re-aimed pass named in its rule column
    (``1.5D-2R (after re-aim 0.25° U)``)."""
    shown = []
    for r in rows:
        r = dict(r)
        if r.get("after_reaim"):
            r["name"] = f"{r['name']} (after re-aim {r['reaim_direction']})"
        shown.append(r)
    table = format_table(shown, title, unevaluated)
    if any(r.get("reaim_deg") for r in rows):
        reaim = max(r.get("reaim_deg", 0.0) for r in rows)
        note = (f"points not passing at their aim were read re-aimed by up to {reaim:g}° "
                "(each at the Bonferroni level over the re-aimed positions)")
        table.caption = f"{table.caption}\n{note}" if table.caption else note
    return table
