"""Print benchmark rows as a table and save them as JSON (one object per row).

Every ``lightsim bench …`` command prints its table with :func:`print_table` and, given
``--json FILE``, writes the same rows with :func:`write_json`, so figures can be tracked
from run to run.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from collections.abc import Sequence
from typing import Any

from rich.console import Console
from rich.table import Table

from lightsim import __version__
from lightsim.io.atomic import write_text


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        if value == 0 or 1e-3 <= abs(value) < 1e6:
            return f"{value:.4g}"
        return f"{value:.3e}"
    return str(value)


def print_table(title: str, rows: Sequence[dict[str, Any]], columns: Sequence[str] | None = None,
                console: Console | None = None) -> None:
    """Print ``rows`` as a table with the given column order (default: keys of row 0)."""
    # a pipe or CI log is not a terminal: give wide tables room instead of 80 columns
    console = console or Console(width=None if sys.stdout.isatty() else 200)
    if not rows:
        console.print(f"{title}: no rows")
        return
    if columns is None:  # every key of every row, in first-seen order
        columns = list(dict.fromkeys(k for row in rows for k in row))
    columns = list(columns)
    table = Table(title=title)
    for col in columns:
        table.add_column(col, justify="right" if isinstance(rows[0].get(col), int | float)
                         else "left")
    for row in rows:
        table.add_row(*(_fmt(row.get(c, "")) for c in columns))
    console.print(table)


def write_json(path: str | os.PathLike, name: str, rows: Sequence[dict[str, Any]],
               meta: dict[str, Any] | None = None) -> None:
    """Write ``rows`` with machine/run metadata to ``path`` atomically."""
    doc = {
        "benchmark": name,
        "lightsim_version": __version__,
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                    "python": platform.python_version()},
        "meta": meta or {},
        "rows": list(rows),
    }
    write_text(path, json.dumps(doc, indent=2, default=float) + "\n")
