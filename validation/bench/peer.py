"""``lightsim bench peer``: time to a true 2 % error, Mitsuba 3's ``ptracer`` against lightsim.

Both tools render the same analytic scene, each as its own process timed by the wall
clock (interpreter start-up, imports, JIT/numba compilation, embree/LLVM builds, the run
and its output files), and both images are scored by the same metric against the exact
answer: the per-pixel relative rms (:func:`lightsim.validation.converge.error_metrics`)
over the pixels whose centre lies in the inner 80 % of the beam radius (``inner``: the
headline score and ratio) and over the lit pixels (``lit``: exact E ≥ 10 % of
its peak, the region lightsim's own error figure covers, rim included). Each tool's
time to the target is found on **both** scores (:data:`SCORES`) and both ratios are
reported: Mitsuba's spp is picked per score from its 1/√spp law, lightsim's
self-stopping run counts for a score when its true error there is below the target.

* **Mitsuba 3** (optional extra ``peer``: ``pip install ".[peer]"``; the ``llvm_ad_rgb``
  variant needs libLLVM ≥ 19, found at run time or given by ``DRJIT_LIBLLVM_PATH``):
  :mod:`~lightsim.validation.bench.peer_mitsuba` renders with the ``ptracer``
  integrator and a camera facing the Lambertian (albedo 1) wall, E = π L; the mirror is
  the same mesh with its analytic vertex normals. After a first render at ``spp0`` the
  spp is set from the 1/√spp noise law to land 3 % below the target on the inner
  score, then on the lit one (and raised again while above it); every render is one
  process and is reported. Knowing the right spp
  in advance favours Mitsuba; lightsim has to find its stopping point itself.
* **lightsim**: ``lightsim simulate SCENE.glb --target-error T`` (the scene written as
  glTF) stops by itself, once per score with its figure over that score's region
  (:data:`REGION_ARGS`: ``--error-region interior`` — the lit pixels 0.2 × √(A/π) inside
  the beam's edge, a round beam's inner 80 % — for the inner score, the lit pixels for
  the lit one); reported are its time, its own error estimate at the stop and the true
  error of the map it wrote (``wall_lux.exr``). With ``ladder`` it then runs
  fixed ``--photons N`` budgets (N from the 1/√N law) until the true error is below the
  target on each score: what a stop at the true target would cost, next to where it did
  stop.

Scenes (:data:`CASES`): ``paraboloid`` — point source at the focus of a paraboloid
(f = 20 mm, rim 30 mm, R = 0.88), wall 0.5 m from the vertex, 64 × 64 pixels of
0.94 mm; ``covered`` — the same behind a 4 mm cover glass (n = 1.5), exact through the
plate's transmittance at normal incidence.

=================  =====  =========  ===============================================
parameter          unit   default    meaning
=================  =====  =========  ===============================================
``target``         —      0.02       relative rms error to reach
``resolution``     px     64         wall pixels per side (0.06 m / 64 = 0.94 mm)
``inner``          —      0.8        scored pixels: centre within inner × rim radius
``spp0``           —      4          Mitsuba's first samples per pixel (then × 2)
``max_seconds``    s      300        cap of one run of either tool
=================  =====  =========  ===============================================
"""

from __future__ import annotations

import ctypes.util
import glob
import importlib.util
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.io.exr import read_exr
from lightsim.luminaires.gltf_writer import write_glb
from lightsim.luminaires.live import scene_gltf_parts
from lightsim.materials import DIELECTRIC, MIRROR
from lightsim.scene import EMITTER, WALL
from lightsim.validation.converge import error_metrics
from lightsim.validation.scenes import analytic as an

