"""Peak memory against photons: the default run (no photon kept) and the keep-all path.

``lightsim simulate`` runs as a child process per (photons, path), one after the other;
each child's peak resident set (``ru_maxrss`` of its own ``wait4``) is its peak RSS, and
``summary.json``'s ``seconds`` over its photons its rate, and its CPU seconds (user +
system, the whole process) its rate per CPU-second — on a loaded machine the steadier
of the two. The default run accumulates
what its outputs read frame by frame (:mod:`lightsim.engine.pointstore`), so its peak
should stay flat as the photons grow; ``--keep-photons`` keeps every photon (the kNN
bandwidth's path) and grows by tens of bytes per photon. Both paths are timed in the
same run, alternated at each photon count, so machine load moves both.

=================  =====  =================================  ===========================
parameter          unit   default                            meaning
=================  =====  =================================  ===========================
``photons``        –      4 M, 16 M, 48 M, 160 M, 480 M      photon counts (``--quick``:
                                                             1 M, 2 M, 4 M)
``resolution``     px     320 × 128                          the README run's wall
``regulation``     –      r112-b-passing,r149-b-passing      the README run's rule sets
``keep_all_max``   –      48 M                               the keep-all path runs up to
                                                             this count (it grows)
=================  =====  =================================  ===========================
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path
from typing import Any

from lightsim.io.atomic import atomic_path

FULL_PHOTONS = (4_000_000, 16_000_000, 48_000_000, 160_000_000, 480_000_000)
QUICK_PHOTONS = (1_000_000, 2_000_000, 4_000_000)
KEEP_ALL_MAX = 48_000_000
REGULATION = "r112-b-passing,r149-b-passing"

#: the child process: the ``lightsim`` command in this interpreter
_CHILD = "import sys; from lightsim.cli.main import main; sys.argv[0] = 'lightsim'; main()"


def run_child(args: list[str]) -> tuple[int, float, int, float]:
    """Run ``lightsim ARGS`` as a child: (exit code, wall seconds, peak RSS in bytes,
    CPU seconds of the whole process: user + system, every thread)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
    if proc.stderr:
        proc.stderr.close()
    if proc.returncode:
        last = err.strip().splitlines()[-1:] or [""]
        raise RuntimeError(f"lightsim {' '.join(args)} failed ({proc.returncode}): {last[0]}")
    return (proc.returncode, time.perf_counter() - t0, int(usage.ru_maxrss) * 1024,
            float(usage.ru_utime + usage.ru_stime))


def measure(scene: str, photons: int, keep: bool, resolution: str = "320x128",
            regulation: str | None = REGULATION, seed: int = 1) -> dict[str, Any]:
    """One ``simulate`` run: its peak RSS (bytes), photons/s and error figure."""
    with tempfile.TemporaryDirectory(prefix="lightsim-bench-memory-") as tmp:
        out = Path(tmp) / "out"
        args = ["simulate", scene, "--photons", str(int(photons)), "--resolution",
                resolution, "--seed", str(seed), "--out", str(out), "--quiet"]
        if regulation:
            args += ["--regulation", regulation]
        if keep:
            args.append("--keep-photons")
        _, wall_s, rss, cpu_s = run_child(args)
        summary = json.loads((out / "summary.json").read_text())
    seconds = float(summary.get("seconds") or wall_s)
    return {"path": "keep-all" if keep else "default", "photons": int(photons),
            "peak_rss_mb": rss / 2**20, "run_s": seconds, "wall_s": wall_s,
            "photons_per_s": photons / seconds if seconds > 0 else float("nan"),
            # the whole process's CPU time: less moved by other jobs than the clock
            "photons_per_cpu_s": photons / cpu_s if cpu_s > 0 else float("nan"),
            "rel_error": summary.get("rel_error")}


def bench_memory(scene: str, photons: tuple[int, ...] = FULL_PHOTONS,
                 keep_all_max: int = KEEP_ALL_MAX, resolution: str = "320x128",
                 regulation: str | None = REGULATION, progress=None) -> list[dict[str, Any]]:
    """Rows of :func:`measure` for every photon count, the default path and (up to
    ``keep_all_max``) the keep-all path, alternated; each row also gets its peak over the
    default path's peak at the same photons (``rss_vs_default``) and over the first
    count's peak of its path (``rss_vs_first``)."""
    rows: list[dict[str, Any]] = []
    first: dict[str, float] = {}
    for n in photons:
        default = measure(scene, n, False, resolution, regulation)
        pair = [default]
        if n <= keep_all_max:
            pair.append(measure(scene, n, True, resolution, regulation))
        for row in pair:
            first.setdefault(row["path"], row["peak_rss_mb"])
            row["rss_vs_first"] = row["peak_rss_mb"] / first[row["path"]]
            row["rss_vs_default"] = row["peak_rss_mb"] / default["peak_rss_mb"]
            rows.append(row)
            if progress is not None:
                progress(row)
    return rows


def plot_memory(rows: list[dict[str, Any]], path: str | Path, title: str) -> Path:
    """Peak RSS (MB) against photons, one line per path, log photons axis (PNG)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=120)
    for name, style in (("default", "o-"), ("keep-all", "s--")):
        pts = [(r["photons"], r["peak_rss_mb"]) for r in rows if r["path"] == name]
        if pts:
            x, y = zip(*pts, strict=True)
            what = "no photon kept" if name == "default" else "--keep-photons"
            ax.plot(x, y, style, label=f"{name} ({what})")
    ax.set_xscale("log")
    ax.set_xlabel("photons")
    ax.set_ylabel("peak RSS (MB)")
    ax.set_ylim(bottom=0)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title("\n".join(textwrap.wrap(title, 90)), fontsize=8)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path
