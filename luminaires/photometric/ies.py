"""IES LM-63 photometric files (``.ies``): read (1986, 1991, 1995, 2002, 2019) and write 2002.

Photometric types 1 (**Type C**, → :class:`CandelaGrid`), 2 (**Type B**) and 3 (**Type A**,
vehicle lamps; both → :class:`HVGrid`). Axes: :mod:`~lightsim.luminaires.photometric.candela`
(Type C: C = 0°, γ = 90° straight ahead, γ = 0° the nadir −Y) and
:mod:`~lightsim.luminaires.photometric.hvgrid` (Type A: H = V = 0° straight ahead, H > 0
right, V > 0 up; Type B: H = V = 0° down, H = 0°, V = 90° ahead), from LM-63-2002's
definitions (see ``docs/reference/conventions.md``).

Reading
    * text decoded as UTF-8, else Latin-1; keyword lines ``[KEY] value`` (``[MORE]``
      continues the previous key) are kept in ``metadata`` (keys lower-cased);
    * ``TILT=NONE`` / ``TILT=INCLUDE`` (its angle/factor table is skipped and recorded) /
      ``TILT=<file>`` (recorded, not loaded): tilt factors only matter for a tilted
      lamp, which lightsim does not model;
    * numbers may be separated by blanks, commas or line breaks;
    * candela = value × candela multiplier × ballast factor (and × the ballast-lamp
      photometric factor of LM-63-1986/1991/1995 files);
    * every header number is checked (finite, in range, whole counts, counts that fit the
      file) before use: one :class:`~lightsim.errors.InputError` line otherwise; repairs
      (negative candela set to 0, numbers after the table, 0 lumens) become ``warnings``;
    * Type C lateral symmetry is expanded to full C coverage: last horizontal angle 0°
      (axial: one plane), 90° (quadrants), 180° (bilateral about C0–C180), first 90°/last
      270° (bilateral about C90–C270), 360° (full; the duplicate 360° plane is dropped);
    * Type A/B: first horizontal angle 0° = laterally symmetric (mirrored to −H), −90° =
      full; other ranges within ±90° are read as listed (zero outside, with a warning);
    * a warning when the intensities integrate to more than 1.05 × the rated lamp lumens;
    * ``lumens per lamp`` −1 means absolute photometry (``lamp_lumens=None``), otherwise
      ``lamp_lumens = number of lamps × lumens per lamp``.

Writing (LM-63-2002)
    Header ``IESNA:LM-63-2002``, keywords from the grid's metadata (``[TEST]``,
    ``[TESTLAB]``, ``[ISSUEDATE]``, ``[MANUFAC]`` always present), ``TILT=NONE``, one lamp,
    candela multiplier 1, units metres, ballast factor 1; Type C with all C-planes 0…360°
    (the 360° plane repeats 0°; a single-plane grid is written as axially symmetric), an
    :class:`HVGrid` as Type A or B with its own H and V angles. Numbers carry
    ``digits`` significant digits (default 7) without exponents; lines stay below 132
    characters (LM-63-2002 allows 256).

Parameters
----------
=============  =====  ===========  ============================================
name           unit   default      meaning
=============  =====  ===========  ============================================
path           –      –            file to read or write (written atomically)
grid           –      –            CandelaGrid or HVGrid to write
digits         1      7            significant digits of written numbers
input_watts    W      0.0          written on the ballast line
dimensions_m   m      (0, 0, 0)    luminous opening width, length, height
=============  =====  ===========  ============================================
"""

from __future__ import annotations

import datetime as _dt
import os
import re
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes

from .candela import CandelaGrid
from .checks import MAX_COUNT, check_angles, check_count, check_number, check_values
from .hvgrid import HVGrid

__all__ = ["IES_TYPES", "expand_type_ab_symmetry", "expand_type_c_symmetry", "format_number",
           "read_ies", "read_lines", "resolve_ies_type", "write_ies"]

_KEY_RE = re.compile(r"^\s*\[([^\]]+)\]\s*(.*?)\s*$")
_SPLIT_RE = re.compile(r"[,\s]+")


def format_number(x: float, digits: int = 7) -> str:
    """``x`` with ``digits`` significant digits, positional notation, no trailing zeros."""
    if x == 0 or not np.isfinite(x):
        return "0"
    s = np.format_float_positional(float(x), precision=digits, unique=False,
                                   fractional=False, trim="-")
    return "0" if s in ("-0", "") else s


