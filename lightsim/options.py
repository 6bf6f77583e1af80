"""Run options declared once: a dataclass field carries its :class:`Option` record.

:class:`lightsim.engine.config.RunConfig` (the engine's settings) and
:class:`lightsim.simulate.SimulateOptions` (one ``simulate`` run) declare every field with
:func:`option`. From those records come, so that they cannot drift apart:

- the click options of ``lightsim simulate`` (and the shared ones of other commands):
  flag, type, choices, help with unit, range and default (:func:`click_options`);
- the range and choice checks (one :class:`~lightsim.errors.InputError` line, exit 2)
  run by both dataclasses' ``__post_init__`` (:func:`check_fields`);
- the JSON form stored in ``checkpoint.json`` and ``summary.json["config"]`` and read
  back (:func:`to_json`, :func:`from_json`).

=================  ======  ========================================================
record field       unit    meaning
=================  ======  ========================================================
``help``           –       one sentence for ``--help`` (unit, range, default added)
``unit``           –       SI / photometric unit of the value ("" = dimensionless)
``flag``           –       command-line flag(s); ``()`` = not on the command line,
                           then ``internal`` says who sets it
``choices``        –       the allowed values (strings, or None/ints)
``low``, ``high``  unit    bounds; ``*_open`` makes them strict; floats must also
                           be finite unless ``allow_inf``
``kind``           –       how the text form is read: ``value`` (click's type),
                           ``pair`` ``AxB``, ``triple`` ``X,Y,Z``, ``flag``
                           (``--x``), ``onoff`` (``--x/--no-x``), ``assign``
                           (repeatable ``NAME=SPEC`` → dict), ``file``, ``dir``,
                           ``tuple`` (numbers or points, set by code only),
                           ``names`` (``a,b,c``: a subset of ``choices``, ``all``
                           = every one)
``resume``         –       may change on ``--resume`` (budgets, where it runs);
                           every other option must match the checkpoint
=================  ======  ========================================================
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import re
import typing
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import click

from lightsim.errors import InputError

KINDS = ("value", "pair", "triple", "flag", "onoff", "assign", "file", "dir", "tuple",
         "names")


@dataclass(frozen=True)
class Option:
    """One run option (see the module docstring); ``name`` and ``default`` come from the
    dataclass field that carries it."""

    help: str
    unit: str = ""
    flag: tuple[str, ...] = ()
    choices: tuple[Any, ...] | None = None
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    allow_inf: bool = False
    kind: str = "value"
    cast: type | None = None      # value (or pair element) type; None = from the field
    suffixes: tuple[str, ...] = ()  # a file name must end in one of these
    default_text: str | None = None  # how --help names a None (or computed) default
    metavar: str | None = None
    envvar: str | None = None
    resume: bool = False
    internal: str | None = None    # why there is no flag (who sets it instead)
    name: str = ""
    default: Any = None

    # -- naming -----------------------------------------------------------------------
    @property
    def on_cli(self) -> bool:
        return bool(self.flag)

    @property
    def label(self) -> str:
        """How messages name the option: its long flag, else its field name."""
        longs = [f for f in self.flag if f.startswith("--")]
        if longs:
            return longs[0].split("/")[0]
        if self.flag:
            return self.flag[0]
        return self.name.replace("_", " ")

    # -- text -------------------------------------------------------------------------
    def range_text(self) -> str:
        """The bounds as text: ``≥ 1``, ``> 0``, ``in (0, 1)``, ``1 … 16``."""
        lo, hi = self.low, self.high
        if lo is None and hi is None:
            return ""
        if lo is not None and hi is not None:
            if not self.low_open and not self.high_open:
                return f"{_num(lo)} … {_num(hi)}"
            return (f"in {'(' if self.low_open else '['}{_num(lo)}, "
                    f"{_num(hi)}{')' if self.high_open else ']'}")
        if lo is not None:
            return f"{'>' if self.low_open else '≥'} {_num(lo)}"
        return f"{'<' if self.high_open else '≤'} {_num(hi)}"

    def default_str(self) -> str:
        """The default as the command line would write it."""
        if self.default_text is not None:
            return self.default_text
        d = self.default
        if self.kind in ("flag", "onoff") and isinstance(d, bool):
            return "on" if d else "off"
        if d is None or d == {} or d == ():
            return "none"
        if self.kind == "pair":
            return "x".join(_num(v) for v in d)
        if self.kind == "triple":
            return ",".join(_num(v) for v in d)
        return _num(d) if isinstance(d, int | float) else str(d)

    def help_text(self) -> str:
        """``help`` plus ``[unit; range; default: …]`` (what ``--help`` shows)."""
        tail = [t for t in (self.unit, self.range_text()) if t]
        tail.append(f"default: {self.default_str()}")
        return f"{self.help} [{'; '.join(tail)}]"

    # -- checks -----------------------------------------------------------------------
    def check(self, value: Any) -> None:
        """Raise :class:`InputError` (one line naming the flag) when ``value`` is outside
        the declared choices or range; None passes when the default is None."""
        if value is None and self.default is None:
            return
        if self.kind == "names":
            names = tuple(self.choices or ())
            if isinstance(value, str):
                raise InputError(f"{self.label} must be a sequence of names, got {value!r}")
            bad = [str(v) for v in value or () if v not in names]
            if bad:
                raise InputError(f"{self.label}: unknown name(s) {', '.join(bad)} (choose "
                                 f"from {', '.join(names)} or all)")
            if not value:
                raise InputError(f"{self.label}: give at least one of {', '.join(names)}")
            return
        if self.choices is not None:
            if value not in self.choices:
                shown = ", ".join("auto" if c is None else str(c) for c in self.choices)
                raise InputError(f"{self.label} must be one of {shown}, got {value!r}")
            return
        if self.suffixes and isinstance(value, str):
            if not value.lower().endswith(tuple(s.lower() for s in self.suffixes)):
                raise InputError(f"{self.label} {value}: the file name must end in "
                                 f"{' or '.join(self.suffixes)}")
        if self.kind in ("pair", "triple"):
            n = 2 if self.kind == "pair" else 3
            if not isinstance(value, list | tuple) or len(value) != n:
                raise InputError(f"{self.label} must be {n} numbers, got {value!r}")
            for v in value:
                self._check_number(v, value)
            return
        if self.kind == "value" and self.cast in (int, float):
            self._check_number(value, value)

    def _check_number(self, v: Any, shown: Any) -> None:
        unit = f" {self.unit}" if self.unit else ""
        whole = self.cast is int
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or (
                whole and math.isfinite(v) and v != int(v)):
            raise InputError(f"{self.label} must be a {'whole ' if whole else ''}number, "
                             f"got {shown!r}")
        x = float(v)
        if math.isnan(x) or (math.isinf(x) and not self.allow_inf):
            raise InputError(f"{self.label} must be finite, got {shown}")
        lo, hi = self.low, self.high
        bad = ((lo is not None and (x <= lo if self.low_open else x < lo))
               or (hi is not None and (x >= hi if self.high_open else x > hi)))
        if bad:
            raise InputError(f"{self.label} must be {self.range_text()}{unit}, got {shown}")

    # -- text form --------------------------------------------------------------------
    def parse(self, raw: Any) -> Any:
        """The typed value of what click handed over (strings for pair/triple/assign)."""
        if raw is None:
            return None
        if self.kind == "pair":
            return parse_pair(raw, self.label, self.cast)
        if self.kind == "triple":
            return parse_triple(raw, self.label)
        if self.kind == "assign":
            return parse_assign(raw, self.label, self.metavar or "NAME=SPEC")
        if self.kind == "names":
            return parse_names(raw, self.choices or ())
        return raw


def _num(x: Any) -> str:
    if isinstance(x, float):
        return "inf" if math.isinf(x) else f"{x:g}"
    return str(x)


def option(default: Any = None, help: str = "", *, default_factory: Callable[[], Any] | None
           = None, **record: Any) -> Any:
    """A dataclass field carrying an :class:`Option` (keyword arguments as its fields)."""
    opt = Option(help=help, **record)
    if opt.kind not in KINDS:
        raise ValueError(f"unknown option kind {opt.kind!r}")
    if default_factory is not None:
        return dataclasses.field(default_factory=default_factory, metadata={"option": opt})
    return dataclasses.field(default=default, metadata={"option": opt})


def table(cls: type) -> tuple[Option, ...]:
    """The :class:`Option` records of dataclass ``cls`` in field order, named and with their
    defaults (fields without a record are left out)."""
    return _table(cls)


@functools.cache
def _table(cls: type) -> tuple[Option, ...]:
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        opt = f.metadata.get("option")
        if opt is None:
            continue
        default = (f.default_factory() if f.default_factory is not dataclasses.MISSING
                   else None if f.default is dataclasses.MISSING else f.default)
        cast = opt.cast or _element_type(hints[f.name])
        out.append(dataclasses.replace(opt, name=f.name, default=default, cast=cast))
    return tuple(out)


def _element_type(hint: Any) -> type:
    """int, float or str: the scalar a field's annotation (or its tuple) holds."""
    text = str(hint)
    for t in (bool, int, float):
        if re.search(rf"\b{t.__name__}\b", text):
            return t
    return str


