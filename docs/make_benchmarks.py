"""Write the manual's benchmarks page (``docs/benchmarks.md``) from a fresh run of every
``lightsim bench`` command.

Each benchmark runs as the command line a user types (with ``--json FILE``), in a
temporary folder; its rows become one table per kind of row, beside the exact command
that reproduces it. Every ratio in a table is against a baseline measured in the same
run, on the same machine. The page names the machine (CPU model, cores, memory, Python,
OS, load average before and after) and the date; it is written anew each time, never
appended to.

    python docs/make_benchmarks.py              # the figures (a quiet machine: an hour or more)
    python docs/make_benchmarks.py --quick      # fewer repeats and photons: checks the page only
    python docs/make_benchmarks.py --only memory  # one benchmark's section run anew, in place

``bench peer`` (against Mitsuba 3) runs only where ``mitsuba`` is installed.

Parameters
----------
==========  ======  ===================  ===========================================
name        unit    default              meaning
==========  ======  ===================  ===========================================
--quick     –       off                  fewer repeats and photons (the page says so)
--out       –       docs/benchmarks.md   the page written
--keep      –       none                 folder for the JSON files (kept)
--only      –       every benchmark      comma-separated names: run only these and replace
                                         their sections of the existing page (each then
                                         says when and under what load it was made)
==========  ======  ===================  ===========================================
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "benchmarks.md"


@dataclass(frozen=True)
class Bench:
    """One ``lightsim bench`` command: its arguments, and the lighter ones of ``--quick``."""

    name: str
    args: tuple[str, ...]
    quick: tuple[str, ...]
    about: str
    needs: str | None = None  # an optional module the benchmark needs


BENCHES = (
    Bench("tracer", ("bench", "tracer"), ("--photons", "200000", "--repeats", "1"),
          "Photon tracing rate of the shipped headlight (embree + the tracer's kernels)."),
    Bench("photonmap", ("bench", "photonmap", "--goals"),
          ("--repeats", "1", "--rss-photons", "2000000"),
          "Photon-map build and kNN queries against scipy's cKDTree (paper Table 5), "
          "bytes per stored photon and the peak memory of a run."),
    Bench("filter", ("bench", "filter"), ("--repeats", "5"),
          "The O(1) box filter against the naive window sum and scipy (paper 4.1)."),
    Bench("frames", ("bench", "frames"), ("--frames", "1", "--max-resolution", "640x480"),
          "Frames per second at growing resolutions in one process (paper Table 7)."),
    Bench("spt", ("bench", "spt"), ("--photons", "100000"),
          "Caustic yield of Selective Photon Tracing against plain sampling (paper Table 4)."),
    Bench("plan", ("bench", "plan"), ("--frames", "1", "--repeats", "1"),
          "Seconds per frame of the planned stages against every stage forced on."),
    Bench("pipeline", ("bench", "pipeline"), ("--photons", "200000", "--repeats", "1"),
          "Where a `simulate` run's time goes, stage by stage."),
    Bench("scaling", ("bench", "scaling"), ("--workers", "0,1", "--frames", "2"),
          "Photons per second with 0, 1, 2 Ray workers on this machine."),
    Bench("view", ("bench", "view"),
          ("--changes", "2", "--drag-seconds", "2", "--converge-timeout", "15"),
          "The live view in Chromium: latency of a change, drag frames per second, time "
          "to a 5 % and a 2 % error."),
    Bench("verdicts", ("bench", "verdicts", "--photons", "400000000"),
          ("--photons", "1000000"),
          "Seconds and photons until every verdict is decided, with and without guiding "
          "(at most the photons shown: the cap of `simulate --until decided`)."),
    Bench("adb", ("bench", "adb", "--memory-photons", "2000000"), ("--frames", "100"),
          "A 1,000-frame traffic sequence composed and judged from per-source maps, against "
          "re-tracing one frame; the memory of --per-source against a plain run."),
    Bench("provenance", ("bench", "provenance"), ("--photons", "200000", "--repeats", "1"),
          "Time and memory of a run with --provenance against the same run without."),
    Bench("memory", ("bench", "memory", "--photons", "4000000,16000000,48000000",
                     "--keep-all-max", "16000000"), ("--quick",),
          "Peak memory against photons: the default run (bounded) and --keep-photons."),
    Bench("peer", ("bench", "peer"), ("--max-seconds", "60"),
          "Time to a true 2 % error against Mitsuba 3's particle tracer, whole processes.",
          needs="mitsuba"),
)


def lightsim_command() -> list[str]:
    """The ``lightsim`` console script beside this interpreter, else the module."""
    script = Path(sys.executable).with_name("lightsim")
    return [str(script)] if script.exists() else [sys.executable, "-m", "lightsim.cli.main"]


# -- the machine -------------------------------------------------------------------------------
def machine() -> dict[str, str]:
    """CPU model, cores, memory, Python, OS and lightsim's version and commit."""
    cpu = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        for line in cpuinfo.read_text(errors="replace").splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    memory = ""
    meminfo = Path("/proc/meminfo")
    if meminfo.exists():
        for line in meminfo.read_text().splitlines():
            if line.startswith("MemTotal:"):
                memory = f"{int(line.split()[1]) / 1024**2:.1f} GiB"
                break
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True, check=False).stdout.strip()
    version = subprocess.run(lightsim_command() + ["--version"], capture_output=True,
                             text=True, check=False).stdout.strip()
    return {"CPU": cpu, "cores": str(os.cpu_count()), "memory": memory,
            "Python": platform.python_version(), "OS": platform.platform(),
            "lightsim": f"{version} (commit {commit})" if commit else version}


