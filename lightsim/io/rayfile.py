"""Ray files of light sources: IES TM-25 (``.tm25ray``) and Zemax binary source files.

A ray file is a light source measured (near-field goniophotometer) or modelled by its
maker: N rays, each a start point, a direction and a flux, optionally a wavelength. The
readers parse the header and map the ray block with :class:`numpy.memmap` — a file of
50 M rays is not loaded; the sampler (:mod:`lightsim.emitters.rayfile`) reads only the rays it
draws. The writers make small files for tests and examples.

Layouts (little-endian, float32 ray records):

* **IES TM-25-13** (read through J. Muschaweck's public-domain TM25RaySetTools, which
  follows the document's section numbers): file header 256 bytes — ``"TM25"``, version
  int32 = 2013, creation method int32, luminous flux float32 (lm, NaN = not given),
  radiant flux float32 (W), ray count uint64, date char[28], start position int32,
  spectrum type int32 (0 none, 1 single λ, 2 per ray, 3/4 tables), λ, λmin, λmax float32
  (nm), spectral tables int32, extra items int32, extra text bytes int32, 168 reserved;
  known-data flags 8 × int32 (position = 1, direction = 1, radiant flux, wavelength,
  luminous flux, Stokes, tristimulus, spectrum index); 9 description texts of 1000 UTF-32
  characters each; spectral tables (int32 count + float32 pairs, padded to 32 bytes);
  512-byte UTF-32 names of the extra columns; the extra text. Each ray: x, y, z (mm),
  kx, ky, kz, then the present items in this order: radiant flux Φ (W), λ (nm),
  luminous flux (Tri_Y, lm), Stokes S1–S3 and the polarisation ellipse (6), tristimulus
  X, Z, spectrum index, extra columns.
* **Zemax OpticStudio binary source file**: header 208 bytes — identifier int32 (1010),
  ray count uint32, description char[100], source flux, ray-set flux, wavelength (µm),
  inclination and azimuth ranges (4 float32), dimension units uint32 (0 m, 1 in, 2 cm,
  3 ft, 4 mm), location, rotation, scale (9 float32), 4 unused float32, ray format int32
  (0 flux only, 2 spectral), flux type int32 (0 W, 1 lm), 2 reserved int32. Each ray: x,
  y, z, kx, ky, kz, flux (+ λ in µm for the spectral format).

=================  =====  =======  =================================================
parameter          unit   default  meaning
=================  =====  =======  =================================================
``positions``      m      –        ray start points (writers; files store mm / units)
``directions``     –      –        ray directions (normalised on reading)
``flux``           lm     –        per-ray luminous flux
``wavelength``     nm     none     per-ray wavelength (read and kept; lightsim traces
                                   luminous flux, one channel)
=================  =====  =======  =================================================
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path

TM25_SUFFIXES = (".tm25ray",)
ZEMAX_SUFFIXES = (".dat", ".ray")
RAYFILE_SUFFIXES = TM25_SUFFIXES + ZEMAX_SUFFIXES

TM25_FILE_HEADER = 256
TM25_FLAGS = 32
TM25_TEXTS = 9
TM25_TEXT_BYTES = 4000
TM25_COLUMN_NAME_BYTES = 512
ZEMAX_HEADER = 208
ZEMAX_ID = 1010
ZEMAX_UNITS_M = {0: 1.0, 1: 0.0254, 2: 0.01, 3: 0.3048, 4: 0.001}
CHUNK = 1 << 20  # rays per chunk when a whole file is scanned (flux sums, checks)


@dataclass
class RayFile:
    """A ray file's header and its memory-mapped ray block.

    Attributes
    ----------
    path : Path
    format : str
        ``tm25`` or ``zemax``.
    n_rays : int
    items : list of str
        Column names of one ray record (``x … kz``, ``phi``, ``lambda``, ``Tri_Y``, …).
    offset : int
        Byte offset of the first ray.
    unit_m : float
        Metres per position unit of the file (TM-25: mm).
    flux_item : str
        The column used as the ray's flux: ``Tri_Y`` (lm) or ``phi`` / ``flux``.
    flux_is_luminous : bool
        Whether that column is luminous flux (lm); otherwise radiant (W), used as
        relative weights only.
    header_flux_lm : float or None
        Total luminous flux the header states (lm), if any.
    wavelength_item : str or None
        Column with the per-ray wavelength, if present.
    wavelength_scale_nm : float
        nm per wavelength unit of the file (TM-25 nm: 1; Zemax µm: 1000).
    meta : dict
        Other header fields (name, manufacturer, single wavelength, …).
    """

    path: Path
    format: str
    n_rays: int
    items: list[str]
    offset: int
    unit_m: float
    flux_item: str
    flux_is_luminous: bool
    header_flux_lm: float | None
    wavelength_item: str | None = None
    wavelength_scale_nm: float = 1.0
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_items(self) -> int:
        return len(self.items)

    def rays(self) -> np.ndarray:
        """(n_rays, n_items) float32 view of the ray block (memory-mapped, read-only)."""
        return np.memmap(self.path, dtype="<f4", mode="r", offset=self.offset,
                         shape=(self.n_rays, self.n_items))

    def column(self, name: str) -> int:
        return self.items.index(name)

    def flux_sum(self) -> float:
        """Sum of the flux column (lm or W), streamed in chunks."""
        mm = self.rays()
        j = self.column(self.flux_item)
        return float(sum(np.sum(mm[i:i + CHUNK, j], dtype=np.float64)
                         for i in range(0, self.n_rays, CHUNK)))

    def luminous_flux(self) -> float | None:
        """Total luminous flux (lm): the sum of per-ray lumens, else the header's."""
        if self.flux_is_luminous:
            return self.flux_sum()
        return self.header_flux_lm

    def describe(self) -> str:
        flux = self.luminous_flux()
        fl = f"{flux:.6g} lm" if flux is not None else "flux in W (relative)"
        wl = ", per-ray wavelength" if self.wavelength_item else ""
        return f"{self.format} ray file, {self.n_rays:,} rays, {fl}{wl}"


