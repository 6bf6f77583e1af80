"""``--provenance``: every regulation rule's light broken down by the path it took.

An :class:`~lightsim.analysis.Analysis` next to the rule sets' tables: before the run it
asks the sets to keep path signatures and count them in the detector apertures
(:mod:`lightsim.provenance`); after it, for every rule of every rule set it splits the
quantity the rule reads into path classes:

=============  ================================================================
rule kind      quantity split
=============  ================================================================
point          the point's aperture intensity
zone           the aperture of the zone sample that governs the verdict (the one
               the table reports: the maximum for a "≤" zone, the minimum for "≥")
sum            the sum of its points' apertures (``1+2+3``)
measure HV     the H-V aperture (Imax: not split, a raster tile)
relation       not split (its two sides are their own rows)
=============  ================================================================

Each class has its value (cd, mean over the interleave sets), its Student-t interval
over the sets and its share; the classes add up to the table's value (``sum_cd``; the
same photons split, so to rounding). ``summary.json["provenance"]`` holds the tables;
``lightsim report --provenance RULE RUN_DIR`` prints one.

Where on the lamp a rule's light was sent out: ``provenance.npz`` holds, per rule, every
lamp triangle's share (cd) by the triangle of the photons' last event that was not a
refraction (the reflector spot, a lens ghost's surface, a diffuse part), and the lamp's
triangles; ``provenance-<RULE>.png`` (written by the run for failing rules, by ``lightsim
report --provenance RULE`` on demand) draws the lamp seen from the screen, each triangle
coloured by the rule's intensity that left it per unit of its projected area.

=================  =====  ========  ====================================================
parameter          unit   default   meaning
=================  =====  ========  ====================================================
``confidence``     –      0.95      two-sided level of the class intervals
``min_share``      –      0.02      classes below this share are pooled as "other"
``top``            –      8         classes listed per rule at most (the rest: "other")
=================  =====  ========  ====================================================
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from rich.table import Table
from scipy.special import stdtrit

from lightsim.analysis import AnalysisReport, FinishedRun
from lightsim.engine.apertures import layout_from_config
from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path
from lightsim.io.caption import add_caption, png_metadata
from lightsim.io.exr import write_exr
from lightsim.provenance import (
    PATH_LENGTH,
    PathElements,
    RegionRaster,
    class_values,
    element_table,
    region_cells,
    region_store,
    region_values,
    share_table,
    spot_values,
    step_texts,
)
from lightsim.render.frame import luminous
from lightsim.road_evaluation import run_caption

from .regulations.check import RegulationAnalysis, regulation_check

__all__ = ["REGIONS_FILE", "SPOTS_FILE", "ProvenanceAnalysis", "draw_region_spots",
           "draw_spots", "failing_breakdowns", "format_breakdown", "format_region",
           "parse_box", "read_regions", "region_breakdown", "region_overview",
           "region_picture", "rule_breakdown", "spots_image_name"]

SPOTS_FILE = "provenance.npz"
"""Per rule, the lamp triangles its light left from (see the module docstring)."""
REGIONS_FILE = "provenance-regions.npz"
"""Every class's and spot's flux on the coarse wall raster, per set (region breakdowns)."""
MAX_RUN_IMAGES = 8
"""Lamp pictures a run draws at most (its failing rules, in table order)."""


def _quantities(reg: dict[str, Any], offset: int) -> list[tuple[str, list[int]]]:
    """(rule name, aperture indices adding up to the value the rule reads) per splittable
    row of a regulation table ``reg`` whose apertures start at ``offset``."""
    probes = reg["_probes"]
    out = []
    for row in reg["results"]:
        name, kind = row["name"], row.get("kind")
        if kind in ("point", "zone"):
            idx = np.asarray(probes.indices(name))
            if len(idx) == 0:
                continue
            if kind == "zone" and row.get("h_deg") is not None:
                d = ((probes.h_deg[idx] - row["h_deg"]) ** 2
                     + (probes.v_deg[idx] - row["v_deg"]) ** 2)
                idx = idx[[int(np.argmin(d))]]
            out.append((name, [offset + int(idx[0])]))
        elif kind == "sum":
            members = [np.asarray(probes.indices(p)) for p in name.split("+")]
            if all(len(m) for m in members):
                out.append((name, [offset + int(m[0]) for m in members]))
        elif kind == "measure" and name == "HV":
            out.append((name, [offset + len(probes)]))
    return out


@dataclass
class ProvenanceAnalysis:
    """``--provenance`` for the run's rule sets (see the module docstring)."""

    regulations: list[RegulationAnalysis]
    confidence: float = 0.95
    name: str = "provenance"
    min_share: float = 0.02
    top: int = 8
    map_text: str = ""
    tables: dict[str, Any] = field(default_factory=dict, init=False)
    #: the class counts are accumulated per frame in every set (apertures, the region
    #: raster, the class map): no photon need be kept
    reads_photons = None

    def prepare(self, config: Any, scene: Any) -> Any:
        """Path signatures kept and counted per aperture (and the ``map_text`` class
        binned into a wall map: a text no class of this lamp can hold is refused)."""
        if self.map_text:
            steps = step_texts(PathElements.from_scene(scene))
            if not any(self.map_text in s for s in steps):
                names = sorted({s.split(" (")[0].split(" facet ")[0] for s in steps})
                raise InputError(f"--provenance-map '{self.map_text}': no part, facet or "
                                 f"path step of the lamp holds it (parts: {', '.join(names)};"
                                 " steps: TIR, Fresnel reflection, refracted, diffuse, "
                                 "direct)")
        return config.with_(path_length=PATH_LENGTH, path_map=self.map_text)

    def report(self, run: FinishedRun, out: Path) -> AnalysisReport:
        session = run.session
        per_set = session.backend.paths()
        stats = session.backend.stats()
        sets = sorted(stats)
        emitted = np.array([stats[s]["emitted"] for s in sets], np.float64)
        layout = layout_from_config(session.config, session.scene.wall.distance_m)
        elements = PathElements.from_scene(session.scene)
        rulesets: dict[str, Any] = {}
        spot_rows: list[tuple[str, str, np.ndarray, np.ndarray]] = []
        for an in self.regulations:
            reg = an.last if an.last is not None else regulation_check(
                session, run.lux, an.ruleset, an.traffic, an.aim, an.confidence, an.offset)
            quantities = _quantities(reg, an.offset)
            shift = -float(reg["aim"]["dv_deg"])
            labels, values = class_values({s: per_set.get(s) for s in sets}, emitted,
                                          layout, elements, shift,
                                          [q for _, q in quantities])
            rows = {r["name"]: r for r in reg["results"]}
            tris, spot_cd = spot_values({s: per_set.get(s) for s in sets}, emitted, layout,
                                        shift, [q for _, q in quantities])
            rules = {}
            for q, (name, _) in enumerate(quantities):
                keep = spot_cd[:, q] > 0
                spot_rows.append((reg["ruleset"], name, tris[keep], spot_cd[keep, q]))
                classes = share_table(labels, values, q, self.confidence, self.min_share,
                                      self.top)
                row = rows[name]
                total = float(values[:, :, q].sum(axis=1).mean()) if len(sets) else 0.0
                rules[name] = {"kind": row.get("kind"), "verdict": row.get("verdict"),
                               "h_deg": row.get("h_deg"), "v_deg": row.get("v_deg"),
                               "value_cd": row.get("value_cd"),
                               "interval_cd": row.get("interval_cd"),
                               "sum_cd": total, "classes": classes,
                               "facets": element_table(labels, values, q, self.confidence)}
            rulesets[reg["ruleset"]] = rules
        summary = {"confidence": self.confidence, "path_length": PATH_LENGTH,
                   "parts": sorted({elements.part_name(e) for e in range(len(elements.names))}
                                   | set(elements.emitters)),
                   "rulesets": rulesets}
        self.tables = summary
        files = [write_spots(out / SPOTS_FILE, session.scene, spot_rows),
                 write_regions(out / REGIONS_FILE, region_store(
                     {s: per_set.get(s) for s in sets}, emitted, elements,
                     RegionRaster.of(session.scene.wall)))]
        caption = None
        if run.caption is not None:  # the run's caption naming the rule sets it breaks down
            caption = replace(run.caption, rulesets=tuple(
                (r.rules.id, r.rules.version) for r in self.regulations)).text()
        first = self.regulations[0].rules.id if self.regulations else ""
        failing = [(rs, name) for rs, rules in rulesets.items() for name, b in rules.items()
                   if b["verdict"] == "fail"][:MAX_RUN_IMAGES]
        for rs, name in failing:
            path = out / spots_image_name(name, rs, first)
            draw_spots(out / SPOTS_FILE, rs, name, path, rulesets[rs][name], caption)
            files.append(path)
        if self.map_text:
            files += write_path_map(out, session.scene.wall, self.map_text, per_set, emitted,
                                    sets, caption)
            summary["map"] = {"class": self.map_text, "files": [p.name for p in files[-2:]]}
        return AnalysisReport(summary, files=files)


