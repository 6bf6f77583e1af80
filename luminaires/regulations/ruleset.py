"""Photometric rule sets (regulations) as versioned data files, and their loader.

A rule set is a TOML (or JSON) file; the format is documented in ``README.md`` beside this
module and checked strictly here (unknown keys, missing references and impossible limits are
reported as one-line :class:`~lightsim.errors.InputError`). New rule sets need no code: drop a
file into a folder named by ``LIGHTSIM_RULESETS`` (``os.pathsep``-separated) or pass its path.

Positions are angular wall positions in degrees (``h`` > 0 right, ``v`` > 0 up of H-V, see
``docs/reference/conventions.md``), limits are luminous intensities in candela. A rule set
states the traffic side its positions are written for; :meth:`RuleSet.for_traffic` mirrors it
(h → −h) for the other side.

Parameters
----------
==================  =======  ========  ==================================================
name                unit     default   meaning
==================  =======  ========  ==================================================
name_or_path        –        –         built-in id (``r112-b-passing``) or a file path
traffic             –        "right"   "right" or "left" (left mirrors H: h → −h)
h, v                deg      –         test-point position (R/U positive)
min, max            cd       –         limits (inclusive)
factor              1        –         relation factor (``lhs op factor·rhs``)
LIGHTSIM_RULESETS   –        unset     extra folders searched for ``<id>.toml|json``
==================  =======  ========  ==================================================
"""

from __future__ import annotations

import json
import math
import os
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from lightsim.errors import InputError

from .conditions import MeasuringConditions, parse_conditions

SCHEMA = "lightsim-ruleset-1"
BUILTIN_DIR = Path(__file__).resolve().parent
ENV_VAR = "LIGHTSIM_RULESETS"
Traffic = Literal["right", "left"]
CERTAINTIES = ("sure", "less-sure")

__all__ = [
    "SCHEMA",
    "Geometry",
    "Relation",
    "RuleSet",
    "SumRule",
    "check_traffic",
    "list_rulesets",
    "load_ruleset",
]


@dataclass(frozen=True)
class Geometry:
    """A test point or a zone with optional limits on its intensity.

    Attributes
    ----------
    name : str
        Unique name within the rule set (``"B50L"``, ``"III"``).
    kind : {"point", "zone"}
        A single direction or an area/line sampled on a grid.
    h, v : float
        Position of a point in degrees (R and U positive); 0 for zones.
    polygon : tuple of (h, v)
        Zone outline in degrees (closed implicitly), or empty.
    line : tuple of (h, v)
        Zone given as a segment (two end points), or empty.
    min, max : float or None
        Limits in cd (inclusive). For zones they apply to ``stat``.
    stat : {"max", "min"} or None
        Zone statistic the limits apply to: ``"max"`` (the brightest point: a max limit
        means *every* point ≤ max, a min limit means *some* point ≥ min) or ``"min"``.
    complete : bool
        False when the data lack what is needed to test it (e.g. an unknown zone outline);
        such rules are listed by ``unevaluated_rules`` instead of being tested.
    certainty, note, source : str
        How sure the data are (``"sure"`` / ``"less-sure"``) and why.
    """

    name: str
    kind: Literal["point", "zone"]
    h: float = 0.0
    v: float = 0.0
    polygon: tuple[tuple[float, float], ...] = ()
    line: tuple[tuple[float, float], ...] = ()
    min: float | None = None
    max: float | None = None
    stat: Literal["max", "min"] | None = None
    complete: bool = True
    certainty: str = "sure"
    note: str = ""
    source: str = ""

    @property
    def has_limits(self) -> bool:
        """True if the rule carries a min or max limit."""
        return self.min is not None or self.max is not None

    def mirrored(self) -> Geometry:
        """The same geometry for the other traffic side (h → −h)."""
        return replace(self, h=-self.h if self.h else 0.0,
                       polygon=tuple((-h, v) for h, v in self.polygon),
                       line=tuple((-h, v) for h, v in self.line))


@dataclass(frozen=True)
class SumRule:
    """A limit on the sum of several points' intensities (cd), e.g. ``1+2+3 ≥ 190``."""

    name: str
    points: tuple[str, ...]
    min: float | None = None
    max: float | None = None
    certainty: str = "sure"
    note: str = ""
    source: str = ""


