"""STEP and IGES import: OpenCASCADE tessellation to named parts.

A headlamp arrives from CAD as exact surfaces (B-rep). Two readers, both OpenCASCADE:

* with its Python binding (``cadquery-ocp``, the ``cad-names`` extra) the file is read
  into an XCAF document (:mod:`lightsim.io.cad_xcaf`): parts keep their CAD names for STEP
  *and* IGES, every face keeps its name (``"<part>/<face>"``, ``face-<k>`` for unnamed
  faces) so a material map can target single faces, and vertex normals are evaluated on
  the exact surface at each mesh node;
* without it, ``cascadio`` (OpenCASCADE's mesher, a trimesh companion, the ``cad``
  extra) tessellates into a glTF binary in memory, read by
  :func:`lightsim.io.gltf.read_gltf`: one part per solid or free face named as in the
  STEP tree (faces inside a solid are not named), normals from the mesher's surface
  evaluation; IGES parts are named ``iges-1``, ``iges-2``, … and its unit is read from
  the IGES global section (parameter 14, the unit flag).

``read_cad(..., backend=)`` picks one: ``"auto"`` (default: XCAF when ``cadquery-ocp``
is importable), ``"xcaf"`` or ``"cascadio"``.

A reflector's facet error is a beam error: the mesher's tolerances are therefore fine by
default. The linear tolerance bounds the distance between facet and surface, the
angular one the angle between neighbouring facet normals; both are given in CAD terms
(mm, degrees). The beam error they leave on an exact paraboloid is measured by
``tests/io/test_cad.py`` and tabulated in ``docs/guides/cad-lamp.md``.

The XCAF reader runs in a child process (a fresh interpreter, ``python -m
lightsim.io.cad``): OpenCASCADE's parsers can crash on a damaged file (a segmentation
fault) or loop on it, and either becomes one line here. The child gets a time limit in
processor seconds (its own CPU time, ``RLIMIT_CPU``, so that a busy machine does not cut
a sound read short), and, as a safety net, ``WALL_FACTOR`` times that in wall-clock
time; a file that is sound but large needs a larger one (``simulate
--cad-time-limit``). A fresh interpreter rather than a fork: a fork of a process whose
threads (the tracer's, the plot process's pipes) hold locks can deadlock in the child.

=================  =====  =======  =====================================================
parameter          unit   default  meaning
=================  =====  =======  =====================================================
``linear_tol``     mm     0.01     largest facet-to-surface distance
``angular_tol``    deg    2        largest angle between neighbouring facet normals
``time_limit``     s      600      processor time a CAD read may use before it is given up
``WALL_FACTOR``    –      10       wall-clock limit = WALL_FACTOR × time_limit + 60 s
=================  =====  =======  =====================================================
"""

from __future__ import annotations

import faulthandler
import math
import os
import pickle
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

try:  # processor-time limits (POSIX); elsewhere the wall-clock limit alone
    import resource
except ImportError:  # pragma: no cover - Windows
    resource = None  # type: ignore[assignment]

from lightsim.errors import InputError
from lightsim.io.cad_xcaf import have_ocp, read_xcaf
from lightsim.io.gltf import read_gltf

STEP_SUFFIXES = (".step", ".stp")
IGES_SUFFIXES = (".iges", ".igs")
CAD_SUFFIXES = STEP_SUFFIXES + IGES_SUFFIXES
DEFAULT_LINEAR_TOL_MM = 0.01
DEFAULT_ANGULAR_TOL_DEG = 2.0
DEFAULT_TIME_LIMIT_S = 600.0
WALL_FACTOR = 10.0
# IGES global parameter 14: unit flag → metres per unit
IGES_UNITS_M = {1: 0.0254, 2: 1e-3, 3: None, 4: 0.3048, 5: 1609.344, 6: 1.0, 7: 1000.0,
                8: 0.0254e-3, 9: 1e-6, 10: 0.01, 11: 0.0254e-6}


