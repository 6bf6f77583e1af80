"""Per-source maps from one run: every emitter group's share of the wall, and their sum.

Light adds up: a photon's contribution to the wall belongs to the emitter that emitted
it, so one run can keep a map per emitter *group* (a matrix lamp's segments) and any
dimming of the groups is then a weighted sum of those maps, with no re-tracing
(``lightsim adb``, ``lightsim view``).

Which group a photon came from is known from its emitted-photon index: the records of a
frame carry ``source``, the index of their emitted photon, whose sample point chose the
emitter (:class:`~lightsim.emitters.mixture.EmitterMix`: u[:, 2] picks the mesh emitter or
another source by flux, then the triangle). :class:`EmitterGroups` repeats that choice
exactly, so it needs nothing from the tracer.

Each group's wall photons are counted per pixel (:class:`PerSourceSums`: ΣΦ and ΣΦ² per
group and pixel, float64): the map is the pixel mean ΣΦ / (N·ΔA) — unbiased, no blur —
and its variance per pixel is (ΣΦ² − (ΣΦ)²/N) / (N·ΔA)², the photons being independent.
Every interleave set also keeps its all-group pixel sums exactly as the binning estimator
keeps its own (the same additions in the same order). Memory grows with groups × pixels
(2 × 8 bytes each) plus sets × pixels (8 bytes per channel), not with photons; only runs
that ask for it (``--per-source``) keep it.

The written maps are float32. The all-on map (channel ``Y`` of ``per_source.exr``) is the
map a plain ``--estimator bin`` run of the same photons writes, bit for bit (the session
repeats that estimator's operations on the sets' sums). The group channels are split from
it (:func:`split_exactly`): each pixel's shares are whole multiples of the float32 spacing
at its total, so the channels read back add up to ``Y`` exactly in float32, in any order
(:func:`compose` with every weight 1), and a share is within that spacing (≈ 6e-8 × the
pixel's all-on value) of its group's own pixel mean.

=====================  ======  ==========================================================
quantity               unit    meaning
=====================  ======  ==========================================================
``lux``                lx      (G, H, W) per-group pixel means split exactly from the
                               all-on map (:func:`split_exactly`), float32
``variance``           lx²     (G, H, W) their variances, float32
``photons``            –       N, photons emitted over all interleave sets
``lit_fraction``       –       0.1: a group's error figure covers its pixels ≥ this × its
                               maximum
``split_cells``        –       2¹⁸: group × pixel cells split at once (bounds the memory)
=====================  ======  ==========================================================

Files (``simulate --per-source``): ``per_source.exr`` (a channel per group, named as the
group, and ``Y`` = their sum; lx) and ``per_source_var.exr`` (the same channels' variances;
lx²), with the wall frame and the group names in the metadata.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.exr import read_exr, wall_metadata, write_exr
from lightsim.wall import WallFrame

ALL_ON = "Y"
"""Channel of the all-on map in ``per_source.exr``."""
MAP_FILE = "per_source.exr"
VARIANCE_FILE = "per_source_var.exr"
LIT_FRACTION = 0.1
SPLIT_CELLS = 1 << 18  # group × pixel cells split_exactly handles at once (memory bound)


def group_name(part: Any) -> str:
    """An emitter part's group: ``extras.lightsim.group`` when given, else the part name."""
    ls = part.extras.get("lightsim") if isinstance(part.extras, dict) else None
    name = ls.get("group") if isinstance(ls, dict) else None
    return str(name) if isinstance(name, str) and name else str(part.name)


def group_names(scene: Any) -> tuple[str, ...]:
    """The scene's emitter groups, in the order of their first emitter part."""
    names: list[str] = []
    for p in scene.emitters:
        if (g := group_name(p)) not in names:
            names.append(g)
    return tuple(names)


