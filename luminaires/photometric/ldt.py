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
ahead). Absolute candela = value × conversion factor × (Σ lamp flux of the sets) / 1000.

Reading
    Numbers may use a decimal comma; several numbers per line are accepted in the angle and
    intensity blocks. Isym 1 (axial: one plane), 2 (C0–C180 plane), 3 (C90–C270 plane) and
    4 (both) are expanded to full C coverage. A negative number of lamps (absolute
    photometry in some writers) is read as its magnitude.

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
import os
from pathlib import Path

import numpy as np

from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes

from .candela import CandelaGrid
from .ies import _read_lines, format_number

__all__ = ["read_ldt", "write_ldt"]


def _num(s: str, name: str, what: str) -> float:
    try:
        return float(s.strip().replace(",", "."))
    except ValueError:
        raise InputError(f"LDT file {name}: {what} '{s.strip()}' is not a number") from None


def read_ldt(path: str | os.PathLike) -> CandelaGrid:
    """Read a EULUMDAT file into a :class:`CandelaGrid` (absolute cd).

    Parameters
    ----------
    path : path-like
        The ``.ldt`` file.

    Returns
    -------
    CandelaGrid
        ``lamp_lumens`` = total lamp flux of all sets (lm); metadata holds the text fields,
        dimensions (mm), DFF and LORL (%), and ``format="LDT"``.

    Raises
    ------
    InputError
        Missing file, malformed numbers or inconsistent counts.
    """
    name = Path(path).name
    lines = _read_lines(path, "LDT")
    pos = 0

    def line(what: str) -> str:
        nonlocal pos
        if pos >= len(lines):
            raise InputError(f"LDT file {name}: ends before {what}")
        s = lines[pos]
        pos += 1
        return s.strip()

    def numbers(n: int, what: str) -> list[float]:
        out: list[float] = []
        while len(out) < n:
            s = line(what)
            if s:
                out.extend(_num(t, name, what) for t in s.split())
        if len(out) != n:
            raise InputError(f"LDT file {name}: {what}: expected {n} numbers, found {len(out)}")
        return out

    meta: dict[str, str] = {"format": "LDT"}
    meta["manufacturer"] = line("the company line")
    ityp = int(_num(line("Ityp"), name, "Ityp"))
    isym = int(_num(line("Isym"), name, "Isym"))
    mc = int(_num(line("Mc"), name, "Mc"))
    _num(line("Dc"), name, "Dc")
    ng = int(_num(line("Ng"), name, "Ng"))
    _num(line("Dg"), name, "Dg")
    for key in ("test", "luminaire", "lumcat", "file_name", "date_user"):
        meta[key] = line(key)
    dims = ["length_mm", "width_mm", "height_mm", "luminous_length_mm", "luminous_width_mm",
            "luminous_height_c0_mm", "luminous_height_c90_mm", "luminous_height_c180_mm",
            "luminous_height_c270_mm"]
    for key in dims:
        meta[key] = format_number(_num(line(key), name, key))
    dff = _num(line("DFF"), name, "DFF")
    lorl = _num(line("LORL"), name, "LORL")
    conv = _num(line("conversion factor"), name, "conversion factor")
    tilt = _num(line("tilt"), name, "tilt")
    n_sets = int(_num(line("number of lamp sets"), name, "number of lamp sets"))
    if isym not in (0, 1, 2, 3, 4):
        raise InputError(f"LDT file {name}: symmetry Isym {isym} is not 0…4")
    if mc < 1 or ng < 2 or n_sets < 1:
        raise InputError(f"LDT file {name}: needs Mc ≥ 1, Ng ≥ 2 and ≥ 1 lamp set "
                         f"(got {mc}, {ng}, {n_sets})")
    flux = 0.0
    lamp_types = []
    watts = 0.0
    for k in range(n_sets):
        n_l = abs(int(_num(line("number of lamps"), name, "number of lamps")))
        lamp_types.append(line("lamp type"))
        f = _num(line("lamp flux"), name, "lamp flux")
        meta.setdefault("cct", line("colour temperature"))
        meta.setdefault("cri", line("colour rendering"))
        watts += _num(line("wattage"), name, "wattage")
        flux += f
        if k == 0:
            meta["number_of_lamps"] = str(n_l)
    meta["lamp"] = "; ".join(t for t in lamp_types if t)
    numbers(10, "the direct ratios")
    c_all = np.array(numbers(mc, "the C angles"))
    gam = np.array(numbers(ng, "the γ angles"))
    n_store = {0: mc, 1: 1, 2: mc // 2 + 1, 3: mc // 2 + 1, 4: mc // 4 + 1}[isym]
    vals = np.array(numbers(n_store * ng, "the intensities")).reshape(n_store, ng)
    if not flux > 0:
        raise InputError(f"LDT file {name}: total lamp flux must be > 0 lm, got {flux:g}")
    cd = vals * (conv if conv != 0 else 1.0) * flux / 1000.0
    c_all = c_all % 360.0
    if isym == 1:
        c_full, cd_full = np.array([0.0]), cd[:1]
    else:
        step_planes = {0: c_all[:mc], 2: c_all[: mc // 2 + 1], 4: c_all[: mc // 4 + 1],
                       3: (270.0 + 360.0 / mc * np.arange(mc // 2 + 1)) % 360.0}[isym]
        pairs: dict[float, np.ndarray] = {}
        for ang, row in zip(step_planes, cd):
            images = {0: (ang,), 2: (ang, -ang), 3: (ang, 180.0 - ang),
                      4: (ang, -ang, 180.0 - ang, 180.0 + ang)}[isym]
            for img in images:
                pairs.setdefault(round(float(img) % 360.0, 9), row)
        keys = sorted(pairs)
        c_full, cd_full = np.array(keys), np.array([pairs[k] for k in keys])
    meta.update({"dff_percent": format_number(dff), "lorl_percent": format_number(lorl),
                 "tilt_deg": format_number(tilt), "ityp": str(ityp), "isym": str(isym),
                 "input_watts": format_number(watts)})
    return CandelaGrid(c_full, gam, np.maximum(cd_full, 0.0), flux, meta)


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