def _decode(raw: bytes) -> str:
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def read_lines(path: str | os.PathLike, kind: str) -> list[str]:
    """Lines of a photometric text file (UTF-8, else Latin-1; any line ends).

    ``kind`` names the format in the error (``"IES"``, ``"LDT"``).
    """
    try:
        text = _decode(Path(path).read_bytes())
    except OSError as exc:
        raise InputError(f"{kind} file {path}: cannot read ({exc.strerror})") from None
    return text.replace("\r\n", "\n").replace("\r", "\n").split("\n")


def expand_type_c_symmetry(c_deg: NDArray, candela: NDArray, where: str = "file"
                           ) -> tuple[NDArray, NDArray]:
    """Expand Type C lateral symmetry to C-planes covering [0, 360).

    Parameters
    ----------
    c_deg : ndarray, shape (nH,)
        Horizontal angles as listed in an IES file (degrees, increasing).
    candela : ndarray, shape (nH, nV)
        Intensities per listed plane.
    where : str
        Name used in error messages.

    Returns
    -------
    c_full, candela_full
        C angles in [0, 360) (increasing) and their intensities; one plane if the file is
        axially symmetric.
    """
    c = np.asarray(c_deg, dtype=float)
    first, last = c[0], c[-1]

    def mirrored(func: object) -> tuple[NDArray, NDArray]:
        pairs: dict[float, NDArray] = {}
        for ang, row in zip(c, candela):
            for img in func(ang):  # type: ignore[operator]
                pairs.setdefault(round(float(img) % 360.0, 9), row)
        keys = sorted(pairs)
        return np.array(keys), np.array([pairs[k] for k in keys])

    if len(c) == 1:
        return np.array([0.0]), candela[:1].copy()
    if first == 0 and last == 90:
        return mirrored(lambda a: (a, 180 - a, 180 + a, 360 - a))
    if first == 0 and last == 180:
        return mirrored(lambda a: (a, 360 - a))
    if first == 90 and last == 270:
        return mirrored(lambda a: (a, 180 - a))
    if first >= 0 and last <= 360 and last > 180:
        if last == 360 and first == 0:
            c, candela = c[:-1], candela[:-1]
        keys = np.round(c % 360.0, 9)
        order = np.argsort(keys, kind="stable")
        keys, rows = keys[order], candela[order]
        uniq, idx = np.unique(keys, return_index=True)
        return uniq, rows[idx]
    raise InputError(f"{where}: horizontal angles {first:g}…{last:g}° are not a Type C "
                     "symmetry LM-63 defines (0, 0–90, 0–180, 90–270, 0–360)")


