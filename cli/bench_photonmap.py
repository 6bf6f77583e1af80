"""``lightsim bench photonmap``: paper Tables 5 and 1 on photons traced in our scenes."""

from __future__ import annotations

import click

from lightsim.errors import InputError
from lightsim.luminaires.headlight import example_headlight
from lightsim.validation.bench import photonmap as pm
from lightsim.validation.bench.table import print_table, write_json
from lightsim.validation.scenes import paper


@click.command("photonmap")
@click.option("--moderate", type=int, default=200_000, show_default=True,
              help="Photons emitted for the moderate photon maps.")
@click.option("--large", type=int, default=2_000_000, show_default=True,
              help="Photons emitted for the large photon maps.")
@click.option("--k", "k", type=int, default=64, show_default=True)
@click.option("--repeats", type=int, default=3, show_default=True)
@click.option("--synthetic", is_flag=True, help="Use the synthetic caustic sets instead.")
@click.option("--goals", is_flag=True,
              help="Only the headline ratios (1 M-photon kNN vs cKDTree, insertion vs "
                   "rebuild) and the memory table.")
@click.option("--rss-photons", type=int, default=16_000_000, show_default=True,
              help="Photons of the `simulate` run whose peak RSS the memory table shows "
                   "(0: skip that run).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write rows as JSON.")
def command(moderate: int, large: int, k: int, repeats: int, synthetic: bool, goals: bool,
            rss_photons: int, json_path: str | None) -> None:
    """Build/query ms per structure vs cKDTree (Table 5) and kNN/s vs embree rays/s (Table 1).

    Photon sets: the wall photons of the shipped headlight and the floor photons of the
    RING scene, each from a moderate and a large number of emitted photons. Then the
    memory table: bytes per stored photon and the peak RSS of a `simulate` run.
    """
    if rss_photons < 0:
        raise InputError(f"--rss-photons must be ≥ 0, got {rss_photons}")
    if goals:
        rows = pm.goal_rows(k=k, repeats=repeats)
        print_table("Photon maps: the headline ratios (same run)", rows, pm.GOAL_COLUMNS)
        memory = _memory(rss_photons)
        if json_path:
            write_json(json_path, "photonmap-goals", rows + memory, meta={"k": k})
        return

    scenes = {"headlight": paper.build("headlight"), "ring": paper.build("ring")}
    if synthetic:
        sets = pm.synthetic_sets()
    else:
        sets = {}
        for name, scene in scenes.items():
            for label, n in (("moderate", moderate), ("large", large)):
                sets[f"{name}-{label}"] = pm.traced_wall_photons(scene, n)
    result = pm.run(sets, k=k, repeats=repeats, show=True)
    rows = result["table5"]
    table1 = pm.table1(scenes, rows)
    print_table("Table 1: kNN queries/s vs raw embree rays/s in the same scene", table1)
    memory = _memory(rss_photons)
    if json_path:
        write_json(json_path, "photonmap", rows + [{"method": "insert-vs-rebuild",
                                                   **result["insert_vs_rebuild"]}] + table1
                   + memory, meta={"k": k, "moderate": moderate, "large": large})


def _memory(rss_photons: int) -> list[dict]:
    """Print and return the memory table (:func:`lightsim.validation.bench.photonmap.memory_rows`
    on the shipped headlight)."""
    rows = pm.memory_rows(rss_photons, example_headlight())
    print_table("Memory: bytes per stored photon; peak RSS of `simulate` vs the pre-flight "
                "estimate", rows, pm.MEMORY_COLUMNS)
    return rows