def rule_breakdown(summary: dict[str, Any], rule: str, part: str | None = None
                   ) -> list[tuple[str, dict[str, Any]]]:
    """The breakdowns of ``rule`` in a run's ``summary.json`` (one per rule set naming
    it), classes limited to those meeting ``part`` if given.

    Raises
    ------
    InputError
        The run was made without ``--provenance``, no rule set has ``rule``, or ``part``
        is not a part of the lamp.
    """
    prov = summary.get("provenance")
    if not isinstance(prov, dict) or "rulesets" not in prov:
        raise InputError("this run was made without --provenance: run lightsim simulate "
                         "--provenance --regulation … to break its rules down by path")
    if part is not None and part not in prov.get("parts", []):
        raise InputError(f"no part '{part}' in the lamp (parts: "
                         f"{', '.join(prov.get('parts', []))})")
    found = [(rs, rules[rule]) for rs, rules in prov["rulesets"].items() if rule in rules]
    if not found:
        names = sorted({r for rules in prov["rulesets"].values() for r in rules})
        raise InputError(f"no rule '{rule}' in the run's rule sets (rules: "
                         f"{', '.join(names)})")
    if part is None:
        return found
    out = []
    for rs, b in found:
        keep = [c for c in b["classes"] if _meets(c["class"], part)]
        out.append((rs, {**b, "classes": keep}))
    return out


