"""Header numbers of photometric files, checked before they are used.

Every number a reader takes from a file header passes through these checks, so a mutated
or corrupt header (``inf``, ``nan``, ``1e400``, ``-3`` lamps, a count larger than the file)
becomes one :class:`~lightsim.errors.InputError` line naming the file and the field, never an
``OverflowError``/``ValueError`` traceback or a huge allocation.

Parameters
----------
==========  =====  =========  =========================================================
name        unit   default    meaning
==========  =====  =========  =========================================================
where       –      –          "IES file x.ies" / "LDT file x.ldt", starts every message
what        –      –          the field's name as the format calls it
lo, hi      1      –          inclusive range of a count or number
MAX_COUNT   1      100 000    largest angle count accepted (a 0.01° web has 36 000)
==========  =====  =========  =========================================================
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from lightsim.errors import InputError

__all__ = ["MAX_COUNT", "check_angles", "check_count", "check_number", "check_values",
           "freeze_grid"]

MAX_COUNT = 100_000


def check_number(x: float, where: str, what: str, lo: float = -math.inf,
                 hi: float = math.inf, lo_open: bool = False) -> float:
    """``x`` if it is finite and within [lo, hi] (or (lo, hi] with ``lo_open``)."""
    if not math.isfinite(x):
        raise InputError(f"{where}: {what} is {x!r}, not a finite number")
    if x < lo or x > hi or (lo_open and x == lo):
        low = f"> {lo:g}" if lo_open else f"≥ {lo:g}"
        rng = low if hi == math.inf else f"{low} and ≤ {hi:g}"
        raise InputError(f"{where}: {what} is {x:g}; it must be {rng}")
    return float(x)


def check_count(x: float, where: str, what: str, lo: int = 0, hi: int = MAX_COUNT) -> int:
    """``x`` as an int if it is a finite whole number within [lo, hi]."""
    if not math.isfinite(x):
        raise InputError(f"{where}: {what} is {x!r}, not a whole number")
    if x != math.floor(x):
        raise InputError(f"{where}: {what} is {x:g}, not a whole number")
    if x < lo or x > hi:
        raise InputError(f"{where}: {what} is {x:g}; it must lie in {lo}…{hi}")
    return int(x)


def check_values(a: NDArray, where: str, what: str, lo: float = -math.inf) -> NDArray:
    """``a`` (float array) if every entry is finite and ≥ lo."""
    a = np.asarray(a, dtype=float)
    bad = ~np.isfinite(a)
    if np.any(bad):
        raise InputError(f"{where}: {what} contain {a[bad][0]!r} (not finite)")
    if np.any(a < lo):
        raise InputError(f"{where}: {what} contain {a[a < lo][0]:g} (must be ≥ {lo:g})")
    return a


def check_angles(a: NDArray, where: str, what: str, lo: float, hi: float) -> NDArray:
    """``a`` if finite, strictly increasing and within [lo, hi] degrees."""
    a = check_values(a, where, what)
    if a.size and (a[0] < lo or a[-1] > hi):
        raise InputError(f"{where}: {what} run {a[0]:g}…{a[-1]:g}°; they must lie in "
                         f"{lo:g}…{hi:g}°")
    if np.any(np.diff(a) <= 0):
        k = int(np.argmax(np.diff(a) <= 0))
        raise InputError(f"{where}: {what} must increase strictly ({a[k]:g}° is followed by "
                         f"{a[k + 1]:g}°)")
    return a


def freeze_grid(grid: object, what: str, axes: dict[str, NDArray], cd: NDArray,
                layout: str) -> None:
    """Check a goniometer grid's intensities and rated flux, then store its arrays read-only.

    Shared by the Type C :class:`CandelaGrid` and the Type A/B ``HVGrid`` (frozen
    dataclasses): ``axes`` maps the two angle fields' names to their arrays (deg), ``cd``
    is the (n0, n1) intensity table (cd), ``what`` starts every message and ``layout``
    names the table's axes in it.
    """
    (n0, a0), (n1, a1) = axes.items()
    if cd.shape != (a0.size, a1.size):
        raise InputError(f"{what}: intensities have shape {cd.shape}, expected "
                         f"({a0.size}, {a1.size}) ({layout})")
    if not np.all(np.isfinite(cd)) or np.any(cd < 0):
        raise InputError(f"{what}: intensities must be finite and ≥ 0 cd")
    lamp_lumens = grid.lamp_lumens  # type: ignore[attr-defined]
    if lamp_lumens is not None and not (np.isfinite(lamp_lumens) and lamp_lumens > 0):
        raise InputError(f"{what}: lamp_lumens must be > 0 or None, got {lamp_lumens!r}")
    for name, arr in ((n0, a0), (n1, a1), ("candela", cd)):
        arr.setflags(write=False)
        object.__setattr__(grid, name, arr)
    object.__setattr__(grid, "metadata", {str(k): str(v) for k, v in
                                          dict(grid.metadata).items()})  # type: ignore[attr-defined]
    object.__setattr__(grid, "warnings", tuple(str(w) for w in grid.warnings))  # type: ignore[attr-defined]
