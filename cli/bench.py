"""``lightsim bench …``: benchmarks that print paper-style tables with in-run baselines.

Each benchmark lives in ``lightsim.cli.bench_<name>`` (argument parsing and printing) and
``lightsim.validation.bench.<name>`` (the measurement). Every table is also written as JSON
with ``--json FILE``.
"""

from __future__ import annotations

import click

from lightsim.cli.main import LazyGroup

BENCHMARKS: dict[str, str] = {
    "tracer": "bench_tracer:command",
    "photonmap": "bench_photonmap:command",
    "filter": "bench_filter:command",
    "frames": "bench_frames:command",
    "plan": "bench_plan:command",
    "spt": "bench_spt:command",
    "scaling": "bench_scaling:command",
    "view": "bench_view:command",
    "peer": "bench_peer:command",
    "pipeline": "bench_pipeline:command",
    "road": "bench_road:command",
    "adb": "bench_adb:command",
    "provenance": "bench_provenance:command",
    "verdicts": "bench_verdicts:command",
    "memory": "bench_memory:command",
}


@click.group(cls=LazyGroup, lazy_commands=BENCHMARKS)
def bench() -> None:
    """Benchmarks (paper tables) with baselines measured in the same run."""