@dataclass(frozen=True)
class Tessellation:
    """Mesher tolerances and the reader's time limit (see the module docstring)."""

    linear_tol_mm: float = DEFAULT_LINEAR_TOL_MM
    angular_tol_deg: float = DEFAULT_ANGULAR_TOL_DEG
    time_limit_s: float = DEFAULT_TIME_LIMIT_S

    def __post_init__(self) -> None:
        if not (math.isfinite(self.linear_tol_mm) and self.linear_tol_mm > 0):
            raise InputError(f"CAD linear tolerance must be a positive number of mm, got "
                             f"{self.linear_tol_mm}")
        if not (math.isfinite(self.angular_tol_deg) and 0 < self.angular_tol_deg < 90):
            raise InputError(f"CAD angular tolerance must lie in (0, 90) degrees, got "
                             f"{self.angular_tol_deg}")
        if not (math.isfinite(self.time_limit_s) and self.time_limit_s > 0):
            raise InputError(f"CAD time limit must be a positive number of seconds, got "
                             f"{self.time_limit_s}")


def iges_unit_m(data: bytes) -> float:
    """Metres per model unit of an IGES file, from its global section (G lines)."""
    lines = data.decode("latin-1", "replace").splitlines()
    glob = "".join(ln[:72] for ln in lines if len(ln) >= 73 and ln[72] == "G")
    if not glob:
        raise InputError("IGES file has no global section")
    pdelim, rdelim = ",", ";"
    if glob.startswith("1H"):  # custom delimiters
        pdelim = glob[2]
    fields, cur, i = [], "", 0
    while i < len(glob) and len(fields) < 16:
        c = glob[i]
        if c.isdigit() and not cur:  # a Hollerith string nH…
            j = i
            while j < len(glob) and glob[j].isdigit():
                j += 1
            if j < len(glob) and glob[j] == "H":
                n = int(glob[i:j])
                fields.append(glob[j + 1:j + 1 + n])
                i = j + 1 + n
                if i < len(glob) and glob[i] in (pdelim, rdelim):
                    i += 1
                continue
        if c in (pdelim, rdelim):
            fields.append(cur)
            cur = ""
        else:
            cur += c
        i += 1
    try:
        flag = int(float(fields[13]))
    except (IndexError, ValueError):
        raise InputError("IGES global section has no unit flag (parameter 14)") from None
    unit = IGES_UNITS_M.get(flag)
    if unit is None:
        raise InputError(f"IGES unit flag {flag} is not supported (give the file in mm)")
    return unit


def iges_as_step(path: Path) -> bytes | None:
    """The IGES file as STEP text with its part names and units (OpenCASCADE's XCAF
    reader and writer), or None without ``cadquery-ocp``."""
    try:
        from OCP.IFSelect import IFSelect_RetDone
        from OCP.IGESCAFControl import IGESCAFControl_Reader
        from OCP.Message import Message, Message_PrinterOStream
        from OCP.STEPCAFControl import STEPCAFControl_Writer
        from OCP.STEPControl import STEPControl_AsIs
        from OCP.TCollection import TCollection_ExtendedString
        from OCP.TDocStd import TDocStd_Document
    except ImportError:
        return None
    Message.DefaultMessenger_s().RemovePrinters(Message_PrinterOStream.get_type_descriptor_s())
    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    reader = IGESCAFControl_Reader()
    reader.SetNameMode(True)
    if reader.ReadFile(str(path)) != IFSelect_RetDone or not reader.Transfer(doc):
        raise InputError(f"{path}: OpenCASCADE could not read this IGES file")
    writer = STEPCAFControl_Writer()
    writer.SetNameMode(True)
    writer.Transfer(doc, STEPControl_AsIs)
    fd, tmp = tempfile.mkstemp(suffix=".step", prefix="lightsim-iges-")
    os.close(fd)
    try:
        if writer.Write(tmp) != IFSelect_RetDone:
            raise InputError(f"{path}: OpenCASCADE could not convert this IGES file")
        return Path(tmp).read_bytes()
    finally:
        Path(tmp).unlink(missing_ok=True)