def _meets(label: str, part: str) -> bool:
    steps = [s.split(" (")[0].split(" facet ")[0].removesuffix(" TIR")
             for s in label.split(" → ")]
    return part in steps


def _cd(x: float) -> str:
    return f"{x:,.4g}" if abs(x) < 1e4 else f"{x:,.0f}"


def _class_table(title: str, classes: list[dict[str, Any]], unit: str) -> Table:
    """A rich table of path classes: value and interval in ``unit`` (cd or lx), share."""
    t = Table(title=title, title_justify="left")
    t.add_column("path class")
    t.add_column(unit, justify="right")
    t.add_column(f"interval ({unit})", justify="right")
    t.add_column("share", justify="right")
    for c in classes:
        name = c["class"] + (f" ({c['classes']} classes)" if "classes" in c else "")
        lo, hi = c[f"interval_{unit}"]
        t.add_row(name, _cd(c[f"value_{unit}"]), f"[{_cd(lo)}, {_cd(hi)}]",
                  f"{c['share']:.1%}")
    return t


def format_breakdown(ruleset: str, rule: str, b: dict[str, Any]) -> Table:
    """A rich table of one rule's path classes."""
    lo, hi = b.get("interval_cd") or (float("nan"), float("nan"))
    title = (f"{ruleset} {rule}: {_cd(b['value_cd'])} cd [{_cd(lo)}, {_cd(hi)}] "
             f"({b.get('verdict')}); classes add up to {_cd(b['sum_cd'])} cd")
    t = _class_table(title, b["classes"], "cd")
    for f in b.get("facets", []):  # the facets a design would move, by their light here
        t.add_row(f"[dim]every path via {f['element']}[/dim]", _cd(f["value_cd"]),
                  f"[{_cd(f['interval_cd'][0])}, {_cd(f['interval_cd'][1])}]",
                  f"{f['share']:.1%}")
    return t