@dataclass(frozen=True)
class Relation:
    """A relative condition ``lhs op factor·rhs``, e.g. ``HV ≥ 0.8·Imax``.

    ``lhs`` is a point or zone (a zone must satisfy it at every point); ``rhs`` is a point,
    or a zone reduced by ``rhs_stat`` (``"max"``: its brightest point).
    """

    name: str
    lhs: str
    op: Literal["<=", ">="]
    factor: float
    rhs: str
    rhs_stat: Literal["max", "min"] = "max"
    complete: bool = True
    certainty: str = "sure"
    note: str = ""
    source: str = ""


@dataclass(frozen=True)
class RuleSet:
    """A versioned photometric rule set (see the module docstring and ``README.md``)."""

    id: str
    title: str
    version: str
    source: str
    traffic: Traffic
    geometries: tuple[Geometry, ...]
    sums: tuple[SumRule, ...] = ()
    relations: tuple[Relation, ...] = ()
    regulation: str = ""
    beam: str = ""
    distance_m: float = 25.0
    notes: tuple[str, ...] = ()
    path: str = ""
    meta: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)
    # how the points are measured (re-aim, aim, angles, distance): ``[measurement]``
    measurement: MeasuringConditions | None = None

    def geometry(self, name: str) -> Geometry:
        """The point or zone called ``name``."""
        for g in self.geometries:
            if g.name == name:
                return g
        raise KeyError(name)

    def for_traffic(self, traffic: str) -> RuleSet:
        """This rule set with positions for ``traffic`` ("right"/"left"), mirrored if needed."""
        traffic = check_traffic(traffic)
        if traffic == self.traffic:
            return self
        if self.measurement is not None and not self.measurement.mirror:
            raise InputError(f"rule set {self.id} applies to {self.traffic}-hand traffic "
                             f"only; {traffic}-hand traffic does not apply")
        return replace(self, traffic=traffic,
                       geometries=tuple(g.mirrored() for g in self.geometries))


def check_traffic(traffic: str) -> Traffic:
    """``traffic`` as "right" or "left" (any case).

    Raises
    ------
    InputError
        Anything else.
    """
    t = str(traffic).lower()
    if t not in ("right", "left"):
        raise InputError(f"traffic must be 'right' or 'left', got {traffic!r}")
    return t  # type: ignore[return-value]


# ---- discovery ---------------------------------------------------------------------------
def _search_dirs() -> list[Path]:
    dirs = [BUILTIN_DIR]
    for part in os.environ.get(ENV_VAR, "").split(os.pathsep):
        if part.strip():
            dirs.append(Path(part.strip()).expanduser())
    return dirs


def _candidates() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for d in _search_dirs():
        if not d.is_dir():
            continue
        for p in sorted(d.iterdir()):
            if p.suffix.lower() in (".toml", ".json") and not p.name.startswith((".", "_")):
                found.setdefault(p.stem, p)
    return found


def list_rulesets() -> list[dict[str, str]]:
    """Available rule sets: built-in ones and those in ``$LIGHTSIM_RULESETS`` folders.

    Returns
    -------
    list of dict
        One ``{"id", "title", "version", "source", "path"}`` per loadable file, sorted by id. Files
        that fail to load are listed with ``"error"`` instead of title/version.
    """
    out = []
    for ident, path in sorted(_candidates().items()):
        try:
            rs = _load_file(path)
            out.append({"id": rs.id, "title": rs.title, "version": rs.version,
                        "source": rs.source, "path": str(path)})
        except InputError as exc:
            out.append({"id": ident, "error": str(exc), "path": str(path)})
    return out


def load_ruleset(name_or_path: str | os.PathLike) -> RuleSet:
    """Load a rule set by built-in id (e.g. ``"r112-b-passing"``) or from a file path.

    Parameters
    ----------
    name_or_path : str or path-like
        An id found by :func:`list_rulesets` or the path of a ``.toml``/``.json`` file.

    Returns
    -------
    RuleSet
        Positions as written in the file (use :meth:`RuleSet.for_traffic` to mirror).

    Raises
    ------
    InputError
        Unknown id (the message lists the available ones) or an invalid file.
    """
    text = str(name_or_path)
    path = Path(text).expanduser()
    if path.suffix.lower() in (".toml", ".json") or os.sep in text or path.is_file():
        if not path.is_file():
            raise InputError(f"rule set file not found: {text}")
        return _load_file(path)
    cands = _candidates()
    if text not in cands:
        avail = ", ".join(sorted(cands)) or "none"
        raise InputError(f"unknown rule set '{text}'; available: {avail}")
    return _load_file(cands[text])