#: the scenes of the bench: name → builder(resolution) of the analytic case
CASES: dict[str, Callable[[int], an.AnalyticScene]] = {
    "paraboloid": lambda n: an.paraboloid_case(
        f=0.02, rim=0.03, reflectance=0.88, wall_distance=0.5, wall_size=0.06,
        resolution=(n, n), radial=128, azimuthal=512),
    "covered": lambda n: an.covered_paraboloid_case(resolution=(n, n)),
}
#: Mitsuba path length (segments incl. the camera connection): light → mirror → wall →
#: camera, plus the two plate crossings of the covered case. Longer paths would add
#: wall → mirror → wall inter-reflections, which the exact answer (and lightsim's
#: absorbing detector wall) leave out; the covered case thereby also drops the plate's
#: second internal order (R² ≈ 0.2 % of the beam).
MAX_DEPTH = {"paraboloid": 3, "covered-paraboloid": 5}
MAX_MITSUBA_RUNS = 7  # renders per case at most (the spp ladder, both scores)
MAX_LADDER_RUNS = 3   # fixed-budget lightsim runs per case at most
CAMERA_DISTANCE = 0.1  # m: Mitsuba's camera in front of the wall (clear of all geometry)
#: the second score's pixels: exact E ≥ this × its peak — the lit region lightsim's own
#: error figure covers (rim included), next to the headline inner-80 % score
LIT_FRACTION = 0.1
#: the two scores every run is timed on: the headline inner one and the lit pixels
SCORES = ("inner", "lit")
#: lightsim's stop per score: its error figure over the beam's interior (the lit pixels
#: 0.2 × √(A/π) inside the edge: the inner 80 % of a round beam) or over the lit pixels
REGION_ARGS = {"inner": ("--error-region", "interior"), "lit": ()}


# =========================================================================== Mitsuba setup
def find_libllvm() -> str | None:
    """Path (or soname) of a libLLVM ≥ 19 for Dr.Jit's LLVM back end, or None.

    ``DRJIT_LIBLLVM_PATH`` wins when it names an existing file; otherwise the dynamic
    linker's names (``ctypes.util.find_library``) and the usual Debian/Ubuntu library
    folders are searched, newest version first.
    """
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and os.path.exists(env):
        return env
    found: list[tuple[int, str]] = []
    for name in ("LLVM", *(f"LLVM-{v}" for v in range(30, 18, -1))):
        lib = ctypes.util.find_library(name)
        if lib:
            found.append((llvm_version(lib), lib))
    for pattern in ("/usr/lib/*-linux-gnu/libLLVM*.so*", "/usr/lib/llvm-*/lib/libLLVM*.so*",
                    "/usr/lib64/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*"):
        found += [(llvm_version(p), p) for p in glob.glob(pattern)]
    found = [f for f in found if f[0] >= 19]
    return max(found)[1] if found else None


def llvm_version(name: str) -> int:
    """The major version in a libLLVM file name or soname (0 when it names none)."""
    m = re.search(r"LLVM(?:-|\.so\.)(\d+)", os.path.basename(name))
    return int(m.group(1)) if m else 0


def mitsuba_unavailable() -> str | None:
    """One line saying why Mitsuba cannot run here, or None when it can."""
    if importlib.util.find_spec("mitsuba") is None:
        return "mitsuba is not installed (pip install \".[peer]\")"
    if find_libllvm() is None:
        return ("no libLLVM ≥ 19 for Mitsuba's llvm_ad_rgb variant (Debian: apt install "
                "libllvm19, or set DRJIT_LIBLLVM_PATH)")
    return None


def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray,
              normals: np.ndarray | None = None) -> Path:
    """Binary little-endian PLY (float32 positions, optional normals, int32 triangles)."""
    v = np.asarray(vertices, np.float32)
    cols = [v] if normals is None else [v, np.asarray(normals, np.float32)]
    props = ["x", "y", "z"] + ([] if normals is None else ["nx", "ny", "nz"])
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(v)}"]
    head += [f"property float {p}" for p in props]
    head += [f"element face {len(faces)}", "property list uchar int vertex_indices",
             "end_header"]
    f = np.asarray(faces, np.int64)
    tri = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    tri["n"] = 3
    tri["i"] = f
    with open(path, "wb") as fh:
        fh.write(("\n".join(head) + "\n").encode())
        fh.write(np.ascontiguousarray(np.hstack(cols), "<f4").tobytes())
        fh.write(tri.tobytes())
    return path