def load_average() -> str:
    """The 1, 5 and 15 minute load averages."""
    try:
        return " / ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


# -- running -----------------------------------------------------------------------------------
@dataclass
class Outcome:
    """What one benchmark gave: its JSON document or the tail of its failure."""

    bench: Bench
    command: str
    seconds: float
    doc: dict[str, Any] | None = None
    error: str = ""


def run_bench(bench: Bench, quick: bool, work: Path) -> Outcome:
    """Run one benchmark as the command line does, in ``work``."""
    json_name = f"bench-{bench.name}.json"
    args = [*bench.args, *(bench.quick if quick else ()), "--json", json_name]
    shown = "lightsim " + " ".join(shlex.quote(a) for a in args)
    print(f"{bench.name}: $ {shown}", flush=True)
    t0 = time.perf_counter()
    log = work / f"bench-{bench.name}.log"
    with log.open("w") as out:
        done = subprocess.run(lightsim_command() + args, cwd=work, stdout=out,
                              stderr=subprocess.STDOUT, check=False)
    seconds = time.perf_counter() - t0
    if done.returncode != 0 or not (work / json_name).exists():
        tail = "\n".join(log.read_text(errors="replace").splitlines()[-12:])
        print(f"  failed (exit {done.returncode}) after {seconds:.0f} s", flush=True)
        return Outcome(bench, shown, seconds, error=tail or f"exit {done.returncode}")
    print(f"  {seconds:.0f} s", flush=True)
    return Outcome(bench, shown, seconds, doc=json.loads((work / json_name).read_text()))


# -- the page ----------------------------------------------------------------------------------
def _cell(value: Any) -> str:
    if isinstance(value, bool):
        text = "yes" if value else "no"
    elif isinstance(value, float):
        text = (f"{value:.4g}" if value == 0 or 1e-3 <= abs(value) < 1e6 else f"{value:.3e}")
    elif isinstance(value, int):
        text = f"{value:,}" if abs(value) >= 10_000 else str(value)
    elif isinstance(value, list | dict):
        text = json.dumps(value, default=float)
    elif value is None:
        text = "–"
    else:
        text = str(value).replace(f"{ROOT}{os.sep}", "")  # repository paths as relative
    return (text.replace("&", "&amp;").replace("<", "&lt;").replace("|", "\\|")
            .replace("\n", " "))


