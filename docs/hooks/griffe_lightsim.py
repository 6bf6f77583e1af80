"""griffe extensions for the API reference (``reference/api.md``).

:class:`SphinxRoles` turns the code's Sphinx cross-reference roles (``:func:`~a.b.f```)
into inline code (`` `f` ``): the manual renders docstrings as Markdown, where the roles
would show as literal text.

:class:`OptionRecords` shows the option records of settings dataclasses. A settings
dataclass declares each field with :func:`lightsim.options.option` (its help, unit, range,
flag and default in one :class:`~lightsim.options.Option` record). Read statically, its
signature would show those ``option(…)`` calls as defaults and its fields would carry no
text. For every class with such fields :class:`OptionRecords`

- sets each ``__init__`` parameter's default to the field's real default, and
- appends a numpydoc ``Parameters`` section built from the records (type, help, flag,
  unit, range, default as ``--help`` words them), which the manual renders as a table.

The records are read from the imported class (:func:`lightsim.options.table`), so the
reference shows exactly what the command line uses.
"""

from __future__ import annotations

import dataclasses
import importlib
import re
from typing import Any

import griffe

from lightsim import options

OPTION_FACTORY = "lightsim.options.option"
ROLE = re.compile(r":(?:py:)?[a-z]+:`(~?)\.?([^`<]*?)\s*(?:<([^>`]+)>)?`")


def _role_text(m: re.Match) -> str:
    """The text a Sphinx role displays: ``~a.b.c`` → ``c``, ``text <target>`` → text."""
    tilde, text, target = m.groups()
    if target and text:
        return f"`{text}`"
    name = target or text
    return f"`{name.rsplit('.', 1)[-1] if tilde else name}`"


class SphinxRoles(griffe.Extension):
    """Sphinx roles in every docstring of a loaded package become inline code."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        """Rewrite the docstrings of ``pkg`` and everything in it."""
        for obj in _objects(pkg):
            if obj.docstring is not None and ":`" in obj.docstring.value:
                obj.docstring.value = ROLE.sub(_role_text, obj.docstring.value)


def _objects(obj: griffe.Object) -> list[griffe.Object]:
    found = [obj]
    for member in obj.members.values():
        if not member.is_alias:
            found.extend(_objects(member))
    return found


def _declares_options(cls: griffe.Class) -> bool:
    for member in cls.members.values():
        value = getattr(member, "value", None) if not member.is_alias else None
        if isinstance(value, griffe.ExprCall) and value.canonical_path == OPTION_FACTORY:
            return True
    return False


def _runtime_class(cls: griffe.Class) -> type | None:
    # the class as imported: griffe gives its module and name as text
    module = importlib.import_module(cls.module.path)
    obj = getattr(module, cls.name, None)
    return obj if dataclasses.is_dataclass(obj) else None


def _describe(opt: options.Option) -> str:
    text = opt.help_text()
    if opt.flag:
        text += " Command line: " + ", ".join(f"`{f}`" for f in opt.flag) + "."
    elif opt.internal:
        text += f" No flag: {opt.internal}."
    return text


def _parameters_section(cls: griffe.Class, records: tuple[options.Option, ...]) -> str:
    lines = ["Parameters", "----------"]
    for opt in records:
        member = cls.members.get(opt.name)
        annotation = getattr(member, "annotation", None)
        lines.append(f"{opt.name} : {annotation}" if annotation else opt.name)
        lines.append(f"    {_describe(opt)}")
    return "\n".join(lines)


def _python_default(field: dataclasses.Field) -> str | None:
    if field.default_factory is not dataclasses.MISSING:
        return repr(field.default_factory())
    if field.default is dataclasses.MISSING:
        return None  # a required argument
    return repr(field.default)


class OptionRecords(griffe.Extension):
    """Defaults and a parameter table from the option records (see the module docstring)."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        """Rewrite every settings dataclass of the loaded package ``pkg``."""
        for cls in _classes(pkg):
            if _declares_options(cls):
                _rewrite(cls)


def _classes(obj: griffe.Module) -> list[griffe.Class]:
    return [o for o in _objects(obj) if o.is_class]


def _rewrite(cls: griffe.Class) -> None:
    runtime = _runtime_class(cls)
    if runtime is None:
        return
    records = options.table(runtime)
    fields = {f.name: f for f in dataclasses.fields(runtime)}
    init = cls.members.get("__init__")
    if init is not None and init.is_function:
        for param in init.parameters:
            if param.name in fields:
                param.default = _python_default(fields[param.name])
    old = cls.docstring
    if old and "\nParameters\n---" in old.value:
        return  # the class documents its parameters itself
    text = (old.value.rstrip() + "\n\n" if old else "") + _parameters_section(cls, records)
    cls.docstring = griffe.Docstring(text, lineno=old.lineno if old else cls.lineno,
                                     endlineno=old.endlineno if old else cls.lineno,
                                     parent=cls, parser=old.parser if old else None,
                                     parser_options=old.parser_options if old else None)