def mitsuba_spec(case: an.AnalyticScene, folder: Path, spp: int, seed: int = 0
                 ) -> dict[str, Any]:
    """The :mod:`peer_mitsuba` spec of ``case`` (PLY meshes written into ``folder``)."""
    meshes = []
    light = None
    for i, p in enumerate(case.scene.parts):
        if p.role == EMITTER:
            centre = p.vertices.mean(axis=0)
            light = {"position": [float(x) for x in centre],
                     "intensity": float(p.flux_lm) / (4 * math.pi)}
            continue
        m = p.material
        if p.role == WALL:
            bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1.0] * 3}}
        elif m.kind == MIRROR:
            bsdf = {"type": "conductor", "material": "none",
                    "specular_reflectance": {"type": "rgb",
                                             "value": [float(x) for x in m.rgb]}}
        elif m.kind == DIELECTRIC:
            bsdf = {"type": "dielectric", "int_ior": float(m.ior), "ext_ior": 1.0}
        else:
            bsdf = {"type": "diffuse", "reflectance": {"type": "rgb",
                                                       "value": [float(x) for x in m.rgb]}}
        if bsdf["type"] != "dielectric":  # one-sided in Mitsuba; both faces like ours
            bsdf = {"type": "twosided", "bsdf": bsdf}
        ply = write_ply(folder / f"part{i}.ply", p.vertices, p.faces, p.normals)
        meshes.append({"ply": str(ply), "bsdf": bsdf, "face_normals": p.normals is None})
    frame = case.frame
    (h0, h1), (v0, v1) = frame.h_range_m, frame.v_range_m
    half_h = 0.5 * (h1 - h0)
    c = frame.centre + 0.5 * (h0 + h1) * frame.h_axis + 0.5 * (v0 + v1) * frame.v_axis
    n = frame.normal  # towards the lamp
    return {"meshes": meshes, "light": light, "resolution": list(frame.resolution),
            "camera": {"origin": [float(x) for x in c + CAMERA_DISTANCE * n],
                       "target": [float(x) for x in c], "up": [float(x) for x in frame.v_axis],
                       "fov": math.degrees(2 * math.atan(half_h / CAMERA_DISTANCE)),
                       "near_clip": 1e-3},
            "spp": int(spp), "max_depth": MAX_DEPTH[case.name], "seed": int(seed)}


# =========================================================================== lightsim setup
LIGHTSIM_OUTPUTS = "exr,json"
"""What the bench's lightsim runs write (``--outputs``): the map the score reads and the
summary (its own error, photons); the plots are left out as Mitsuba writes only its EXR.
A later ``--lightsim-arg --outputs …`` overrides it."""

def write_scene_glb(case: an.AnalyticScene, path: Path) -> Path:
    """The case's scene as glTF (the mirror with its analytic vertex normals)."""
    write_glb(path, scene_gltf_parts(case.scene))
    return path


# =========================================================================== scoring
@dataclass
class Truth:
    """Exact pixel means and the scored pixels of one case."""

    exact_px: np.ndarray  # (H, W) lx
    inner: np.ndarray     # (H, W) bool: the headline score (inner 80 % of the rim)
    lit: np.ndarray | None = None  # (H, W) bool: exact ≥ LIT_FRACTION × its peak

    def error(self, lux: np.ndarray, where: str = "inner") -> float:
        """Relative rms error of a lux map (H, W) over the ``inner`` pixels (the headline
        score) or the ``lit`` ones (what lightsim's own figure covers: the rim too)."""
        if lux.shape != self.exact_px.shape:
            raise ValueError(f"map {lux.shape} does not match the exact {self.exact_px.shape}")
        mask = self.inner if where == "inner" else self.lit
        return error_metrics(lux, self.exact_px, mask)["rel_rmse"]


def truth_of(case: an.AnalyticScene, inner: float = 0.8) -> Truth:
    """Exact pixel means of ``case`` and its pixels within ``inner`` × the rim radius."""
    fr = case.frame
    px = case.pixel_means(fr) if case.pixel_means is not None else an.pixel_average(
        case.exact, fr)
    h, v = fr.pixel_centres()
    hh, vv = np.meshgrid(h, v)
    rim = float(case.params["rim_radius_m"])
    return Truth(px, np.hypot(hh, vv) < inner * rim, px >= LIT_FRACTION * px.max())


