"""Material map files: optics for CAD parts by name pattern, without editing the CAD.

A CAD export carries geometry and names, not optics. A material map (TOML) assigns them::

    schema = "lightsim-materials-1"

    [[rule]]
    match = "reflector*"      # shell-style pattern on the part name, case-insensitive
    kind = "mirror"
    reflectance = 0.88

    [[rule]]
    match = "lens"
    kind = "glass"
    ior = 1.59

    [[rule]]
    match = "filament"
    kind = "emitter"
    flux_lm = 1000
    emission = "isotropic"    # or lambertian

    [[rule]]
    match = "housing*"
    kind = "ignore"

The first rule whose pattern matches a part decides; parts no rule matches keep the
file's own material (glTF) or the default diffuse grey. A ``--part-material`` given on
the command line wins over the map.

Single CAD faces: with OpenCASCADE's XCAF reader (``cadquery-ocp``) every face of a STEP
or IGES part has an address ``"<part>/<face>"`` — its CAD name, or ``face-<k>`` — and a
rule (or ``--part-material``) that matches the address but not the part splits that face
off into a part of its own (:func:`split_cad_faces`)::

    [[rule]]
    match = "reflector/face-3"   # before "reflector*": the first matching rule decides
    kind = "diffuse"

==============  =====  ==========  ==============  ===========================================
key             unit   default     applies to      meaning
==============  =====  ==========  ==============  ===========================================
``match``       –      required    every rule      pattern (``*``, ``?``, ``[ab]``) on the name
``kind``        –      required    every rule      ``mirror``, ``glass``, ``diffuse``,
                                                   ``emitter``, ``wall``, ``ignore``
``reflectance`` –      0.88        mirror          mirror reflectance
``ior``         –      1.5         glass           glass refractive index
``attenuation`` 1/m    0           glass           absorption coefficient σ (Beer–Lambert)
``albedo``      –      0.5         diffuse, wall   diffuse reflectance
``flux_lm``     lm     the file's  emitter         emitter flux (or ``--flux``)
``emission``    –      isotropic   emitter         ``isotropic`` or ``lambertian``
==============  =====  ==========  ==============  ===========================================

The single declaration of these keys is :data:`RULE_KEYS` (the manual's table is
:func:`key_table_markdown`). A key that does not apply to its rule's kind (``reflectance``
on a diffuse rule) is refused in one line, as is an unknown key.
"""

from __future__ import annotations

import fnmatch
import math
import os
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lightsim.errors import InputError
from lightsim.materials import DIELECTRIC, DIFFUSE, MIRROR, Material

SCHEMA = "lightsim-materials-1"
KINDS = ("mirror", "glass", "diffuse", "emitter", "wall", "ignore")


@dataclass(frozen=True)
class RuleKey:
    """One key of a ``[[rule]]`` table: what it is and which kinds it applies to.

    Attributes
    ----------
    key, type, unit, default, range, meaning : str
        As printed in the manual's table (``unit`` "–" for dimensionless values).
    kinds : tuple of str
        The rule kinds the key applies to; empty for keys every rule has.
    """

    key: str
    type: str
    unit: str
    default: str
    range: str
    kinds: tuple[str, ...]
    meaning: str


#: Every rule key (the single declaration: reader, refusal of misplaced keys, manual).
RULE_KEYS = (
    RuleKey("match", "string", "–", "required", "non-empty", (),
            "shell-style pattern (`*`, `?`, `[ab]`) on the part name or face address, "
            "case-insensitive"),
    RuleKey("kind", "string", "–", "required", ", ".join(f"`{k}`" for k in KINDS), (),
            "what the part is"),
    RuleKey("reflectance", "number", "–", "0.88", "0 … 1", ("mirror",),
            "mirror reflectance (the rest is absorbed)"),
    RuleKey("ior", "number", "–", "1.5", "1 … 5", ("glass",), "glass refractive index"),
    RuleKey("attenuation", "number", "1/m", "0", "≥ 0", ("glass",),
            "glass absorption coefficient σ (Beer–Lambert: transmittance e^(−σd) over a "
            "path d)"),
    RuleKey("albedo", "number", "–", "0.5", "0 … 1", ("diffuse", "wall"),
            "diffuse reflectance (a wall's, for camera views)"),
    RuleKey("flux_lm", "number", "lm", "the file's", "> 0", ("emitter",),
            "emitter flux; required unless the file has one or `--flux` is given"),
    RuleKey("emission", "string", "–", "`isotropic`", "`isotropic`, `lambertian`",
            ("emitter",), "emitter's angular emission"),
)
KEYS = {k.key for k in RULE_KEYS}
_APPLIES = {k.key: k.kinds for k in RULE_KEYS}