def failing_breakdowns(summary: dict[str, Any]) -> list[Table]:
    """Tables of every failing or uncertain rule of a ``--provenance`` run."""
    prov = summary.get("provenance") or {}
    return [format_breakdown(rs, name, b)
            for rs, rules in (prov.get("rulesets") or {}).items()
            for name, b in rules.items() if b.get("verdict") in ("fail", "uncertain")]


def spots_image_name(rule: str, ruleset: str, first: str) -> str:
    """``provenance-<RULE>.png`` for the run's first rule set,
    ``provenance-<RULESET>-<RULE>.png`` for a further one (unsafe characters as "_")."""
    safe = "".join(ch if ch.isalnum() or ch in "+-_." else "_" for ch in rule)
    return (f"provenance-{safe}.png" if ruleset == first
            else f"provenance-{ruleset}-{safe}.png")


def write_spots(path: Path, scene: Any, rows: list[tuple[str, str, np.ndarray, np.ndarray]]
                ) -> Path:
    """``provenance.npz``: the lamp's triangles (m, float32), their parts, and per rule
    the triangles its light left from with their cd."""
    lamp = ~np.asarray(scene.tri_is_wall, bool)
    index = np.full(len(lamp), -1, np.int64)
    index[lamp] = np.arange(int(lamp.sum()))
    tri = np.asarray(scene.triangles, np.float32)[lamp]
    part = np.asarray(scene.tri_part, np.int32)[lamp]
    names = np.asarray([p.name for p in scene.surfaces], dtype=str)
    rule_of = np.concatenate([np.full(len(t), i, np.int32) for i, (_, _, t, _) in
                              enumerate(rows)]) if rows else np.zeros(0, np.int32)
    spot = (np.concatenate([index[t] for _, _, t, _ in rows]) if rows
            else np.zeros(0, np.int64))
    cd = np.concatenate([c for _, _, _, c in rows]) if rows else np.zeros(0)
    with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
        np.savez(fh, triangles=tri, part=part, part_names=names,
                 rulesets=np.asarray([r[0] for r in rows], dtype=str),
                 rules=np.asarray([r[1] for r in rows], dtype=str),
                 rule=rule_of, spot=spot, cd=cd)
    return Path(path)


def write_regions(path: Path, store: dict[str, np.ndarray]) -> Path:
    """``provenance-regions.npz``: :func:`lightsim.provenance.region_store`'s arrays."""
    with atomic_path(path, suffix=".npz") as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **store)
    return Path(path)


def read_regions(path: Path) -> dict[str, np.ndarray]:
    """The region raster a ``--provenance`` run wrote."""
    if not Path(path).exists():
        raise InputError(f"{path}: missing (a run made with --provenance writes it)")
    try:
        with np.load(path, allow_pickle=False) as d:
            data = {k: d[k] for k in d.files}
        need = ("labels", "set", "label", "cell", "flux", "emitted", "spot", "spot_cell",
                "spot_flux", "h_edges_deg", "v_edges_deg", "area_m2")
        missing = [k for k in need if k not in data]
        if missing:
            raise KeyError(", ".join(missing))
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise InputError(f"{path}: corrupt provenance file ({exc})") from None
    return data


