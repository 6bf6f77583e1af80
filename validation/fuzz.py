"""Input fuzzing: a seeded mutation corpus of every input lightsim reads, each run through the
real command line, each result judged by the input-error promise.

Input kinds (``KINDS``) and how each case runs:

==============  ===========================================  ================================
kind            seed and mutations                           run as
==============  ===========================================  ================================
``glb``         a small lamp (and the shipped headlight);    ``simulate CASE``
                bytes, BIN chunk, targeted and random
                glTF JSON edits, ``.gltf`` text
``ies``/``ldt``  the shipped IES sample (and it as LDT);      ``simulate CASE``
                header numbers, deleted lines, bytes
``photo``       synthetic JPEG/PNG/TIFF photos; bytes, TIFF  ``compare CASE --sim …``
                tags
``step``        the example CAD headlamp (OpenCASCADE);      ``simulate CASE --materials …``
``iges``        numbers, entity lines deleted or doubled,
                bytes
``materials``   a material map (TOML) of the small lamp;     ``simulate lamp --materials CASE``
                values, keys, TOML syntax, bytes
``tm25``        a Lambertian square as a TM-25 ray file /    ``simulate CASE``; ``simulate
``zemax``       a Zemax binary source file; header fields,   lamp --rayfile CASE`` (the ray
                ray records, bytes                           file is the light source)
``points``      ``--points`` control points of a synthetic   ``compare PHOTO --points CASE``
                photo; numbers, separators, counts
``state``       a view ``state.json``; JSON edits, bytes     ``view lamp --state CASE`` (a
                                                             process, :mod:`.fuzz_view`)
``ws``          WebSocket messages of the page (edits,       sent to a running ``view``
                tabs, saves); JSON edits, bytes, nesting     (:mod:`.fuzz_view`)
==============  ===========================================  ================================

Commands run in a worker process, with stdout and stderr captured at the file-descriptor
level (so C libraries' and numpy's warning lines count too) and a time limit per case.

A case **passes** when either

* exit 0, no stderr line other than ``lightsim: warning: …``, the complete output set
  (``summary.json`` present, no temporary or staging leftovers), every lux value finite
  and the energy budget closed (``summary.json["energy_lm"]["closure_relative"]`` ≤ 1e-6;
  compare: every number in ``comparison.json`` finite), or
* exit 2, exactly one stderr line ``lightsim: error: …``, no traceback, no file in
  ``--out``.

For the view the same promise in its terms (:mod:`lightsim.validation.fuzz_view`): a bad
state file exits 2 with one line, a good one starts the session; a bad message gets one
error line in the page, a good one is acted on (a saved run with a closed energy budget).

Everything else is a failure with a class: ``traceback``, ``lines`` (exit 2 with more or
fewer than one line), ``leftover`` (files after an error), ``stray`` (extra stderr lines
on success), ``nonfinite``, ``energy``, ``incomplete``, ``exit`` (another code),
``timeout``, ``crash`` (the worker died).

============================  =====  ==========  ===========================================
parameter                     unit   default     meaning
============================  =====  ==========  ===========================================
``n``                         –      –           number of cases
``seed``                      –      1           corpus seed (case i depends on seed and i)
``kinds``                     –      all         ``KINDS`` (taken in turn)
``photons``                   –      20 000      ``simulate --photons`` (and per frame)
``resolution``                px     64x32       ``simulate --resolution``
``timeout_s``                 s      180         per case; the worker is restarted after it
                                                 (a CAD case's reader gets a sixth of
                                                 it in processor seconds, ``simulate
                                                 --cad-time-limit``: on a busy machine
                                                 the wall clock runs several times
                                                 faster than a process's CPU time)
``headlight``                 –      False       also mutate the shipped headlight GLB (slow)
``command``                   –      –           the command line's entry point, run in the
                                                 worker process (:data:`Command`)
============================  =====  ==========  ===========================================

Command line: ``lightsim fuzz N [--seed S] [--kind glb] [--json FILE]``; the test suite
runs a few dozen cases by default and a few hundred in the ``slow`` study
(``tests/validation/test_fuzz.py``).
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import logging
import math
import multiprocessing as mp
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
import trimesh

from lightsim.errors import InputError
from lightsim.io.atomic import STAGING_PREFIX, TEMP_RE
from lightsim.io.exr import read_exr
from lightsim.io.rayfile import (
    TM25_FILE_HEADER,
    TM25_FLAGS,
    TM25_TEXT_BYTES,
    TM25_TEXTS,
    ZEMAX_HEADER,
    write_tm25,
    write_zemax,
)
from lightsim.luminaires.cad_example import write_example
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, glb_bytes
from lightsim.luminaires.headlight import example_headlight
from lightsim.luminaires.photometric import SAMPLE_IES, read_ies, write_ldt
from lightsim.luminaires.rayfiles import lambertian_square
from lightsim.scene import SceneSettings, load_scene
from lightsim.simulate import folder_notes
from lightsim.validation.fuzz_view import MessageTarget, judge_state
from lightsim.validation.synthetic_photo import (
    CameraSettings,
    lowbeam_lux,
    render_photo,
    wall_frame,
    write_photo,
    write_result,
)
from lightsim.view.editor import SceneEditor

KINDS = ("glb", "ies", "ldt", "photo", "step", "iges", "materials", "tm25", "zemax",
         "points", "state", "ws")
VIEW_KINDS = ("state", "ws")
TM25_BLOCK = TM25_FILE_HEADER + TM25_FLAGS + TM25_TEXTS * TM25_TEXT_BYTES  # before the rays
SIM_OUTPUTS = frozenset({"summary.json", "wall_lux.exr", "wall_lux.png", "error_vs_time.png",
                         "isolux.png", "road.png"})
COMPARE_OUTPUTS = frozenset({"comparison.json", "overlay.png", "difference.png",
                             "contours.png"})
CLOSURE_TOL = 1e-6
#: the command line's in-process entry point, ``command(argv)`` running ``lightsim argv`` and
#: ending in ``SystemExit`` (:func:`lightsim.cli.main.main`; ``lightsim fuzz`` hands it over)
Command = Callable[[list[str]], object]

# values a corrupt writer might put in a field
_PALETTE: tuple[Any, ...] = (None, "red", "", -1, 0, 1, 2**31, 2**53, 1e30, -1e30, 1e-30,
                             math.nan, math.inf, -math.inf, [], {}, True, [1e30, 1e30, 1e30],
                             [math.nan] * 3, -0.5, 3.5, 5123, 5120)
_NUM_TOKENS = ("nan", "inf", "-inf", "-1", "0", "1e30", "1e-30", "abc", "99999999", "2",
               "3", "1.5", "-0", "1e400", "")


# --------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------

@dataclass
class FuzzCase:
    """One mutated input and the command that runs it."""

    index: int
    kind: str
    mutation: str
    filename: str
    data: bytes

    def label(self) -> str:
        return f"#{self.index} {self.kind}: {self.mutation}"


@dataclass
class CaseResult:
    """The outcome of one case: exit code, stderr lines and the verdict."""

    case: FuzzCase
    exit_code: int | None
    stderr: list[str]
    seconds: float
    verdict: str            # "ran", "rejected" or a failure class
    detail: str = ""

    @property
    def ok(self) -> bool:
        return self.verdict in ("ran", "rejected")

    def describe(self) -> str:
        first = self.stderr[-1] if self.stderr else ""
        return (f"{self.case.label()} → exit {self.exit_code}, {len(self.stderr)} stderr "
                f"line(s): {self.verdict} {self.detail} | {first[:160]}")


@dataclass
class FuzzReport:
    """Every case's result and the counts by kind and verdict."""

    seed: int
    results: list[CaseResult] = field(default_factory=list)

    @property
    def failures(self) -> list[CaseResult]:
        return [r for r in self.results if not r.ok]

    def counts(self) -> dict[str, dict[str, int]]:
        """{kind: {verdict: count}} including a "total" row."""
        out: dict[str, dict[str, int]] = {}
        for r in self.results:
            for key in (r.case.kind, "total"):
                out.setdefault(key, Counter())[r.verdict] += 1
        return {k: dict(v) for k, v in out.items()}

    def table(self) -> list[str]:
        verdicts = sorted({r.verdict for r in self.results},
                          key=lambda v: (v not in ("ran", "rejected"), v))
        rows = [["kind", "cases", *verdicts]]
        counts = self.counts()
        for kind in [*KINDS, "total"]:
            if kind in counts:
                c = counts[kind]
                rows.append([kind, str(sum(c.values())), *(str(c.get(v, 0)) for v in verdicts)])
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        return ["  ".join(x.rjust(w) for x, w in zip(r, widths)) for r in rows]

    def to_json(self) -> dict[str, Any]:
        return {"seed": self.seed, "counts": self.counts(),
                "cases": [{"index": r.case.index, "kind": r.case.kind,
                           "mutation": r.case.mutation, "exit_code": r.exit_code,
                           "verdict": r.verdict, "detail": r.detail, "stderr": r.stderr,
                           "seconds": round(r.seconds, 3)} for r in self.results]}


