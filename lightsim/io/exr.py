"""OpenEXR lux maps: float32 channels plus typed metadata, written atomically.

:func:`write_exr` writes one single-part scan-line EXR with ZSTD compression (lossless;
faster and ~20 % smaller than ZIP on float maps) and 32-bit float pixels. It goes to a
temporary name beside the target and is renamed over it only when complete, so a crash
never leaves a half file and an older file stays intact. :func:`read_exr` restores what
:func:`write_exr` stored and also reads foreign EXRs (e.g. RGB, RGBA or Y in half or float).

Metadata mapping (header attribute ← Python value)
--------------------------------------------------
==============================  ============================================  ==============
Python value                    EXR attribute                                 read back as
==============================  ============================================  ==============
``str``                         ``string`` under the key                      ``str``
``int`` within int32            ``int`` under the key                         ``int``
``float`` (incl. NaN, ±inf)     ``double`` under the key (exact)              ``float``
list of floats, all exactly     ``floatvector`` under the key                 ``list[float]``
float32
list of 2 or 3 other floats     ``v2d`` / ``v3d`` (exact)                     ``list[float]``
list of 2 or 3 int32 ints       ``v2i`` / ``v3i``                             ``list[int]``
anything else (dicts, bools,    ``string`` holding JSON under ``json:<key>``  the JSON value
None, other lists, big ints)
==============================  ============================================  ==============

So nested dicts such as the wall frame (``docs/reference/conventions.md``) are stored as JSON text
under ``json:wall``. Tuples and 1-D arrays are treated as lists (and read back as lists);
a list mixing ints and floats is stored and read back as floats. Inside JSON values NaN
and ±inf become ``null`` (:mod:`lightsim.io.summary`). Keys must be non-empty strings,
must not start with ``json:`` and must not be a structural EXR attribute
(:data:`RESERVED`). Foreign attributes read back as the closest Python value (vectors
and matrices → lists, enums → their name, other types → ``str``).

Parameters (user documentation)
-------------------------------
================  ====  ============  ==================================================
name              unit  default       meaning
================  ====  ============  ==================================================
``path``          –     required      file to write/read
``channels``      lx    required      name → (H, W) array, stored as float32 (EXR
                                      sorts channel names)
``metadata``      –     ``{}``        header attributes (mapping above)
``threads``       –     see below     OpenEXR worker threads for (de)compression
================  ====  ============  ==================================================

OpenEXR compresses and decompresses on its own global thread pool, which is off (0
threads) unless set. On first use this module sets it to the number of CPUs this
process may use, at most 8, or to ``$LIGHTSIM_EXR_THREADS``; :func:`set_exr_threads`
changes it (0 = off, e.g. inside many parallel worker processes).
"""

from __future__ import annotations

import enum
import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import OpenEXR

from lightsim.errors import InputError, LightsimError
from lightsim.io.atomic import atomic_path
from lightsim.io.summary import dumps as _json_dumps

__all__ = ["JSON_PREFIX", "RESERVED", "read_exr", "set_exr_threads", "wall_metadata", "write_exr"]

#: Attribute-name prefix of values stored as JSON text.
JSON_PREFIX = "json:"

#: Structural header attributes that metadata keys may not use (and read_exr leaves out).
RESERVED = frozenset({
    "channels", "compression", "dataWindow", "displayWindow", "lineOrder",
    "pixelAspectRatio", "screenWindowCenter", "screenWindowWidth", "type", "name",
    "tiles", "version", "chunkCount", "view", "multiView",
})

_EXR_MAGIC = b"\x76\x2f\x31\x01"
_INT32 = (-(2**31), 2**31 - 1)
_threads_set = False


def set_exr_threads(n: int | None = None) -> int:
    """Set OpenEXR's global (de)compression thread count.

    Parameters
    ----------
    n : int, optional
        Threads (0 = compress in the calling thread). Default: ``$LIGHTSIM_EXR_THREADS``
        or the number of CPUs this process may use, at most 8.

    Returns
    -------
    int
        The thread count now in effect.
    """
    global _threads_set
    if n is None:
        env = os.environ.get("LIGHTSIM_EXR_THREADS")
        if env is not None and env.strip():
            try:
                n = int(env)
            except ValueError:
                raise LightsimError(f"LIGHTSIM_EXR_THREADS must be an integer, got {env!r}"
                                    ) from None
        else:
            try:
                cpus = len(os.sched_getaffinity(0))
            except AttributeError:  # pragma: no cover - not on Linux
                cpus = os.cpu_count() or 1
            n = min(cpus, 8)
    n = max(0, int(n))
    OpenEXR.set_global_thread_count(n)
    _threads_set = True
    return n