@dataclass(frozen=True)
class EmitterGroups:
    """Emitter groups of a scene and the group each sample point emits from.

    Attributes
    ----------
    names : tuple of str
        Group names, in the order of the scene's emitter parts' first appearance.
    triangle_group : (E,) int64
        Group of each emissive triangle of the mesh emitter, in its CDF order.
    cdf : (E,) float64
        The mesh emitter's triangle CDF (empty without one).
    source_group : (K,) int64
        Group of each other source (point, filament, ray file), in the mix's order.
    edges : (K + 1,) float64
        The u[:, 2] edges of the other sources (the mix's own formula).
    mesh_share : float
        Share of u[:, 2] below which the mesh emitter emits.
    """

    names: tuple[str, ...]
    triangle_group: np.ndarray
    cdf: np.ndarray
    source_group: np.ndarray
    edges: np.ndarray
    mesh_share: float

    @classmethod
    def of(cls, scene: Any, mix: Any) -> EmitterGroups:
        """The groups of ``scene``'s emitters as ``mix`` (its
        :class:`~lightsim.emitters.mixture.EmitterMix`) samples them."""
        names: list[str] = []
        tri_groups, src_groups = [], []
        for p in scene.emitters:  # EmitterMix.from_scene's order
            g = group_name(p)
            if g not in names:
                names.append(g)
            if p.emitter is not None:
                src_groups.append(names.index(g))
            else:
                tri_groups.append(np.full(len(p.faces), names.index(g), np.int64))
        mesh = mix.mesh
        cdf = np.zeros(0) if mesh is None else np.asarray(mesh.cdf, np.float64)
        tri = np.concatenate(tri_groups) if tri_groups else np.zeros(0, np.int64)
        if len(tri) != len(cdf):
            raise ValueError("emitter groups: the mesh emitter's triangles do not match "
                             "the scene's emitter parts")
        fluxes = np.array([s.flux_lm for s in mix.sources], np.float64)
        share = float(mix.mesh_share) if mix.sources else 1.0
        edges = (share + (1.0 - share) * np.concatenate([[0.0], np.cumsum(fluxes)
                                                          / fluxes.sum()])
                 if len(fluxes) else np.zeros(1))
        return cls(tuple(names), tri, cdf, np.asarray(src_groups, np.int64), edges, share)

    def __len__(self) -> int:
        return len(self.names)

    def of_points(self, u: np.ndarray) -> np.ndarray:
        """(n,) group index of the photons emitted from sample points ``u`` (n, 5): the
        same choice as :meth:`EmitterMix.sample` makes."""
        x = np.asarray(u, np.float64)[:, 2]
        out = np.zeros(len(x), np.int64)
        if len(x) == 0:
            return out
        if len(self.source_group) == 0:
            on_mesh = np.ones(len(x), np.bool_)
            xm = x
        else:
            on_mesh = x < self.mesh_share if len(self.cdf) else np.zeros(len(x), np.bool_)
            xm = np.minimum(x / max(self.mesh_share, 1e-300), np.nextafter(1.0, 0.0))
        if len(self.cdf) and on_mesh.any():
            k = np.searchsorted(self.cdf, xm[on_mesh], side="right")
            out[on_mesh] = self.triangle_group[np.minimum(k, len(self.cdf) - 1)]
        last = len(self.source_group) - 1
        for k, g in enumerate(self.source_group):
            sel = (~on_mesh) & (x >= self.edges[k]) & ((x < self.edges[k + 1]) | (k == last))
            out[sel] = g
        return out


class PerSourceSums:
    """ΣΦ and ΣΦ² (luminous, lm) of every group's wall photons per pixel (float64).

    Parameters
    ----------
    groups : EmitterGroups
    frame : WallFrame
    """

    def __init__(self, groups: EmitterGroups, frame: WallFrame) -> None:
        self.groups = groups
        self.frame = frame
        W, H = frame.resolution
        self.shape = (len(groups), int(H), int(W))
        self.power = np.zeros(int(np.prod(self.shape)))
        self.square = np.zeros_like(self.power)
        self.sets: dict[int, np.ndarray] = {}  # set → (H, W, C) all-group sums (set_sums)

    @property
    def nbytes(self) -> int:
        return (self.power.nbytes + self.square.nbytes
                + sum(a.nbytes for a in self.sets.values()))

    def set_sums(self, s: int, channels: int) -> np.ndarray:
        """Set ``s``'s (H, W, C) pixel sums of every group's wall photons (lm), kept as the
        binning estimator keeps its own, so the all-on map can be that estimator's."""
        if s not in self.sets:
            _, H, W = self.shape
            self.sets[s] = np.zeros((H, W, int(channels)))
        return self.sets[s]

    def add(self, group: np.ndarray, h: np.ndarray, v: np.ndarray, power: np.ndarray) -> None:
        """Add wall photons: group index (n,), wall coordinates h, v (n,) m, luminous
        power (n,) lm; photons outside the wall's pixels are left out."""
        if len(group) == 0:
            return
        _, H, W = self.shape
        row, col = self.frame.pixel_index(h, v)
        ok = (row >= 0) & (row < H) & (col >= 0) & (col < W)
        flat = (group[ok] * H + row[ok]) * W + col[ok]
        p = np.asarray(power, np.float64)[ok]
        self.power += np.bincount(flat, weights=p, minlength=self.power.size)
        self.square += np.bincount(flat, weights=p * p, minlength=self.power.size)

    def reset(self) -> None:
        self.power[:] = 0.0
        self.square[:] = 0.0
        self.sets.clear()