def parse_box(text: str) -> tuple[float, float, float, float]:
    """``H0,H1,V0,V1`` (deg) → four floats (checked by :func:`region_breakdown`)."""
    try:
        parts = [float(x) for x in str(text).split(",")]
    except ValueError:
        parts = []
    if len(parts) != 4:
        raise InputError(f"region box must be H0,H1,V0,V1 in degrees (e.g. -8,-1,0.5,2), "
                         f"got '{text}'")
    return parts[0], parts[1], parts[2], parts[3]


def region_breakdown(run_dir: Path, box: tuple[float, float, float, float],
                     confidence: float = 0.95, min_share: float = 0.02, top: int = 8,
                     store: dict[str, np.ndarray] | None = None) -> dict[str, Any]:
    """A screen region's light by path class, from a ``--provenance`` run folder.

    Returns
    -------
    dict
        ``box_deg`` (asked), ``covered_deg`` (the raster cells' edges), ``value_lx`` (mean
        illuminance over the covered cells, set mean), ``interval_lx`` (its Student-t
        interval over the sets), ``sum_lx`` (the classes' sum), ``classes``
        (:func:`lightsim.provenance.share_table` rows in lx). ``store``: the run's
        :func:`read_regions` if already read.
    """
    if store is None:
        store = read_regions(Path(run_dir) / REGIONS_FILE)
    labels, values, covered = region_values(store, box)
    S = values.shape[0]
    per = values[:, :, 0].sum(axis=1)
    mu = float(per.mean()) if S else 0.0
    t = float(stdtrit(S - 1, 0.5 + confidence / 2)) if S >= 2 else 0.0
    half = t * float(per.std(ddof=1)) / np.sqrt(S) if S >= 2 else 0.0
    classes = share_table(labels, values, 0, confidence, min_share, top, unit="lx")
    return {"box_deg": [float(x) for x in box], "covered_deg": list(covered),
            "value_lx": mu, "interval_lx": [max(mu - half, 0.0), mu + half],
            "sum_lx": float(sum(c["value_lx"] for c in classes)), "sets": S,
            "classes": classes}


def format_region(b: dict[str, Any]) -> Table:
    """A rich table of one region's path classes."""
    h0, h1, v0, v1 = b["covered_deg"]
    lo, hi = b["interval_lx"]
    title = (f"region H {h0:.2f}..{h1:.2f}°, V {v0:.2f}..{v1:.2f}°: mean "
             f"{_cd(b['value_lx'])} lx [{_cd(lo)}, {_cd(hi)}]; classes add up to "
             f"{_cd(b['sum_lx'])} lx")
    return _class_table(title, b["classes"], "lx")


def region_image_name(covered: list[float] | tuple[float, ...]) -> str:
    """``provenance-box-H0_H1_V0_V1.png`` (the covered box, 0.01° steps)."""
    return "provenance-box-" + "_".join(f"{x:+.2f}" for x in covered) + ".png"


def region_overview(store: dict[str, np.ndarray]) -> dict[str, Any]:
    """The raster's cell edges (deg) and its mean illuminance per cell (lx, set mean,
    row 0 the top) of :func:`read_regions`: the screen the view draws to pick from."""
    nr, nc = np.asarray(store["area_m2"]).shape
    S = max(len(store["emitted"]), 1)
    flux = np.bincount(store["cell"], store["flux"], nr * nc) / S
    lx = flux.reshape(nr, nc) / np.maximum(store["area_m2"], 1e-300)
    return {"h_edges_deg": [float(x) for x in store["h_edges_deg"]],
            "v_edges_deg": [float(x) for x in store["v_edges_deg"]],
            "lx": [[float(x) for x in row] for row in lx], "max_lx": float(lx.max(initial=0))}