def lookup(cls: type, name: str) -> Option:
    for opt in table(cls):
        if opt.name == name:
            return opt
    raise KeyError(name)


def check_fields(obj: Any) -> None:
    """Check every declared field of dataclass instance ``obj`` (first failure raises)."""
    for opt in table(type(obj)):
        opt.check(getattr(obj, opt.name))


# -- JSON form (checkpoint.json, summary.json) ----------------------------------------------
def _jsonable(v: Any) -> Any:
    if isinstance(v, tuple | list):
        return [_jsonable(x) for x in v]
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, float) and math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return v


def to_json(obj: Any) -> dict[str, Any]:
    """Every field of dataclass instance ``obj`` as JSON values (tuples → lists, ±inf →
    ``"inf"``); :func:`from_json` reads it back to an equal object."""
    return {f.name: _jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}


def _tuples(v: Any) -> Any:
    if isinstance(v, list | tuple):
        return tuple(_tuples(x) for x in v)
    return v


def from_json(cls: type, doc: dict[str, Any]) -> dict[str, Any]:
    """Keyword arguments for ``cls`` from a :func:`to_json` document (or part of one):
    lists become the declared tuples, ``"inf"`` a float. Unknown names raise
    :class:`InputError`."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(doc) - names)
    if unknown:
        raise InputError(f"unknown {cls.__name__} setting(s): {', '.join(unknown)}")
    out = {}
    for name, v in doc.items():
        hint = str(hints[name])
        if isinstance(v, str) and v in ("inf", "-inf") and "float" in hint:
            v = float(v)
        elif isinstance(v, list) and "tuple" in hint:
            v = _tuples(v)
        out[name] = v
    return out


# -- the text forms -------------------------------------------------------------------------
def parse_pair(text: Any, what: str, cast: type = float) -> tuple | None:
    """``AxB`` (also ``A×B``) → two positive finite numbers of type ``cast``."""
    if text is None:
        return None
    if isinstance(text, list | tuple):
        return tuple(cast(v) for v in text)
    parts = str(text).lower().replace("×", "x").split("x")
    try:
        vals = tuple(cast(p) for p in parts)
    except ValueError:
        raise InputError(f"{what} must look like AxB, got '{text}'") from None
    if len(vals) != 2 or not all(v > 0 and math.isfinite(v) for v in vals):
        raise InputError(f"{what} must be two positive numbers AxB, got '{text}'")
    return vals


def parse_triple(text: Any, what: str) -> tuple[float, float, float] | None:
    """``X,Y,Z`` → three finite floats."""
    if text is None:
        return None
    if isinstance(text, list | tuple):
        return tuple(float(v) for v in text)  # type: ignore[return-value]
    try:
        vals = tuple(float(p) for p in str(text).split(","))
    except ValueError:
        raise InputError(f"{what} must be X,Y,Z in metres, got '{text}'") from None
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise InputError(f"{what} must be three finite numbers X,Y,Z, got '{text}'")
    return vals  # type: ignore[return-value]


def parse_names(text: Any, choices: Iterable[str]) -> tuple[str, ...]:
    """``a,b,c`` (or a sequence) → the names in the order of ``choices``, without
    repeats; ``all`` stands for every choice. Unknown names are kept for the check to
    name them."""
    items = ([str(t) for t in text] if isinstance(text, list | tuple)
             else [t for t in str(text).replace(" ", "").split(",") if t])
    order = list(choices)
    if "all" in items:
        items = [t for t in items if t != "all"] + order
    known = [c for c in order if c in items]
    return tuple(known + [t for t in dict.fromkeys(items) if t not in order])


def parse_assign(items: Iterable[str] | dict, what: str, metavar: str) -> dict[str, str]:
    """Repeated ``NAME=SPEC`` → {NAME: SPEC}."""
    if isinstance(items, dict):
        return dict(items)
    out = {}
    for item in items:
        name, sep, spec = item.partition("=")
        if not sep or not name or not spec:
            raise InputError(f"{what} must be {metavar}, got '{item}'")
        out[name] = spec
    return out


# -- click ----------------------------------------------------------------------------------
def click_option(opt: Option, **override: Any) -> Callable:
    """The click decorator of ``opt``: the command receives the parsed value, checked
    against the record (one :class:`InputError` line otherwise). ``override`` may change
    ``default`` (another command's default for the same setting; the help says it)."""
    if "default" in override:
        opt = dataclasses.replace(opt, default=override.pop("default"), default_text=None)
    if override:
        raise TypeError(f"unknown override(s): {', '.join(override)}")
    kw: dict[str, Any] = {"help": opt.help_text(), "show_default": False}
    decls = list(opt.flag)
    if opt.kind == "onoff":
        kw["default"] = opt.default
    elif opt.kind == "flag":
        kw.update(is_flag=True, default=bool(opt.default))
    elif opt.kind == "assign":
        kw.update(multiple=True, default=())
    elif opt.kind == "names":
        kw.update(default=",".join(opt.default or ()), type=str)
    else:
        kw["default"] = (opt.default_str() if opt.kind in ("pair", "triple")
                         and opt.default is not None else opt.default)
        if opt.choices is not None:
            kw["type"] = click.Choice([c for c in opt.choices if c is not None])
        elif opt.kind == "file":
            kw["type"] = click.Path(dir_okay=False)
        elif opt.kind == "dir":
            kw["type"] = click.Path(file_okay=False)
        elif opt.kind == "value" and opt.cast in (int, float):
            kw["type"] = opt.cast
    metavar = opt.metavar or {"pair": "WxH", "triple": "X,Y,Z", "names": "A,B,…"}.get(opt.kind)
    if metavar and opt.kind != "flag":
        kw["metavar"] = metavar
    if opt.envvar:
        kw.update(envvar=opt.envvar, show_envvar=True)

    def checked(_ctx: click.Context, _param: click.Parameter, raw: Any) -> Any:
        value = opt.parse(raw)  # the typed value, checked against the record
        opt.check(value)
        return value

    return click.option(*decls, opt.name, callback=checked, **kw)


def click_options(*classes: type, skip: Iterable[str] = ()) -> Callable:
    """Decorator adding the click options of every command-line field of ``classes`` (in
    order) except those named in ``skip``."""
    skipped = set(skip)
    opts = [o for cls in classes for o in table(cls) if o.on_cli and o.name not in skipped]

    def decorate(fn: Callable) -> Callable:
        for opt in reversed(opts):  # click lists the last-applied decorator first
            fn = click_option(opt)(fn)
        return fn

    return decorate