def read_ies(path: str | os.PathLike) -> CandelaGrid | HVGrid:
    """Read an IES LM-63 file (Type A, B or C) into a grid.

    Parameters
    ----------
    path : path-like
        The ``.ies`` file.

    Returns
    -------
    CandelaGrid or HVGrid
        Type C → :class:`CandelaGrid`; Types A and B → :class:`HVGrid`. Absolute
        intensities in cd; ``metadata`` holds the keywords (lower-case keys), ``format``,
        ``version``, ``photometric_type``, ``tilt``, ``units``, dimensions in m,
        ``input_watts``; ``warnings`` what was repaired.

    Raises
    ------
    InputError
        Missing file, malformed or out-of-range header numbers, counts that do not fit the
        file, angles that are not a layout LM-63 defines.
    """
    name = Path(path).name
    where = f"IES file {name}"
    lines = read_lines(path, "IES")
    meta: dict[str, str] = {"format": "IES"}
    warns: list[str] = []
    i = 0
    first = lines[0].strip() if lines else ""
    version = "LM-63-1986"
    if first.upper().startswith(("IESNA", "IES:")):
        version = first.split(":", 1)[-1].strip() if ":" in first else first
        if first.upper().startswith("IESNA91"):
            version = "LM-63-1991"
        i = 1
    meta["version"] = version
    last_key: str | None = None
    while i < len(lines) and not lines[i].strip().upper().startswith("TILT"):
        m = _KEY_RE.match(lines[i])
        if m:
            key, val = m.group(1).strip().lower(), m.group(2)
            if key == "more" and last_key:
                meta[last_key] = (meta[last_key] + " " + val).strip()
            else:
                k = key
                n = 2
                while k in meta:
                    k = f"{key}_{n}"
                    n += 1
                meta[k] = val
                last_key = k
        elif lines[i].strip():
            meta["header"] = (meta.get("header", "") + " " + lines[i].strip()).strip()
        i += 1
    if i >= len(lines):
        raise InputError(f"{where}: no TILT= line")
    tilt = lines[i].split("=", 1)[1].strip() if "=" in lines[i] else ""
    meta["tilt"] = tilt or "NONE"
    tokens = [t for t in _SPLIT_RE.split(" ".join(lines[i + 1:])) if t]
    pos = 0

    def take(n: int, what: str) -> NDArray:
        nonlocal pos
        if pos + n > len(tokens):
            raise InputError(f"{where}: expected {n} number(s) for {what}, found "
                             f"{len(tokens) - pos}")
        try:
            vals = np.array([float(t) for t in tokens[pos:pos + n]], dtype=float)
        except ValueError:
            bad = next(t for t in tokens[pos:pos + n] if not _is_float(t))
            raise InputError(f"{where}: '{bad}' in {what} is not a number") from None
        pos += n
        return vals

    if tilt.upper() == "INCLUDE":
        geom, n_pairs = take(2, "the TILT header")
        geom_i = check_count(geom, where, "the TILT lamp-to-luminaire geometry", 1, 3)
        n_pairs_i = check_count(n_pairs, where, "the number of TILT angles", 0,
                                (len(tokens) - pos) // 2)
        check_values(take(2 * n_pairs_i, "the TILT table"), where, "the TILT table")
        meta["tilt"] = f"INCLUDE (geometry {geom_i}, {n_pairs_i} angles; ignored)"
    elif tilt.upper() not in ("", "NONE"):
        meta["tilt"] = f"{tilt} (external tilt file; ignored)"
    (n_lamps, lumens, mult, n_v, n_h, ptype, units, width, length, height) = take(
        10, "the lamp line")
    ballast, factor2, watts = take(3, "the ballast line")
    n_lamps_i = check_count(n_lamps, where, "the number of lamps", 1, 1_000_000)
    lumens = check_number(lumens, where, "lumens per lamp")
    if lumens < 0 and lumens != -1:
        raise InputError(f"{where}: lumens per lamp is {lumens:g}; it must be > 0, or -1 for "
                         "absolute photometry")
    mult = check_number(mult, where, "the candela multiplier", 0.0, lo_open=True)
    kind = {1: "C", 2: "B", 3: "A"}.get(int(ptype) if np.isfinite(ptype) and ptype == int(
        ptype) else 0)
    if kind is None:
        raise InputError(f"{where}: photometric type is {ptype:g}; it must be 1 (C), 2 (B) "
                         "or 3 (A)")
    remaining = len(tokens) - pos
    n_v_i = check_count(n_v, where, "the number of vertical angles", 2, MAX_COUNT)
    n_h_i = check_count(n_h, where, "the number of horizontal angles", 1, MAX_COUNT)
    if n_v_i + n_h_i + n_v_i * n_h_i > remaining:
        raise InputError(f"{where}: {n_v_i} vertical × {n_h_i} horizontal angles need "
                         f"{n_v_i + n_h_i + n_v_i * n_h_i} numbers after the header, the file "
                         f"has {remaining}")
    units_i = check_count(units, where, "the units type", 1, 2)
    for what, x in (("the luminous width", width), ("the luminous length", length),
                    ("the luminous height", height), ("the input watts", watts)):
        check_number(x, where, what)
    ballast = check_number(ballast, where, "the ballast factor", 0.0, lo_open=True)
    factor2 = check_number(factor2, where, "the ballast-lamp photometric factor", 0.0)
    gam = take(n_v_i, "the vertical angles")
    hor = take(n_h_i, "the horizontal angles")
    values = take(n_v_i * n_h_i, "the candela values").reshape(n_h_i, n_v_i)
    if pos < len(tokens):
        warns.append(f"{where}: {len(tokens) - pos} number(s) after the candela table "
                     "ignored")
    check_values(values, where, "the candela values")
    scale = mult * ballast
    if version in ("LM-63-1986", "LM-63-1991", "LM-63-1995") and factor2 > 0:
        scale *= factor2  # ballast-lamp photometric factor before LM-63-2002
    with np.errstate(over="ignore", invalid="ignore"):
        cd = values * scale
    check_values(cd, where, "the candela values × multiplier × ballast factor")
    if np.any(cd < 0):
        warns.append(f"{where}: {int(np.sum(cd < 0))} negative candela value(s) (down to "
                     f"{cd.min():g} cd) set to 0")
        cd = np.maximum(cd, 0.0)
    to_m = 0.3048 if units_i == 1 else 1.0
    meta.update({"photometric_type": kind,
                 "units": "feet" if units_i == 1 else "metres",
                 "width_m": format_number(width * to_m), "length_m": format_number(
                     length * to_m), "height_m": format_number(height * to_m),
                 "input_watts": format_number(watts), "number_of_lamps": str(n_lamps_i),
                 "candela_multiplier": format_number(mult),
                 "ballast_factor": format_number(ballast)})
    lamp_lumens = None if lumens <= 0 else float(lumens) * n_lamps_i
    if lumens == 0:
        warns.append(f"{where}: lumens per lamp is 0; read as absolute photometry")
    if kind == "C":
        check_angles(gam, where, "the vertical angles (Type C)", 0.0, 180.0)
        check_angles(hor, where, "the horizontal angles", 0.0, 360.0)
        c_full, cd_full = expand_type_c_symmetry(hor, cd, where=where)
        grid: CandelaGrid | HVGrid = CandelaGrid(c_full, gam, cd_full, lamp_lumens, meta)
    else:
        check_angles(gam, where, f"the vertical angles (Type {kind})", -90.0, 90.0)
        check_angles(hor, where, f"the horizontal angles (Type {kind})", -90.0, 90.0)
        h_full, cd_full = expand_type_ab_symmetry(hor, cd, where, warns)
        grid = HVGrid(h_full, gam, cd_full, kind, lamp_lumens, meta)
    with np.errstate(over="ignore", invalid="ignore"):
        flux = grid.total_flux()
    if not np.isfinite(flux):
        raise InputError(f"{where}: the intensities are too large to integrate "
                         f"(peak {grid.max_candela():.3g} cd)")
    if lamp_lumens is not None and flux > 1.05 * lamp_lumens:
        warns.append(f"{where}: the intensities integrate to {flux:.6g} lm, more than the "
                     f"rated lamp flux {lamp_lumens:.6g} lm (an efficiency above 100 %); the "
                     "intensities are used as they are")
    return replace(grid, warnings=tuple(warns)) if warns else grid


def expand_type_ab_symmetry(h_deg: NDArray, candela: NDArray, where: str,
                            warns: list[str]) -> tuple[NDArray, NDArray]:
    """Type A/B horizontal angles as a full table (LM-63-2002 lateral symmetry).

    First angle 0° (LM-63: last 90°): laterally symmetric about the vertical reference
    plane, mirrored to −H. First angle −90° or any other layout within ±90°: read as listed
    (zero intensity outside). A single horizontal angle is not a Type A/B layout.
    """
    h = np.asarray(h_deg, dtype=float)
    if len(h) < 2:
        raise InputError(f"{where}: Type A/B photometry needs at least two horizontal angles "
                         "(LM-63 defines 0…90° or −90…90°)")
    if h[0] == 0.0:
        if h[-1] != 90.0:
            warns.append(f"{where}: horizontal angles 0…{h[-1]:g}°: read as laterally "
                         "symmetric (LM-63's rule for a first angle of 0°)")
        return (np.concatenate([-h[:0:-1], h]),
                np.concatenate([candela[:0:-1], candela], axis=0))
    if h[0] != -90.0 or h[-1] != 90.0:
        warns.append(f"{where}: horizontal angles {h[0]:g}…{h[-1]:g}° cover part of the "
                     "hemisphere; intensity outside is 0")
    return h, candela


IES_TYPES = ("auto", "A", "C")


def resolve_ies_type(requested: str, source_type: str | None) -> str:
    """The photometric type ("A" or "C") of a written far-field IES file.

    ``requested`` is ``--ies-type``: "A", "C" or "auto". Auto writes **Type A** for vehicle
    lamps — a lamp model (``source_type`` None: a GLB/mesh scene) or a Type A file — and Type C
    for a general luminaire (a Type B/C IES or an LDT file as the scene).
    """
    if requested not in IES_TYPES:
        raise InputError(f"--ies-type must be one of {', '.join(IES_TYPES)}, got {requested!r}")
    if requested != "auto":
        return requested
    return "A" if source_type in (None, "A") else "C"


def _is_float(t: str) -> bool:
    try:
        float(t)
    except ValueError:
        return False
    return True


def _wrap(values: Sequence[float], digits: int, width: int = 128) -> list[str]:
    out: list[str] = []
    line = ""
    for v in values:
        tok = format_number(v, digits)
        if line and len(line) + 1 + len(tok) > width:
            out.append(line)
            line = tok
        else:
            line = f"{line} {tok}" if line else tok
    if line:
        out.append(line)
    return out


def _clean(text: str) -> str:
    return " ".join(str(text).replace("\r", " ").replace("\n", " ").split())[:240]


def write_ies(path: str | os.PathLike, grid: CandelaGrid | HVGrid, *, digits: int = 7,
              input_watts: float = 0.0,
              dimensions_m: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Path:
    """Write ``grid`` as an IES LM-63-2002 file (absolute cd), atomically.

    A :class:`CandelaGrid` is written as Type C (photometric type 1), an :class:`HVGrid` as
    Type A (3) or B (2) with its horizontal and vertical angles as they are.

    Parameters
    ----------
    path : path-like
        Destination ``.ies`` file.
    grid : CandelaGrid or HVGrid
        Intensities in cd. Metadata keys ``test``, ``testlab``, ``issuedate``,
        ``manufac``/``manufacturer``, ``lumcat``, ``luminaire``, ``lampcat``, ``lamp``,
        ``other`` become keywords (defaults name lightsim); other keys go to ``[OTHER]``.
    digits : int, default 7
        Significant digits of angles and intensities.
    input_watts : float, default 0
        Input power (W) written on the ballast line.
    dimensions_m : (width, length, height), default zeros
        Luminous opening in metres (0, 0, 0 = point).

    Returns
    -------
    Path
        The written file.
    """
    meta = {k.lower(): v for k, v in grid.metadata.items()}
    today = _dt.date.today().isoformat()
    kw = [
        ("TEST", meta.get("test", "lightsim far-field simulation")),
        ("TESTLAB", meta.get("testlab", "lightsim (simulated, not measured)")),
        ("ISSUEDATE", meta.get("issuedate", today)),
        ("MANUFAC", meta.get("manufac", meta.get("manufacturer", "lightsim"))),
    ]
    for key in ("lumcat", "luminaire", "lampcat", "lamp"):
        if key in meta:
            kw.append((key.upper(), meta[key]))
    if isinstance(grid, HVGrid) and grid.photometric_type == "A":
        kw.append(("OTHER", "Type A axes: H=0 V=0 is the lamp axis (straight ahead), H>0 "
                            "to the right, V>0 up"))
    elif isinstance(grid, HVGrid):
        kw.append(("OTHER", "Type B axes: H=0 V=0 is photometric zero (down), H=0 V=90 "
                            "straight ahead, H>0 to the right"))
    else:
        kw.append(("OTHER", "Type C axes: C=0 gamma=90 is the lamp axis (straight ahead), "
                            "gamma=0 nadir, C=90 towards the driver's left"))
    known = {"test", "testlab", "issuedate", "manufac", "manufacturer", "lumcat",
             "luminaire", "lampcat", "lamp", "format", "version", "tilt", "units", "width_m",
             "length_m", "height_m", "input_watts", "number_of_lamps", "candela_multiplier",
             "ballast_factor", "photometric_type"}
    for key in sorted(set(meta) - known):
        kw.append(("OTHER", f"{key}: {meta[key]}"))
    lines = ["IESNA:LM-63-2002"]
    lines += [f"[{k}] {_clean(v)}".rstrip() for k, v in kw]
    lines.append("TILT=NONE")
    lumens = "-1" if grid.lamp_lumens is None else format_number(grid.lamp_lumens, digits)
    w, l_, h = dimensions_m
    if isinstance(grid, HVGrid):
        ptype = 3 if grid.photometric_type == "A" else 2
        lines.append(f"1 {lumens} 1 {grid.shape[1]} {grid.shape[0]} {ptype} 2 "
                     f"{format_number(w, 6)} {format_number(l_, 6)} {format_number(h, 6)}")
        lines.append(f"1 1 {format_number(input_watts, 6)}")
        lines += _wrap(grid.v_deg, digits)
        lines += _wrap(grid.h_deg, digits)
        for row in grid.candela:
            lines += _wrap(row, digits)
        write_bytes(path, ("\r\n".join(lines) + "\r\n").encode("ascii", errors="replace"))
        return Path(path)
    if grid.shape[0] == 1:
        c_out = np.array([0.0])
        cd_out = grid.candela[:1]
    else:
        c_out = np.concatenate([grid.c_deg, [360.0]])
        cd_out = np.vstack([grid.candela, grid.candela[:1]])
        if grid.c_deg[0] != 0.0:
            raise InputError("write_ies: a multi-plane grid must start at C = 0°")
    lines.append(f"1 {lumens} 1 {grid.shape[1]} {len(c_out)} 1 2 "
                 f"{format_number(w, 6)} {format_number(l_, 6)} {format_number(h, 6)}")
    lines.append(f"1 1 {format_number(input_watts, 6)}")
    lines += _wrap(grid.gamma_deg, digits)
    lines += _wrap(c_out, digits)
    for row in cd_out:
        lines += _wrap(row, digits)
    # LM-63 files are ASCII text with CR LF line ends
    write_bytes(path, ("\r\n".join(lines) + "\r\n").encode("ascii", errors="replace"))
    return Path(path)