def region_picture(run_dir: Path, b: dict[str, Any],
                   store: dict[str, np.ndarray] | None = None) -> bytes:
    """:func:`draw_region_spots`'s PNG as bytes (drawn in a temporary folder)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = draw_region_spots(run_dir, b, Path(tmp) / "lamp.png", store)
        return path.read_bytes()


def draw_region_spots(run_dir: Path, b: dict[str, Any], path: Path,
                      store: dict[str, np.ndarray] | None = None) -> Path:
    """``provenance-box-….png``: the lamp seen from the screen, every triangle coloured
    by the region's light it sent out (as :func:`draw_spots` for a rule)."""
    run_dir = Path(run_dir)
    if store is None:
        store = read_regions(run_dir / REGIONS_FILE)
    cells, _ = region_cells(store, b["covered_deg"])
    sel = np.isin(store["spot_cell"], cells)
    lamp = _read_lamp(run_dir / SPOTS_FILE)
    h0, h1, v0, v1 = b["covered_deg"]
    head = b["classes"][0]["class"] if b.get("classes") else "no photons"
    title = (f"H {h0:.2f}..{h1:.2f}°, V {v0:.2f}..{v1:.2f}°: {_cd(b['value_lx'])} lx"
             f"\nlargest class: {head}")
    return _draw_lamp(lamp, store["spot"][sel], store["spot_flux"][sel], title, path,
                      "flux sent out per projected area (lm/mm², log scale)",
                      run_caption(run_dir))


def _read_lamp(path: Path) -> dict[str, np.ndarray]:
    if not Path(path).exists():
        raise InputError(f"{path}: missing (a run made with --provenance writes it)")
    try:
        with np.load(path, allow_pickle=False) as d:
            return {"triangles": d["triangles"], "part": d["part"],
                    "part_names": d["part_names"]}
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise InputError(f"{path}: corrupt provenance file ({exc})") from None


def read_spots(path: Path, ruleset: str, rule: str) -> dict[str, np.ndarray]:
    """One rule's spots from ``provenance.npz``."""
    if not Path(path).exists():
        raise InputError(f"{path}: missing (a run made with --provenance writes it)")
    try:
        with np.load(path, allow_pickle=False) as d:
            data = {k: d[k] for k in d.files}
    except (OSError, ValueError, KeyError) as exc:
        raise InputError(f"{path}: corrupt provenance file ({exc})") from None
    hit = np.flatnonzero((data["rulesets"] == ruleset) & (data["rules"] == rule))
    if len(hit) == 0:
        raise InputError(f"{path}: no rule '{rule}' of {ruleset}")
    sel = data["rule"] == hit[0]
    return {"triangles": data["triangles"], "part": data["part"],
            "part_names": data["part_names"], "spot": data["spot"][sel],
            "cd": data["cd"][sel]}


def draw_spots(spots_file: Path, ruleset: str, rule: str, path: Path,
               breakdown: dict[str, Any], caption: str | None = None) -> Path:
    """``provenance-<RULE>.png``: the lamp seen from the screen (looking back along −z,
    world +X to the right), every triangle coloured by the rule's intensity it sent out
    (its last reflection or scattering) per unit of its projected area (cd/mm², log
    scale), drawn over the unlit parts (grey: a clear lens shows what lies behind it)."""
    d = read_spots(spots_file, ruleset, rule)
    head = (breakdown["classes"][0]["class"] if breakdown.get("classes") else "no photons")
    title = (f"{ruleset} {rule}: {_cd(breakdown['value_cd'])} cd ({breakdown['verdict']})"
             f"\nlargest class: {head}")
    if caption is None:  # drawn after the run: its own summary says what it was
        caption = run_caption(Path(spots_file).parent)
    return _draw_lamp(d, d["spot"], d["cd"], title, path,
                      "intensity sent out per projected area (cd/mm²)", caption)