# ------------------------------------------------------------------------------------------
# Reading
# ------------------------------------------------------------------------------------------

def _check_size(path: Path, offset: int, n_rays: int, n_items: int, what: str) -> None:
    size = path.stat().st_size
    need = offset + n_rays * n_items * 4
    if size < need:
        raise InputError(f"{path}: truncated {what} ray file ({size} bytes, header says "
                         f"{n_rays:,} rays = {need} bytes)")
    if size > need:
        raise InputError(f"{path}: {what} ray file has {size - need} bytes after its "
                         f"{n_rays:,} rays (corrupt header?)")


def _utf32(raw: bytes) -> str:
    return raw.decode("utf-32-le", errors="replace").split("\x00", 1)[0].strip()


def read_tm25(path: str | os.PathLike) -> RayFile:
    """Parse an IES TM-25 ray file's header (see the module docstring)."""
    p = Path(path)
    with open(p, "rb") as f:
        head = f.read(TM25_FILE_HEADER + TM25_FLAGS)
        if len(head) < TM25_FILE_HEADER + TM25_FLAGS or head[:4] != b"TM25":
            raise InputError(f"{p}: not a TM-25 ray file (no 'TM25' header)")
        (version, _method, phi_v, phi, n_rays) = struct.unpack_from("<iiffQ", head, 4)
        date = head[28:56].split(b"\x00", 1)[0].decode("ascii", "replace")
        (start, spec_type, lam, lam_min, lam_max, n_spectra, n_extra,
         text_bytes) = struct.unpack_from("<iifffiii", head, 56)
        flags = struct.unpack_from("<8i", head, TM25_FILE_HEADER)
        if version != 2013:
            raise InputError(f"{p}: TM-25 version {version} (only 2013 is defined)")
        if flags[0] != 1 or flags[1] != 1 or any(x not in (0, 1) for x in flags[2:]):
            raise InputError(f"{p}: corrupt TM-25 data flags {list(flags)}")
        size = os.fstat(f.fileno()).st_size
        # counts the file cannot hold are refused before any loop runs over them
        if (n_spectra < 0 or n_extra < 0 or text_bytes < 0 or text_bytes % 32
                or n_spectra > size // 12 or n_extra > size // TM25_COLUMN_NAME_BYTES
                or text_bytes > size):
            raise InputError(f"{p}: corrupt TM-25 header (tables {n_spectra}, extra items "
                             f"{n_extra}, text {text_bytes} bytes, in a file of {size} "
                             "bytes)")
        rad, wavel, lum, stokes, tri, spec_idx = (bool(x) for x in flags[2:])
        if not (rad or lum):
            raise InputError(f"{p}: TM-25 file has neither radiant nor luminous flux")
        texts = [_utf32(f.read(TM25_TEXT_BYTES)) for _ in range(TM25_TEXTS)]
        nbytes = 0
        for _ in range(n_spectra):  # spectral tables: skipped (one luminous channel)
            raw = f.read(4)
            if len(raw) < 4:
                raise InputError(f"{p}: TM-25 file ends inside its spectral tables")
            (n_pairs,) = struct.unpack("<i", raw)
            if n_pairs <= 0:
                raise InputError(f"{p}: corrupt TM-25 spectral table ({n_pairs} pairs)")
            f.seek(8 * n_pairs, os.SEEK_CUR)
            nbytes += 4 + 8 * n_pairs
        if nbytes % 32:
            f.seek(32 - nbytes % 32, os.SEEK_CUR)
        extra = [_utf32(f.read(TM25_COLUMN_NAME_BYTES)) or f"extra{i}"
                 for i in range(n_extra)]
        f.seek(text_bytes, os.SEEK_CUR)
        offset = f.tell()
    items = ["x", "y", "z", "kx", "ky", "kz"]
    items += ["phi"] * rad + ["lambda"] * wavel + ["Tri_Y"] * lum
    if stokes:
        items += ["S1", "S2", "S3", "PolEllipseX", "PolEllipseY", "PolEllipseZ"]
    if tri:
        items += ["Tri_X", "Tri_Z"]
    items += ["spectrumIdx"] * spec_idx + extra
    _check_size(p, offset, int(n_rays), len(items), "TM-25")
    names = ("name", "manufacturer", "model_creator", "rayfile_creator", "equipment",
             "camera", "operation", "info", "reference")
    meta = {"date": date, "start_position": start, "spectrum_type": spec_type,
            "wavelength_nm": lam if spec_type == 1 else None, "wavelength_range_nm":
            (lam_min, lam_max), "radiant_flux_W": None if math.isnan(phi) else phi,
            **dict(zip(names, texts, strict=True))}
    return RayFile(p, "tm25", int(n_rays), items, offset, 1e-3,
                   "Tri_Y" if lum else "phi", lum,
                   None if not (math.isfinite(phi_v) and phi_v > 0) else float(phi_v),
                   "lambda" if wavel else None, 1.0, meta)