def key_table_markdown() -> str:
    """The rule keys as the Markdown table of the manual's material-map reference."""
    rows = ["| key | kind of value | unit | default | range | applies to | meaning |",
            "|---|---|---|---|---|---|---|"]
    for k in RULE_KEYS:
        applies = ", ".join(f"`{x}`" for x in k.kinds) if k.kinds else "every rule"
        rows.append(f"| `{k.key}` | {k.type} | {k.unit} | {k.default} | {k.range} | "
                    f"{applies} | {k.meaning} |")
    return "\n".join(rows) + "\n"


@dataclass(frozen=True)
class MaterialRule:
    """One rule of a material map (see the module docstring)."""

    match: str
    kind: str
    reflectance: float = 0.88
    ior: float = 1.5
    attenuation: float = 0.0
    albedo: float = 0.5
    flux_lm: float | None = None
    emission: str = "isotropic"

    def matches(self, name: str) -> bool:
        return fnmatch.fnmatchcase(name.lower(), self.match.lower())

    def material(self, name: str) -> Material | None:
        """The lightsim material of a part this rule assigns (None for emitters/ignore)."""
        if self.kind == "mirror":
            return Material(name, MIRROR, np.full(3, self.reflectance))
        if self.kind == "glass":
            return Material(name, DIELECTRIC, np.ones(3), self.ior,
                            np.full(3, self.attenuation))
        if self.kind in ("diffuse", "wall"):
            return Material(name, DIFFUSE, np.full(3, self.albedo))
        return None


@dataclass(frozen=True)
class MaterialMap:
    path: str
    rules: tuple[MaterialRule, ...]

    def rule_for(self, name: str) -> MaterialRule | None:
        """The first rule whose pattern matches ``name`` (None if none does)."""
        return next((r for r in self.rules if r.matches(name)), None)

    def rule_number(self, name: str) -> int | None:
        """The 1-based number of the first rule matching ``name`` (None if none does)."""
        return next((i + 1 for i, r in enumerate(self.rules) if r.matches(name)), None)