def _draw_lamp(d: dict[str, np.ndarray], spot: np.ndarray, amount: np.ndarray, title: str,
               path: Path, label: str, caption: str | None = None) -> Path:
    """The lamp's triangles ``d`` seen from the screen, ``amount`` of each ``spot``
    triangle per its projected area (log colour scale) over the unlit parts in grey."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from matplotlib.colors import LogNorm

    tri = d["triangles"].astype(np.float64)
    xy = tri[:, :, :2] * 1e3  # mm, seen from the screen: +X right, +Y up
    e1, e2 = xy[:, 1] - xy[:, 0], xy[:, 2] - xy[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    dens = np.zeros(len(tri))
    np.add.at(dens, spot, amount)
    lit = (dens > 0) & (area > 1e-12)
    dens = np.where(lit, dens / np.maximum(area, 1e-12), 0.0)
    order = np.argsort(tri[:, :, 2].mean(axis=1), kind="stable")  # far from the screen first
    fig, ax = plt.subplots(figsize=(7.5, 6.5), dpi=110)
    grey = PolyCollection(xy[order][~lit[order]], facecolors="0.85", edgecolors="0.6",
                          linewidths=0.1)
    ax.add_collection(grey)
    if lit.any():
        top = float(dens[lit].max())
        norm = LogNorm(vmin=max(top * 1e-3, float(dens[lit].min())), vmax=top)
        li = order[lit[order]]
        coll = PolyCollection(xy[li], array=np.maximum(dens[li], norm.vmin), cmap="inferno",
                              norm=norm, edgecolors="none")
        ax.add_collection(coll)
        fig.colorbar(coll, ax=ax, label=label)
    if len(xy):
        ax.set_xlim(xy[..., 0].min(), xy[..., 0].max())
        ax.set_ylim(xy[..., 1].min(), xy[..., 1].max())
    ax.set_aspect("equal")
    ax.set_xlabel("X (mm), lamp seen from the screen")
    ax.set_ylabel("Y (mm)")
    ax.set_title(title, fontsize=8)
    add_caption(fig, caption)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", metadata=png_metadata(caption))
    plt.close(fig)
    return Path(path)


def write_path_map(out: Path, frame: Any, text: str, per_set: dict[int, Any],
                   emitted: np.ndarray, sets: list[int], caption: str | None = None
                   ) -> list[Path]:
    """``provenance-map.exr`` (channel Y, lx: the wall illuminance of the photons whose
    class name holds ``text``, the sets' binned flux over their emitted photons per pixel
    area) and ``provenance-map.png`` (false colour, log scale)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    W, H = frame.resolution
    total = np.zeros((H * W,))
    for s in sets:
        data = per_set.get(s) or {}
        m = data.get("map")
        if m is not None:
            total += luminous(m)
    dh, dv = frame.pixel_size_m
    n = float(emitted.sum())
    lux = (total / n / (dh * dv) if n > 0 else total).reshape(H, W)
    exr = out / "provenance-map.exr"
    write_exr(exr, {"Y": lux}, {"units": "lx", "provenance_class": text})
    png = out / "provenance-map.png"
    fig, ax = plt.subplots(figsize=(9, 4), dpi=110)
    h0, h1, v0, v1 = frame.extent_deg()
    top = float(lux.max())
    if top > 0:
        im = ax.imshow(np.maximum(lux, top * 1e-4), extent=(h0, h1, v0, v1), origin="upper",
                       cmap="inferno", norm=LogNorm(top * 1e-4, top), aspect="auto")
        fig.colorbar(im, ax=ax, label="lx")
    ax.set_xlabel("H (°)")
    ax.set_ylabel("V (°)")
    ax.set_title(f"light of path classes naming '{text}': max {top:.4g} lx", fontsize=9)
    add_caption(fig, caption)
    with atomic_path(png, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", metadata=png_metadata(caption))
    plt.close(fig)
    return [exr, png]