@dataclass
class PerSourceMaps:
    """Every group's map and its variance (see the module table)."""

    names: tuple[str, ...]
    lux: np.ndarray        # (G, H, W) float32, lx
    variance: np.ndarray   # (G, H, W) float32, lx²
    photons: int
    wall: dict[str, Any]

    @classmethod
    def from_sums(cls, names: tuple[str, ...], power: np.ndarray, square: np.ndarray,
                  photons: int, frame: WallFrame,
                  all_on: np.ndarray | None = None) -> PerSourceMaps:
        """The maps of summed :class:`PerSourceSums` arrays after ``photons`` photons;
        with ``all_on`` (H, W) float32, the group maps are split from it
        (:func:`split_exactly`) so that they add up to it exactly."""
        G = len(names)
        W, H = frame.resolution
        dh, dv = frame.pixel_size_m
        area = dh * dv
        n = max(int(photons), 1)
        p = np.asarray(power, np.float64).reshape(G, H, W)
        q = np.asarray(square, np.float64).reshape(G, H, W)
        lux = p / (n * area)
        var = np.maximum(q - p * p / n, 0.0) / (float(n) * n * area * area)
        maps = lux.astype(np.float32) if all_on is None else split_exactly(lux, all_on)
        return cls(tuple(names), maps, var.astype(np.float32), int(photons), frame.to_dict())

    def index(self, name: str) -> int:
        if name not in self.names:
            raise InputError(f"no emitter group '{name}' (the run has: "
                             f"{', '.join(self.names)})")
        return self.names.index(name)

    def all_on(self) -> np.ndarray:
        """The all-on map (H, W) float32: :func:`compose` with every weight 1."""
        return compose(self.lux, np.ones(len(self.names)))

    def group_errors(self) -> list[dict[str, Any]]:
        """Per group: flux on the wall (lm), maximum (lx), and the relative error of its
        pixel means over its lit pixels (≥ ``LIT_FRACTION`` × its maximum)."""
        dh, dv = WallFrame.from_dict(self.wall).pixel_size_m
        out = []
        for g, name in enumerate(self.names):
            e = self.lux[g].astype(np.float64)
            var = self.variance[g].astype(np.float64)
            peak = float(e.max()) if e.size else 0.0
            rec: dict[str, Any] = {"name": name, "channel": name,
                                   "flux_on_wall_lm": float(e.sum() * dh * dv),
                                   "max_lx": peak, "rel_error": None, "lit_pixels": 0}
            if peak > 0:
                lit = e >= LIT_FRACTION * peak
                rec["rel_error"] = float(np.sqrt(var[lit].mean()) / e[lit].mean())
                rec["lit_pixels"] = int(lit.sum())
            out.append(rec)
        return out

    def write(self, out: Path, meta: dict[str, Any] | None = None) -> dict[str, Any]:
        """Write ``per_source.exr`` and ``per_source_var.exr`` into ``out``; returns the
        ``summary.json["per_source"]`` record."""
        if ALL_ON in self.names:
            raise InputError(f"an emitter group is named '{ALL_ON}', the all-on map's "
                             "channel: rename the group")
        info = {"groups": list(self.names), "photons": self.photons,
                "all_on_channel": ALL_ON, **(meta or {})}
        lux = {n: self.lux[g] for g, n in enumerate(self.names)}
        lux[ALL_ON] = self.all_on()
        write_exr(out / MAP_FILE, lux, wall_metadata(self.wall, units="lx",
                                                      quantity="illuminance", **info))
        var = {n: self.variance[g] for g, n in enumerate(self.names)}
        var[ALL_ON] = compose(self.variance, np.ones(len(self.names)))
        write_exr(out / VARIANCE_FILE, var, wall_metadata(self.wall, units="lx2",
                                                          quantity="illuminance variance",
                                                          **info))
        return {"file": MAP_FILE, "variance_file": VARIANCE_FILE,
                "estimator": "pixel means (photons counted per pixel: unbiased, no blur)",
                "photons": self.photons, "all_on_channel": ALL_ON,
                "groups": self.group_errors()}


