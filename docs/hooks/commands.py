"""Build hook: the command reference (``reference/commands.md``) from the click tree.

At build time the marker line of the page is replaced by one section per command, found
by walking :data:`lightsim.cli.main.cli` (groups such as ``bench`` and ``luminaire``
included): its usage line, its description and a table of every option. An option made
from an :class:`lightsim.options.Option` record (the option table of ``RunConfig``,
``SimulateOptions`` …) is described by the record: flag, kind or choices, unit, range
and default as ``--help`` shows them. Any other option is described as click has it
(type, choices, range of an ``IntRange``/``FloatRange``, default).

Headings are ``lightsim <command> [<sub-command>]``; their anchors are the same words
joined by ``-`` (``#lightsim-simulate``, ``#lightsim-bench-tracer``).
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Iterator
from typing import Any

import click
import mdtext

from lightsim.cli.main import cli
from lightsim.options import Option

PAGE = "reference/commands.md"
MARKER = "<!-- generated: commands -->"
HEADER = ("option", "type", "unit", "range", "default", "meaning")

_KIND_TYPES = {"pair": "WxH", "triple": "X,Y,Z", "flag": "flag", "onoff": "on/off",
               "file": "file", "dir": "folder", "tuple": "numbers"}
_CLICK_TYPES = {"integer": "integer", "float": "number", "text": "text", "boolean": "on/off",
                "path": "path", "choice": "choice", "integer range": "integer",
                "float range": "number", "filename": "file", "directory": "folder",
                "file": "file"}
_DEFAULT_IN_HELP = re.compile(r"\s*\[default: ([^\]]*)\]\s*$")


def walk(group: click.Command = cli, ctx: click.Context | None = None
         ) -> Iterator[tuple[str, click.Command, click.Context]]:
    """Every command under ``group`` (itself first): ``(full name, command, context)``."""
    ctx = ctx or click.Context(group, info_name="lightsim")
    yield ctx.command_path, group, ctx
    if isinstance(group, click.Group):
        for name in group.list_commands(ctx):
            sub = group.get_command(ctx, name)
            if sub is not None and not sub.hidden:
                yield from walk(sub, click.Context(sub, info_name=name, parent=ctx))


def record_of(param: click.Parameter) -> Option | None:
    """The :class:`Option` record an option was made from (the one its checking callback
    holds, see :func:`lightsim.options.click_option`), or None for a plain click option."""
    for cell in getattr(param.callback, "__closure__", None) or ():
        value = cell.cell_contents
        if isinstance(value, Option):
            return value
    return None


def _unset(value: Any) -> bool:
    return value is None or type(value).__name__ == "Sentinel"  # click's UNSET


def _flags(param: click.Option) -> str:
    flags = [mdtext.code(f) for f in param.opts]
    if param.secondary_opts:
        flags.append(mdtext.code("/".join(param.secondary_opts)))
    return ", ".join(flags)


def _choices(values: Any) -> str:
    return " ".join(mdtext.code(v) for v in values)


def _record_row(param: click.Option, opt: Option) -> list[str]:
    if opt.kind == "names":
        kind = f"names: {_choices(opt.choices or ())} or {mdtext.code('all')}"
    elif opt.choices is not None:
        kind = _choices(c for c in opt.choices if c is not None)
    elif opt.kind == "assign":
        kind = f"{mdtext.code(opt.metavar or 'NAME=SPEC')}, repeatable"
    elif opt.kind in _KIND_TYPES:
        kind = _KIND_TYPES[opt.kind]
        if opt.suffixes:
            kind += " " + " ".join(mdtext.code(s) for s in opt.suffixes)
    else:
        kind = {int: "integer", float: "number"}.get(opt.cast, "text")
    meaning = mdtext.text(opt.help)
    if opt.resume:
        meaning += " May be given anew on `--resume`."
    if opt.envvar:
        meaning += f" Environment: {mdtext.code(opt.envvar)}."
    return [_flags(param), kind, mdtext.text(opt.unit), mdtext.text(opt.range_text()),
            mdtext.text(opt.default_str()), meaning]


def _click_range(kind: click.ParamType) -> str:
    lo, hi = getattr(kind, "min", None), getattr(kind, "max", None)
    if lo is None and hi is None:
        return ""
    lo_open, hi_open = getattr(kind, "min_open", False), getattr(kind, "max_open", False)
    if lo is not None and hi is not None:
        return (f"{lo} … {hi}" if not (lo_open or hi_open) else
                f"in {'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}")
    if lo is not None:
        return f"{'>' if lo_open else '≥'} {lo}"
    return f"{'<' if hi_open else '≤'} {hi}"


def _click_row(param: click.Option, ctx: click.Context) -> list[str]:
    help_text = param.help or ""
    default_text = None
    m = _DEFAULT_IN_HELP.search(help_text)
    if m:  # a default the help names in words ("the preset's")
        help_text, default_text = help_text[:m.start()], m.group(1)
    if isinstance(param.type, click.Choice):
        kind = _choices(param.type.choices)
    elif param.is_flag and not param.secondary_opts:
        kind = "flag"
    else:
        kind = _CLICK_TYPES.get(param.type.name, param.type.name)
        if param.metavar:
            kind = mdtext.code(param.metavar)
    if param.multiple:
        kind += ", repeatable"
    default = param.get_default(ctx, call=False)
    if default_text is None:
        if param.is_flag:
            default_text = "on" if default else "off"
        elif callable(default):
            default_text = "computed"
        elif _unset(default) or (param.multiple and not default):
            default_text = ""
        else:
            default_text = str(default)
    meaning = mdtext.text(help_text)
    if param.envvar:
        envvars = [param.envvar] if isinstance(param.envvar, str) else param.envvar
        meaning += f" Environment: {', '.join(mdtext.code(e) for e in envvars)}."
    return [_flags(param), kind, "", mdtext.text(_click_range(param.type)),
            mdtext.text(default_text), meaning]


def _description(command: click.Command) -> list[str]:
    """The command's help as paragraphs (click's ``\\b`` blocks keep their lines)."""
    doc = inspect.cleandoc(command.help or "").split("\f")[0]
    out = []
    for block in re.split(r"\n\s*\n", doc):
        lines = block.splitlines()
        if lines and lines[0].strip() == "\b":
            out.append("<br>\n".join(mdtext.text(x) for x in lines[1:]))
        elif block.strip():
            out.append(mdtext.text(block))
    return out


def _arguments(command: click.Command, ctx: click.Context) -> str:
    rows = []
    for p in command.params:
        if isinstance(p, click.Argument):
            what = "required" if p.required else "optional"
            if p.nargs != 1:
                what += ", several" if p.nargs == -1 else f", {p.nargs} values"
            rows.append([mdtext.code(p.make_metavar(ctx)), what,
                         mdtext.text(_CLICK_TYPES.get(p.type.name, p.type.name))])
    return mdtext.table(("argument", "", "type"), rows) if rows else ""


def section(name: str, command: click.Command, ctx: click.Context) -> str:
    """One command's section: heading, usage, description, arguments, options."""
    level = 2 if name.count(" ") < 2 else 3  # sub-commands under their group
    usage = " ".join([name, *command.collect_usage_pieces(ctx)])
    parts = [f"{'#' * level} {name}", f"```\n{usage}\n```", *_description(command)]
    args = _arguments(command, ctx)
    if args:
        parts.append(args)
    rows = []
    for p in command.params:
        if not isinstance(p, click.Option) or p.hidden:
            continue
        opt = record_of(p)
        rows.append(_record_row(p, opt) if opt is not None else _click_row(p, ctx))
    if isinstance(command, click.Group):
        subs = [n for n in command.list_commands(ctx) if command.get_command(ctx, n)]
        anchor = name.replace(" ", "-")
        parts.append("Commands: " + ", ".join(f"[{n}](#{anchor}-{n})" for n in subs) + ".")
    if rows:
        parts.append(mdtext.table(HEADER, rows))
    return "\n\n".join(parts)


def generate() -> str:
    """The whole generated part of the page."""
    return "\n\n".join(section(name, command, ctx) for name, command, ctx in walk())


def on_page_markdown(markdown: str, page: Any, **_: Any) -> str:
    """mkdocs hook: fill the commands page's marker."""
    if page.file.src_uri != PAGE:
        return markdown
    return mdtext.replace_marker(markdown, MARKER, generate(), PAGE)
