"""``lightsim view``: the paper's interactive session in a web browser.

Modules, one concept each:

=================  ==========================================================================
module             holds
=================  ==========================================================================
``controls``       the engineer's controls (name, unit, range, default) and their validation
``editor``         base scene + controls → the edited scene (filament pose, bulb, flux, aim,
                   wall distance); the engine's ``Session.update`` receives the result
``encode``         frames as compressed binary: log-encoded uint16 + zlib, JSON header
``live``           the session thread: interaction frames after a change, accumulation when
                   nothing changes, regulation table, autosaved edit log, "save run"
``app``            the starlette/uvicorn web app: page, WebSocket fan-out (latest frame only,
                   never a queue), upload of a second scene
``static/``        the page (plain HTML/JS/canvas; nothing from a CDN)
=================  ==========================================================================

Regulation evaluation, bulb presets and the run-folder/GLB writers are *injected* by
``lightsim.cli.view`` (the engine must not import ``luminaires``/``validation``/``cli``).
"""
