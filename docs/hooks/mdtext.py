"""Markdown pieces shared by the manual's build hooks: escaped text and tables.

The hooks (``commands.py``, ``rulesets.py`` beside this file) write their reference pages
as Markdown at build time; text taken from the code (help strings, rule-set sources) must
not turn into emphasis, links or table cells by accident.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence

from mkdocs.exceptions import PluginError

# characters Markdown would read as markup outside code spans (and table cell borders)
_SPECIAL = re.compile(r"([\\*_\[\]|])")
_CODE = re.compile(r"(`+)(.+?)\1")


def text(value: object) -> str:
    """``value`` as literal Markdown text on one line: markup characters escaped, code
    spans kept (the tables extension does not split cells at a ``|`` inside one)."""
    s = " ".join(str(value).split())
    out, pos = [], 0
    for m in _CODE.finditer(s):
        out.append(_escape(s[pos:m.start()]))
        out.append(m.group(0))
        pos = m.end()
    out.append(_escape(s[pos:]))
    return "".join(out)


def _escape(s: str) -> str:
    s = s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return _SPECIAL.sub(r"\\\1", s)


def code(value: object) -> str:
    """``value`` as an inline code span (backticks inside it are allowed)."""
    s = str(value)
    fence = "``" if "`" in s else "`"
    pad = " " if s.startswith("`") or s.endswith("`") else ""
    return f"{fence}{pad}{s}{pad}{fence}"


def table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A Markdown table; cells must already be Markdown (see :func:`text`)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for row in rows:
        lines.append("| " + " | ".join(c if c else "–" for c in row) + " |")
    return "\n".join(lines)


def replace_marker(markdown: str, marker: str, generated: str, page: str) -> str:
    """``markdown`` with the line ``marker`` replaced by ``generated``; a page that lost
    its marker stops the build (the reference would silently go stale)."""
    if marker not in markdown:
        raise PluginError(f"{page}: the marker {marker} is missing; the generated "
                          "reference has nowhere to go")
    return markdown.replace(marker, generated)
