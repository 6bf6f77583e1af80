"""Bit-identity check of a refactoring: run fixed-seed cases, keep their outputs, compare.

A change that only moves code (the wall frame, the import layering) must leave every lux
map bit-identical. ``snapshot`` runs the analytic paraboloid (bin and kNN) and the
isotropic case through the :class:`~lightsim.engine.server.Session` at a fixed seed and
writes their lux maps and per-set probe values to ``analytic.npz``; ``compare`` compares
two such folders, and two ``lightsim simulate`` output folders (``wall_lux.exr``,
``probes.npz``, ``summary.json`` without its timings, IES/LDT files byte for byte).

Usage::

    python -m lightsim.validation.snapshot analytic DIR      # write DIR/analytic.npz
    python -m lightsim.validation.snapshot compare BEFORE AFTER

=================  =====  ========  ======================================================
parameter          unit   default   meaning
=================  =====  ========  ======================================================
``photons``        –      100 000   photons per analytic case
``seed``           –      1         photon sequence
``TIMING_KEYS``    –      below     summary.json keys that hold wall-clock figures (s,
                                    photons/s) or the machine: not compared
=================  =====  ========  ======================================================
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.io.exr import read_exr
from lightsim.validation.analytic import run_image_case
from lightsim.validation.scenes import analytic as an

TIMING_KEYS = frozenset({"seconds", "machine", "photons_per_second", "rate", "elapsed_s",
                         "time_s", "wall_seconds", "eta_s", "rays_per_second"})
"""summary.json keys whose values are timings (differ between identical runs)."""

CASES = (("paraboloid", "bin"), ("paraboloid", "knn"), ("isotropic", "knn"))


def analytic_snapshot(out: Path, photons: int = 100_000, seed: int = 1) -> Path:
    """Run :data:`CASES` at ``seed`` and write their lux maps to ``out/analytic.npz``."""
    builders = {"paraboloid": an.paraboloid_case, "isotropic": an.isotropic_case}
    arrays: dict[str, np.ndarray] = {}
    for name, est in CASES:
        run = run_image_case(builders[name](), RunConfig(seed=seed, estimator=est), photons)
        arrays[f"{name}/{est}/lux"] = run.lux
        arrays[f"{name}/{est}/per_set"] = run.per_set
    out.mkdir(parents=True, exist_ok=True)
    path = out / "analytic.npz"
    np.savez(path, **arrays)
    return path


def _json_diffs(a: Any, b: Any, where: str = "", roots: tuple[str, str] = ("", "")
                ) -> Iterator[str]:
    """Paths at which two JSON documents differ, timing keys left out; strings are compared
    with the two folders ``roots`` written as ``<root>`` (file names of the outputs)."""
    if isinstance(a, str) and isinstance(b, str) and all(roots):
        a, b = a.replace(roots[0], "<root>"), b.replace(roots[1], "<root>")
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if key in TIMING_KEYS:
                continue
            if key not in a or key not in b:
                yield f"{where}/{key}: only in {'after' if key not in a else 'before'}"
            else:
                yield from _json_diffs(a[key], b[key], f"{where}/{key}", roots)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            yield f"{where}: {len(a)} items before, {len(b)} after"
        for i, (x, y) in enumerate(zip(a, b)):
            yield from _json_diffs(x, y, f"{where}[{i}]", roots)
    elif a != b and not (isinstance(a, float) and isinstance(b, float) and a != a and b != b):
        yield f"{where}: {a!r} before, {b!r} after"


def _npz_diffs(a: Path, b: Path) -> Iterator[str]:
    with np.load(a, allow_pickle=False) as x, np.load(b, allow_pickle=False) as y:
        for key in sorted(set(x.files) | set(y.files)):
            if key not in x.files or key not in y.files:
                yield f"{a.name}:{key}: missing on one side"
                continue
            u, v = x[key], y[key]
            if u.shape != v.shape or u.dtype != v.dtype or u.tobytes() != v.tobytes():
                yield f"{a.name}:{key}: arrays differ (shape {u.shape} vs {v.shape})"


def compare(before: Path, after: Path, roots: tuple[str, str] | None = None) -> list[str]:
    """Every difference between two snapshot or simulate folders (empty: identical).

    Lux maps and probe arrays are compared bit for bit, ``summary.json`` key by key
    without :data:`TIMING_KEYS`, other files (IES, LDT) byte for byte. PNG figures are not
    compared (matplotlib embeds nothing run-specific, but they are renderings of the maps).
    """
    roots = roots or (str(before), str(after))
    diffs: list[str] = []
    names = sorted({p.name for p in before.iterdir()} | {p.name for p in after.iterdir()})
    for name in names:
        a, b = before / name, after / name
        if a.is_dir() or b.is_dir():
            if a.is_dir() and b.is_dir():
                diffs += [f"{name}/{d}" for d in compare(a, b, roots)]
            else:
                diffs.append(f"{name}: folder on one side only")
            continue
        if not (a.exists() and b.exists()):
            diffs.append(f"{name}: only in {'before' if a.exists() else 'after'}")
        elif name.endswith(".npz"):
            diffs += list(_npz_diffs(a, b))
        elif name.endswith(".exr"):
            ca, _ = read_exr(a)
            cb, _ = read_exr(b)
            if sorted(ca) != sorted(cb):
                diffs.append(f"{name}: channels {sorted(ca)} vs {sorted(cb)}")
            diffs += [f"{name}:{c}: pixels differ" for c in sorted(set(ca) & set(cb))
                      if ca[c].tobytes() != cb[c].tobytes()]
        elif name.endswith(".json"):
            diffs += [f"{name}{d}" for d in _json_diffs(json.loads(a.read_text()),
                                                         json.loads(b.read_text()),
                                                         roots=roots)]
        elif not name.endswith(".png") and not name.endswith(".log"):
            if a.read_bytes() != b.read_bytes():
                diffs.append(f"{name}: bytes differ")
    return diffs


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "analytic":
        print(analytic_snapshot(Path(argv[1])))
        return 0
    if len(argv) == 3 and argv[0] == "compare":
        diffs = compare(Path(argv[1]), Path(argv[2]))
        print("\n".join(diffs) if diffs else "identical (timings left out)")
        return 1 if diffs else 0
    print(__doc__.split("Usage::")[1].split("=====")[0].strip(), file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
