"""Path signatures: which part of the lamp sends a test point's light, and by what path.

With ``--provenance`` the tracer keeps, for every wall photon, its emitter and the first
:data:`PATH_LENGTH` surface events of its path (triangle and event: reflection, refraction,
total internal reflection, diffuse; :mod:`lightsim.tracer`). Here those are turned into
*path signatures* — the emitter and the sequence of lamp *elements* met (a part, or one
facet of a faceted reflector) with the event at each — and every interleave set counts
each signature's flux in every detector-aperture strip bin, exactly as it counts the
total (:mod:`lightsim.engine.apertures`). The photons of an aperture are split among the
signatures, so the signatures' intensities add up to the aperture's, set by set.

Readable classes. A signature is named by its steps, e.g. ``filament → bulb (refracted) →
reflector facet 22 → lens (refracted)``: consecutive refractions on one glass part (in
and out) are one step, a reflection off glass is a "Fresnel reflection", a total internal
reflection "TIR", a diffuse part "(diffuse)"; a path longer than the kept events ends in
"→ …". Signatures with the same name are one class.

=================  =====  ========  =========================================================
parameter          unit   default   meaning
=================  =====  ========  =========================================================
``PATH_LENGTH``    –      8         surface events kept per photon
``min_share``      –      0.02      classes below this share of a point, or beyond the
                                    ``top`` largest, are pooled as "other"
``top``            –      8         classes shown per point at most
``confidence``     –      0.95      two-sided level of the class intervals
``REGION_CELL_DEG`` °     0.5       pitch (at H-V) of the coarse wall raster regions read
=================  =====  ========  =========================================================

A class's value at a point is the mean over the S interleave sets of its per-set
intensity (cd), its interval the Student-t interval of that mean (S − 1 degrees of
freedom), as the regulation's point intervals are where the sets hold photons.

Each set also counts, per aperture bin, the *spot* of every photon — the triangle of its
last reflection or scatter (:func:`spot_values`: where on the lamp a point's light was
sent out) — and, with ``--provenance-map``, bins the wall photons of one class into a
wall map (:class:`ClassMatcher`).

Regions. Each set also counts every class's luminous flux, and every spot's, on a coarse
raster of the wall (:class:`RegionRaster`: the image's pixels pooled into cells of about
:data:`REGION_CELL_DEG` at H-V). Any box of the screen in H/V degrees can then be broken
down after the run (:func:`region_values`): the cells whose centres lie in the box, their
mean illuminance (lx) split by class, with the same Student-t intervals. Memory: one
entry per (class, cell) and per (spot triangle, cell) a photon reached, at most one per
wall photon.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import stdtrit

from lightsim.emitters import EmitterMix
from lightsim.engine.apertures import ApertureLayout
from lightsim.errors import InputError
from lightsim.materials import DIELECTRIC, DIFFUSE, MIRROR
from lightsim.render.frame import luminous
from lightsim.tracer import EV_DIFFUSE, EV_REFLECT, EV_REFRACT, EV_TIR
from lightsim.wall import WallFrame

__all__ = [
    "PATH_LENGTH",
    "REGION_CELL_DEG",
    "ClassMatcher",
    "PathCounter",
    "PathElements",
    "RegionRaster",
    "class_label",
    "class_values",
    "element_table",
    "emitter_index",
    "region_cells",
    "region_store",
    "region_values",
    "share_table",
    "signature_rows",
    "spot_values",
    "step_texts",
    "unique_rows",
]

PATH_LENGTH = 8
"""Surface events a wall photon's signature keeps."""
REGION_CELL_DEG = 0.5
"""Pitch (deg, at H-V) of the coarse wall raster that region breakdowns read."""