# =========================================================================== runs
@dataclass
class PeerRun:
    """One timed process of either tool."""

    case: str
    tool: str
    setting: str
    seconds: float          # wall clock of the whole process
    paths: int              # light paths (Mitsuba) or photons (lightsim) traced
    true_error: float       # relative rms against the exact answer (inner pixels)
    own_error: float | None = None  # lightsim's own estimate at the stop
    true_error_lit: float | None = None  # the same over the lit pixels (≥ 10 % of peak)
    phases: dict[str, float] | None = None  # lightsim: summary.json["timings_s"] (s)
    ok: bool = True
    note: str = ""
    lux: np.ndarray | None = field(default=None, repr=False)

    def score(self, where: str) -> float:
        """The true error on score ``where`` (``inner`` or ``lit``; NaN without it)."""
        e = self.true_error if where == "inner" else self.true_error_lit
        return math.nan if e is None else float(e)

    def row(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("lux")
        d.pop("phases")
        return d

    def breakdown(self) -> dict[str, Any] | None:
        """Where a lightsim process's wall time went (s): ``startup`` (interpreter, imports,
        option parsing: the process's time outside ``run_simulation``'s phases) and the
        phases of ``summary.json["timings_s"]``; None without them."""
        if not self.phases:
            return None
        inside = sum(self.phases.values())
        return {"case": self.case, "setting": self.setting, "process_s": self.seconds,
                "startup": max(self.seconds - inside, 0.0), **self.phases}


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    lib = find_libllvm()
    if lib:
        env.setdefault("DRJIT_LIBLLVM_PATH", lib)
    return env


def run_mitsuba(case: an.AnalyticScene, truth: Truth, folder: Path, spp: int,
                seed: int = 0, timeout: float = 300.0) -> PeerRun:
    """One Mitsuba render as its own process, timed and scored."""
    spec = mitsuba_spec(case, folder, spp, seed)
    spec["out"] = str(folder / f"mitsuba-{spp}.npy")
    spec_path = folder / f"mitsuba-{spp}.json"
    spec_path.write_text(json.dumps(spec))
    cmd = [sys.executable, "-m", "lightsim.validation.bench.peer_mitsuba", str(spec_path)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=_child_env(), capture_output=True, text=True,
                          timeout=timeout, check=False)
    dt = time.perf_counter() - t0
    W, H = case.frame.resolution
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["?"])[-1]
        return PeerRun(case.name, "mitsuba", f"spp {spp}", dt, spp * W * H, math.nan,
                       ok=False, note=last[:160])
    lux = np.load(spec["out"])
    return PeerRun(case.name, "mitsuba", f"ptracer spp {spp}", dt, spp * W * H,
                   truth.error(lux), true_error_lit=truth.error(lux, "lit"), lux=lux)


def run_lightsim(case: an.AnalyticScene, truth: Truth, folder: Path, target: float,
                 extra_args: Sequence[str] = (), timeout: float = 300.0,
                 photons: int | None = None) -> PeerRun:
    """``lightsim simulate SCENE --target-error target`` as its own process (or, given
    ``photons``, ``--photons N``: a fixed budget, for the time to a true error)."""
    glb = folder / "scene.glb"
    if not glb.exists():
        write_scene_glb(case, glb)
    out = folder / "lightsim-out"
    W, H = case.frame.resolution
    budget = (["--target-error", f"{target:g}"] if photons is None
              else ["--photons", str(int(photons))])
    # like Mitsuba, which writes only its image: the map and the summary, no plots
    cmd = [sys.executable, "-m", "lightsim.cli.main", "simulate", str(glb), *budget,
           "--resolution", f"{W}x{H}", "--out", str(out), "--quiet", "--time",
           f"{timeout:g}", "--outputs", LIGHTSIM_OUTPUTS, *extra_args]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout + 120,
                          check=False)
    dt = time.perf_counter() - t0
    setting = " ".join([*budget, *extra_args])
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["?"])[-1]
        return PeerRun(case.name, "lightsim", setting, dt, 0, math.nan, ok=False,
                       note=last[:160])
    summary = json.loads((out / "summary.json").read_text())
    lux = read_exr(out / "wall_lux.exr")[0]["Y"].astype(np.float64)
    own = summary.get("rel_error")
    return PeerRun(case.name, "lightsim", setting, dt, int(summary["photons"]),
                   truth.error(lux), None if own is None else float(own),
                   truth.error(lux, "lit"), phases=summary.get("timings_s"), lux=lux)


