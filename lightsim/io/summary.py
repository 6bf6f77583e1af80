"""JSON summaries (``summary.json``, run reports): strict JSON, written atomically.

:func:`write_json` accepts the objects the engine produces — numpy scalars and arrays,
tuples, paths, dataclasses — and always writes *valid* JSON (RFC 8259), which has no NaN
or infinity: **every NaN, +inf and −inf float becomes ``null``** (in arrays too). A reader
therefore sees ``null`` wherever a value was undefined or unbounded; write a separate
field (e.g. ``"converged": false``) where the reason matters. :func:`read_json` reports a
missing or corrupt file as a one-line :class:`~lightsim.errors.InputError`.

Parameters (user documentation)
-------------------------------
==========  ====  =======  ==========================================================
name        unit  default  meaning
==========  ====  =======  ==========================================================
``path``    –     required file to write or read (UTF-8)
``obj``     –     required value to write (conversion rules: :func:`to_jsonable`)
``indent``  –     2        indentation of the written JSON (None: one line)
==========  ====  =======  ==========================================================
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import enum
import json
import math
import os
from collections.abc import Mapping
from pathlib import PurePath
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.atomic import write_text

__all__ = ["dumps", "read_json", "to_jsonable", "write_json"]


def _float(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _key(k: Any) -> str:
    if isinstance(k, str):
        return k
    if isinstance(k, bool | np.bool_):
        return "true" if k else "false"
    if isinstance(k, int | np.integer):
        return str(int(k))
    if isinstance(k, float | np.floating):
        return repr(float(k))
    if isinstance(k, PurePath | enum.Enum):
        return str(k.value if isinstance(k, enum.Enum) else k)
    raise TypeError(f"JSON object keys must be strings or numbers, got {type(k).__name__}")


def to_jsonable(obj: Any) -> Any:
    """Convert ``obj`` to plain JSON types (dict, list, str, int, float, bool, None).

    Rules: numpy scalars → Python scalars; arrays → nested lists; NaN/±inf → None;
    tuples, sets (sorted when possible) → lists; mapping keys → str (numbers as in
    Python's ``json``); ``pathlib`` paths → str; enums → their value; dataclasses →
    dicts; dates/times → ISO 8601 strings. Anything else raises ``TypeError``.

    Parameters
    ----------
    obj : any
        Value to convert.

    Returns
    -------
    any
        A value ``json.dumps(..., allow_nan=False)`` accepts.
    """
    if obj is None or isinstance(obj, str | bool):
        return obj
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return _float(float(obj))
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in "biufUOM":
            raise TypeError(f"cannot write a {obj.dtype} array as JSON")
        return to_jsonable(obj.tolist())
    if isinstance(obj, Mapping):
        return {_key(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(x) for x in obj]
    if isinstance(obj, set | frozenset):
        items = [to_jsonable(x) for x in obj]
        try:
            return sorted(items)
        except TypeError:
            return sorted(items, key=repr)
    if isinstance(obj, PurePath):
        return str(obj)
    if isinstance(obj, enum.Enum):
        return to_jsonable(obj.value)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return to_jsonable(dataclasses.asdict(obj))
    if isinstance(obj, _dt.datetime | _dt.date | _dt.time):
        return obj.isoformat()
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    raise TypeError(f"cannot write {type(obj).__name__} as JSON")


def dumps(obj: Any, indent: int | None = 2) -> str:
    """Strict JSON text of ``obj`` after :func:`to_jsonable` (UTF-8 characters kept)."""
    return json.dumps(to_jsonable(obj), indent=indent, ensure_ascii=False, allow_nan=False)


def write_json(path: str | os.PathLike, obj: Any, *, indent: int | None = 2) -> None:
    """Write ``obj`` as strict JSON (NaN/±inf → null) to ``path`` atomically.

    Parameters
    ----------
    path : path-like
        Destination; an existing file is replaced only once the new one is complete.
    obj : any
        Value to write (see :func:`to_jsonable`).
    indent : int or None, default 2
        Indentation; None writes one line.

    Raises
    ------
    TypeError
        ``obj`` holds a value with no JSON form (nothing is written).
    """
    write_text(path, dumps(obj, indent=indent) + "\n")


def read_json(path: str | os.PathLike) -> Any:
    """Read a JSON file.

    Parameters
    ----------
    path : path-like
        UTF-8 JSON file. (Python's parser also accepts the non-standard ``NaN`` and
        ``Infinity`` tokens other tools may write.)

    Returns
    -------
    any
        The parsed value.

    Raises
    ------
    InputError
        The file is missing, unreadable, not UTF-8 or not valid JSON (one line with the
        position of the error).
    """
    p = os.fspath(path)
    try:
        with open(p, encoding="utf-8") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise InputError(f"JSON file not found: {p}") from None
    except IsADirectoryError:
        raise InputError(f"expected a JSON file, got a directory: {p}") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"JSON file {p} is not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise InputError(f"cannot read JSON file {p}: {exc.strerror or exc}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"corrupt JSON in {p}: {exc.msg} at line {exc.lineno} "
                         f"column {exc.colno}") from None