@dataclass(frozen=True)
class RegionRaster:
    """The wall's pixels pooled into coarse cells (``factor`` columns × rows each).

    Attributes
    ----------
    frame : WallFrame
        The run's wall.
    factor : (int, int)
        Pixels per cell along H and V.
    """

    frame: WallFrame
    factor: tuple[int, int]

    @classmethod
    def of(cls, frame: WallFrame, cell_deg: float = REGION_CELL_DEG) -> RegionRaster:
        """Cells of about ``cell_deg`` (deg at H-V), whole pixels, at least one."""
        ph, pv = frame.pixel_pitch_deg
        W, H = frame.resolution
        fx = np.clip(np.rint(cell_deg / max(ph, 1e-30)), 1, W)
        fy = np.clip(np.rint(cell_deg / max(pv, 1e-30)), 1, H)
        return cls(frame, (int(fx), int(fy)))

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of cells (a partial cell at the image's edge counts)."""
        W, H = self.frame.resolution
        return -(-H // self.factor[1]), -(-W // self.factor[0])

    def cell(self, h: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(n,) int64 flat cell of wall points (h, v in m), −1 outside the image."""
        h, v = np.asarray(h, np.float64), np.asarray(v, np.float64)
        finite = np.isfinite(h) & np.isfinite(v)
        # off the image by far: clamped before the cast, so no integer overflows
        lim = 4.0 * max(abs(x) for x in (*self.frame.h_range_m, *self.frame.v_range_m)) + 1.0
        row, col = self.frame.pixel_index(np.clip(np.where(finite, h, 0.0), -lim, lim),
                                          np.clip(np.where(finite, v, 0.0), -lim, lim))
        ok = self.frame.inside(row, col) & finite
        out = (row // self.factor[1]) * self.shape[1] + col // self.factor[0]
        return np.where(ok, out, -1).astype(np.int64)

    def geometry(self) -> dict[str, np.ndarray]:
        """Cell edges in degrees from H-V (``h_edges_deg`` (nc + 1,) increasing,
        ``v_edges_deg`` (nr + 1,) decreasing) and every cell's area ``area_m2`` (nr, nc)."""
        W, H = self.frame.resolution
        fx, fy = self.factor
        cols = np.minimum(np.arange(self.shape[1] + 1) * fx, W)
        rows = np.minimum(np.arange(self.shape[0] + 1) * fy, H)
        he, ve = self.frame.edges_deg()
        dh, dv = self.frame.pixel_size_m
        area = np.outer(np.diff(rows) * dv, np.diff(cols) * dh)
        return {"h_edges_deg": he[cols], "v_edges_deg": ve[rows], "area_m2": area}


@dataclass(frozen=True)
class PathElements:
    """The lamp's elements a path can meet: parts, and the facets of faceted reflectors.

    Attributes
    ----------
    tri_element : (T,) int32
        Element of every traced triangle (the scene's triangle order).
    names : list of str
        Element names: the part's name, or ``"<part> facet <k>"`` (k: the facet's index in
        the part's ``extras["lightsim"]["facets"]`` list, from 0).
    kinds : (E,) int
        Surface kind of each element (:mod:`lightsim.materials`).
    emitters : list of str
        Emitter names, in :func:`emitter_index`'s numbering.
    emitter_triangles : tuple of int
        Triangles of each mesh emitter (the first of ``emitters``), in order.
    """

    tri_element: np.ndarray
    names: list[str]
    kinds: np.ndarray
    emitters: list[str] = field(default_factory=list)
    emitter_triangles: tuple[int, ...] = ()

    @classmethod
    def from_scene(cls, scene) -> PathElements:
        surfaces = scene.surfaces
        tri_part = np.asarray(scene.tri_part, np.int64)
        kinds_of = np.asarray(scene.materials.arrays.kind)
        tri_element = np.zeros(len(tri_part), np.int32)
        names: list[str] = []
        kinds: list[int] = []
        for p, part in enumerate(surfaces):
            rows = np.flatnonzero(tri_part == p)
            facets = (part.extras.get("lightsim") or {}).get("facets") or []
            if facets and len(rows) and len(rows) % len(facets) == 0:
                # the faceted reflector's mesh holds its facets one after another, each
                # with the same rings × columns triangles (lightsim.luminaires.reflector)
                per = len(rows) // len(facets)
                tri_element[rows] = len(names) + np.arange(len(rows)) // per
                names += [f"{part.name} facet {k}" for k in range(len(facets))]
                kinds += [int(kinds_of[p])] * len(facets)
            else:
                tri_element[rows] = len(names)
                names.append(part.name)
                kinds.append(int(kinds_of[p]))
        mesh = [p.name for p in scene.emitters if p.emitter is None]
        point = [p.name for p in scene.emitters if p.emitter is not None]
        tris = tuple(len(p.faces) for p in scene.emitters if p.emitter is None)
        return cls(tri_element, names, np.asarray(kinds), mesh + point, tris)

    def part_name(self, element: int) -> str:
        """The part an element belongs to."""
        return self.names[element].split(" facet ")[0]


def emitter_index(mix: EmitterMix, u: np.ndarray, mesh_triangles: tuple[int, ...] = ()
                  ) -> np.ndarray:
    """The emitter each sample point ``u`` (n, 5) emits from, as :meth:`EmitterMix.sample`
    picks it: the mesh emitters in the scene's order (by their triangles' flux share,
    ``u[:, 2]``; ``mesh_triangles``: each one's triangles), then the point and ray-file
    sources."""
    u = np.asarray(u, np.float64).reshape(-1, 5)
    out = np.zeros(len(u), np.int32)
    if len(u) == 0:
        return out
    n_mesh = 0
    mesh_sel = np.ones(len(u), bool) if not mix.sources else u[:, 2] < mix.mesh_share
    if mix.mesh is not None:
        x = u[mesh_sel, 2]
        if mix.sources:
            x = np.minimum(x / mix.mesh_share, np.nextafter(1.0, 0.0))
        k = np.minimum(np.searchsorted(mix.mesh.cdf, x, side="right"), len(mix.mesh.cdf) - 1)
        ends = (np.cumsum(mesh_triangles) if sum(mesh_triangles) == len(mix.mesh.cdf)
                else np.array([len(mix.mesh.cdf)]))
        out[mesh_sel] = np.searchsorted(ends, k, side="right")
        n_mesh = len(ends)
    if mix.sources:
        fluxes = np.array([s.flux_lm for s in mix.sources])
        share = mix.mesh_share
        edges = share + (1.0 - share) * np.concatenate([[0.0], np.cumsum(fluxes) / fluxes.sum()])
        k = np.clip(np.searchsorted(edges, u[~mesh_sel, 2], side="right") - 1, 0,
                    len(mix.sources) - 1)
        out[~mesh_sel] = n_mesh + k
    return out


def signature_rows(elements: PathElements, path: np.ndarray, events: np.ndarray,
                   emitter: np.ndarray) -> np.ndarray:
    """(n, K + 3) int32 signature rows of records: emitter, K steps ``element · 4 +
    event`` (−1 past the path's end), 1 where the path had more than K events, and the
    *spot*: the triangle of the path's last event that was not a refraction — the
    reflector facet, the lens surface of a ghost, the diffuse part — that sent the light
    on its way out (−1 for a direct photon, one only refracted, or a longer path)."""
    n, K = path.shape
    rows = np.full((n, K + 3), -1, np.int32)
    turn = (path >= 0) & (path % 4 != EV_REFRACT)
    any_turn = turn.any(axis=1) & (events.astype(np.int64) <= K)
    last = K - 1 - np.argmax(turn[:, ::-1], axis=1)
    rows[any_turn, K + 2] = path[any_turn, last[any_turn]] // 4
    rows[:, 0] = emitter
    ok = path >= 0
    code = np.where(ok, path, 0)
    rows[:, 1:K + 1] = np.where(ok, elements.tri_element[code // 4] * 4 + code % 4, -1)
    rows[:, K + 1] = events.astype(np.int32) > K
    return rows


_ROW_MIX = np.random.default_rng(0x5EED).integers(1, 2**62, 64, dtype=np.int64) | 1
"""Odd multipliers of :func:`unique_rows`' row hash (fixed: runs are reproducible)."""


def unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(rows, axis=0, return_inverse=True)`` of small-int rows, faster: rows
    hashed to one int64 (wrapping multiply-add) and the 1-D hashes made unique; every row
    is checked against its hash's first row, and a collision falls back to the 2-D way.
    The same unique rows, in the same (lexicographic) order."""
    r = np.ascontiguousarray(rows, np.int64)
    if r.ndim != 2 or r.shape[1] > len(_ROW_MIX) or len(r) == 0:
        uniq, inv = np.unique(rows, axis=0, return_inverse=True)
        return uniq, inv.reshape(-1)
    with np.errstate(over="ignore"):
        h = (r + 1) @ _ROW_MIX[:r.shape[1]]
    _, first, inv = np.unique(h, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    uniq = r[first]
    if not np.array_equal(uniq[inv], r):  # a hash collision (never seen): the exact way
        uniq, inv = np.unique(rows, axis=0, return_inverse=True)
        return uniq, inv.reshape(-1)
    order = np.lexsort(uniq.T[::-1])  # the few unique rows in np.unique's order
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    return uniq[order].astype(rows.dtype), rank[inv]


def _accumulate(keys: np.ndarray, flux: np.ndarray, new_keys: np.ndarray,
                new_flux: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted unique keys and their summed flux of two sparse stores together."""
    k = np.concatenate([keys, new_keys])
    f = np.concatenate([flux, new_flux])
    uk, back = np.unique(k, return_inverse=True)
    back = back.reshape(-1)
    return uk, np.stack([np.bincount(back, f[:, c], len(uk)) for c in range(f.shape[1])],
                        axis=1)


class PathCounter:
    """One interleave set's flux per (signature, aperture strip bin).

    Kept sparse: only the bins a signature's photons reached. :meth:`export` gives the
    counts with the signatures as tuples (a set's numbering is its own).
    """

    def __init__(self, channels: int) -> None:
        self.channels = channels
        self.index: dict[tuple[int, ...], int] = {}
        self.signatures: list[tuple[int, ...]] = []
        self.keys = np.zeros(0, np.int64)  # signature · 2³² + bin, sorted
        self.flux = np.zeros((0, channels))
        self.spot_keys = np.zeros(0, np.int64)  # spot triangle · 2³² + bin, sorted
        self.spot_flux = np.zeros((0, channels))
        # region raster (RegionRaster): luminous flux per signature · 2³² + cell, and per
        # spot triangle · 2³² + cell; its own numbering (the apertures' stays as it was)
        self.cell_index: dict[tuple[int, ...], int] = {}
        self.cell_signatures: list[tuple[int, ...]] = []
        self.cell_keys = np.zeros(0, np.int64)
        self.cell_flux = np.zeros((0, 1))
        self.spot_cell_keys = np.zeros(0, np.int64)
        self.spot_cell_flux = np.zeros((0, 1))

    def _signature_ids(self, rows: np.ndarray, index: dict[tuple[int, ...], int],
                       signatures: list[tuple[int, ...]]) -> np.ndarray:
        """(n,) signature index of signature rows (n, K + 2) in ``index``/``signatures``
        (new ones appended)."""
        if len(rows) == 0:
            return np.zeros(0, np.int64)
        uniq, inv = unique_rows(rows)
        ids = np.empty(len(uniq), np.int64)
        for i, r in enumerate(map(tuple, uniq.tolist())):
            sid = index.get(r)
            if sid is None:
                sid = index[r] = len(signatures)
                signatures.append(r)
            ids[i] = sid
        return ids[inv.reshape(-1)]

    def add_cells(self, rows: np.ndarray, cells: np.ndarray, power: np.ndarray) -> None:
        """Add wall photons to the region raster: signature rows (n, K + 3), their
        :meth:`RegionRaster.cell` (−1: off the image, skipped), powers (n, C)."""
        ok = np.asarray(cells) >= 0
        if not ok.any():
            return
        lum = luminous(np.asarray(power, np.float64).reshape(len(power), -1)[ok])[:, None]
        cell = np.asarray(cells, np.int64)[ok]
        sid = self._signature_ids(rows[ok, :-1], self.cell_index, self.cell_signatures)
        self.cell_keys, self.cell_flux = _accumulate(self.cell_keys, self.cell_flux,
                                                     sid * 2**32 + cell, lum)
        spot = rows[ok, -1].astype(np.int64)
        placed = spot >= 0
        self.spot_cell_keys, self.spot_cell_flux = _accumulate(
            self.spot_cell_keys, self.spot_cell_flux, spot[placed] * 2**32 + cell[placed],
            lum[placed])

    def add(self, rows: np.ndarray, located: tuple[np.ndarray, np.ndarray],
            power: np.ndarray) -> None:
        """Add wall photons: their signature rows (n, K + 2), the (photon, bin) pairs of
        :meth:`lightsim.engine.apertures.ApertureCounter.locate`, their powers (n, C)."""
        who, where = located
        if len(who) == 0:
            return
        pw = np.asarray(power, np.float64).reshape(len(power), -1)[who]
        spot = rows[who, -1].astype(np.int64)
        placed = spot >= 0
        self.spot_keys, self.spot_flux = _accumulate(
            self.spot_keys, self.spot_flux, spot[placed] * 2**32 + where[placed], pw[placed])
        self.keys, self.flux = _accumulate(self.keys, self.flux,
                                           self._signature_ids(rows[who, :-1], self.index,
                                                               self.signatures) * 2**32
                                           + where, pw)

    def export(self) -> dict[str, Any]:
        """{"signatures": tuples, "signature": (n,) index into them, "bin": (n,) flat
        strip bin, "flux": (n, C) unnormalised photon power; "spot", "spot_bin",
        "spot_flux": the same per triangle where the light left the lamp; "cell_signature",
        "cell", "cell_flux" (n,) luminous, and "cell_spot", "spot_cell", "spot_cell_flux":
        the same on the region raster, "cell_signatures" its numbering}."""
        return {"signatures": list(self.signatures), "signature": self.keys // 2**32,
                "bin": self.keys % 2**32, "flux": self.flux.copy(),
                "spot": self.spot_keys // 2**32, "spot_bin": self.spot_keys % 2**32,
                "spot_flux": self.spot_flux.copy(),
                "cell_signatures": list(self.cell_signatures),
                "cell_signature": self.cell_keys // 2**32, "cell": self.cell_keys % 2**32,
                "cell_flux": self.cell_flux[:, 0].copy(),
                "cell_spot": self.spot_cell_keys // 2**32,
                "spot_cell": self.spot_cell_keys % 2**32,
                "spot_cell_flux": self.spot_cell_flux[:, 0].copy()}


def _step_text(elements: PathElements, element: int, event: int) -> tuple[str, str]:
    """(element key, text) of one step."""
    name = elements.names[element]
    kind = int(elements.kinds[element])
    if kind == DIFFUSE or event == EV_DIFFUSE:
        return name, f"{name} (diffuse)"
    if kind == DIELECTRIC:
        if event == EV_REFRACT:
            return name, f"{name} (refracted)"
        if event == EV_TIR:
            return name, f"{name} TIR"
        return name, f"{name} (Fresnel reflection)"
    if kind == MIRROR and event == EV_REFLECT:
        return name, name
    return name, name


def class_label(elements: PathElements, signature: tuple[int, ...]) -> str:
    """The readable class name of a signature (see the module docstring)."""
    emitter = (elements.emitters[signature[0]]
               if 0 <= signature[0] < len(elements.emitters) else "emitter")
    steps: list[str] = []
    last: tuple[str, int] | None = None
    for code in signature[1:-1]:
        if code < 0:
            break
        element, event = divmod(int(code), 4)
        key, text = _step_text(elements, element, event)
        if event == EV_REFRACT and last == (key, EV_REFRACT):
            continue  # into the glass and out again: one pass through the part
        steps.append(text)
        last = (key, event)
    label = " → ".join([emitter, *steps]) if steps else f"{emitter} (direct)"
    return label + (" → …" if signature[-1] > 0 else "")


def _luminous_rows(flux: Any, n: int) -> np.ndarray:
    """(n,) luminous values of (n, C) channel fluxes (n may be 0)."""
    f = np.asarray(flux, np.float64)
    return np.zeros(0) if n == 0 else luminous(f.reshape(n, -1))


def class_values(per_set: dict[int, dict[str, Any]], emitted: np.ndarray,
                 layout: ApertureLayout, elements: PathElements, shift_deg: float,
                 points: list[list[int]]) -> tuple[list[str], np.ndarray]:
    """Per-set intensities (cd) of every class at every quantity.

    Parameters
    ----------
    per_set : {set: :meth:`PathCounter.export`}, in set order
    emitted : (S,) photons emitted per set
    layout : the run's aperture layout
    shift_deg : the aperture shift the regulation read (aiming), deg
    points : per quantity, the aperture indices whose intensities add up to it (one for a
        point, several for a sum of points)

    Returns
    -------
    labels : list of str (L,)
    values : (S, L, Q) luminous cd
    """
    k, _ = layout.quantize_shift(shift_deg)
    B, m, r = layout.n_bins, layout.substeps, layout.reach_bins
    omega = layout.solid_angles(shift_deg)
    labels: dict[str, int] = {}
    rows = []
    for s_pos, (_s, data) in enumerate(per_set.items()):
        if data is None:
            continue
        sig_label = []
        for sig in data["signatures"]:
            lab = class_label(elements, tuple(sig))
            sig_label.append(labels.setdefault(lab, len(labels)))
        b = np.asarray(data["bin"], np.int64)
        point, off = b // B, b % B - (r + k)
        inside = (off >= 0) & (off < m)  # the bins of the (shifted) aperture
        lab = np.asarray(sig_label, np.int64)[np.asarray(data["signature"], np.int64)]
        lum = _luminous_rows(data["flux"], len(b))
        rows.append((s_pos, lab[inside], point[inside], lum[inside]))
    S = len(emitted)
    Q = len(points)
    values = np.zeros((S, len(labels), Q))
    for s_pos, lab, point, lum in rows:
        if emitted[s_pos] <= 0:
            continue
        cd = lum / emitted[s_pos] / omega[point]
        for q, members in enumerate(points):
            sel = np.isin(point, members)
            np.add.at(values[s_pos, :, q], lab[sel], cd[sel])
    return list(labels), values


def share_table(labels: list[str], values: np.ndarray, q: int, confidence: float = 0.95,
                min_share: float = 0.02, top: int = 8, unit: str = "cd"
                ) -> list[dict[str, Any]]:
    """Classes of quantity ``q`` (of :func:`class_values`, or :func:`region_values` with
    ``unit`` "lx"), largest first, rare ones pooled as "other": name, value (set mean),
    interval, share of the total (keys ``value_<unit>``, ``interval_<unit>``)."""
    per = values[:, :, q]  # (S, L)
    S = per.shape[0]
    total = float(per.sum(axis=1).mean()) if S else 0.0
    mean = per.mean(axis=0) if S else np.zeros(per.shape[1])
    order = [int(i) for i in np.argsort(-mean, kind="stable") if mean[i] > 0]
    keep = [i for n, i in enumerate(order) if n < top and mean[i] >= min_share * total]
    pooled = [i for i in order if i not in keep]
    groups = [(labels[i], per[:, [i]]) for i in keep]
    if pooled:
        groups.append(("other", per[:, pooled]))
    t = float(stdtrit(S - 1, 0.5 + confidence / 2)) if S >= 2 else 0.0
    out = []
    for name, cols in groups:
        v = cols.sum(axis=1)
        mu = float(v.mean())
        half = t * float(v.std(ddof=1)) / np.sqrt(S) if S >= 2 else 0.0
        out.append({"class": name, f"value_{unit}": mu,
                    f"interval_{unit}": [max(mu - half, 0.0), mu + half],
                    "share": mu / total if total > 0 else 0.0,
                    **({"classes": len(cols[0])} if name == "other" else {})})
    return out


def element_table(labels: list[str], values: np.ndarray, q: int, confidence: float = 0.95,
                  marker: str = " facet ", top: int = 5) -> list[dict[str, Any]]:
    """The lamp elements (by default reflector facets: names holding ``marker``) whose
    light reaches quantity ``q``, largest first: per element the value (cd) and share of
    the classes whose path met it, with the Student-t interval over the sets. A path
    meeting two facets counts for both, so shares may add up to more than 1."""
    per = values[:, :, q]
    S = per.shape[0]
    total = float(per.sum(axis=1).mean()) if S else 0.0
    members: dict[str, list[int]] = {}
    for i, lab in enumerate(labels):
        for step in set(lab.split(" → ")):
            name = step.split(" (")[0].removesuffix(" TIR")
            if marker in name:
                members.setdefault(name, []).append(i)
    t = float(stdtrit(S - 1, 0.5 + confidence / 2)) if S >= 2 else 0.0
    out = []
    for name, cols in members.items():
        v = per[:, cols].sum(axis=1)
        mu = float(v.mean())
        if mu <= 0:
            continue
        half = t * float(v.std(ddof=1)) / np.sqrt(S) if S >= 2 else 0.0
        out.append({"element": name, "value_cd": mu,
                    "interval_cd": [max(mu - half, 0.0), mu + half],
                    "share": mu / total if total > 0 else 0.0})
    out.sort(key=lambda r: -r["value_cd"])
    return out[:top]


def step_texts(elements: PathElements) -> list[str]:
    """Every step text a class name of this lamp can hold (for checking a
    ``--provenance-map`` text before a run)."""
    out = [*elements.emitters, "(direct)"]
    for e in range(len(elements.names)):
        for ev in (EV_REFLECT, EV_REFRACT, EV_TIR, EV_DIFFUSE):
            out.append(_step_text(elements, e, ev)[1])
    return out


class ClassMatcher:
    """Which signatures' class names contain ``text`` (cached per signature)."""

    def __init__(self, elements: PathElements, text: str) -> None:
        self.elements, self.text = elements, text
        self.cache: dict[tuple[int, ...], bool] = {}

    def __call__(self, rows: np.ndarray) -> np.ndarray:
        """(n,) bool for signature rows (n, K + 3) of :func:`signature_rows`."""
        if len(rows) == 0:
            return np.zeros(0, bool)
        uniq, inv = unique_rows(rows[:, :-1])
        hit = np.empty(len(uniq), bool)
        for i, r in enumerate(map(tuple, uniq.tolist())):
            got = self.cache.get(r)
            if got is None:
                got = self.cache[r] = self.text in class_label(self.elements, r)
            hit[i] = got
        return hit[inv.reshape(-1)]


def spot_values(per_set: dict[int, dict[str, Any]], emitted: np.ndarray,
                layout: ApertureLayout, shift_deg: float, points: list[list[int]]
                ) -> tuple[np.ndarray, np.ndarray]:
    """Where on the lamp each quantity's light left it: the triangles of the last surface
    event (T,) and their mean contribution over the sets (T, Q) in luminous cd (a direct
    photon, or a path longer than the signature keeps, has no spot)."""
    k, _ = layout.quantize_shift(shift_deg)
    B, m, r = layout.n_bins, layout.substeps, layout.reach_bins
    omega = layout.solid_angles(shift_deg)
    tris, parts = [], []
    for s_pos, (_s, data) in enumerate(per_set.items()):
        if data is None or emitted[s_pos] <= 0:
            continue
        b = np.asarray(data["spot_bin"], np.int64)
        point, off = b // B, b % B - (r + k)
        inside = (off >= 0) & (off < m)
        lum = _luminous_rows(data["spot_flux"], len(b))
        cd = np.where(inside, lum / emitted[s_pos] / omega[np.where(inside, point, 0)], 0.0)
        q_cd = np.stack([np.where(np.isin(point, members), cd, 0.0) for members in points],
                        axis=1) if points else np.zeros((len(b), 0))
        tris.append(np.asarray(data["spot"], np.int64))
        parts.append(q_cd)
    if not tris:
        return np.zeros(0, np.int64), np.zeros((0, len(points)))
    t = np.concatenate(tris)
    v = np.concatenate(parts)
    uniq, back = np.unique(t, return_inverse=True)
    out = np.zeros((len(uniq), len(points)))
    np.add.at(out, back.reshape(-1), v)
    return uniq, out / max(len(emitted), 1)


def _cached_label(elements: PathElements, sig: tuple[int, ...],
                  named: dict[tuple[int, ...], str]) -> str:
    got = named.get(sig)
    if got is None:
        got = named[sig] = class_label(elements, sig)
    return got


def region_store(per_set: dict[int, dict[str, Any]], emitted: np.ndarray,
                 elements: PathElements, raster: RegionRaster) -> dict[str, np.ndarray]:
    """The region raster of a run, sets in order, as arrays a file can hold.

    Returns
    -------
    dict
        ``labels`` (L,) class names; ``set``, ``label``, ``cell`` (n,) int and ``flux``
        (n,) luminous flux per emitted photon (lm per lm emitted… the sets' counts over
        their emitted photons); ``emitted`` (S,); ``spot``, ``spot_cell`` (m,) int and
        ``spot_flux`` (m,) the spots' flux per emitted photon pooled over the sets; the
        raster's ``h_edges_deg``, ``v_edges_deg``, ``area_m2``.
    """
    labels: dict[str, int] = {}
    named: dict[tuple[int, ...], str] = {}  # the sets share most signatures
    sets, labs, cells, flux = [], [], [], []
    spots, spot_cells, spot_flux = [], [], []
    total = float(np.sum(emitted))
    for s_pos, data in enumerate(per_set.values()):
        if data is None or emitted[s_pos] <= 0 or "cell" not in data:
            continue
        sig_label = np.asarray([labels.setdefault(_cached_label(elements, tuple(sig), named),
                                                  len(labels))
                                for sig in data["cell_signatures"]], np.int64)
        sig = np.asarray(data["cell_signature"], np.int64)
        labs.append(sig_label[sig] if len(sig) else np.zeros(0, np.int64))
        cells.append(np.asarray(data["cell"], np.int64))
        flux.append(np.asarray(data["cell_flux"], np.float64) / emitted[s_pos])
        sets.append(np.full(len(sig), s_pos, np.int64))
        spots.append(np.asarray(data["cell_spot"], np.int64))
        spot_cells.append(np.asarray(data["spot_cell"], np.int64))
        spot_flux.append(np.asarray(data["spot_cell_flux"], np.float64) / max(total, 1e-300))

    def cat(parts: list[np.ndarray], dtype: Any) -> np.ndarray:
        return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)

    spot, spot_cell, sflux = (cat(spots, np.int64), cat(spot_cells, np.int64),
                              cat(spot_flux, np.float64))
    if len(spot):  # pooled over the sets: one row per (triangle, cell)
        key, back = np.unique(spot * 2**32 + spot_cell, return_inverse=True)
        sflux = np.bincount(back.reshape(-1), sflux, len(key))
        spot, spot_cell = key // 2**32, key % 2**32
    return {"labels": np.asarray(list(labels), dtype=str), "set": cat(sets, np.int32),
            "label": cat(labs, np.int32), "cell": cat(cells, np.int32),
            "flux": cat(flux, np.float64), "emitted": np.asarray(emitted, np.float64),
            "spot": spot, "spot_cell": spot_cell, "spot_flux": sflux, **raster.geometry()}


def region_cells(store: dict[str, np.ndarray], box: tuple[float, float, float, float]
                 ) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """The raster cells whose centres lie in ``box`` (H0, H1, V0, V1 in deg, H0 < H1,
    V0 < V1) and the box they cover (their outer edges, deg).

    Raises
    ------
    InputError
        A box that is not four finite numbers in order, or holds no cell centre.
    """
    b = np.asarray(box, np.float64).reshape(-1)
    if b.shape != (4,) or not np.all(np.isfinite(b)) or b[0] >= b[1] or b[2] >= b[3]:
        raise InputError(f"region box must be H0,H1,V0,V1 in degrees with H0 < H1 and "
                         f"V0 < V1, got {','.join(str(x) for x in np.ravel(box))}")
    he, ve = store["h_edges_deg"], store["v_edges_deg"]  # ve decreasing (row 0 on top)
    hc, vc = 0.5 * (he[1:] + he[:-1]), 0.5 * (ve[1:] + ve[:-1])
    cols = np.flatnonzero((hc >= b[0]) & (hc <= b[1]))
    rows = np.flatnonzero((vc >= b[2]) & (vc <= b[3]))
    if len(cols) == 0 or len(rows) == 0:
        raise InputError(f"region box H {b[0]:g}..{b[1]:g}°, V {b[2]:g}..{b[3]:g}° holds no "
                         f"cell of the wall raster (wall H {he[0]:.3g}..{he[-1]:.3g}°, V "
                         f"{ve[-1]:.3g}..{ve[0]:.3g}°, cells "
                         f"{float(np.mean(np.diff(he))):.2g}° wide)")
    cells = (rows[:, None] * len(hc) + cols[None, :]).ravel()
    covered = (float(he[cols[0]]), float(he[cols[-1] + 1]), float(ve[rows[-1] + 1]),
               float(ve[rows[0]]))
    return cells, covered


def region_values(store: dict[str, np.ndarray], box: tuple[float, float, float, float]
                  ) -> tuple[list[str], np.ndarray, tuple[float, float, float, float]]:
    """Per-set mean illuminance (lx) of every class over the region ``box``.

    Returns
    -------
    labels : list of str (L,)
    values : (S, L, 1) lx: a set's class flux in the region's cells per the cells' area
        (as the wall map's illuminance)
    covered : the box the cells cover (deg)
    """
    cells, covered = region_cells(store, box)
    area = float(np.asarray(store["area_m2"]).ravel()[cells].sum())
    labels = [str(x) for x in store["labels"]]
    S = len(store["emitted"])
    values = np.zeros((S, len(labels), 1))
    sel = np.isin(store["cell"], cells)
    np.add.at(values[:, :, 0], (store["set"][sel], store["label"][sel]),
              store["flux"][sel] / max(area, 1e-300))
    return labels, values, covered