def read_zemax(path: str | os.PathLike) -> RayFile:
    """Parse a Zemax OpticStudio binary source file's header (see the module docstring)."""
    p = Path(path)
    with open(p, "rb") as f:
        head = f.read(ZEMAX_HEADER)
    if len(head) < ZEMAX_HEADER:
        raise InputError(f"{p}: not a Zemax binary ray file (shorter than its header)")
    ident, n_rays = struct.unpack_from("<iI", head, 0)
    desc = head[8:108].split(b"\x00", 1)[0].decode("latin-1").strip()
    src_flux, set_flux, wavelength = struct.unpack_from("<fff", head, 108)
    (units,) = struct.unpack_from("<I", head, 136)
    fmt, flux_type = struct.unpack_from("<ii", head, 192)
    if ident != ZEMAX_ID:
        raise InputError(f"{p}: not a Zemax binary ray file (identifier {ident}, "
                         f"expected {ZEMAX_ID})")
    if units not in ZEMAX_UNITS_M or fmt not in (0, 2) or flux_type not in (0, 1):
        raise InputError(f"{p}: corrupt Zemax header (units {units}, format {fmt}, "
                         f"flux type {flux_type})")
    items = ["x", "y", "z", "kx", "ky", "kz", "flux"] + (["lambda"] if fmt == 2 else [])
    _check_size(p, ZEMAX_HEADER, int(n_rays), len(items), "Zemax")
    lumens = fmt == 0 and flux_type == 1
    header_lm = float(set_flux) if lumens and set_flux > 0 else None
    meta = {"description": desc, "source_flux": float(src_flux),
            "wavelength_nm": float(wavelength) * 1e3 if wavelength > 0 else None}
    return RayFile(p, "zemax", int(n_rays), items, ZEMAX_HEADER, ZEMAX_UNITS_M[units],
                   "flux", lumens, header_lm, "lambda" if fmt == 2 else None, 1e3, meta)