@dataclass
class PeerResult:
    """All runs of one case and the comparison."""

    case: str
    runs: list[PeerRun]
    mitsuba_seconds: float | None   # first Mitsuba run below the target (inner score)
    lightsim_seconds: float | None  # lightsim's self-stop, if below the target there
    ratio: float | None             # Mitsuba time / lightsim time (target ≥ 3)
    lightsim_reached: bool | None   # lightsim's true error at its stop is below the target
    stopped_near_target: bool | None  # lightsim's true error within ±10 % of the target
    lightsim_fixed_seconds: float | None = None  # first fixed budget below the target
    ratio_fixed: float | None = None             # Mitsuba time / that time
    # the same on the lit-pixel score (what lightsim's own figure covers, rim included)
    mitsuba_seconds_lit: float | None = None
    lightsim_seconds_lit: float | None = None
    ratio_lit: float | None = None
    lightsim_reached_lit: bool | None = None
    lightsim_fixed_seconds_lit: float | None = None
    ratio_fixed_lit: float | None = None
    #: lightsim's self-stopping run of each score (``--error-region`` of REGION_ARGS)
    stops: dict[str, PeerRun] = field(default_factory=dict)


def run_case(name: str, *, target: float = 0.02, resolution: int = 64, spp0: int = 4,
             max_seconds: float = 300.0, lightsim_args: Sequence[str] = (),
             mitsuba: bool = True, ladder: bool = True, folder: Path | None = None,
             progress: Callable[[str], None] | None = None) -> PeerResult:
    """Both tools on case ``name`` until each reaches ``target`` (see module doc).

    ``ladder``: after the self-stopping run, lightsim also runs fixed photon budgets
    (``--photons N`` from the 1/√N law) until its true error is below the target on each
    score: the time a stop at the true target would take (``lightsim_fixed_seconds``,
    ``lightsim_fixed_seconds_lit``).
    """
    case = CASES[name](resolution)
    truth = truth_of(case)
    runs: list[PeerRun] = []
    with tempfile.TemporaryDirectory(prefix="lightsim-peer-") as tmp:
        work = Path(folder or tmp)
        work.mkdir(parents=True, exist_ok=True)
        t_m: dict[str, float | None] = dict.fromkeys(SCORES)
        if mitsuba:
            spp = spp0
            for _ in range(MAX_MITSUBA_RUNS):
                r = run_mitsuba(case, truth, work, spp, timeout=max_seconds)
                runs.append(r)
                if progress:
                    progress(f"{name}: mitsuba spp {spp}: {r.seconds:.1f} s, error "
                             f"{r.true_error:.4f} (lit {r.score('lit'):.4f}) {r.note}")
                if not r.ok:
                    break
                for k in SCORES:
                    if t_m[k] is None and r.score(k) < target:
                        t_m[k] = r.seconds
                if all(t is not None for t in t_m.values()) or r.seconds > max_seconds:
                    break
                # noise ∝ 1/√spp, for the first score not reached yet: aim just below the
                # target (3 %), so that Mitsuba's time is that of about the target error
                err = r.score(next(k for k in SCORES if t_m[k] is None))
                spp = max(spp + 1, math.ceil(spp * (err / (0.97 * target)) ** 2))
        # one self-stopping run per score, its figure over that score's region
        stops: dict[str, PeerRun] = {}
        for k in SCORES:
            lr = run_lightsim(case, truth, work, target, [*REGION_ARGS[k], *lightsim_args],
                              timeout=max_seconds)
            runs.append(lr)
            stops[k] = lr
            if progress:
                progress(f"{name}: lightsim ({k} stop): {lr.seconds:.1f} s, own error "
                         f"{lr.own_error}, true {lr.true_error:.4f} "
                         f"(lit {lr.score('lit'):.4f}) {lr.note}")
        t_fixed: dict[str, float | None] = dict.fromkeys(SCORES)
        if ladder:
            for k in SCORES:
                if stops[k].ok and stops[k].paths > 0:
                    t_fixed[k] = _ladder(case, truth, work, target, lightsim_args,
                                         max_seconds, stops[k], k, runs, progress)
    reached = {k: (bool(stops[k].score(k) < target) if stops[k].ok else None)
               for k in SCORES}
    t_l = {k: stops[k].seconds if reached[k] else None for k in SCORES}
    ratio = {k: t_m[k] / t_l[k] if (t_m[k] is not None and t_l[k]) else None for k in SCORES}
    ratio_fixed = {k: t_m[k] / t_fixed[k] if (t_m[k] is not None and t_fixed[k]) else None
                   for k in SCORES}
    near = _near(stops["inner"].true_error, target, stops["inner"].ok)
    return PeerResult(name, runs, t_m["inner"], t_l["inner"], ratio["inner"],
                      reached["inner"], near, t_fixed["inner"], ratio_fixed["inner"],
                      t_m["lit"], t_l["lit"], ratio["lit"], reached["lit"], t_fixed["lit"],
                      ratio_fixed["lit"], stops)