def tessellate(path: str | os.PathLike, tess: Tessellation | None = None) -> Path:
    """Tessellate a STEP or IGES file into a temporary GLB file (metres); returns its path.

    The caller removes the file. Raises :class:`InputError` for unreadable CAD files.
    """
    tess = tess or Tessellation()
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in CAD_SUFFIXES:
        raise InputError(f"{p}: not a STEP or IGES file")
    try:
        import cascadio
    except ImportError:
        raise InputError("STEP/IGES import needs OpenCASCADE: pip install "
                         "'lightsim[cad-names]' (cadquery-ocp) or 'lightsim[cad]' "
                         "(cascadio)") from None
    data = p.read_bytes()
    kind = "step" if suffix in STEP_SUFFIXES else "iges"
    if kind == "iges":
        as_step = iges_as_step(p)
        if as_step is not None:
            data, kind = as_step, "step"
    if kind == "step" and b"ISO-10303-21" not in data[:200]:
        raise InputError(f"{p}: not a STEP file (no ISO-10303-21 header)")
    # OpenCASCADE meshes in the file's length unit after reading: mm for STEP (the
    # reader converts to its mm session unit), the file's own unit for IGES
    unit_mm = 1.0 if kind == "step" else iges_unit_m(data) * 1e3
    glb = cascadio.load(data, file_type=kind, tol_linear=tess.linear_tol_mm / unit_mm,
                        tol_angular=math.radians(tess.angular_tol_deg),
                        merge_primitives=kind == "step")
    if not glb:
        raise InputError(f"{p}: OpenCASCADE could not read or mesh this {kind.upper()} file")
    fd, tmp = tempfile.mkstemp(suffix=".glb", prefix="lightsim-cad-")
    with os.fdopen(fd, "wb") as f:
        f.write(glb)
    return Path(tmp)


def _has_ocp() -> bool:
    return have_ocp()


BACKENDS = ("auto", "xcaf", "cascadio")


def _read_in_child(path: Path, tess: Tessellation) -> tuple[bool, Any]:
    try:
        return True, read_xcaf(path, tess)
    except InputError as exc:
        return False, str(exc)
    except Exception as exc:  # the parent reports it in one line
        return False, (f"{path}: OpenCASCADE cannot read the file "
                       f"({type(exc).__name__}: {exc})")


def _limit_cpu(seconds: float) -> None:
    """Let this process use ``seconds`` more processor time, then SIGXCPU ends it."""
    if resource is None:
        return
    use = resource.getrusage(resource.RUSAGE_SELF)
    soft = math.ceil(use.ru_utime + use.ru_stime + seconds)
    _, hard = resource.getrlimit(resource.RLIMIT_CPU)
    if hard != resource.RLIM_INFINITY and soft > hard:
        return
    resource.setrlimit(resource.RLIMIT_CPU, (soft, hard))


def _child_main(argv: list[str]) -> int:
    """The child process: ``PATH LINEAR_TOL ANGULAR_TOL CPU_LIMIT RESULT``; the parts (or
    the one-line reason) go pickled to RESULT."""
    path, lin, ang, cpu, result = argv
    faulthandler.disable()  # a crash is reported by the parent, in one line
    _limit_cpu(float(cpu))  # counted from here: the imports are not the reader's
    payload = _read_in_child(Path(path), Tessellation(float(lin), float(ang)))
    with open(result, "wb") as fh:
        pickle.dump(payload, fh, pickle.HIGHEST_PROTOCOL)
    return 0


