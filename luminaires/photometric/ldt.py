"""EULUMDAT photometric files (``.ldt``): read (symmetries 0–4) and write (no symmetry).

EULUMDAT stores a Type C distribution in cd per 1000 lm of lamp flux (cd/klm) after a fixed
header of one field per line (LiTG/EULUMDAT layout as described e.g. by P. Bourke):

 1 company, 2 type indicator Ityp, 3 symmetry Isym, 4 Mc (C-planes), 5 Dc (°), 6 Ng
 (γ angles), 7 Dg (°), 8 report number, 9 luminaire name, 10 luminaire number, 11 file
 name, 12 date/user, 13–15 luminaire length/width/height (mm), 16–17 luminous area
 length/width (mm), 18–21 luminous area heights at C0/C90/C180/C270 (mm), 22 downward
 flux fraction DFF (%), 23 light output ratio LORL (%), 24 intensity conversion factor,
 25 tilt (°), 26 number of lamp sets n, then per set: 26a number of lamps, 26b lamp type,
 26c total lamp flux (lm), 26d colour temperature, 26e colour rendering, 26f wattage (W);
 27 ten direct ratios; 28 Mc C-angles; 29 Ng γ-angles; 30 intensities (cd/klm),
 plane by plane, for the planes the symmetry stores.

Axes are those of :mod:`lightsim.luminaires.photometric.candela` (C = 0°, γ = 90° straight
ahead). Absolute candela = value × conversion factor × (lamp flux of the chosen set) / 1000.

Reading
    Numbers may use a decimal comma; several numbers per line are accepted in the angle and
    intensity blocks. Every header number is checked (finite, in range, counts that fit the
    file) before it is used. The **listed C angles** are used (Dc = 0 means uneven spacing;
    a Dc that disagrees with the list gives a warning). The stored planes follow EULUMDAT's
    Mc1…Mc2 rule: Isym 0 all Mc, 1 the first, 2 C0…C180 (Mc/2+1), 3 C270…C0…C90 (indices
    3Mc/4+1…3Mc/4+1+Mc/2, wrapping), 4 C0…C90 (Mc/4+1); their angles must run from the
    symmetry's first to its last plane, and they are mirrored (Isym 2: C → −C, 3: C → 180°−C,
    4: both) to full C coverage. **Lamp sets**: the intensities are cd per 1000 lm of one
    set's flux — the first set (a warning names all when there are several) or the one
    ``lamp_set`` chooses; they are not added. A **warning** is given when the intensities
    integrate to more than 5 % away from the header's luminaire flux (lamp flux × LORL). A
    negative number of lamps (absolute photometry in some writers) is read as its magnitude.

Writing
    Isym 0 (all Mc planes, Dc = 360/Mc if equidistant else 0), Ityp 3 (point source, no
    rotational symmetry; 1 for a single-plane grid written as Isym 1), one lamp set whose
    flux is ``grid.lamp_lumens`` (or, for absolute photometry, the grid's total flux with
    LORL = 100 %). LORL = luminaire flux / lamp flux · 100, DFF from the grid; the direct
    ratios (a room-utilisation quantity) are written as zeros. Values carry ``digits``
    significant digits; text fields are cut to 78 characters (file name to 8).

Parameters
----------
=========  =====  =======  ================================================
name       unit   default  meaning
=========  =====  =======  ================================================
path       –      –        file to read or write (written atomically)
grid       –      –        CandelaGrid to write
digits     1      7        significant digits of written numbers
watts      W      0.0      lamp wattage written in the lamp set
=========  =====  =======  ================================================
"""

from __future__ import annotations

import datetime as _dt
import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes

from .candela import CandelaGrid
from .checks import MAX_COUNT, check_angles, check_count, check_number, check_values
from .ies import format_number, read_lines

__all__ = ["read_ldt", "write_ldt"]


def _num(s: str, name: str, what: str) -> float:
    try:
        return float(s.strip().replace(",", "."))
    except ValueError:
        raise InputError(f"LDT file {name}: {what} '{s.strip()}' is not a number") from None