def split_exactly(parts: np.ndarray, total: np.ndarray) -> np.ndarray:
    """(G, H, W) float32 shares of ``total`` (H, W) float32 in proportion to ``parts``
    (G, H, W) float64 (≥ 0), adding up to ``total`` exactly in float32, in any order.

    Each pixel's shares are whole multiples of q, the float32 spacing at the pixel's total
    (the total is a whole multiple K of q, K < 2²⁴): the parts in units of q, scaled to sum
    to K, are floored and the missing units go to the largest remainders (then any unit
    still off to the largest share). Every partial sum is a multiple of q no larger than
    the total, so float32 adds them without rounding. A share moves by less than q
    (≈ 6e-8 × the pixel's total) from its part.
    """
    parts = np.asarray(parts, np.float64)
    total = np.asarray(total, np.float32)
    out = np.zeros(parts.shape, np.float32)
    if parts.shape[0] == 0:
        return out
    rows = max(1, SPLIT_CELLS // max(parts.shape[0] * int(np.prod(parts.shape[2:])), 1))
    for r in range(0, parts.shape[1], rows):  # a block of rows at a time: bounded memory
        out[:, r:r + rows] = _split_block(np.maximum(parts[:, r:r + rows], 0.0),
                                          total[r:r + rows])
    return out


def _split_block(parts: np.ndarray, total: np.ndarray) -> np.ndarray:
    """:func:`split_exactly` of one block of rows."""
    G = parts.shape[0]
    q = np.spacing(total).astype(np.float64)  # > 0, also at a zero total
    K = np.where(total > 0, np.round(total.astype(np.float64) / q), 0.0)
    s = parts.sum(axis=0)
    units = np.where(s > 0, parts * (K / np.where(s > 0, s, 1.0)), 0.0)
    units[:, (s == 0) & (K > 0)] = K[(s == 0) & (K > 0)] / G  # no part: an even split
    whole = np.floor(units)
    missing = K - whole.sum(axis=0)  # 0 ≤ missing ≤ G, up to rounding
    rank = np.argsort(np.argsort(-(units - whole), axis=0, kind="stable"), axis=0,
                      kind="stable")
    whole += rank < np.clip(missing, 0, G)
    off = K - whole.sum(axis=0)  # what rounding left: onto the largest share
    if np.any(off != 0):
        top = np.argmax(whole, axis=0)
        np.put_along_axis(whole, top[None], np.take_along_axis(whole, top[None], 0) + off, 0)
    return (whole * q).astype(np.float32)


def compose(maps: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Σ_g w_g · maps[g] in float32, in group order (maps (G, H, W), weights (G,)): the
    composed map (H, W). With weights 1 it is the all-on channel, bit for bit."""
    maps = np.asarray(maps)
    out = np.zeros(maps.shape[1:], np.float32)
    for g, w in enumerate(np.asarray(weights, np.float32)):
        if w == 1:
            out += maps[g].astype(np.float32, copy=False)
        elif w != 0:
            out += w * maps[g].astype(np.float32, copy=False)
    return out


def read_per_source(run_dir: str | os.PathLike) -> PerSourceMaps:
    """The per-source maps a ``simulate --per-source`` run wrote into ``run_dir``; one
    line (:class:`~lightsim.errors.InputError`) when there are none."""
    d = Path(run_dir)
    path, vpath = d / MAP_FILE, d / VARIANCE_FILE
    if not d.is_dir():
        raise InputError(f"{d}: no such run folder")
    if not path.is_file() or not vpath.is_file():
        raise InputError(f"{d}: no per-source maps ({MAP_FILE}): run lightsim simulate "
                         "--per-source")
    try:
        ch, meta = read_exr(path)
        vch, _ = read_exr(vpath)
        names = tuple(str(n) for n in meta["groups"])
        lux = np.stack([ch[n] for n in names]).astype(np.float32)
        var = np.stack([vch[n] for n in names]).astype(np.float32)
        wall = meta["wall"]
        WallFrame.from_dict(wall)
        photons = int(meta["photons"])
    except (KeyError, TypeError, ValueError, OSError) as exc:
        raise InputError(f"{path}: not a per-source map set ({exc})") from None
    return PerSourceMaps(names, lux, var, photons, wall)