# --------------------------------------------------------------------------------------
# seeds: valid inputs built here (nothing outside the repository is read)
# --------------------------------------------------------------------------------------

def small_scene_glb() -> bytes:
    """A small valid luminaire: a 1000 lm emitter, a glass plate (with volume absorption
    and normals) and a mirror, as a GLB (m, lm)."""
    ico = trimesh.creation.icosphere(1, radius=1e-3)
    plate = trimesh.creation.box((0.2, 0.2, 0.01))
    plate.apply_translation((0.0, 0.0, 0.1))
    mirror = trimesh.creation.box((0.3, 0.3, 0.01))
    mirror.apply_translation((0.0, 0.0, -0.1))
    parts = [
        GltfPart("filament", np.asarray(ico.vertices), np.asarray(ico.faces), None,
                 GltfMaterial("filament", emissive=(1.0, 1.0, 1.0)),
                 extras={"lightsim": {"flux_lm": 1000.0}}),
        GltfPart("lens", np.asarray(plate.vertices), np.asarray(plate.faces),
                 np.asarray(plate.vertex_normals),
                 GltfMaterial("glass", transmission=1.0, ior=1.5, attenuation_distance=0.1,
                              attenuation_color=(0.9, 0.9, 0.9))),
        GltfPart("reflector", np.asarray(mirror.vertices), np.asarray(mirror.faces), None,
                 GltfMaterial("chrome", base_color=(0.9, 0.9, 0.9), metallic=1.0),
                 translation=(0.0, 0.01, 0.0)),
    ]
    return glb_bytes(parts)


def headlight_glb() -> bytes:
    """The shipped example headlight (``luminaires/examples/headlight.glb``)."""
    return example_headlight().read_bytes()


def split_glb(raw: bytes) -> tuple[dict[str, Any], bytes]:
    """(JSON document, BIN chunk) of a well-formed GLB."""
    json_len = struct.unpack_from("<I", raw, 12)[0]
    doc = json.loads(raw[20:20 + json_len].decode("utf-8"))
    rest = raw[20 + json_len:]
    blob = rest[8:8 + struct.unpack_from("<I", rest, 0)[0]] if len(rest) >= 8 else b""
    return doc, blob