# ---- parsing and validation ---------------------------------------------------------------
_TOP_KEYS = {"schema", "id", "title", "version", "source", "traffic", "regulation", "beam",
             "distance_m", "notes", "point", "zone", "sum", "relation", "meta",
             "measurement"}
_COMMON = {"name", "certainty", "note", "source"}
_POINT_KEYS = _COMMON | {"h", "v", "min", "max"}
_ZONE_KEYS = _COMMON | {"polygon", "line", "min", "max", "stat", "complete"}
_SUM_KEYS = _COMMON | {"points", "min", "max"}
_REL_KEYS = _COMMON | {"lhs", "op", "factor", "rhs", "rhs_stat", "complete"}


class _Ctx:
    def __init__(self, path: Path):
        self.path = path

    def fail(self, msg: str) -> InputError:
        return InputError(f"rule set {self.path.name}: {msg}")


def _num(ctx: _Ctx, where: str, key: str, value: Any, *, optional: bool = False
         ) -> float | None:
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ctx.fail(f"{where}: '{key}' must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise ctx.fail(f"{where}: '{key}' must be finite, got {value!r}")
    return x


def _str(ctx: _Ctx, where: str, key: str, value: Any, default: str | None = None) -> str:
    if value is None:
        if default is None:
            raise ctx.fail(f"{where}: missing '{key}'")
        return default
    if not isinstance(value, str):
        raise ctx.fail(f"{where}: '{key}' must be text, got {value!r}")
    return value


def _keys(ctx: _Ctx, where: str, table: Mapping[str, Any], allowed: set[str]) -> None:
    if not isinstance(table, Mapping):
        raise ctx.fail(f"{where}: expected a table, got {table!r}")
    extra = sorted(set(table) - allowed)
    if extra:
        raise ctx.fail(f"{where}: unknown key(s) {', '.join(extra)} "
                       f"(allowed: {', '.join(sorted(allowed))})")


def _limits(ctx: _Ctx, where: str, t: Mapping[str, Any]) -> tuple[float | None, float | None]:
    lo = _num(ctx, where, "min", t.get("min"), optional=True)
    hi = _num(ctx, where, "max", t.get("max"), optional=True)
    if lo is not None and lo < 0:
        raise ctx.fail(f"{where}: 'min' must be ≥ 0 cd, got {lo}")
    if lo is not None and hi is not None and lo > hi:
        raise ctx.fail(f"{where}: 'min' {lo} exceeds 'max' {hi}")
    return lo, hi


def _certainty(ctx: _Ctx, where: str, t: Mapping[str, Any]) -> str:
    c = _str(ctx, where, "certainty", t.get("certainty"), "sure")
    if c not in CERTAINTIES:
        raise ctx.fail(f"{where}: 'certainty' must be one of {', '.join(CERTAINTIES)}")
    if c == "less-sure" and not t.get("note"):
        raise ctx.fail(f"{where}: a 'less-sure' rule needs a 'note' saying why")
    return c


def _head(ctx: _Ctx, kind: str, i: int, t: Mapping[str, Any], allowed: set[str]
          ) -> tuple[str, str]:
    """Check table ``i`` of ``kind`` for unknown keys; return (its name, where)."""
    where = f"{kind} #{i + 1}"
    _keys(ctx, where, t, allowed)
    name = _str(ctx, where, "name", t.get("name"))
    return name, f"{kind} '{name}'"


def _about(ctx: _Ctx, where: str, t: Mapping[str, Any], default_source: str
           ) -> dict[str, str]:
    """The ``certainty``, ``note`` and ``source`` every rule carries (checked in that order)."""
    return {"certainty": _certainty(ctx, where, t),
            "note": _str(ctx, where, "note", t.get("note"), ""),
            "source": _str(ctx, where, "source", t.get("source"), default_source)}


def _complete(ctx: _Ctx, where: str, t: Mapping[str, Any]) -> bool:
    complete = t.get("complete", True)
    if not isinstance(complete, bool):
        raise ctx.fail(f"{where}: 'complete' must be true or false")
    return complete


def _vertices(ctx: _Ctx, where: str, key: str, value: Any, n_min: int
              ) -> tuple[tuple[float, float], ...]:
    if not isinstance(value, list) or len(value) < n_min:
        raise ctx.fail(f"{where}: '{key}' must be a list of at least {n_min} [h, v] pairs")
    out = []
    for vert in value:
        if not isinstance(vert, list) or len(vert) != 2:
            raise ctx.fail(f"{where}: '{key}' vertex {vert!r} is not an [h, v] pair")
        h = _num(ctx, where, key, vert[0])
        v = _num(ctx, where, key, vert[1])
        if abs(h) >= 90 or abs(v) >= 90:
            raise ctx.fail(f"{where}: '{key}' vertex {vert!r} must lie within ±90°")
        out.append((h, v))
    return tuple(out)


def _parse_point(ctx: _Ctx, i: int, t: Mapping[str, Any], default_source: str) -> Geometry:
    name, where = _head(ctx, "point", i, t, _POINT_KEYS)
    h = _num(ctx, where, "h", t.get("h"))
    v = _num(ctx, where, "v", t.get("v"))
    if abs(h) >= 90 or abs(v) >= 90:
        raise ctx.fail(f"{where}: position must lie within ±90°")
    lo, hi = _limits(ctx, where, t)
    return Geometry(name=name, kind="point", h=h, v=v, min=lo, max=hi,
                    **_about(ctx, where, t, default_source))


def _parse_zone(ctx: _Ctx, i: int, t: Mapping[str, Any], default_source: str) -> Geometry:
    name, where = _head(ctx, "zone", i, t, _ZONE_KEYS)
    complete = _complete(ctx, where, t)
    polygon: tuple[tuple[float, float], ...] = ()
    line: tuple[tuple[float, float], ...] = ()
    if "polygon" in t and "line" in t:
        raise ctx.fail(f"{where}: give either 'polygon' or 'line', not both")
    if "polygon" in t:
        polygon = _vertices(ctx, where, "polygon", t["polygon"], 3)
    elif "line" in t:
        line = _vertices(ctx, where, "line", t["line"], 2)
        if len(line) != 2:
            raise ctx.fail(f"{where}: 'line' must have exactly two end points")
    elif complete:
        raise ctx.fail(f"{where}: needs 'polygon' or 'line' (or complete = false)")
    lo, hi = _limits(ctx, where, t)
    stat = t.get("stat")
    if stat is None:
        if lo is not None and hi is not None:
            raise ctx.fail(f"{where}: with both 'min' and 'max' say which zone statistic "
                           "they limit: stat = \"max\" or \"min\"")
        stat = "min" if lo is not None else "max"
    if stat not in ("max", "min"):
        raise ctx.fail(f"{where}: 'stat' must be \"max\" or \"min\", got {stat!r}")
    note = _str(ctx, where, "note", t.get("note"), "")
    if not complete and not note:
        raise ctx.fail(f"{where}: an incomplete zone needs a 'note' saying what is missing")
    return Geometry(name=name, kind="zone", polygon=polygon, line=line, min=lo, max=hi,
                    stat=stat, complete=complete, **_about(ctx, where, t, default_source))


def _parse_sum(ctx: _Ctx, i: int, t: Mapping[str, Any], default_source: str,
               kinds: Mapping[str, str]) -> SumRule:
    name, where = _head(ctx, "sum", i, t, _SUM_KEYS)
    pts = t.get("points")
    if not isinstance(pts, list) or len(pts) < 2 or not all(isinstance(p, str) for p in pts):
        raise ctx.fail(f"{where}: 'points' must list at least two point names")
    for p in pts:
        if kinds.get(p) != "point":
            raise ctx.fail(f"{where}: '{p}' is not a point of this rule set")
    lo, hi = _limits(ctx, where, t)
    if lo is None and hi is None:
        raise ctx.fail(f"{where}: needs 'min' and/or 'max'")
    return SumRule(name=name, points=tuple(pts), min=lo, max=hi,
                   **_about(ctx, where, t, default_source))


def _parse_relation(ctx: _Ctx, i: int, t: Mapping[str, Any], default_source: str,
                    kinds: Mapping[str, str]) -> Relation:
    name, where = _head(ctx, "relation", i, t, _REL_KEYS)
    lhs = _str(ctx, where, "lhs", t.get("lhs"))
    rhs = _str(ctx, where, "rhs", t.get("rhs"))
    for ref in (lhs, rhs):
        if ref not in kinds:
            raise ctx.fail(f"{where}: '{ref}' is not a point or zone of this rule set")
    op = t.get("op")
    if op not in ("<=", ">="):
        raise ctx.fail(f"{where}: 'op' must be \"<=\" or \">=\", got {op!r}")
    factor = _num(ctx, where, "factor", t.get("factor"))
    if factor <= 0:
        raise ctx.fail(f"{where}: 'factor' must be > 0")
    rhs_stat = t.get("rhs_stat", "max")
    if rhs_stat not in ("max", "min"):
        raise ctx.fail(f"{where}: 'rhs_stat' must be \"max\" or \"min\"")
    complete = _complete(ctx, where, t)
    return Relation(name=name, lhs=lhs, op=op, factor=factor, rhs=rhs, rhs_stat=rhs_stat,
                    complete=complete, **_about(ctx, where, t, default_source))


def _read_doc(path: Path) -> dict[str, Any]:
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"rule set {path}: cannot read ({exc.strerror})") from None
    try:
        if path.suffix.lower() == ".json":
            doc = json.loads(raw.decode("utf-8"))
        else:
            doc = tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"rule set {path.name}: not valid "
                         f"{'JSON' if path.suffix.lower() == '.json' else 'TOML'}: {first}"
                         ) from None
    if not isinstance(doc, dict):
        raise InputError(f"rule set {path.name}: the top level must be a table")
    return doc