def _ensure_threads() -> None:
    if not _threads_set:
        set_exr_threads()


# ---------------------------------------------------------------------------------------
# metadata encoding
# ---------------------------------------------------------------------------------------

def _is_int(x: Any) -> bool:
    return isinstance(x, int | np.integer) and not isinstance(x, bool | np.bool_)


def _is_real(x: Any) -> bool:
    return _is_int(x) or isinstance(x, float | np.floating)


def _encode_value(key: str, value: Any) -> tuple[str, Any]:
    """(attribute name, value the OpenEXR binding stores as the intended type)."""
    if isinstance(value, str):
        return key, value
    if _is_int(value):
        if _INT32[0] <= int(value) <= _INT32[1]:
            return key, int(value)
    elif isinstance(value, float | np.floating):
        return key, np.array([float(value)], dtype=np.float64)       # 'double'
    elif isinstance(value, list | tuple | np.ndarray) and np.ndim(value) == 1 \
            and len(value) > 0 and all(_is_real(x) for x in value):
        if all(_is_int(x) for x in value):
            if len(value) in (2, 3) and all(_INT32[0] <= int(x) <= _INT32[1] for x in value):
                return key, np.array([int(x) for x in value], dtype=np.int32)  # v2i/v3i
        else:
            arr = np.array([float(x) for x in value], dtype=np.float64)
            if np.array_equal(arr.astype(np.float32).astype(np.float64), arr, equal_nan=True):
                return key, [float(x) for x in arr]                    # floatvector
            if arr.size in (2, 3):
                return key, arr                                         # v2d/v3d
    return JSON_PREFIX + key, _json_dumps(value, indent=None)


def _encode_metadata(metadata: Mapping[str, Any]) -> dict[str, Any]:
    header: dict[str, Any] = {}
    for key, value in metadata.items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"EXR metadata keys must be non-empty strings, got {key!r}")
        if key in RESERVED or key.startswith(JSON_PREFIX):
            raise ValueError(f"EXR metadata key {key!r} is reserved")
        name, enc = _encode_value(key, value)
        header[name] = enc
    return header


def _decode_value(value: Any) -> Any:
    if isinstance(value, str | bool | int | float):
        return value
    if isinstance(value, np.ndarray):
        if value.shape == (1,) and value.dtype == np.float64:
            return float(value[0])
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, list | tuple):
        return [_decode_value(v) for v in value]
    if isinstance(value, enum.Enum):
        return value.name
    return str(value)


def _decode_metadata(header: Mapping[str, Any]) -> dict[str, Any]:
    meta: dict[str, Any] = {}
    for name, value in header.items():
        if name in RESERVED:
            continue
        if name.startswith(JSON_PREFIX) and isinstance(value, str):
            try:
                meta[name[len(JSON_PREFIX):]] = json.loads(value)
                continue
            except json.JSONDecodeError:
                pass  # a foreign attribute that happens to use the prefix: keep as text
        meta[name] = _decode_value(value)
    return meta


# ---------------------------------------------------------------------------------------
# write / read
# ---------------------------------------------------------------------------------------

def _encode(exr: OpenEXR.File, tmp: Path) -> None:
    """Encode ``exr`` into the temporary file ``tmp`` (separate so tests can fail it)."""
    exr.write(str(tmp))


def _check_channels(channels: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    if not isinstance(channels, Mapping) or not channels:
        raise ValueError("write_exr needs at least one channel (name → (H, W) array)")
    out: dict[str, np.ndarray] = {}
    shape = None
    for name, arr in channels.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"EXR channel names must be non-empty strings, got {name!r}")
        a = np.asarray(arr)
        if a.ndim != 2 or a.size == 0:
            raise ValueError(f"EXR channel {name!r} must be a non-empty (H, W) array, "
                             f"got shape {a.shape}")
        if a.dtype.kind not in "fiub":
            raise ValueError(f"EXR channel {name!r} must be real-valued, got {a.dtype}")
        if shape is None:
            shape = a.shape
        elif a.shape != shape:
            raise ValueError(f"EXR channel {name!r} has shape {a.shape}, others {shape}")
        with np.errstate(over="ignore"):
            f32 = np.ascontiguousarray(a, dtype=np.float32)
        if a.dtype != np.float32 and np.any(np.isfinite(a) & ~np.isfinite(f32)):
            raise ValueError(f"EXR channel {name!r} has values beyond the float32 range")
        out[name] = f32
    return out