def _number(where: str, key: str, value: object, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{where}: '{key}' must be a number, got {value!r}")
    x = float(value)
    if not (math.isfinite(x) and lo <= x <= hi):
        raise InputError(f"{where}: '{key}' = {x:g} must lie in [{lo:g}, {hi:g}]")
    return x


def read_material_map(path: str | os.PathLike) -> MaterialMap:
    """Read and check a material map; one-line :class:`InputError` for any problem."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such material map")
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        msg = str(exc).splitlines()[0]
        raise InputError(f"{p}: not a TOML material map ({msg})") from None
    if doc.get("schema", SCHEMA) != SCHEMA:
        raise InputError(f"{p}: schema must be '{SCHEMA}', got {doc.get('schema')!r}")
    unknown = set(doc) - {"schema", "rule", "title", "source"}
    if unknown:
        raise InputError(f"{p}: unknown key(s) {', '.join(sorted(unknown))} (expected "
                         "[[rule]] tables)")
    rules = []
    for i, t in enumerate(doc.get("rule", [])):
        where = f"{p}: rule {i + 1}"
        if not isinstance(t, dict):
            raise InputError(f"{where}: must be a table")
        bad = set(t) - KEYS
        if bad:
            raise InputError(f"{where}: unknown key(s) {', '.join(sorted(bad))}")
        match, kind = t.get("match"), str(t.get("kind", "")).lower()
        if not isinstance(match, str) or not match:
            raise InputError(f"{where}: 'match' must be a non-empty name pattern")
        if kind not in KINDS:
            raise InputError(f"{where}: 'kind' must be one of {', '.join(KINDS)}, "
                             f"got {t.get('kind')!r}")
        misplaced = sorted(k for k in t if _APPLIES[k] and kind not in _APPLIES[k])
        if misplaced:
            key = misplaced[0]
            raise InputError(f"{where}: '{key}' does not apply to kind '{kind}' (it is for "
                             f"{', '.join(_APPLIES[key])} rules)")
        kw: dict[str, object] = {}
        if "reflectance" in t:
            kw["reflectance"] = _number(where, "reflectance", t["reflectance"], 0.0, 1.0)
        if "ior" in t:
            kw["ior"] = _number(where, "ior", t["ior"], 1.0, 5.0)
        if "attenuation" in t:
            kw["attenuation"] = _number(where, "attenuation", t["attenuation"], 0.0, 1e9)
        if "albedo" in t:
            kw["albedo"] = _number(where, "albedo", t["albedo"], 0.0, 1.0)
        if "flux_lm" in t:
            kw["flux_lm"] = _number(where, "flux_lm", t["flux_lm"], 1e-30, 1e30)
        if "emission" in t:
            em = str(t["emission"]).lower()
            if em not in ("isotropic", "lambertian"):
                raise InputError(f"{where}: emission must be isotropic or lambertian")
            kw["emission"] = em
        rules.append(MaterialRule(match, kind, **kw))  # type: ignore[arg-type]
    if not rules:
        raise InputError(f"{p}: the material map has no [[rule]]")
    return MaterialMap(str(p), tuple(rules))


def split_cad_faces(raw: list[tuple], mmap: MaterialMap | None,
                    explicit: Iterable[str] = ()) -> list[tuple]:
    """Split CAD parts so that single faces named by a rule or option become parts.

    Parts read through OpenCASCADE's XCAF document (:mod:`lightsim.io.cad_xcaf`) carry
    ``extras["cad_faces"]``: the name of the CAD face each triangle came from. A face is
    addressed as ``"<part>/<face>"`` (``"reflector/face-3"``, ``"reflector/hot-spot"``).
    It becomes a part of its own when ``--part-material`` names it (``explicit``) or when
    the first map rule matching its address exists and differs from the first rule
    matching the part (first match decides, as for parts: ``match = "reflector/face-3"``
    must come before ``match = "reflector*"``). The rest of the part keeps the part's
    name. The face labels are removed from ``extras`` either way.

    Parameters
    ----------
    raw : list of (name, vertices, faces, normals, material json, extras)
        Parts as read by ``lightsim.scene``.
    mmap : MaterialMap or None
        The material map, if any.
    explicit : iterable of str
        Names given on the command line (``--part-material NAME=…``).

    Returns
    -------
    list of (name, vertices, faces, normals, material json, extras)
    """
    wanted = {n.lower() for n in explicit}
    out = []
    for name, verts, faces, normals, mat, extras in raw:
        labels = extras.get("cad_faces") if isinstance(extras, dict) else None
        if labels is None:
            out.append((name, verts, faces, normals, mat, extras))
            continue
        extras = {k: v for k, v in extras.items() if k != "cad_faces"}
        whole = mmap.rule_for(name) if mmap is not None else None
        own = []
        for i, face in enumerate(labels.names):
            addr = f"{name}/{face}"
            rule = mmap.rule_for(addr) if mmap is not None else None
            if addr.lower() in wanted or (rule is not None and rule is not whole):
                own.append((i, addr))
        if not own:
            out.append((name, verts, faces, normals, mat, extras))
            continue
        tri_face = np.asarray(labels.triangle_face)
        rest = np.ones(len(faces), dtype=bool)
        for i, addr in own:
            sel = tri_face == i
            rest &= ~sel
            out.append((addr, *_subset(verts, faces, normals, sel), mat, dict(extras)))
        if rest.any():
            out.append((name, *_subset(verts, faces, normals, rest), mat, extras))
    return out


def _subset(verts: np.ndarray, faces: np.ndarray, normals: np.ndarray | None,
            keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The triangles ``keep`` of a mesh with only the vertices they use (re-indexed)."""
    sub = np.asarray(faces)[keep]
    used, inverse = np.unique(sub.ravel(), return_inverse=True)
    return (np.asarray(verts)[used], inverse.reshape(sub.shape).astype(np.int64),
            None if normals is None else np.asarray(normals)[used])
