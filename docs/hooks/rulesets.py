"""Build hook: the rule-set reference (``reference/rulesets.md``) from the shipped files.

At build time two marker lines of the page are replaced:

- ``<!-- generated: rulesets -->``: a summary table, then one section per rule set shipped
  in ``lightsim/luminaires/regulations/*.toml``, read with the package's own loader
  (:func:`lightsim.luminaires.regulations.load_ruleset`): id, title, regulation, version,
  traffic, distance, notes, and every rule (kind, position in degrees, limits in cd) with
  its source (numbered below the table) and certainty; "less sure" rules are marked and
  carry their note, rules without the data to test them say so.
- ``<!-- generated: ruleset-format -->``: the file format, taken from the ``README.md``
  beside the rule sets (its list of shipped sets left out: the sections above are that
  list), headings moved one level down.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import mdtext

from lightsim.luminaires.regulations import (
    Geometry,
    Relation,
    RuleSet,
    SumRule,
    format_position,
    load_ruleset,
)
from lightsim.luminaires.regulations.ruleset import BUILTIN_DIR

PAGE = "reference/rulesets.md"
MARKER = "<!-- generated: rulesets -->"
FORMAT_MARKER = "<!-- generated: ruleset-format -->"
LEFT_OUT = ("Shipped rule sets",)  # README sections the generated sections replace
HEADER = ("rule", "kind", "position", "min (cd)", "max (cd)", "certainty", "source")

Rule = Geometry | SumRule | Relation


def shipped() -> list[RuleSet]:
    """Every rule set shipped with lightsim, by id."""
    paths = sorted(p for p in BUILTIN_DIR.glob("*.toml") if not p.name.startswith((".", "_")))
    return [load_ruleset(p) for p in paths]


def _num(x: float) -> str:
    return f"{x:,.0f}" if abs(x) >= 1000 else f"{x:g}"


def _cd(x: float | None) -> str:
    return "" if x is None else _num(x)


def _hv(h: float, v: float) -> str:
    return f"({h:g}, {v:g})"


def _kind_and_position(rule: Rule, ruleset: RuleSet) -> tuple[str, str]:
    if isinstance(rule, SumRule):
        return "sum", "sum of " + " + ".join(mdtext.code(p) for p in rule.points)
    if isinstance(rule, Relation):
        op = {"<=": "≤", ">=": "≥"}[rule.op]
        rhs = mdtext.code(rule.rhs)
        if rule.rhs in {g.name for g in ruleset.geometries if g.kind == "zone"}:
            rhs = f"{rule.rhs_stat}({rhs})"
        return "relation", f"{mdtext.code(rule.lhs)} {op} {rule.factor:g} × {rhs}"
    if rule.kind == "point":
        where = format_position(rule.h, rule.v)
        return "point", f"{where} {_hv(rule.h, rule.v)}"
    stat = {"max": "brightest point", "min": "dimmest point"}.get(rule.stat or "", "")
    if rule.line:
        (h1, v1), (h2, v2) = rule.line
        shape = f"segment {_hv(h1, v1)} – {_hv(h2, v2)}"
    elif rule.polygon:
        shape = "polygon " + " ".join(_hv(h, v) for h, v in rule.polygon)
    else:
        shape = "outline not given"
    return "zone", f"{shape}; limits on its {stat}" if stat else shape


def _certainty(rule: Rule) -> str:
    parts = ["**less sure**" if rule.certainty == "less-sure" else "sure"]
    if not getattr(rule, "complete", True):
        parts.append("**not tested** (data incomplete)")
    text = ", ".join(parts)
    return f"{text}: {mdtext.text(rule.note)}" if rule.note else text


def section(rs: RuleSet) -> str:
    """One rule set: its facts, its rules and their numbered sources."""
    facts = [("title", mdtext.text(rs.title)), ("regulation", mdtext.text(rs.regulation)),
             ("beam", mdtext.text(rs.beam)), ("version", mdtext.text(rs.version)),
             ("traffic", f"{rs.traffic} only (not mirrored)"
              if rs.measurement is not None and not rs.measurement.mirror
              else f"{rs.traffic} (the other side mirrors every position, h → −h)"),
             ("distance", f"{rs.distance_m:g} m"),
             ("file", mdtext.code(f"lightsim/luminaires/regulations/{Path(rs.path).name}"))]
    parts = [f"## {rs.id}", "\n".join(f"- **{k}**: {v}" for k, v in facts if v)]
    if rs.notes:
        parts.append("\n".join(f"- {mdtext.text(n)}" for n in rs.notes))
    if rs.measurement is not None:
        parts.append(measuring(rs))
    sources: dict[str, int] = {}
    rows = []
    for rule in (*rs.geometries, *rs.sums, *rs.relations):
        kind, where = _kind_and_position(rule, rs)
        src = rule.source or rs.source
        number = sources.setdefault(src, len(sources) + 1)
        rows.append([mdtext.code(rule.name), kind, where, _cd(rule.min) if kind != "relation"
                     else "", _cd(rule.max) if kind != "relation" else "", _certainty(rule),
                     f"[{number}]"])
    parts.append(mdtext.table(HEADER, rows))
    parts.append("Sources:\n\n" + "\n".join(f"{n}. {mdtext.text(s)}"
                                            for s, n in sources.items()))
    return "\n\n".join(parts)


def measuring(rs: RuleSet) -> str:
    """The ``[measurement]`` table: how ``lightsim check`` reads the points."""
    mc = rs.measurement
    aim = {"screen": "as the run is", "mechanical": "the lamp's own axis",
           "visual": (f"by the cut-off ({mc.visual_aim}): put at {mc.cutoff_target_deg:+g}°, "
                      f"gradient at least {mc.cutoff_gradient_min:g}")}[mc.aim]
    facts = [("angles", mc.angles), ("re-aim at every test point", f"{mc.reaim_deg:g}°"),
             ("least test distance", f"{mc.min_distance_m:g} m"),
             ("photometer aperture", f"{mc.aperture_deg:g}°" if mc.aperture_deg
              else "none (point values)"),
             ("aim", aim), ("beam", mc.beam or "any"),
             ("traffic", "mirrored for the other side" if mc.mirror else "this side only"),
             ("certainty", _certainty(mc)), ("source", mdtext.text(mc.source))]
    return ("Measuring conditions (`lightsim check`):\n\n"
            + "\n".join(f"- **{k}**: {v}" for k, v in facts))


def summary(rulesets: list[RuleSet]) -> str:
    """One line per rule set: id (linked), title, traffic, rules, less-sure rules."""
    rows = []
    for rs in rulesets:
        rules = (*rs.geometries, *rs.sums, *rs.relations)
        unsure = sum(r.certainty == "less-sure" for r in rules)
        untested = sum(not getattr(r, "complete", True) for r in rules)
        rows.append([f"[{rs.id}](#{rs.id})", mdtext.text(rs.title), rs.traffic,
                     str(len(rules)), str(unsure), str(untested)])
    return mdtext.table(("id", "title", "traffic", "rules", "less sure", "not tested"), rows)


def file_format() -> str:
    """The README without its title and left-out sections, headings one level down."""
    lines = (BUILTIN_DIR / "README.md").read_text(encoding="utf-8").splitlines()
    out, keep, fenced = [], True, False
    for line in lines:
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("#"):
            level, _, title = line.partition(" ")
            if level == "#":  # the title: the page has its own
                continue
            if level == "##":
                keep = title.strip() not in LEFT_OUT
            line = "#" + line
        if keep:
            out.append(line)
    return "\n".join(out).strip()


def on_page_markdown(markdown: str, page: Any, **_: Any) -> str:
    """mkdocs hook: fill the rule-set page's markers."""
    if page.file.src_uri != PAGE:
        return markdown
    rulesets = shipped()
    generated = "\n\n".join([summary(rulesets), *(section(rs) for rs in rulesets)])
    markdown = mdtext.replace_marker(markdown, MARKER, generated, PAGE)
    return mdtext.replace_marker(markdown, FORMAT_MARKER, file_format(), PAGE)