def _tables(ctx: _Ctx, doc: Mapping[str, Any], key: str) -> list[Mapping[str, Any]]:
    val = doc.get(key, [])
    if not isinstance(val, list):
        raise ctx.fail(f"'{key}' must be an array of tables ([[{key}]])")
    return val


def _load_file(path: Path) -> RuleSet:
    ctx = _Ctx(path)
    doc = _read_doc(path)
    _keys(ctx, "top level", doc, _TOP_KEYS)
    schema = doc.get("schema")
    if schema != SCHEMA:
        raise ctx.fail(f"'schema' must be \"{SCHEMA}\", got {schema!r}")
    ident = _str(ctx, "top level", "id", doc.get("id"))
    source = _str(ctx, "top level", "source", doc.get("source"))
    traffic = doc.get("traffic")
    if traffic not in ("right", "left"):
        raise ctx.fail("'traffic' must be \"right\" or \"left\" (the side the positions "
                       "are written for)")
    distance = _num(ctx, "top level", "distance_m", doc.get("distance_m", 25.0))
    if distance <= 0:
        raise ctx.fail("'distance_m' must be > 0")
    notes = doc.get("notes", [])
    if isinstance(notes, str):
        notes = [notes]
    if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
        raise ctx.fail("'notes' must be text or a list of texts")
    geoms: list[Geometry] = []
    for i, t in enumerate(_tables(ctx, doc, "point")):
        geoms.append(_parse_point(ctx, i, t, source))
    for i, t in enumerate(_tables(ctx, doc, "zone")):
        geoms.append(_parse_zone(ctx, i, t, source))
    kinds: dict[str, str] = {}
    for g in geoms:
        if g.name in kinds:
            raise ctx.fail(f"the name '{g.name}' is used twice")
        kinds[g.name] = g.kind
    sums = [_parse_sum(ctx, i, t, source, kinds) for i, t in
            enumerate(_tables(ctx, doc, "sum"))]
    rels = [_parse_relation(ctx, i, t, source, kinds) for i, t in
            enumerate(_tables(ctx, doc, "relation"))]
    rule_names = [g.name for g in geoms] + [s.name for s in sums] + [r.name for r in rels]
    dup = {n for n in rule_names if rule_names.count(n) > 1}
    if dup:
        raise ctx.fail(f"rule name(s) used twice: {', '.join(sorted(dup))}")
    if not any(g.has_limits for g in geoms) and not sums and not rels:
        raise ctx.fail("no limits: a rule set needs at least one point/zone with 'min' or "
                       "'max', a sum or a relation")
    meta = doc.get("meta", {})
    if not isinstance(meta, dict):
        raise ctx.fail("'meta' must be a table")
    measurement = (parse_conditions(doc["measurement"], ctx.fail, source)
                   if "measurement" in doc else None)
    return RuleSet(id=ident, title=_str(ctx, "top level", "title", doc.get("title")),
                   version=_str(ctx, "top level", "version", doc.get("version")),
                   source=source, traffic=traffic, geometries=tuple(geoms),
                   sums=tuple(sums), relations=tuple(rels),
                   regulation=_str(ctx, "top level", "regulation", doc.get("regulation"), ""),
                   beam=_str(ctx, "top level", "beam", doc.get("beam"), ""),
                   distance_m=distance, notes=tuple(notes), path=str(path), meta=meta,
                   measurement=measurement)


def iter_rule_names(ruleset: RuleSet) -> Iterable[str]:
    """Names of all rules (limited points/zones, sums, relations) in file order."""
    for g in ruleset.geometries:
        if g.has_limits:
            yield g.name
    for s in ruleset.sums:
        yield s.name
    for r in ruleset.relations:
        yield r.name
