"""``lightsim bench …``: benchmarks that print paper-style tables with in-run baselines.

Each benchmark lives in ``lightsim.cli.bench_<name>`` (argument parsing and printing) and
``lightsim.validation.bench.<name>`` (the measurement). Every table is also written as JSON
with ``--json FILE``.
"""

from __future__ import annotations

import importlib

import click

BENCHMARKS: dict[str, str] = {
    "tracer": "bench_tracer",
    "photonmap": "bench_photonmap",
    "filter": "bench_filter",
    "frames": "bench_frames",
    "plan": "bench_plan",
    "spt": "bench_spt",
    "scaling": "bench_scaling",
}


class _LazyBench(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(BENCHMARKS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        module_name = BENCHMARKS.get(cmd_name)
        if module_name is None:
            return None
        try:
            module = importlib.import_module(f"lightsim.cli.{module_name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"lightsim.cli.{module_name}":
                return None
            raise
        return module.command


@click.group(cls=_LazyBench)
def bench() -> None:
    """Benchmarks (paper tables) with baselines measured in the same run."""