def write_exr(path: str | os.PathLike, channels: Mapping[str, np.ndarray],
              metadata: Mapping[str, Any] | None = None) -> None:
    """Write float32 channels and metadata to an OpenEXR file atomically (ZSTD).

    Parameters
    ----------
    path : path-like
        Destination ``.exr``; an existing file is replaced only when the new one is
        complete.
    channels : mapping str → ndarray (H, W)
        Channel name → image (e.g. ``{"E": lux}`` in lx); all the same shape, stored as
        float32 (values are converted; values beyond the float32 range are an error).
    metadata : mapping, optional
        Header attributes; value types as in the module's mapping table.

    Raises
    ------
    ValueError
        Bad channels or metadata keys (caller's bug).
    LightsimError
        The file cannot be written (missing folder, permissions, disk full).
    """
    chans = _check_channels(channels)
    header: dict[str, Any] = {"compression": OpenEXR.ZSTD_COMPRESSION,
                              "type": OpenEXR.scanlineimage}
    header.update(_encode_metadata(metadata or {}))
    _ensure_threads()
    exr = OpenEXR.File(header, chans)
    p = Path(path)
    try:
        with atomic_path(p, suffix=".exr") as tmp:
            _encode(exr, tmp)
    except (OSError, RuntimeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise LightsimError(f"cannot write EXR file {p}: {reason}") from exc


def read_exr(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read the first part of an OpenEXR file.

    Parameters
    ----------
    path : path-like
        EXR file (scan-line or tiled; one or more parts — only part 0 is read).

    Returns
    -------
    channels : dict str → ndarray
        Channel name → (h, w) array of the data window: float32 for HALF and FLOAT
        channels, float64 for UINT channels (exact); in the file's (alphabetical) order.
        Sub-sampled channels keep their stored size.
    metadata : dict
        Header attributes except the structural ones (:data:`RESERVED`), decoded as in
        the module's mapping table.

    Raises
    ------
    InputError
        Missing file, not an EXR, truncated or corrupt file, deep data (one line).
    """
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            magic = fh.read(4)
    except FileNotFoundError:
        raise InputError(f"EXR file not found: {p}") from None
    except IsADirectoryError:
        raise InputError(f"expected an EXR file, got a directory: {p}") from None
    except OSError as exc:
        raise InputError(f"cannot read EXR file {p}: {exc.strerror or exc}") from None
    if magic != _EXR_MAGIC:
        raise InputError(f"not an OpenEXR file: {p}")
    _ensure_threads()
    try:
        exr = OpenEXR.File(str(p), separate_channels=True)
        if not exr.parts:
            raise ValueError("no readable part")
        header = exr.header(0)
        raw = exr.channels(0)
        if "deep" in str(header.get("type", "")).lower():
            raise InputError(f"deep EXR files are not supported: {p}")
        chans: dict[str, np.ndarray] = {}
        for name, ch in raw.items():
            px = ch.pixels
            if px is None:
                raise ValueError(f"channel {name!r} has no pixel data")
            px = np.asarray(px)
            if px.dtype == np.uint32:
                chans[name] = px.astype(np.float64)
            else:
                chans[name] = np.ascontiguousarray(px, dtype=np.float32)
    except InputError:
        raise
    except (RuntimeError, ValueError, TypeError, KeyError, IndexError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"cannot read EXR file {p} (truncated or corrupt?): {msg}") from None
    return chans, _decode_metadata(header)


def wall_metadata(wall: Mapping[str, Any], **extra: Any) -> dict[str, Any]:
    """Metadata for a lux map: the wall frame as ``json:wall`` plus native attributes.

    The wall frame (``docs/reference/conventions.md``) is kept whole under ``wall``; its
    ``distance_m`` (double) and ``resolution`` (v2i) are repeated as ``wall_distance_m``
    and ``wall_resolution`` for tools that only show native attributes. ``extra``
    (e.g. ``units="lx"``) is added as is.
    """
    meta: dict[str, Any] = {"wall": dict(wall)}
    if "distance_m" in wall and _is_real(wall["distance_m"]) \
            and math.isfinite(float(wall["distance_m"])):
        meta["wall_distance_m"] = float(wall["distance_m"])
    if isinstance(wall.get("resolution"), Sequence) and len(wall["resolution"]) == 2:
        meta["wall_resolution"] = [int(x) for x in wall["resolution"]]
    meta.update(extra)
    return meta