def read_isolated(path: Path, tess: Tessellation) -> list:
    """:func:`~lightsim.io.cad_xcaf.read_xcaf` in a child process with a time limit
    (``tess.time_limit_s``): a crash of OpenCASCADE's parser on a damaged file, or a
    read that does not end, becomes one :class:`InputError` line."""
    fd, result = tempfile.mkstemp(suffix=".pickle", prefix="lightsim-cad-")
    os.close(fd)
    # -P: the working folder is not put on the module path (a folder named like a
    # package there must not shadow lightsim)
    cmd = [sys.executable, "-P", "-m", "lightsim.io.cad", str(path), repr(tess.linear_tol_mm),
           repr(tess.angular_tol_deg), repr(tess.time_limit_s), result]
    too_long = (f"{path}: OpenCASCADE did not finish reading the file within "
                f"{tess.time_limit_s:g} s of processor time (a damaged file can make its "
                "reader loop; for a large sound file raise --cad-time-limit)")
    wall_s = WALL_FACTOR * tess.time_limit_s + 60.0
    try:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        try:
            code = proc.wait(wall_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            raise InputError(f"{too_long[:-1]}; given up after {wall_s:g} s on the "
                             "clock)") from None
        except BaseException:  # Ctrl-C: the child goes too
            proc.kill()
            proc.wait()
            raise
        raw = Path(result).read_bytes() if code == 0 else b""
    finally:
        Path(result).unlink(missing_ok=True)
    if code == -signal.SIGXCPU:
        raise InputError(too_long)
    if not raw:
        how = f"signal {-code}" if code < 0 else f"exit {code}"
        raise InputError(f"{path}: OpenCASCADE crashed reading the file ({how}): the file "
                         f"is damaged")
    ok, value = pickle.loads(raw)
    if not ok:
        raise InputError(value)
    return value


def read_cad(path: str | os.PathLike, tess: Tessellation | None = None,
             backend: str = "auto") -> list:
    """Parts of a STEP/IGES file as :class:`lightsim.io.gltf.GltfPrimitive` records.

    Parameters
    ----------
    path : path-like
        ``.step``/``.stp``/``.iges``/``.igs`` file.
    tess : Tessellation, optional
        Mesher tolerances (mm, deg); the defaults when omitted.
    backend : {"auto", "xcaf", "cascadio"}
        Reader (see the module docstring).

    Returns
    -------
    list of GltfPrimitive
        Names are the CAD names; positions in metres; normals from the exact surface.
        The XCAF reader adds ``extras["cad_faces"]``
        (:class:`lightsim.io.cad_xcaf.FaceLabels`).
    """
    tess = tess or Tessellation()
    if backend not in BACKENDS:
        raise InputError(f"CAD backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    p = Path(path)
    if p.suffix.lower() not in CAD_SUFFIXES:
        raise InputError(f"{p}: not a STEP or IGES file")
    if not p.is_file():
        raise InputError(f"{p}: no such file")
    ocp = _has_ocp()
    if backend == "xcaf" and not ocp:
        raise InputError("the XCAF CAD reader needs OpenCASCADE's Python binding: pip "
                         "install 'lightsim[cad-names]' (cadquery-ocp)")
    if backend == "xcaf" or (backend == "auto" and ocp):
        return read_isolated(p, tess)
    glb = tessellate(p, tess)
    try:
        parts = read_gltf(glb)
    finally:
        glb.unlink(missing_ok=True)
    if p.suffix.lower() in IGES_SUFFIXES and not ocp:
        scale = iges_unit_m(p.read_bytes())
        out = []
        for i, part in enumerate(parts):
            part.name = f"iges-{i + 1}"
            part.vertices = np.asarray(part.vertices, dtype=np.float64) * scale
            out.append(part)
        parts = out
    if not parts:
        raise InputError(f"{p}: no surfaces in this CAD file")
    return parts


if __name__ == "__main__":  # the reader's child process (read_isolated)
    sys.exit(_child_main(sys.argv[1:]))
