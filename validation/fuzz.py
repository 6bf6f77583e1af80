"""Input fuzzing: a seeded mutation corpus of GLB/glTF, IES, LDT and photo files, each run
through the real command line, each result judged by the input-error promise.

The promise (README, *Commands*): bad input gives **one** stderr line and exit code 2,
never a traceback, and leaves no files in ``--out``; good input exits 0 with finite,
closed results. Every case here is a real file made from a valid seed by one mutation —
byte flips, truncation, chunk duplication, JSON edits of the glTF document (targeted at
the fields the loader reads, or at a random leaf), header-number edits of IES/LDT files,
tag and byte damage of JPEG/PNG/TIFF photos — and is run as ``lightsim simulate`` (meshes
and photometric files) or ``lightsim compare`` (photos) in a worker process, with stdout
and stderr captured at the file-descriptor level (so C libraries' and numpy's warning
lines count too) and a time limit per case.

A case **passes** when either

* exit 0, no stderr line other than ``lightsim: warning: …``, the complete output set
  (``summary.json`` present, no temporary or staging leftovers), every lux value finite
  and the energy budget closed (``summary.json["energy_lm"]["closure_relative"]`` ≤ 1e-6;
  compare: every number in ``comparison.json`` finite), or
* exit 2, exactly one stderr line ``lightsim: error: …``, no traceback, no file in
  ``--out``.

Everything else is a failure with a class: ``traceback``, ``lines`` (exit 2 with more or
fewer than one line), ``leftover`` (files after an error), ``stray`` (extra stderr lines
on success), ``nonfinite``, ``energy``, ``incomplete``, ``exit`` (another code),
``timeout``, ``crash`` (the worker died).

============================  =====  ==========  ===========================================
parameter                     unit   default     meaning
============================  =====  ==========  ===========================================
``n``                         –      –           number of cases
``seed``                      –      1           corpus seed (case i depends on seed and i)
``kinds``                     –      all four    ``glb``, ``ies``, ``ldt``, ``photo``
``photons``                   –      20 000      ``simulate --photons`` (and per frame)
``resolution``                px     64x32       ``simulate --resolution``
``timeout_s``                 s      180         per case; the worker is restarted after it
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
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, glb_bytes
from lightsim.luminaires.headlight import example_headlight
from lightsim.luminaires.photometric import SAMPLE_IES, read_ies, write_ldt
from lightsim.simulate import folder_notes
from lightsim.validation.synthetic_photo import (
    CameraSettings,
    lowbeam_lux,
    render_photo,
    wall_frame,
    write_photo,
    write_result,
)

KINDS = ("glb", "ies", "ldt", "photo")
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


def build_corpus(n: int, seed: int, workdir: Path, kinds: Sequence[str] = KINDS,
                 headlight: bool = False) -> tuple[list[FuzzCase], Path | None]:
    """``n`` mutated inputs (round robin over ``kinds``) and the photo cases' result folder.

    Case i is a function of (seed, i) only, so a failure is reproduced by its index.
    """
    for k in kinds:
        if k not in KINDS:
            raise InputError(f"fuzz kind must be one of {', '.join(KINDS)}, got '{k}'")
    glb_seeds = [split_glb(small_scene_glb())]
    if headlight:
        glb_seeds.append(split_glb(headlight_glb()))
    ies = sample_ies() if "ies" in kinds else b""
    ldt = sample_ldt(workdir) if "ldt" in kinds else b""
    sim, photos = photo_seeds(workdir) if "photo" in kinds else (None, {})
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
        else:
            suffix = _pick(rng, sorted(photos))
            raw, what = _mutate_photo(photos[suffix], suffix, rng)
            what = f"{suffix[1:]}: {what}"
        cases.append(FuzzCase(i, kind, what, f"case{i}{suffix}", raw))
    return cases, sim


# --------------------------------------------------------------------------------------
# running and judging
# --------------------------------------------------------------------------------------

def case_argv(case: FuzzCase, input_path: Path, out: Path, sim: Path | None,
              photons: int, resolution: str) -> list[str]:
    if case.kind == "photo":
        return ["compare", str(input_path), "--sim", str(sim), "--out", str(out), "-q"]
    return ["simulate", str(input_path), "--photons", str(photons), "--frame-photons",
            str(photons), "--resolution", resolution, "--quiet", "--out", str(out)]


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
    expected = COMPARE_OUTPUTS if case.kind == "photo" else SIM_OUTPUTS
    top = {f for f in files if "/" not in f}
    if not expected <= top:
        return "incomplete", "missing " + ", ".join(sorted(expected - top))
    extra = sorted(f for f in files if f not in expected)
    if extra and case.kind != "photo":
        return "leftover", "extra " + ", ".join(extra[:4])
    if case.kind == "photo":
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
        Input kinds (``glb``, ``ies``, ``ldt``, ``photo``), taken in turn.
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
    worker = None
    try:
        cases, sim = build_corpus(n, seed, root, tuple(kinds), headlight)
        worker = _Worker(command)
        for case in cases:
            case_dir = root / f"case{case.index}"
            case_dir.mkdir(exist_ok=True)
            inp = case_dir / case.filename
            inp.write_bytes(case.data)
            out = case_dir / "out"
            argv = case_argv(case, inp, out, sim, photons, resolution)
            t0 = time.perf_counter()
            code, lines, failure = worker.run(argv, timeout_s)
            dt = time.perf_counter() - t0
            if failure:
                verdict, detail = failure, f"after {dt:.0f} s"
                worker.proc.kill()
                worker.proc.join(5)
                worker = _Worker(command)
            else:
                verdict, detail = judge(case, code, lines, out)
            result = CaseResult(case, code, lines, dt, verdict, detail)
            report.results.append(result)
            if progress is not None:
                progress(result)
            if owned:
                shutil.rmtree(case_dir, ignore_errors=True)
    finally:
        if worker is not None:
            worker.close()
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