def _stored_planes(isym: int, mc: int) -> NDArray:
    """Indices (0-based, into the Mc listed C angles) of the planes the file stores.

    EULUMDAT: Isym 0 → 1…Mc, 1 → 1, 2 → 1…Mc/2+1, 3 → 3Mc/4+1…3Mc/4+1+Mc/2 (wrapping,
    i.e. C270 → C0 → C90), 4 → 1…Mc/4+1.
    """
    if isym == 0:
        return np.arange(mc)
    if isym == 1:
        return np.array([0])
    if isym == 2:
        return np.arange(mc // 2 + 1)
    if isym == 3:
        return (3 * mc // 4 + np.arange(mc // 2 + 1)) % mc
    return np.arange(mc // 4 + 1)


_SPAN = {2: (0.0, 180.0), 3: (270.0, 90.0), 4: (0.0, 90.0)}  # first/last stored plane


def read_ldt(path: str | os.PathLike, *, lamp_set: int | None = None) -> CandelaGrid:
    """Read a EULUMDAT file into a :class:`CandelaGrid` (absolute cd).

    Parameters
    ----------
    path : path-like
        The ``.ldt`` file.
    lamp_set : int, optional
        Which lamp set (1-based) gives the flux that turns cd/klm into cd. Default: the
        first, with a warning when the file has several.

    Returns
    -------
    CandelaGrid
        ``lamp_lumens`` = the chosen set's lamp flux (lm); metadata holds the text fields,
        dimensions (mm), DFF and LORL (%), ``format="LDT"``; ``warnings`` what was noticed.

    Raises
    ------
    InputError
        Missing file, malformed or out-of-range numbers, counts that do not fit the file,
        C angles that do not match the symmetry.
    """
    name = Path(path).name
    where = f"LDT file {name}"
    lines = read_lines(path, "LDT")
    warns: list[str] = []
    pos = 0

    def line(what: str) -> str:
        nonlocal pos
        if pos >= len(lines):
            raise InputError(f"{where}: ends before {what}")
        s = lines[pos]
        pos += 1
        return s.strip()

    def number(what: str, lo: float = -math.inf, hi: float = math.inf,
               lo_open: bool = False) -> float:
        return check_number(_num(line(what), name, what), where, what, lo, hi, lo_open)

    def count(what: str, lo: int, hi: int = MAX_COUNT) -> int:
        return check_count(_num(line(what), name, what), where, what, lo, hi)

    def numbers(n: int, what: str) -> NDArray:
        out: list[float] = []
        while len(out) < n:
            s = line(what)
            if s:
                out.extend(_num(t, name, what) for t in s.split())
        if len(out) != n:
            raise InputError(f"{where}: {what}: expected {n} numbers, found {len(out)}")
        return check_values(np.array(out, dtype=float), where, what)

    meta: dict[str, str] = {"format": "LDT"}
    meta["manufacturer"] = line("the company line")
    ityp = count("the type indicator Ityp", 0, 3)
    isym = count("the symmetry indicator Isym", 0, 4)
    mc = count("the number of C-planes Mc", 1)
    dc = number("the C-plane distance Dc", 0.0, 360.0)
    ng = count("the number of γ angles Ng", 2)
    dg = number("the γ distance Dg", 0.0, 180.0)
    n_store = len(_stored_planes(isym, mc))
    if isym in (2, 3, 4) and mc % (2 if isym == 2 else 4):
        raise InputError(f"{where}: symmetry Isym {isym} needs Mc divisible by "
                         f"{2 if isym == 2 else 4}, got Mc = {mc}")
    left = sum(len(x.split()) for x in lines[pos:])
    if mc + ng + n_store * ng > left:
        raise InputError(f"{where}: Mc = {mc} C-planes and Ng = {ng} γ angles need at least "
                         f"{mc + ng + n_store * ng} numbers, the file has {left} fields left")
    for key in ("test", "luminaire", "lumcat", "file_name", "date_user"):
        meta[key] = line(key)
    dims = ["length_mm", "width_mm", "height_mm", "luminous_length_mm", "luminous_width_mm",
            "luminous_height_c0_mm", "luminous_height_c90_mm", "luminous_height_c180_mm",
            "luminous_height_c270_mm"]
    for key in dims:
        meta[key] = format_number(number(key.replace("_mm", " (mm)").replace("_", " ")))
    dff = number("the downward flux fraction DFF (%)", 0.0)
    lorl = number("the light output ratio LORL (%)", 0.0)
    conv = number("the intensity conversion factor", 0.0)
    tilt = number("the tilt angle (°)", -360.0, 360.0)
    n_sets = count("the number of lamp sets", 1, 1000)
    if lamp_set is not None and not 1 <= lamp_set <= n_sets:
        raise InputError(f"{where}: --lamp-set {lamp_set} chosen, the file has {n_sets} lamp "
                         f"set(s)")
    chosen = 1 if lamp_set is None else lamp_set
    sets = []
    for k in range(n_sets):
        n_l = _num(line("number of lamps"), name, "number of lamps")
        if not math.isfinite(n_l):
            raise InputError(f"{where}: number of lamps of set {k + 1} is {n_l!r}")
        lamp_type = line("lamp type")
        f = number(f"the lamp flux of set {k + 1} (lm)")
        cct = line("colour temperature")
        cri = line("colour rendering")
        w = number(f"the wattage of set {k + 1} (W)")
        sets.append((abs(n_l), lamp_type, f, cct, cri, w))
    n_l, lamp_type, flux, cct, cri, watts = sets[chosen - 1]
    if n_sets > 1:
        others = ", ".join(f"set {k + 1}: {s[2]:g} lm" for k, s in enumerate(sets))
        how = "" if lamp_set is not None else "; --lamp-set N chooses another"
        warns.append(f"{where}: {n_sets} lamp sets ({others}); the intensities are scaled "
                     f"by set {chosen} ({flux:g} lm){how}")
    meta.update({"number_of_lamps": format_number(n_l), "lamp": lamp_type, "cct": cct,
                 "cri": cri, "lamp_set": str(chosen), "lamp_sets": str(n_sets)})
    numbers(10, "the direct ratios")
    c_all = numbers(mc, "the C angles")
    gam = check_angles(numbers(ng, "the γ angles"), where, "the γ angles", 0.0, 180.0)
    vals = numbers(n_store * ng, "the intensities").reshape(n_store, ng)
    if np.any(vals < 0):
        warns.append(f"{where}: {int(np.sum(vals < 0))} negative intensities set to 0")
        vals = np.maximum(vals, 0.0)
    if not flux > 0:
        raise InputError(f"{where}: the lamp flux of set {chosen} must be > 0 lm, got "
                         f"{flux:g}")
    with np.errstate(over="ignore", invalid="ignore"):
        cd = vals * (conv if conv != 0 else 1.0) * flux / 1000.0
    check_values(cd, where, "the intensities × conversion factor × lamp flux")
    c_full, cd_full = _expand(c_all, cd, isym, mc, dc, where, warns)
    meta.update({"dff_percent": format_number(dff), "lorl_percent": format_number(lorl),
                 "tilt_deg": format_number(tilt), "ityp": str(ityp), "isym": str(isym),
                 "dc_deg": format_number(dc), "dg_deg": format_number(dg),
                 "input_watts": format_number(watts)})
    grid = CandelaGrid(c_full, gam, cd_full, flux, meta)
    with np.errstate(over="ignore", invalid="ignore"):
        total = grid.total_flux()
    if not np.isfinite(total):
        raise InputError(f"{where}: the intensities are too large to integrate "
                         f"(peak {grid.max_candela():.3g} cd)")
    stated = flux * lorl / 100.0
    if lorl > 0 and abs(total - stated) > 0.05 * stated:
        warns.append(f"{where}: the intensities integrate to {total:.6g} lm, the header says "
                     f"{stated:.6g} lm (lamp flux {flux:g} lm × LORL {lorl:g} %), "
                     f"{100 * (total / stated - 1):+.1f} %; the intensities are used")
    return replace(grid, warnings=tuple(warns)) if warns else grid


def _expand(c_all: NDArray, cd: NDArray, isym: int, mc: int, dc: float, where: str,
            warns: list[str]) -> tuple[NDArray, NDArray]:
    """C angles and intensities covering [0, 360) from the stored planes (listed angles)."""
    if isym == 1:
        return np.array([0.0]), cd[:1]
    if np.any(c_all < 0) or np.any(c_all > 360):
        raise InputError(f"{where}: C angles must lie in 0…360°")
    c_mod = c_all % 360.0
    if dc > 0:
        even = (np.arange(mc) * dc) % 360.0
        dev = np.abs((c_mod - even + 180.0) % 360.0 - 180.0)
        if dev.max() > 1e-3:
            warns.append(f"{where}: Dc = {dc:g}° but the listed C angles are not "
                         f"0, {dc:g}, {2 * dc:g}… (off by up to {dev.max():.3g}°); the listed "
                         "angles are used")
    planes = c_mod[_stored_planes(isym, mc)]
    if isym in _SPAN:
        first, last = _SPAN[isym]
        rel = (planes - first) % 360.0
        rel[-1] = rel[-1] if rel[-1] > 0 else 360.0
        span = (last - first) % 360.0
        if abs(planes[0] - first) > 1e-6 or abs(rel[-1] - span) > 1e-6 or np.any(
                np.diff(rel) <= 0):
            raise InputError(f"{where}: symmetry Isym {isym} stores the planes C{first:g}…"
                             f"C{last:g}, but the listed C angles give "
                             f"{planes[0]:g}…{planes[-1]:g}° (not increasing from C{first:g} "
                             f"to C{last:g})")
    elif isym == 0:
        check_angles(c_all, where, "the C angles", 0.0, 360.0)
        if c_all[-1] >= 360.0:
            raise InputError(f"{where}: Isym 0 lists C angles below 360° (got "
                             f"{c_all[-1]:g}°)")
    pairs: dict[float, NDArray] = {}
    for ang, row in zip(planes, cd):
        images = {0: (ang,), 2: (ang, -ang), 3: (ang, 180.0 - ang),
                  4: (ang, -ang, 180.0 - ang, 180.0 + ang)}[isym]
        for img in images:
            pairs.setdefault(round(float(img) % 360.0, 9), row)
    keys = sorted(pairs)
    return np.array(keys), np.array([pairs[k] for k in keys])


def _text(s: str, n: int = 78) -> str:
    return " ".join(str(s).split())[:n]


def write_ldt(path: str | os.PathLike, grid: CandelaGrid, *, digits: int = 7,
              watts: float = 0.0) -> Path:
    """Write ``grid`` as a EULUMDAT file (Isym 0, cd/klm), atomically.

    Parameters
    ----------
    path : path-like
        Destination ``.ldt`` file.
    grid : CandelaGrid
        Intensities in cd; metadata ``manufacturer``/``manufac``, ``test``, ``luminaire``,
        ``lumcat``, ``lamp``, ``cct``, ``cri`` fill the text fields.
    digits : int, default 7
        Significant digits of written numbers.
    watts : float, default 0
        Lamp wattage (W) of the lamp set.

    Returns
    -------
    Path
        The written file.
    """
    meta = {k.lower(): v for k, v in grid.metadata.items()}
    total = grid.total_flux()
    lamp_flux = grid.lamp_lumens if grid.lamp_lumens is not None else total
    if not lamp_flux > 0:
        raise InputError("write_ldt: the grid emits no flux and has no lamp lumens")
    nc, ng = grid.shape
    single = nc == 1
    c = grid.c_deg
    dc = 360.0 / nc if (single or np.allclose(np.diff(np.concatenate([c, [c[0] + 360]])),
                                              360.0 / nc)) else 0.0
    dg_all = np.diff(grid.gamma_deg)
    dg = float(dg_all[0]) if np.allclose(dg_all, dg_all[0]) else 0.0
    if not single and c[0] != 0.0:
        raise InputError("write_ldt: a multi-plane grid must start at C = 0°")

    def fmt(x: float) -> str:
        return format_number(x, digits)

    out = [
        _text(meta.get("manufacturer", meta.get("manufac", "lightsim"))),
        "1" if single else "3",
        "1" if single else "0",
        str(nc),
        fmt(dc),
        str(ng),
        fmt(dg),
        _text(meta.get("test", "lightsim far-field simulation")),
        _text(meta.get("luminaire", "lightsim luminaire")),
        _text(meta.get("lumcat", "")),
        _text(Path(path).stem, 8),
        _text(meta.get("date_user", f"{_dt.date.today().isoformat()} lightsim")),
    ]
    out += ["0"] * 9  # luminaire and luminous-area dimensions (mm): a point source
    out += [fmt(100.0 * grid.downward_flux_fraction()), fmt(100.0 * total / lamp_flux),
            "1", "0", "1"]
    out += ["1", _text(meta.get("lamp", "lightsim source"), 24), fmt(lamp_flux),
            _text(meta.get("cct", ""), 16), _text(meta.get("cri", ""), 6), fmt(watts)]
    out += ["0"] * 10  # direct ratios: not computed
    out += [fmt(x) for x in (np.array([0.0]) if single else c)]
    out += [fmt(x) for x in grid.gamma_deg]
    scale = 1000.0 / lamp_flux
    out += [fmt(x * scale) for x in grid.candela.ravel()]
    # EULUMDAT files are ISO-8859-1 text
    write_bytes(path, ("\r\n".join(out) + "\r\n").encode("latin-1", errors="replace"))
    return Path(path)
