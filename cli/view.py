"""``lightsim view``: the interactive session in the browser (see ``lightsim.view``).

The options are :class:`~lightsim.view.settings.ViewSettings`' command-line fields; the
session is :func:`lightsim.luminaires.live.start_view`'s. This module parses, starts the
session and its web server, prints the address (with the session's access token) and waits
for Ctrl-C.
"""

from __future__ import annotations

import time
from typing import Any

import click

from lightsim.errors import InputError
from lightsim.luminaires.live import start_view
from lightsim.options import click_options
from lightsim.simulate import check_out_dir
from lightsim.view.launch import read_state
from lightsim.view.settings import ViewSettings


@click.command("view")
@click.argument("scene", type=click.Path(dir_okay=False))
@click_options(ViewSettings)
def view(scene: str, **values: Any) -> None:
    """Interactive session in the browser: live lux, controls, regulation, save run."""
    settings = ViewSettings.from_command_line(values)
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