def _ladder(case: an.AnalyticScene, truth: Truth, work: Path, target: float,
            lightsim_args: Sequence[str], max_seconds: float, lr: PeerRun, where: str,
            runs: list[PeerRun], progress: Callable[[str], None] | None) -> float | None:
    """Fixed photon budgets from the 1/√N law (bias may break it: raised again while
    above the target), starting from the self-stopping run ``lr``, until the true error
    on score ``where`` is below ``target``: the seconds of that run (None if none got
    there). Every run is appended to ``runs``."""
    n, err = lr.paths, lr.score(where)
    for _ in range(MAX_LADDER_RUNS):
        n = max(1000, math.ceil(n * (err / (0.97 * target)) ** 2))
        fr = run_lightsim(case, truth, work, target, lightsim_args, timeout=max_seconds,
                          photons=n)
        runs.append(fr)
        if progress:
            progress(f"{case.name}: lightsim --photons {n} ({where}): {fr.seconds:.1f} s, "
                     f"true {fr.score(where):.4f} {fr.note}")
        if not fr.ok:
            return None
        err = fr.score(where)
        if err < target:
            return fr.seconds
        n = fr.paths
    return None


PEER_COLUMNS = ["case", "tool", "setting", "seconds", "paths", "true_error",
                "true_error_lit", "own_error",
                "ok", "note"]


def _near(e: float | None, target: float, ok: bool = True) -> bool | None:
    """Whether ``e`` lies within ±10 % of ``target`` (None without a figure)."""
    return None if e is None or not ok else bool(abs(e - target) <= 0.1 * target)


def summary_rows(results: Sequence[PeerResult], target: float) -> list[dict[str, Any]]:
    """One row per case: the two times to target, their ratio (Mitsuba / lightsim) and
    the stop check (``ls_*``: lightsim; ``ls_fixed_s``: its first fixed budget with a
    true error below ``target``; ``ratio_vs_fixed``: Mitsuba's time over that), on the
    inner score (the headline) and the same with ``_lit`` on the lit-pixel score
    (``lightsim_s_lit`` None: the self-stop's lit-pixel error is not below the target).
    Both tools' true errors at their stops over the scored inner pixels (``*_err``) and
    over the lit pixels (``*_err_lit``, what lightsim's own figure covers);
    ``ls_own_within_10pct``: lightsim's own figure at the stop is within ±10 % of the
    target (the stop lands on it), ``ls_stop_within_10pct`` the same for the true error
    over the inner pixels, ``ls_lit_within_10pct`` over the lit ones."""
    rows = []
    for res in results:
        lr, ll = res.stops["inner"], res.stops["lit"]
        mr = next((r for r in res.runs if r.tool == "mitsuba" and r.ok
                   and r.seconds == res.mitsuba_seconds), None)

        rows.append({"case": res.case, "mitsuba_s": res.mitsuba_seconds,
                     "mitsuba_err": None if mr is None else mr.true_error,
                     "mitsuba_err_lit": None if mr is None else mr.true_error_lit,
                     "lightsim_s": lr.seconds, "ls_true_err": lr.true_error,
                     "ls_true_err_lit": lr.true_error_lit,
                     "ls_own_err": lr.own_error, "ratio": res.ratio, "ratio_goal": 3.0,
                     "ls_true_below": res.lightsim_reached,
                     "ls_own_within_10pct": _near(lr.own_error, target, lr.ok),
                     "ls_stop_within_10pct": res.stopped_near_target,
                     "ls_lit_within_10pct": _near(ll.true_error_lit, target, ll.ok),
                     "ls_own_err_lit": ll.own_error,
                     "ls_true_err_lit_stop": ll.true_error_lit,
                     "ls_fixed_s": res.lightsim_fixed_seconds,
                     "ratio_vs_fixed": res.ratio_fixed,
                     "mitsuba_s_lit": res.mitsuba_seconds_lit,
                     "lightsim_s_lit": res.lightsim_seconds_lit, "ratio_lit": res.ratio_lit,
                     "ls_true_below_lit": res.lightsim_reached_lit,
                     "ls_fixed_s_lit": res.lightsim_fixed_seconds_lit,
                     "ratio_vs_fixed_lit": res.ratio_fixed_lit})
    return rows