def read_rayfile(path: str | os.PathLike) -> RayFile:
    """Open a TM-25 (``.tm25ray``) or Zemax binary (``.dat``, ``.ray``) ray file.

    The format is recognised by content (the ``TM25`` magic), so a TM-25 file with
    another suffix also opens. Raises :class:`~lightsim.errors.InputError` with one line
    for a missing, truncated or corrupt file.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such ray file")
    if not p.is_file():
        raise InputError(f"{p}: not a file")
    with open(p, "rb") as f:
        magic = f.read(4)
    rf = read_tm25(p) if magic == b"TM25" else read_zemax(p)
    if rf.n_rays == 0:
        raise InputError(f"{p}: the ray file holds no rays")
    return rf


# ------------------------------------------------------------------------------------------
# Writing
# ------------------------------------------------------------------------------------------

def _ray_block(positions_m: np.ndarray, directions: np.ndarray, flux: np.ndarray,
               unit_m: float, extra: list[np.ndarray]) -> np.ndarray:
    pos = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
    k = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    fl = np.asarray(flux, dtype=np.float64).reshape(-1)
    if not (len(pos) == len(k) == len(fl)) or len(pos) == 0:
        raise InputError("ray file: positions, directions and flux need the same, "
                         "non-zero number of rays")
    cols = [pos / unit_m, k, fl[:, None], *[np.asarray(e, float).reshape(-1, 1)
                                             for e in extra]]
    block = np.hstack(cols).astype("<f4")
    if not np.all(np.isfinite(block)) or np.any(fl < 0):
        raise InputError("ray file: rays must be finite with non-negative flux")
    return block


def _utf32_block(text: str, nbytes: int) -> bytes:
    raw = text.encode("utf-32-le")[: nbytes - 4]
    return raw + b"\x00" * (nbytes - len(raw))


def write_tm25(path: str | os.PathLike, positions_m: np.ndarray, directions: np.ndarray,
               flux_lm: np.ndarray, wavelength_nm: np.ndarray | None = None, *,
               name: str = "lightsim ray file", manufacturer: str = "unknown") -> Path:
    """Write an IES TM-25 ray file with luminous flux per ray (and wavelengths).

    Positions are stored in mm (TM-25's unit), the header's luminous flux is the sum of
    the rays'. Written atomically.
    """
    extra = [] if wavelength_nm is None else [wavelength_nm]
    block = _ray_block(positions_m, directions, flux_lm, 1e-3, extra)
    total = float(np.sum(block[:, 6], dtype=np.float64))
    # spectrum type 2 (per-ray λ) requires radiant flux; per-ray λ beside lumens is
    # written as type 0 with the wavelength flag set
    spec_type = 0
    lam_min = lam_max = float("nan")
    if wavelength_nm is not None:
        lam_min, lam_max = float(np.min(wavelength_nm)), float(np.max(wavelength_nm))
    head = b"TM25" + struct.pack("<iiffQ", 2013, 0, total, float("nan"), len(block))
    head += b"1970-01-01T00:00:00+00:00".ljust(28, b"\x00")
    head += struct.pack("<iifffiii", 0, spec_type, float("nan"), lam_min, lam_max, 0, 0, 0)
    head += b"\x00" * (TM25_FILE_HEADER - len(head))
    # flags: position, direction, radiant, wavelength, luminous, Stokes, tristimulus, index
    head += struct.pack("<8i", 1, 1, 0, int(wavelength_nm is not None), 1, 0, 0, 0)
    texts = [name, manufacturer, "lightsim", "lightsim", "lightsim write_tm25", "none",
             "unknown", "none", "none"]
    body = b"".join(_utf32_block(t, TM25_TEXT_BYTES) for t in texts)
    # column order: x y z kx ky kz [lambda] Tri_Y — lambda precedes the luminous flux
    if wavelength_nm is not None:
        block = block[:, [0, 1, 2, 3, 4, 5, 7, 6]]
    p = Path(path)
    with atomic_path(p) as tmp, open(tmp, "wb") as f:
        f.write(head + body)
        block.tofile(f)
    return p


def write_zemax(path: str | os.PathLike, positions_m: np.ndarray, directions: np.ndarray,
                flux_lm: np.ndarray, *, units: str = "mm",
                description: str = "lightsim ray file") -> Path:
    """Write a Zemax binary source file (flux-only format, flux in lumens). Atomic."""
    code = {"m": 0, "in": 1, "cm": 2, "ft": 3, "mm": 4}.get(units)
    if code is None:
        raise InputError(f"Zemax units must be m, in, cm, ft or mm, got '{units}'")
    block = _ray_block(positions_m, directions, flux_lm, ZEMAX_UNITS_M[code], [])
    total = float(np.sum(block[:, 6], dtype=np.float64))
    head = struct.pack("<iI", ZEMAX_ID, len(block))
    head += description.encode("latin-1", "replace")[:99].ljust(100, b"\x00")
    head += struct.pack("<7f", total, total, 0.55, 0.0, 90.0, 0.0, 360.0)
    head += struct.pack("<I", code) + struct.pack("<13f", *([0.0] * 6), 1.0, 1.0, 1.0,
                                                   0.0, 0.0, 0.0, 0.0)
    head += struct.pack("<4i", 0, 1, 0, 0)
    assert len(head) == ZEMAX_HEADER
    p = Path(path)
    with atomic_path(p) as tmp, open(tmp, "wb") as f:
        f.write(head)
        block.tofile(f)
    return p


def write_rayfile(path: str | os.PathLike, positions_m: np.ndarray, directions: np.ndarray,
                  flux_lm: np.ndarray, title: str = "lightsim ray file") -> Path:
    """Write a ray file in the format its suffix names: TM-25 (:data:`TM25_SUFFIXES`,
    :func:`write_tm25`, ``title`` as its name) or Zemax binary (:data:`ZEMAX_SUFFIXES`,
    :func:`write_zemax`, ``title`` as its description). Atomic; another suffix raises
    :class:`~lightsim.errors.InputError`."""
    suffix = Path(path).suffix.lower()
    if suffix in TM25_SUFFIXES:
        return write_tm25(path, positions_m, directions, flux_lm, name=title)
    if suffix in ZEMAX_SUFFIXES:
        return write_zemax(path, positions_m, directions, flux_lm, description=title)
    raise InputError(f"{path}: ray file name must end in .tm25ray, .dat or .ray")