def pack_glb(doc: dict[str, Any], blob: bytes) -> bytes:
    """A GLB from a JSON document (NaN/inf written as JSON extensions) and a BIN chunk."""
    js = json.dumps(doc, allow_nan=True).encode("utf-8")
    js += b" " * (-len(js) % 4)
    blob = blob + b"\0" * (-len(blob) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js
    if blob:
        body += struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def to_gltf_text(doc: dict[str, Any], blob: bytes) -> bytes:
    """The same scene as a .gltf JSON file with the buffer as a base64 data URI."""
    doc = json.loads(json.dumps(doc))
    if doc.get("buffers"):
        doc["buffers"][0]["uri"] = ("data:application/octet-stream;base64,"
                                    + base64.b64encode(blob).decode("ascii"))
    return json.dumps(doc, allow_nan=True).encode("utf-8")


def sample_ies() -> bytes:
    """The shipped, published IES sample (see ``luminaires/photometric/SAMPLES.md``)."""
    return SAMPLE_IES.read_bytes()


def sample_ldt(workdir: Path) -> bytes:
    """The IES sample rewritten as EULUMDAT by lightsim's writer."""
    path = workdir / "seed.ldt"
    write_ldt(path, read_ies(SAMPLE_IES))
    return path.read_bytes()


def photo_seeds(workdir: Path) -> tuple[Path, dict[str, bytes]]:
    """A synthetic result folder and photos of it (JPEG, 8-bit PNG, 16-bit TIFF)."""
    frame = wall_frame((96, 40))
    lux = lowbeam_lux(frame)
    sim = write_result(workdir / "sim", lux, frame)
    out: dict[str, bytes] = {}
    for suffix, bits in ((".jpg", 8), (".png", 8), (".tif", 16)):
        shot = render_photo(lux, CameraSettings(rotate_deg=2.0, noise=0.01, bits=bits, seed=3))
        path, side = write_photo(workdir / f"seed{suffix}", shot)
        out[suffix] = path.read_bytes()
        side.unlink()
    return sim, out


def material_map_seed() -> str:
    """A material map (TOML) of :func:`small_scene_glb`'s parts: the optics it gives them
    are those of the GLB, the filament's flux another (800 lm)."""
    return """schema = "lightsim-materials-1"
title = "small lamp"

[[rule]]
match = "filament*"
kind = "emitter"
flux_lm = 800
emission = "isotropic"

[[rule]]
match = "lens"
kind = "glass"
ior = 1.5
attenuation = 1.05

[[rule]]
match = "reflector"
kind = "mirror"
reflectance = 0.9
"""


def cad_seeds(workdir: Path, kinds: Sequence[str]) -> dict[str, tuple[bytes, Path]]:
    """The example CAD headlamp as STEP and/or IGES (OpenCASCADE's writers): {kind:
    (file bytes, its material map)}."""
    out = {}
    for kind in ("step", "iges"):
        if kind in kinds:
            mmap = write_example(workdir / f"seed.{kind}")
            out[kind] = ((workdir / f"seed.{kind}").read_bytes(), mmap)
    return out


def rayfile_seeds(workdir: Path, kinds: Sequence[str]) -> dict[str, bytes]:
    """A 1 mm Lambertian square of 400 rays (1000 lm) as a TM-25 and a Zemax ray file."""
    pos, dirs, flux = lambertian_square(1e-3, 400, 1000.0)
    out = {}
    if "tm25" in kinds:
        out["tm25"] = write_tm25(workdir / "seed.tm25ray", pos, dirs, flux).read_bytes()
    if "zemax" in kinds:
        out["zemax"] = write_zemax(workdir / "seed.dat", pos, dirs, flux).read_bytes()
    return out


def points_seed(photo_size: tuple[int, int], matrix: Any, frame: dict[str, Any]) -> str:
    """``--points`` of a synthetic photo: the four points at a quarter of its width and
    height from its corners, each with the screen angles its known transform (photo px →
    simulation px) and the wall frame (:func:`wall_frame`'s dict) give."""
    w, h = photo_size
    m = np.asarray(matrix, float)
    hr, vr, d = frame["h_range_m"], frame["v_range_m"], frame["distance_m"]
    nx, ny = frame["resolution"]
    parts = []
    for x, y in ((w / 4, h / 4), (3 * w / 4, h / 4), (3 * w / 4, 3 * h / 4), (w / 4, 3 * h / 4)):
        sx, sy, sw = m @ (x, y, 1.0)
        u, v = (sx / sw + 0.5) / nx, (sy / sw + 0.5) / ny  # pixel centres; row 0 at the top
        hm = hr[0] + u * (hr[1] - hr[0])
        vm = vr[1] - v * (vr[1] - vr[0])
        parts.append(f"{x:g},{y:g}={math.degrees(math.atan2(hm, d)):.3f},"
                     f"{math.degrees(math.atan2(vm, d)):.3f}")
    return "; ".join(parts)


def view_state_seed(controls: dict[str, Any], scene: str) -> bytes:
    """A ``state.json`` as the view writes it (scene and controls)."""
    return json.dumps({"scene": scene, "controls": controls}, indent=2).encode("utf-8")


def view_message_seeds(controls: dict[str, Any]) -> list[dict[str, Any]]:
    """Messages the page sends: an edit of each numeric control (a small step from the
    scene's value), a bulb change, both tabs, a save."""
    out: list[dict[str, Any]] = []
    for k, v in controls.items():
        if isinstance(v, bool):
            continue
        if isinstance(v, int | float):
            step = 1 if isinstance(v, int) else 0.1 * (abs(v) or 1.0)
            out.append({"type": "set", "changes": {k: v + step}, "token": len(out) + 1})
        elif isinstance(v, str):
            out.append({"type": "set", "changes": {k: v}, "token": len(out) + 1})
    out += [{"type": "view", "tab": "camera"}, {"type": "view", "tab": "wall"},
            {"type": "save"}]
    return out


# --------------------------------------------------------------------------------------
# mutations
# --------------------------------------------------------------------------------------

def flip_bytes(data: bytes, rng: np.random.Generator, lo: int = 0,
               hi: int | None = None) -> tuple[bytes, str]:
    b = bytearray(data)
    hi = len(b) if hi is None else min(hi, len(b))
    n = int(rng.integers(1, 9))
    for _ in range(n):
        i = int(rng.integers(lo, max(hi, lo + 1)))
        if i < len(b):
            b[i] ^= 1 << int(rng.integers(0, 8))
    return bytes(b), f"{n} bit flip(s) in bytes {lo}–{hi}"


def truncate(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    cut = int(rng.integers(0, max(len(data), 1)))
    return data[:cut], f"truncated to {cut} of {len(data)} bytes"


def duplicate_chunk(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    i = int(rng.integers(0, max(len(data), 1)))
    n = int(rng.integers(1, min(4096, max(len(data) - i, 1)) + 1))
    return data[:i + n] + data[i:i + n] + data[i + n:], f"bytes {i}+{n} duplicated"


def _bytes_mutation(data: bytes, rng: np.random.Generator, header: int) -> tuple[bytes, str]:
    r = rng.random()
    if r < 0.3:
        return flip_bytes(data, rng, 0, header)
    if r < 0.5:
        return flip_bytes(data, rng)
    if r < 0.8:
        return truncate(data, rng)
    return duplicate_chunk(data, rng)


def _leaves(obj: Any, path: tuple = ()) -> Iterator[tuple]:
    if isinstance(obj, dict):
        for k, v in obj.items():
            if path == () and k == "asset":
                continue
            yield from _leaves(v, (*path, k))
    elif isinstance(obj, list) and obj and not all(isinstance(x, int | float) for x in obj):
        for i, v in enumerate(obj):
            yield from _leaves(v, (*path, i))
    else:
        yield path


def _set(doc: Any, path: tuple, value: Any) -> None:
    for k in path[:-1]:
        doc = doc[k]
    doc[path[-1]] = value


def _pick(rng: np.random.Generator, seq: Sequence[Any]) -> Any:
    return seq[int(rng.integers(0, len(seq)))]


def _targeted_gltf_edits(doc: dict[str, Any]) -> list[tuple[str, Callable[[dict], None]]]:
    """Edits of the fields the loader reads (nodes, accessors, views, materials, scenes)."""
    edits: list[tuple[str, Callable[[dict], None]]] = []
    nodes = [i for i, n in enumerate(doc.get("nodes", [])) if "mesh" in n]
    for value, what in (([0.0, 0.0, 0.0], "scale 0"), ([1e30] * 3, "scale 1e30"),
                        ([1e-30] * 3, "scale 1e-30"), ([-1.0, 1.0, 1.0], "scale −1"),
                        ([1.0, 0.0, 1.0], "scale with a zero"), (["a", 1, 1], "scale text")):
        edits += [(f"node {i} {what}", lambda d, i=i, v=value: d["nodes"][i].update(scale=v))
                  for i in nodes]
    edits += [(f"node {i} translation 1e30",
               lambda d, i=i: d["nodes"][i].update(translation=[1e30, 0.0, 0.0])) for i in nodes]
    edits += [(f"node {i} rotation NaN",
               lambda d, i=i: d["nodes"][i].update(rotation=[math.nan, 0, 0, 1])) for i in nodes]
    edits += [(f"node {i} rotation zero quaternion",
               lambda d, i=i: d["nodes"][i].update(rotation=[0, 0, 0, 0])) for i in nodes]
    edits += [(f"node {i} matrix NaN",
               lambda d, i=i: d["nodes"][i].update(matrix=[math.nan] * 16)) for i in nodes]
    edits += [(f"node {i} singular matrix",
               lambda d, i=i: d["nodes"][i].update(matrix=[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0,
                                                           0, 0, 0, 1])) for i in nodes]
    edits += [(f"node {i} matrix of 15 numbers",
               lambda d, i=i: d["nodes"][i].update(matrix=[1.0] * 15)) for i in nodes]
    edits += [(f"node {i} mesh index 99", lambda d, i=i: d["nodes"][i].update(mesh=99))
              for i in nodes]
    edits += [(f"node {i} children cycle",
               lambda d, i=i: d["nodes"][i].update(children=[i])) for i in nodes]
    for a in range(len(doc.get("accessors", []))):
        for ct in (5120, 5121, 5122, 5123, 5125, 5126, 1234):
            edits.append((f"accessor {a} componentType {ct}",
                          lambda d, a=a, ct=ct: d["accessors"][a].update(componentType=ct)))
        for what, v in (("count +1", "+1"), ("count 0", 0), ("count 2**31", 2**31),
                        ("count −1", -1), ("count text", "x")):
            edits.append((f"accessor {a} {what}", lambda d, a=a, v=v: d["accessors"][a].update(
                count=d["accessors"][a]["count"] + 1 if v == "+1" else v)))
        for off in (1, 2, 3, 10**9):
            edits.append((f"accessor {a} byteOffset {off}",
                          lambda d, a=a, off=off: d["accessors"][a].update(byteOffset=off)))
        edits.append((f"accessor {a} type VEC2",
                      lambda d, a=a: d["accessors"][a].update(type="VEC2")))
        edits.append((f"accessor {a} type MAT9",
                      lambda d, a=a: d["accessors"][a].update(type="MAT9")))
        edits.append((f"accessor {a} without bufferView",
                      lambda d, a=a: d["accessors"][a].pop("bufferView", None)))
        edits.append((f"accessor {a} min/max NaN",
                      lambda d, a=a: d["accessors"][a].update(min=[math.nan] * 3)))
    for v in range(len(doc.get("bufferViews", []))):
        for off in (1, 2, 4, 10**9):
            edits.append((f"bufferView {v} byteOffset +{off}", lambda d, v=v, off=off:
                          d["bufferViews"][v].update(
                              byteOffset=d["bufferViews"][v].get("byteOffset", 0) + off)))
        for stride in (1, 3, 5, 300):
            edits.append((f"bufferView {v} byteStride {stride}", lambda d, v=v, s=stride:
                          d["bufferViews"][v].update(byteStride=s)))
        edits.append((f"bufferView {v} buffer 7",
                      lambda d, v=v: d["bufferViews"][v].update(buffer=7)))
        edits.append((f"bufferView {v} byteLength 1",
                      lambda d, v=v: d["bufferViews"][v].update(byteLength=1)))
    for m in range(len(doc.get("materials", []))):
        for v in ("red", [math.inf, 1, 1], [-1.0, -1.0, -1.0], [1.0, 1.0], [math.nan] * 3,
                  [1e30, 0, 0], [0.5, "x", 1]):
            edits.append((f"material {m} emissiveFactor {v}",
                          lambda d, m=m, v=v: d["materials"][m].update(emissiveFactor=v)))
        for v in ([2.0, 1, 1, 1], "grey", [math.nan, 0, 0, 1], [0.5]):
            edits.append((f"material {m} baseColorFactor {v}", lambda d, m=m, v=v: d[
                "materials"][m].setdefault("pbrMetallicRoughness", {}).update(
                    baseColorFactor=v)))
        for v in ("shiny", math.nan, -3):
            edits.append((f"material {m} metallicFactor {v}", lambda d, m=m, v=v: d[
                "materials"][m].setdefault("pbrMetallicRoughness", {}).update(
                    metallicFactor=v)))
        for v in (0.0, math.nan, "glass", math.inf):
            edits.append((f"material {m} ior {v}", lambda d, m=m, v=v: d["materials"][m]
                          .setdefault("extensions", {}).setdefault("KHR_materials_ior", {})
                          .update(ior=v)))
        for v in ("full", math.nan, -1):
            edits.append((f"material {m} transmissionFactor {v}", lambda d, m=m, v=v: d[
                "materials"][m].setdefault("extensions", {}).setdefault(
                    "KHR_materials_transmission", {}).update(transmissionFactor=v)))
        for v in (0.0, "far", math.inf):
            edits.append((f"material {m} attenuationDistance {v}", lambda d, m=m, v=v: d[
                "materials"][m].setdefault("extensions", {}).setdefault(
                    "KHR_materials_volume", {}).update(attenuationDistance=v)))
        edits.append((f"material {m} is a list", lambda d, m=m: d["materials"].__setitem__(
            m, [1, 2])))
    for i in nodes:
        for v in ("abc", -1, math.nan, 1e300, math.inf, None):
            edits.append((f"node {i} flux_lm {v}", lambda d, i=i, v=v: d["nodes"][i]
                          .setdefault("extras", {}).setdefault("lightsim", {})
                          .update(flux_lm=v)))
        edits.append((f"node {i} role bogus", lambda d, i=i: d["nodes"][i].setdefault(
            "extras", {}).setdefault("lightsim", {}).update(role="bogus")))
        edits.append((f"node {i} extras a string",
                      lambda d, i=i: d["nodes"][i].update(extras="x")))
        edits.append((f"node {i} name 123", lambda d, i=i: d["nodes"][i].update(name=123)))
    for me in range(len(doc.get("meshes", []))):
        edits.append((f"mesh {me} primitive mode 0", lambda d, me=me: d["meshes"][me][
            "primitives"][0].update(mode=0)))
        edits.append((f"mesh {me} primitive mode 99", lambda d, me=me: d["meshes"][me][
            "primitives"][0].update(mode=99)))
        edits.append((f"mesh {me} material 42", lambda d, me=me: d["meshes"][me][
            "primitives"][0].update(material=42)))
        edits.append((f"mesh {me} POSITION removed", lambda d, me=me: d["meshes"][me][
            "primitives"][0]["attributes"].pop("POSITION", None)))
        edits.append((f"mesh {me} indices = POSITION", lambda d, me=me: d["meshes"][me][
            "primitives"][0].update(indices=d["meshes"][me]["primitives"][0]["attributes"]
                                    .get("POSITION", 0))))
        edits.append((f"mesh {me} primitives not a list", lambda d, me=me: d["meshes"][me]
                      .update(primitives={"a": 1})))
    edits.append(("scenes []", lambda d: d.update(scenes=[])))
    edits.append(("scene index 5", lambda d: d.update(scene=5)))
    edits.append(("scene nodes [99]", lambda d: d["scenes"][0].update(nodes=[99])))
    edits.append(("nodes removed", lambda d: d.pop("nodes", None)))
    edits.append(("accessors removed", lambda d: d.pop("accessors", None)))
    edits.append(("buffer byteLength 10**12",
                  lambda d: d["buffers"][0].update(byteLength=10**12)))
    edits.append(("buffer uri missing file", lambda d: d["buffers"][0].update(uri="nope.bin")))
    edits.append(("buffer data uri corrupt", lambda d: d["buffers"][0].update(
        uri="data:application/octet-stream;base64,@@@")))
    edits.append(("document is a list", lambda d: (d.clear(), d.update({"__list__": True}))))
    return edits


def _benign_gltf_edits(doc: dict[str, Any]) -> list[tuple[str, Callable[[dict], None]]]:
    """Valid variations (the run must succeed): moves, scales, colours, fluxes."""
    nodes = [i for i, n in enumerate(doc.get("nodes", [])) if "mesh" in n]
    edits: list[tuple[str, Callable[[dict], None]]] = []
    for i in nodes:
        edits += [(f"node {i} scale 2", lambda d, i=i: d["nodes"][i].update(scale=[2.0] * 3)),
                  (f"node {i} translation 1 cm", lambda d, i=i: d["nodes"][i].update(
                      translation=[0.01, 0.0, 0.0])),
                  (f"node {i} rotation 90° about y", lambda d, i=i: d["nodes"][i].update(
                      rotation=[0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5)])),
                  (f"node {i} name 'wall'", lambda d, i=i: d["nodes"][i].update(name="wall"))]
    for m in range(len(doc.get("materials", []))):
        edits.append((f"material {m} baseColorFactor 0.3", lambda d, m=m: d["materials"][m]
                      .setdefault("pbrMetallicRoughness", {}).update(
                          baseColorFactor=[0.3, 0.4, 0.5, 1.0])))
        edits.append((f"material {m} emissiveFactor 0.5", lambda d, m=m: d["materials"][m]
                      .update(emissiveFactor=[0.5, 0.5, 0.5])))
    return edits


def _mutate_gltf(doc: dict[str, Any], blob: bytes, rng: np.random.Generator
                 ) -> tuple[bytes, str, str]:
    """(file bytes, description, suffix) of one glTF mutation."""
    r = rng.random()
    if r < 0.15:
        raw, what = _bytes_mutation(pack_glb(doc, blob), rng, header=20 + 4096)
        return raw, what, ".glb"
    if r < 0.35:  # damage the geometry itself: coordinates, normals, indices
        new_blob, what = flip_bytes(blob, rng)
        return pack_glb(doc, new_blob), "BIN chunk: " + what, ".glb"
    d = json.loads(json.dumps(doc))
    if r < 0.45:
        name, edit = _pick(rng, _benign_gltf_edits(d))
        edit(d)
    elif r < 0.8:
        name, edit = _pick(rng, _targeted_gltf_edits(d))
        with contextlib.suppress(KeyError, IndexError, TypeError, AttributeError):
            edit(d)
    else:
        path = _pick(rng, list(_leaves(d)))
        value = _pick(rng, _PALETTE)
        _set(d, path, value)
        name = f"{'/'.join(map(str, path))} = {value!r}"
    if d.get("__list__"):
        raw = pack_glb([1, 2, 3], blob)  # type: ignore[arg-type]
        return raw, name, ".glb"
    if rng.random() < 0.2:
        return to_gltf_text(d, blob), name + " (.gltf)", ".gltf"
    return pack_glb(d, blob), name, ".glb"


def _mutate_text_numbers(text: str, rng: np.random.Generator, header_lines: Sequence[int]
                         ) -> tuple[str, str]:
    """Replace one number on one of ``header_lines`` (or a random line) with a bad token."""
    lines = text.splitlines()
    pool = [i for i in header_lines if i < len(lines)] if rng.random() < 0.8 else \
        list(range(len(lines)))
    for _ in range(20):  # find a line with a number on it (bounded)
        i = _pick(rng, pool)
        toks = list(re.finditer(r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", lines[i]))
        if toks:
            t = _pick(rng, toks)
            new = _pick(rng, _NUM_TOKENS)
            lines[i] = lines[i][:t.start()] + new + lines[i][t.end():]
            return "\r\n".join(lines) + "\r\n", f"line {i + 1}: {t.group()!r} → {new!r}"
    return text, "unchanged"


def _ies_header_lines(text: str) -> list[int]:
    lines = text.splitlines()
    for i, ln in enumerate(lines):
        if ln.strip().upper().startswith("TILT"):
            return [i + 1, i + 2, i + 1, i + 2, i + 3]
    return list(range(min(len(lines), 20)))


def _mutate_photometric(data: bytes, kind: str, rng: np.random.Generator
                        ) -> tuple[bytes, str]:
    r = rng.random()
    text = data.decode("latin-1")
    if r < 0.6:
        header = _ies_header_lines(text) if kind == "ies" else list(range(26))
        new, what = _mutate_text_numbers(text, rng, header)
        return new.encode("latin-1"), "header " + what
    if r < 0.75:
        lines = text.splitlines()
        i = int(rng.integers(0, max(len(lines), 1)))
        del lines[i:i + int(rng.integers(1, 4))]
        return ("\r\n".join(lines) + "\r\n").encode("latin-1"), f"lines from {i + 1} deleted"
    return _bytes_mutation(data, rng, header=600)


def _mutate_photo(data: bytes, suffix: str, rng: np.random.Generator) -> tuple[bytes, str]:
    if suffix == ".tif" and rng.random() < 0.4:
        with tifffile.TiffFile(io.BytesIO(data)) as tf:
            tags = [(t.name, t.offset) for t in tf.pages[0].tags]
        name, off = _pick(rng, tags)
        b = bytearray(data)
        pos = off + int(rng.integers(2, 12))  # type, count or value of the tag entry
        b[pos] = int(rng.integers(0, 256))
        return bytes(b), f"TIFF tag {name} byte {pos - off} set to {b[pos]}"
    return _bytes_mutation(data, rng, header=64 if suffix != ".jpg" else 600)


def _mutate_cad(data: bytes, kind: str, rng: np.random.Generator) -> tuple[bytes, str]:
    """A STEP or IGES file: a number, whole entity lines deleted or doubled, or bytes."""
    r = rng.random()
    text = data.decode("latin-1")
    lines = text.splitlines()
    if r < 0.45:
        new, what = _mutate_text_numbers(text, rng, list(range(len(lines))))
        return new.encode("latin-1"), what
    if r < 0.7:
        i = int(rng.integers(0, max(len(lines), 1)))
        n = int(rng.integers(1, 4))
        if rng.random() < 0.5:
            del lines[i:i + n]
            what = f"lines {i + 1}+{n} deleted"
        else:
            lines[i:i] = lines[i:i + n]
            what = f"lines {i + 1}+{n} doubled"
        return ("\n".join(lines) + "\n").encode("latin-1"), what
    return _bytes_mutation(data, rng, header=2000)


def _mutate_toml(text: str, rng: np.random.Generator) -> tuple[bytes, str]:
    """A material map: a value replaced (palette), a key renamed or removed, TOML syntax
    broken, or bytes."""
    r = rng.random()
    lines = text.splitlines()
    values = [i for i, ln in enumerate(lines) if "=" in ln]
    if r < 0.5:
        i = _pick(rng, values)
        key = lines[i].split("=")[0].strip()
        new = _pick(rng, ('"mirror"', '"glass"', '"emitter"', '"ignore"', '"wall"', '"bogus"',
                          "nan", "inf", "-inf", "-1", "0", "1e30", "1e-30", "2", "true",
                          "[1, 2]", '""', '"*"', '"[a-"', "{}", "99999999999999999999"))
        lines[i] = f"{key} = {new}"
        what = f"{key} = {new}"
    elif r < 0.65:
        i = _pick(rng, values)
        key = lines[i].split("=")[0].strip()
        if rng.random() < 0.5:
            del lines[i]
            what = f"{key} removed"
        else:
            lines[i] = "colour" + lines[i][len(lines[i]) - len(lines[i].lstrip()):] + \
                lines[i][lines[i].index("="):]
            what = f"{key} renamed colour"
    elif r < 0.8:
        i = int(rng.integers(0, max(len(lines), 1)))
        broken = _pick(rng, ("[[rule]", "[rule]", "match = ", 'match = "unterminated',
                             "= 3", "[[rule]]\n[[rule]]", "schema = \"other\"", "\x00"))
        lines.insert(i, broken)
        what = f"line {i + 1} inserted: {broken!r}"
    else:
        raw, what = _bytes_mutation(text.encode("utf-8"), rng, header=len(text))
        return raw, what
    return ("\n".join(lines) + "\n").encode("utf-8"), what


# (offset, struct format, field) of the header fields a ray-file reader trusts
_TM25_FIELDS = ((4, "<i", "version"), (8, "<i", "creation method"), (12, "<f", "luminous flux"),
                (20, "<Q", "ray count"), (56, "<i", "start position"),
                (60, "<i", "spectrum type"),
                (76, "<i", "spectral tables"), (80, "<i", "extra items"),
                (84, "<i", "extra text bytes"), (256, "<i", "position flag"),
                (260, "<i", "direction flag"), (264, "<i", "radiant flag"),
                (268, "<i", "wavelength flag"), (272, "<i", "luminous flag"),
                (276, "<i", "Stokes flag"))
_ZEMAX_FIELDS = ((0, "<i", "identifier"), (4, "<I", "ray count"), (108, "<f", "source flux"),
                 (112, "<f", "ray-set flux"), (136, "<I", "units"), (164, "<f", "scale x"),
                 (192, "<i", "ray format"), (196, "<i", "flux type"))
_FIELD_VALUES = {"<i": (0, -1, 1, 2, 3, 4, 2**31 - 1, -2**31), "<I": (0, 1, 2**32 - 1, 10**6),
                 "<Q": (0, 1, 2**64 - 1, 10**12, 399, 401),
                 "<f": (0.0, -1.0, math.nan, math.inf, 1e30, 1e-30, 1.0)}


def _mutate_rayfile(data: bytes, kind: str, rng: np.random.Generator) -> tuple[bytes, str]:
    """A ray file: a header field (count, flux, units, flags, …), ray records (NaN, zero
    directions, huge or negative flux), truncation or bytes."""
    r = rng.random()
    header = TM25_BLOCK if kind == "tm25" else ZEMAX_HEADER
    if r < 0.4:
        off, fmt, name = _pick(rng, _TM25_FIELDS if kind == "tm25" else _ZEMAX_FIELDS)
        value = _pick(rng, _FIELD_VALUES[fmt])
        b = bytearray(data)
        struct.pack_into(fmt, b, off, value)
        return bytes(b), f"header {name} = {value}"
    if r < 0.65:
        n_items = 7
        rays = (len(data) - header) // (4 * n_items)
        if rays <= 0:
            return _bytes_mutation(data, rng, header)
        i = int(rng.integers(0, rays))
        col = int(rng.integers(0, n_items))
        value = float(_pick(rng, (math.nan, math.inf, -1.0, 0.0, 1e30, -1e30, 1e-30)))
        b = bytearray(data)
        struct.pack_into("<f", b, header + 4 * (n_items * i + col), value)
        return bytes(b), f"ray {i} column {col} = {value}"
    return _bytes_mutation(data, rng, header)


def _mutate_points(text: str, rng: np.random.Generator) -> tuple[bytes, str]:
    """``--points``: a number replaced, a separator changed, points dropped or repeated."""
    r = rng.random()
    parts = [p.strip() for p in text.split(";")]
    if r < 0.4:
        toks = list(re.finditer(r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", text))
        t = _pick(rng, toks)
        new = _pick(rng, (*_NUM_TOKENS, "89", "-89.5", "1e308", "0x10", "١٢"))
        out, what = text[:t.start()] + new + text[t.end():], f"{t.group()!r} → {new!r}"
    elif r < 0.6:
        seps = [m.start() for m in re.finditer(r"[;,=]", text)]
        i = _pick(rng, seps)
        new = _pick(rng, (";", ",", "=", " ", "", "==", ";;", ":"))
        out, what = text[:i] + new + text[i + 1:], f"separator {i} {text[i]!r} → {new!r}"
    elif r < 0.8:
        k = int(rng.integers(0, len(parts) + 1))
        out, what = "; ".join(parts[:k]), f"first {k} of {len(parts)} points"
    else:
        i = int(rng.integers(0, len(parts)))
        extra = parts[i] if rng.random() < 0.5 else parts[i].split("=")[0] + "=" + \
            parts[(i + 1) % len(parts)].split("=")[1]
        out, what = "; ".join([*parts, extra]), f"point {i + 1} repeated or crossed"
    return out.encode("utf-8"), what


def _mutate_json_doc(doc: Any, rng: np.random.Generator) -> tuple[bytes, str]:
    """A JSON document: a leaf set to a palette value, a key removed or added, the
    document replaced by another type, or bytes of its text."""
    r = rng.random()
    if r < 0.55:
        d = json.loads(json.dumps(doc))
        leaves = list(_leaves(d))
        path = _pick(rng, leaves) if leaves else ()
        value = _pick(rng, _PALETTE)
        if path:
            _set(d, path, value)
        return json.dumps(d, allow_nan=True).encode("utf-8"), \
            f"{'/'.join(map(str, path))} = {value!r}"
    if r < 0.7:
        d = json.loads(json.dumps(doc))
        if isinstance(d, dict) and d:
            target = d
            inner = [v for v in d.values() if isinstance(v, dict) and v]
            if inner and rng.random() < 0.7:
                target = _pick(rng, inner)
            if rng.random() < 0.5:
                key = _pick(rng, sorted(target))
                target.pop(key)
                return json.dumps(d).encode("utf-8"), f"{key} removed"
            target["path" if rng.random() < 0.5 else "bogus"] = "../../outside"
            return json.dumps(d).encode("utf-8"), "an unknown field added"
    if r < 0.8:
        other = _pick(rng, ([], "text", 3, None, [doc], {"type": None}))
        return json.dumps(other).encode("utf-8"), f"document replaced by {other!r}"[:80]
    return _bytes_mutation(json.dumps(doc).encode("utf-8"), rng, header=64)


def _mutate_message(msg: dict[str, Any], rng: np.random.Generator) -> tuple[bytes, str]:
    """A page message: as a JSON document, or deep nesting, a huge value, binary."""
    r = rng.random()
    if r < 0.85:
        raw, what = _mutate_json_doc(msg, rng)
        return raw, f"{msg.get('type')}: {what}"
    if r < 0.9:
        n = int(rng.integers(30, 100_000))
        return ("[" * n + "]" * n).encode(), f"nested {n} deep"
    if r < 0.95:
        return json.dumps({"type": "set", "changes": {"k": "9" * 100_000}}).encode(), \
            "a 100 000-digit value"
    return b"\x00\xff binary", "binary frame"


@dataclass
class CorpusFiles:
    """The files the cases run against: the photo cases' result folder (and the photo
    the ``--points`` cases use), the small lamp (material maps, view), the CAD material
    maps, the folder of the view's cases."""

    root: Path
    sim: Path | None = None
    photo: Path | None = None
    lamp: Path | None = None
    cad_maps: dict[str, Path] = field(default_factory=dict)


def build_corpus(n: int, seed: int, workdir: Path, kinds: Sequence[str] = KINDS,
                 headlight: bool = False) -> tuple[list[FuzzCase], CorpusFiles]:
    """``n`` mutated inputs (round robin over ``kinds``) and the files they run against.

    Case i is a function of (seed, i) only, so a failure is reproduced by its index.
    """
    for k in kinds:
        if k not in KINDS:
            raise InputError(f"fuzz kind must be one of {', '.join(KINDS)}, got '{k}'")
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    files = CorpusFiles(workdir)
    glb_seeds = [split_glb(small_scene_glb())]
    if headlight:
        glb_seeds.append(split_glb(headlight_glb()))
    ies = sample_ies() if "ies" in kinds else b""
    ldt = sample_ldt(workdir) if "ldt" in kinds else b""
    photos: dict[str, bytes] = {}
    points = ""
    if "photo" in kinds or "points" in kinds:
        files.sim, photos, points = photo_seeds_with_points(workdir)
        files.photo = workdir / "points-photo.png"
        files.photo.write_bytes(photos[".png"])
    if {"materials", "zemax", "state", "ws"} & set(kinds):
        files.lamp = workdir / "lamp.glb"
        files.lamp.write_bytes(small_scene_glb())
    cad = cad_seeds(workdir, kinds)
    files.cad_maps = {k: v[1] for k, v in cad.items()}
    rays = rayfile_seeds(workdir, kinds)
    controls = lamp_controls(files.lamp) if {"state", "ws"} & set(kinds) else {}
    messages = view_message_seeds(controls) if "ws" in kinds else []
    cases = []
    for i in range(n):
        rng = np.random.default_rng([seed, i])
        kind = kinds[i % len(kinds)]
        if kind == "glb":
            j = int(rng.integers(0, len(glb_seeds)))
            raw, what, suffix = _mutate_gltf(*glb_seeds[j], rng)
            what = ("headlight: " if j else "") + what
        elif kind in ("ies", "ldt"):
            raw, what = _mutate_photometric(ies if kind == "ies" else ldt, kind, rng)
            suffix = "." + kind
        elif kind == "photo":
            suffix = _pick(rng, sorted(photos))
            raw, what = _mutate_photo(photos[suffix], suffix, rng)
            what = f"{suffix[1:]}: {what}"
        elif kind in ("step", "iges"):
            raw, what = _mutate_cad(cad[kind][0], kind, rng)
            suffix = "." + kind
        elif kind == "materials":
            raw, what = _mutate_toml(material_map_seed(), rng)
            suffix = ".toml"
        elif kind in ("tm25", "zemax"):
            raw, what = _mutate_rayfile(rays[kind], kind, rng)
            suffix = ".tm25ray" if kind == "tm25" else ".dat"
        elif kind == "points":
            raw, what = _mutate_points(points, rng)
            suffix = ".txt"
        elif kind == "state":
            raw, what = _mutate_json_doc(json.loads(view_state_seed(controls, "lamp.glb")),
                                         rng)
            suffix = ".json"
        else:
            raw, what = _mutate_message(_pick(rng, messages), rng)
            suffix = ".msg"
        cases.append(FuzzCase(i, kind, what, f"case{i}{suffix}", raw))
    return cases, files


def photo_seeds_with_points(workdir: Path) -> tuple[Path, dict[str, bytes], str]:
    """:func:`photo_seeds` and the ``--points`` of its PNG (:func:`points_seed`)."""
    sim, photos = photo_seeds(workdir)
    shot = render_photo(lowbeam_lux(wall_frame((96, 40))),
                        CameraSettings(rotate_deg=2.0, noise=0.01, bits=8, seed=3))
    frame = wall_frame((96, 40))
    return sim, photos, points_seed((96, 40), shot.matrix, frame)


def lamp_controls(lamp: Path) -> dict[str, Any]:
    """The view's controls of ``lamp`` as its ``state.json`` holds them."""
    scene = load_scene(lamp, SceneSettings(resolution=(32, 16)))
    return SceneEditor(scene, {}).defaults().to_dict()


# --------------------------------------------------------------------------------------
# running and judging
# --------------------------------------------------------------------------------------

def case_argv(case: FuzzCase, input_path: Path, out: Path, files: CorpusFiles,
              photons: int, resolution: str, cad_time_limit_s: float = 90.0) -> list[str]:
    """The command line of a file case (not the view's kinds); a CAD case gives the
    reader ``cad_time_limit_s`` (processor s), well within the case's own time limit."""
    if case.kind == "photo":
        return ["compare", str(input_path), "--sim", str(files.sim), "--out", str(out), "-q"]
    if case.kind == "points":
        return ["compare", str(files.photo), "--sim", str(files.sim), "--points",
                case.data.decode("utf-8", "replace"), "--out", str(out), "-q"]
    sim = ["--photons", str(photons), "--frame-photons", str(photons), "--resolution",
           resolution, "--quiet", "--out", str(out)]
    if case.kind in ("step", "iges"):
        return ["simulate", str(input_path), "--materials", str(files.cad_maps[case.kind]),
                "--cad-time-limit", f"{cad_time_limit_s:g}", *sim]
    if case.kind == "materials":
        return ["simulate", str(files.lamp), "--materials", str(input_path), *sim]
    if case.kind == "zemax":  # ".dat" names no scene: the ray file replaces the emitter
        return ["simulate", str(files.lamp), "--rayfile", str(input_path), *sim]
    return ["simulate", str(input_path), *sim]


def _all_finite(obj: Any) -> bool:
    if isinstance(obj, float):
        return math.isfinite(obj)
    if isinstance(obj, dict):
        return all(_all_finite(v) for v in obj.values())
    if isinstance(obj, list):
        return all(_all_finite(v) for v in obj)
    return True


def judge(case: FuzzCase, code: int | None, stderr: list[str], out: Path) -> tuple[str, str]:
    """(verdict, detail) of one finished case; see the module docstring."""
    files = sorted(str(p.relative_to(out)) for p in out.rglob("*")) if out.is_dir() else []
    if any("Traceback" in ln for ln in stderr):
        return "traceback", stderr[-1][:120] if stderr else ""
    if code == 2:
        if len(stderr) != 1 or not stderr[0].startswith("lightsim: error: "):
            return "lines", f"{len(stderr)} lines"
        real = [f for f in files if (out / f).is_file()]
        if real:
            return "leftover", ", ".join(real[:4])
        return "rejected", ""
    if code != 0:
        return "exit", f"exit code {code}"
    stray = [ln for ln in stderr if not ln.startswith("lightsim: warning: ")]
    if stray:
        return "stray", stray[0][:120]
    compared = case.kind in ("photo", "points")
    expected = COMPARE_OUTPUTS if compared else SIM_OUTPUTS
    top = {f for f in files if "/" not in f}
    if not expected <= top:
        return "incomplete", "missing " + ", ".join(sorted(expected - top))
    extra = sorted(f for f in files if f not in expected)
    if extra and not compared:
        return "leftover", "extra " + ", ".join(extra[:4])
    if compared:
        doc = json.loads((out / "comparison.json").read_text())
        return ("ran", "") if _all_finite(doc) else ("nonfinite", "comparison.json")

    chans, _ = read_exr(out / "wall_lux.exr")
    if not all(np.all(np.isfinite(c)) for c in chans.values()):
        return "nonfinite", "wall_lux.exr"
    summary = json.loads((out / "summary.json").read_text())
    e = summary.get("energy_lm") or {}
    emitted = e.get("emitted")
    closure = e.get("closure_relative")
    if not (isinstance(emitted, float | int) and math.isfinite(emitted) and emitted > 0):
        return "energy", f"emitted {emitted}"
    if not (isinstance(closure, float | int) and closure <= CLOSURE_TOL):
        return "energy", f"closure {closure}"
    if summary.get("lux", {}).get("max_lx") is None:
        return "nonfinite", "summary lux"
    return "ran", ""


@contextlib.contextmanager
def _captured_fds() -> Iterator[list[str]]:
    """Capture fd 1 and fd 2 (Python and C writes alike); yields the stderr lines after."""
    lines: list[str] = []
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with tempfile.TemporaryFile() as fout, tempfile.TemporaryFile() as ferr:
        os.dup2(fout.fileno(), 1)
        os.dup2(ferr.fileno(), 2)
        try:
            yield lines
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            ferr.seek(0)
            text = ferr.read().decode("utf-8", "replace")
            lines.extend(ln for ln in text.splitlines() if ln.strip())


def run_in_process(command: Command, argv: list[str]) -> tuple[int, list[str]]:
    """Run ``lightsim argv`` here through ``command`` (:data:`Command`) as a fresh process
    would; (exit code, stderr lines)."""
    code = 1
    with _captured_fds() as lines, warnings.catch_warnings():
        # a fresh process shows each warning once; resetting the filters makes every case
        # a fresh process in that respect (Python drops its once-per-location registry)
        warnings.resetwarnings()
        warnings.simplefilter("default")
        logging.captureWarnings(False)
        try:
            command(argv)
        except SystemExit as exc:
            c = exc.code
            code = 0 if c is None else c if isinstance(c, int) else 1
            if not isinstance(c, int | None):
                print(c, file=sys.stderr)
        except BaseException:  # what an uncaught exception would print
            traceback.print_exc()
            code = 1
    return code, lines


def _worker(conn: Any, command: Command) -> None:
    """Worker process: run the argv lists it receives, send back (code, stderr lines)."""
    sys.stdin = open(os.devnull)  # commands never read input
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if msg is None:
            return
        conn.send(run_in_process(command, msg))


class _Worker:
    def __init__(self, command: Command) -> None:
        ctx = mp.get_context("spawn")
        self.conn, child = ctx.Pipe()
        # the command goes by reference (its module and name): the worker imports it
        self.proc = ctx.Process(target=_worker, args=(child, command), daemon=True)
        self.proc.start()
        child.close()

    def run(self, argv: list[str], timeout: float) -> tuple[int | None, list[str], str]:
        """(code, stderr lines, failure class or "")."""
        try:
            self.conn.send(argv)
        except OSError:
            return None, [], "crash"
        if not self.conn.poll(timeout):
            return None, [], "timeout"
        try:
            code, lines = self.conn.recv()
        except (EOFError, OSError):
            self.proc.join(5)
            return self.proc.exitcode, [], "crash"
        return code, lines, ""

    def alive(self) -> bool:
        return self.proc.is_alive()

    def close(self) -> None:
        with contextlib.suppress(OSError, BrokenPipeError):
            self.conn.send(None)
        self.proc.join(10)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(5)


def _message_text(data: bytes) -> str | bytes:
    """A message case as the page would send it: text when it is UTF-8, else binary."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data


def run_fuzz(n: int, seed: int = 1, kinds: Sequence[str] = KINDS, *, command: Command,
             photons: int = 20_000, resolution: str = "64x32", timeout_s: float = 180.0,
             headlight: bool = False, workdir: str | os.PathLike | None = None,
             progress: Callable[[CaseResult], None] | None = None) -> FuzzReport:
    """Build the corpus, run every case in a worker process and judge it.

    Parameters
    ----------
    n : int
        Number of cases.
    seed : int
        Corpus seed.
    kinds : sequence of str
        Input kinds (:data:`KINDS`), taken in turn.
    command : callable
        The command line's entry point (:data:`Command`), run in the worker process.
    photons : int
        Photons per simulated case.
    resolution : str
        Wall pixels ``WxH`` of simulated cases.
    timeout_s : float
        Time limit per case (s); the worker is restarted after a timeout or a crash.
    headlight : bool
        Also mutate the shipped headlight GLB (slower cases).
    workdir : path-like, optional
        Where inputs and outputs go (a temporary folder, removed afterwards, by default).
    progress : callable, optional
        Called with each :class:`CaseResult`.
    """
    owned = workdir is None
    root = Path(tempfile.mkdtemp(prefix="lightsim-fuzz-")) if owned else Path(workdir)
    root.mkdir(parents=True, exist_ok=True)
    report = FuzzReport(seed)
    worker: _Worker | None = None
    target: MessageTarget | None = None
    try:
        cases, files = build_corpus(n, seed, root, tuple(kinds), headlight)
        for case in cases:
            case_dir = root / f"case{case.index}"
            case_dir.mkdir(exist_ok=True)
            inp = case_dir / case.filename
            inp.write_bytes(case.data)
            out = case_dir / "out"
            t0 = time.perf_counter()
            if case.kind == "state":
                code, lines, verdict, detail = judge_state(files.lamp, inp, out)
            elif case.kind == "ws":
                if target is None:
                    target = MessageTarget(files.lamp, root / "ws")
                    (root / "ws").mkdir(exist_ok=True)
                code, lines, verdict, detail = target.judge(_message_text(case.data))
            else:
                if worker is None:
                    worker = _Worker(command)
                argv = case_argv(case, inp, out, files, photons, resolution,
                                 cad_time_limit_s=timeout_s / 6)
                code, lines, failure = worker.run(argv, timeout_s)
                if failure:
                    verdict, detail = failure, f"after {time.perf_counter() - t0:.0f} s"
                    worker.proc.kill()
                    worker.proc.join(5)
                    worker = _Worker(command)
                else:
                    verdict, detail = judge(case, code, lines, out)
            result = CaseResult(case, code, lines, time.perf_counter() - t0, verdict, detail)
            report.results.append(result)
            if progress is not None:
                progress(result)
            if owned:
                shutil.rmtree(case_dir, ignore_errors=True)
    finally:
        if worker is not None:
            worker.close()
        if target is not None:
            target.close()
        if owned:
            shutil.rmtree(root, ignore_errors=True)
    return report


# --------------------------------------------------------------------------------------
# SIGKILL during the write phase
# --------------------------------------------------------------------------------------

@dataclass
class KillResult:
    """What one SIGKILL during ``simulate``'s write phase left in the output folder.

    ``state`` is ``complete`` (summary.json and every file it lists), ``unfinished`` (no
    summary.json) or ``broken`` (summary.json without its set: the promise is broken).
    ``problems`` lists everything wrong before and after the next run's clean-up.
    """

    delay_s: float
    state: str
    top_files: list[str]
    notes: list[str]
    problems: list[str]
    in_write_phase: bool = True   # the staging folder existed when the kill was sent

    @property
    def ok(self) -> bool:
        return not self.problems


def _simulate_argv(scene: Path, out: Path, photons: int, resolution: str, seed: int = 1
                   ) -> list[str]:
    return [sys.executable, "-m", "lightsim.cli", "simulate", str(scene), "--photons",
            str(photons), "--frame-photons", str(photons), "--resolution", resolution,
            "--seed", str(seed), "--quiet", "--out", str(out)]


def _write_started(out: Path) -> bool:
    with contextlib.suppress(OSError):
        for p in out.glob(STAGING_PREFIX + "*"):
            if p.is_dir() and any(True for _ in p.iterdir()):
                return True
    return False


def inspect_output(out: Path) -> tuple[str, list[str], list[str]]:
    """(state, top-level files, problems) of a simulate output folder after a kill."""
    top = sorted(p.name for p in out.iterdir() if p.is_file()) if out.is_dir() else []
    problems = [f"empty file {n}" for n in top if (out / n).stat().st_size == 0]
    problems += [f"temporary file {n} in the folder" for n in top if TEMP_RE.match(n)]
    if "summary.json" not in top:
        return "unfinished", top, problems
    try:
        listed = json.loads((out / "summary.json").read_text()).get("outputs", [])
    except (OSError, ValueError) as exc:
        return "broken", top, [*problems, f"summary.json unreadable ({exc})"]
    missing = sorted((set(listed) | SIM_OUTPUTS) - set(top))
    if missing:
        return "broken", top, [*problems, "summary.json without " + ", ".join(missing)]

    seed = json.loads((out / "summary.json").read_text()).get("seed")
    exr_seed = read_exr(out / "wall_lux.exr")[1].get("seed")
    if seed != exr_seed:  # runs differ by seed: one run's summary over another's map
        return "broken", top, [*problems, f"mixed set: summary seed {seed}, EXR seed "
                               f"{exr_seed}"]
    return "complete", top, problems


def kill_during_write(scene: Path, out: Path, delay_s: float, *, photons: int = 20_000,
                      resolution: str = "64x32", timeout_s: float = 180.0) -> KillResult:
    """Start ``simulate`` (seed 2), SIGKILL it ``delay_s`` after its first staged file
    appears, and judge the folder before and after the clean-up the next run does
    (:func:`lightsim.simulate.folder_notes`). A folder holding an earlier run of another
    seed shows whether old and new files mixed."""
    proc = subprocess.Popen(_simulate_argv(scene, out, photons, resolution, seed=2),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < timeout_s and proc.poll() is None:
            if _write_started(out):
                break
            time.sleep(0.002)
        time.sleep(delay_s)
        during = proc.poll() is None and _write_started(out)
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(30)
    state, top, problems = inspect_output(out)
    notes = folder_notes(out)
    left = [p.name for p in out.glob(STAGING_PREFIX + "*")] if out.is_dir() else []
    problems += [f"{n} left after the clean-up" for n in left]
    if state == "unfinished" and [n for n in top if n in SIM_OUTPUTS] and not any(
            "unfinished" in n for n in notes):
        problems.append("an unfinished set was not reported")
    return KillResult(delay_s, state, top, notes, problems, during)


def write_phase_seconds(scene: Path, out: Path, *, photons: int = 20_000,
                        resolution: str = "64x32", timeout_s: float = 180.0) -> float:
    """Seconds from the first staged file to the appearance of ``summary.json`` in an
    uninterrupted run into the fresh folder ``out`` (the window the kills are spread over)."""
    proc = subprocess.Popen(_simulate_argv(scene, out, photons, resolution),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    t0 = time.monotonic()
    start = end = None
    try:
        while time.monotonic() - t0 < timeout_s and proc.poll() is None:
            if start is None and _write_started(out):
                start = time.monotonic()
            if start is not None and end is None and (out / "summary.json").exists():
                end = time.monotonic()
            time.sleep(0.002)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(30)
    if proc.returncode != 0 or start is None:
        raise RuntimeError(f"simulate of {scene} did not finish (exit {proc.returncode})")
    return (end or time.monotonic()) - start


def kill_study(n: int, workdir: Path, *, photons: int = 20_000, resolution: str = "64x32",
               timeout_s: float = 180.0) -> list[KillResult]:
    """``n`` SIGKILLs spread evenly over the write phase of the small seed scene (as timed
    in one uninterrupted run: load changes it, see ``KillResult.in_write_phase``), each
    into a folder holding a finished earlier run (so old and new sets could mix)."""
    workdir = Path(workdir)
    scene = workdir / "kill-scene.glb"
    scene.write_bytes(small_scene_glb())
    window = write_phase_seconds(scene, workdir / "kill-timing", photons=photons,
                                 resolution=resolution, timeout_s=timeout_s)
    results = []
    for i, delay in enumerate(np.linspace(0.0, window, n)):
        out = workdir / f"kill{i}"
        shutil.copytree(workdir / "kill-timing", out)  # a finished set to be replaced
        results.append(kill_during_write(scene, out, float(delay), photons=photons,
                                         resolution=resolution, timeout_s=timeout_s))
    return results
