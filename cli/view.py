"""``lightsim view``: the interactive session in the browser (see ``lightsim.view``).

The options are :class:`~lightsim.view.settings.ViewSettings`' command-line fields; the
session is :func:`lightsim.luminaires.live.start_view`'s. This module parses, starts the
session and its web server, prints the address (with the session's access token) and waits
for Ctrl-C.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import click

from lightsim.errors import InputError
from lightsim.luminaires.adb import panel_solver
from lightsim.luminaires.live import start_view
from lightsim.luminaires.provenance_report import (
    REGIONS_FILE,
    read_regions,
    region_breakdown,
    region_overview,
    region_picture,
)
from lightsim.options import click_options
from lightsim.persource import MAP_FILE, read_per_source
from lightsim.simulate import check_out_dir
from lightsim.view.adb_panel import serve_adb
from lightsim.view.launch import read_state
from lightsim.view.provenance_panel import serve_provenance
from lightsim.view.settings import ViewSettings


@click.command("view")
@click.argument("scene", type=click.Path())
@click_options(ViewSettings)
def view(scene: str, **values: Any) -> None:
    """Interactive session in the browser: live lux, controls, regulation, save run. A run
    folder of ``simulate --per-source`` opens the ADB panel instead: toggle segments, drag a
    road user, the map re-composed from the per-source maps; one of ``simulate --provenance``
    the provenance panel: click or drag on the screen, see where that light comes from."""
    settings = ViewSettings.from_command_line(values)
    if Path(scene).is_dir():
        if (Path(scene) / REGIONS_FILE).exists() and not (Path(scene) / MAP_FILE).exists():
            _provenance_panel(scene, settings)
        else:
            _adb_panel(scene, settings)
        return
    state = read_state(settings.state_file) if settings.state_file is not None else None
    folder = check_out_dir(settings.out_dir)
    live, server = start_view(scene, settings, folder=folder, state=state)
    # the numba kernels compile now (the session's warm-up), not at the first edit
    click.echo("lightsim view: warming up (compiling kernels, first frames)…", err=True)
    while not live.ready.wait(0.5) and server.thread.is_alive():
        pass
    if live.error:
        server.stop()
        live.stop()
        raise InputError(live.error)
    click.echo(f"lightsim view: {server.url}  (session folder {folder}; Ctrl-C to stop)")
    if not server.loopback:
        click.echo(f"lightsim view: listening on {settings.host}: anyone who can reach it "
                   "needs the token above; traffic is unencrypted unless tunnelled "
                   "(e.g. ssh -L)", err=True)
    try:
        while server.thread.is_alive():
            time.sleep(0.5)
    finally:
        server.stop()
        live.stop()


def _adb_panel(run_dir: str, settings: ViewSettings) -> None:
    """Serve the ADB panel of a ``--per-source`` run until Ctrl-C."""
    maps = read_per_source(run_dir)
    server = serve_adb(maps, panel_solver(maps), settings.host, settings.port)
    click.echo(f"lightsim view: ADB panel of {run_dir}: {server.url}  (Ctrl-C to stop)")
    try:
        while server.thread is not None and server.thread.is_alive():
            time.sleep(0.5)
    finally:
        server.stop()


def _provenance_panel(run_dir: str, settings: ViewSettings) -> None:
    """Serve the provenance panel of a ``--provenance`` run until Ctrl-C."""
    store = read_regions(Path(run_dir) / REGIONS_FILE)
    screen = {**region_overview(store), "run": Path(run_dir).name}
    server = serve_provenance(
        screen, lambda box: region_breakdown(Path(run_dir), box, store=store),
        lambda box: region_picture(Path(run_dir), region_breakdown(Path(run_dir), box,
                                                                   store=store), store),
        settings.host, settings.port)
    click.echo(f"lightsim view: provenance panel of {run_dir}: {server.url}  (Ctrl-C to stop)")
    try:
        while server.thread is not None and server.thread.is_alive():
            time.sleep(0.5)
    finally:
        server.stop()
