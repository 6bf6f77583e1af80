"""Headlamp regulations as data: rule sets, probe directions, verdicts with error bars.

Typical use (the engine supplies one intensity estimate per interleave set and probe)::

    from lightsim.luminaires.regulations import (
        load_ruleset, probe_points, evaluate, unevaluated_rules, format_table)

    rs = load_ruleset("r112-b-passing")              # or a path to a .toml/.json file
    probes = probe_points(rs, traffic="right", spacing_deg=0.25, frame=wall_frame)
    values = engine_estimates(probes.h_deg, probes.v_deg)  # (S, P) cd, one row per set
    results = evaluate(rs, probes, values, confidence=0.95)  # list of JSON-ready dicts
    Console().print(format_table(results, unevaluated=unevaluated_rules(rs, probes)))

Rule sets are TOML/JSON files (format in ``README.md`` here); built-in ids:
``r112-a-passing``, ``r112-b-passing``, ``r112-b-driving``, ``sae-j1383-low``; more are
found in the folders of ``$LIGHTSIM_RULESETS``. Unit conversions (H/V degrees ↔ wall metres,
lux ↔ candela on a flat wall) are the engine's :mod:`lightsim.wall` (named in :mod:`.units`);
running a check on a finished run: :mod:`.check`.

Parameters
----------
============  ======  ========  =================================================
name          unit    default   meaning
============  ======  ========  =================================================
traffic       –       "right"   "left" mirrors every position (h → −h)
spacing_deg   deg     0.25      zone sampling step
values_cd     cd      –         (S, P) per-set intensity estimates
confidence    1       0.95      Student-t interval level
distance_m    m       25.0      measuring distance (wall plane z = D)
============  ======  ========  =================================================
"""

from lightsim.wall import (
    DEFAULT_DISTANCE_M,
    WallFrame,
    candela_from_lux,
    deg_from_wall_m,
    lux_from_candela,
    sample_wall,
    wall_m_from_deg,
)

from .evaluate import (
    VERDICT_STYLES,
    Probes,
    evaluate,
    format_position,
    format_table,
    probe_points,
    unevaluated_rules,
)
from .ruleset import SCHEMA, Geometry, Relation, RuleSet, SumRule, list_rulesets, load_ruleset

__all__ = [
    "DEFAULT_DISTANCE_M",
    "SCHEMA",
    "VERDICT_STYLES",
    "Geometry",
    "Probes",
    "Relation",
    "RuleSet",
    "SumRule",
    "WallFrame",
    "candela_from_lux",
    "deg_from_wall_m",
    "evaluate",
    "format_position",
    "format_table",
    "list_rulesets",
    "load_ruleset",
    "lux_from_candela",
    "probe_points",
    "sample_wall",
    "unevaluated_rules",
    "wall_m_from_deg",
]