def tables(rows: list[dict[str, Any]]) -> list[str]:
    """The rows as Markdown tables, one per set of columns (a benchmark may write rows of
    several kinds), in first-seen order."""
    groups: dict[tuple[str, ...], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault(tuple(row), []).append(row)
    out = []
    for columns, members in groups.items():
        lines = ["| " + " | ".join(_cell(c) for c in columns) + " |",
                 "|" + "|".join("---" for _ in columns) + "|"]
        lines += ["| " + " | ".join(_cell(r.get(c)) for c in columns) + " |" for r in members]
        out.append("\n".join(lines))
    return out


def section(o: Outcome, stamp: str | None = None) -> str:
    """One benchmark's section: what it measures, the command, its tables (``stamp``: when
    and under what load a section made alone was generated)."""
    parts = [f"## {o.bench.name}", o.bench.about, f"```bash\n{o.command}\n```"]
    if o.doc is None:
        if o.error.startswith("skipped"):
            parts.append(o.error)
        else:
            parts.append(f"**Failed** after {o.seconds:.0f} s:\n\n```\n{o.error}\n```")
        return "\n\n".join(parts)
    parts += tables(o.doc.get("rows", []))
    meta = o.doc.get("meta") or {}
    facts = [f"{k}: {_cell(v)}" for k, v in meta.items() if not isinstance(v, list | dict)]
    facts.append(f"whole command: {o.seconds:.0f} s")
    if stamp:
        facts.append(stamp)
    parts.append("*" + "; ".join(facts) + ".*")
    return "\n\n".join(parts)


def replace_sections(text: str, new: dict[str, str]) -> str:
    """``text`` (the page) with the sections named in ``new`` replaced (a section runs
    from its ``## name`` heading to the next heading of that level)."""
    head, *rest = text.split("\n## ")
    sections = {part.split("\n", 1)[0].strip(): part for part in rest}
    missing = sorted(set(new) - set(sections))
    if missing:
        raise SystemExit(f"--only: no section {', '.join(missing)} on the page; run the whole "
                         "page instead")
    parts = [new[name][3:].rstrip("\n") + "\n" if name in new else part
             for name, part in sections.items()]
    return "\n## ".join([head, *parts])


def page(outcomes: list[Outcome], facts: dict[str, str], quick: bool, started: str,
         loads: tuple[str, str]) -> str:
    """The whole page."""
    head = ["# Benchmarks", ""]
    if quick:
        head += ["!!! warning \"Generated with `--quick`: not the figures\"",
                 "    This page was made with fewer repeats and photons, to check the page "
                 "itself. Its numbers say nothing about lightsim's speed; regenerate it "
                 "on a quiet machine with `python docs/make_benchmarks.py`.", ""]
    head += [
        "Every `lightsim bench` command measures its baseline in the same run, on the same "
        "machine, so the ratios in each table compare like with like; the absolute "
        "figures belong to the machine below. What each benchmark measures and why: "
        "[What the benchmarks measure](explanation/benchmarks.md).",
        "",
        "This page is generated by `python docs/make_benchmarks.py`, which runs each "
        "command shown here with `--json FILE` and writes the page anew.",
        "",
        f"- **generated**: {started}" + (" with `--quick`" if quick else ""),
        *(f"- **{k}**: {v}" for k, v in facts.items() if v),
        f"- **load average** (1 / 5 / 15 min): {loads[0]} before, {loads[1]} after",
        "",
    ]
    return "\n".join(head) + "\n" + "\n\n".join(section(o) for o in outcomes) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="fewer repeats and photons: for checking the page only")
    parser.add_argument("--out", default=str(PAGE), help="the page to write")
    parser.add_argument("--keep", metavar="DIR", help="run in DIR and keep the JSON files")
    parser.add_argument("--only", metavar="NAMES",
                        help="comma-separated benchmarks to run anew, their sections "
                             "replaced in the existing page")
    args = parser.parse_args(argv)
    only = [n.strip() for n in (args.only or "").split(",") if n.strip()]
    unknown = sorted(set(only) - {b.name for b in BENCHES})
    if unknown:
        parser.error(f"--only: unknown benchmark {', '.join(unknown)}")
    started = datetime.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    load_before = load_average()
    facts = machine()
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="lightsim-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    outcomes = []
    try:
        for bench in BENCHES:
            if only and bench.name not in only:
                continue
            if bench.needs and importlib.util.find_spec(bench.needs) is None:
                shown = "lightsim " + " ".join(bench.args)
                print(f"{bench.name}: skipped ({bench.needs} is not installed)", flush=True)
                outcomes.append(Outcome(bench, shown, 0.0, error=f"skipped: `{bench.needs}` "
                                        "is not installed on this machine."))
                continue
            outcomes.append(run_bench(bench, args.quick, work))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    out = Path(args.out)
    if only:
        stamp = f"generated {started}, load average {load_before} before, {load_average()} after"
        text = replace_sections(out.read_text(encoding="utf-8"),
                                {o.bench.name: section(o, stamp) for o in outcomes})
    else:
        text = page(outcomes, facts, args.quick, started, (load_before, load_average()))
    tmp = out.with_suffix(".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, out)
    failed = [o.bench.name for o in outcomes if o.doc is None and not o.error.startswith(
        "skipped")]
    print(f"wrote {out}" + (f"; failed: {', '.join(failed)}" if failed else ""))
    if failed:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
