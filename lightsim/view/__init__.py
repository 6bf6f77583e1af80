"""``lightsim view``: the paper's interactive session in a web browser.

Modules, one concept each:

=================  ==========================================================================
module             holds
=================  ==========================================================================
``controls``       the engineer's controls (name, unit, range, default) and their validation
``editor``         base scene + controls → the edited scene (filament pose, bulb, flux, aim,
                   wall distance); the engine's ``Session.update`` receives the result
``encode``         frames as compressed binary: log-encoded uint16 + zlib, JSON header
``settings``       :class:`~.settings.ViewSettings`: the command's options and the session's
                   tuning, declared once (``--help``, range checks, the settings)
``schedule``       when the pooled map is due (the error law) and the numba thread choice
``live``           the session thread: interaction frames after a change, accumulation when
                   nothing changes, regulation table, autosaved edit log, "save run"
``launch``         a live session from a scene, its settings and the product's hooks
``app``            the starlette/uvicorn web app: page, WebSocket fan-out (latest frame only,
                   never a queue), upload of a second scene
``static/``        the page (plain HTML/JS/canvas; nothing from a CDN)
=================  ==========================================================================

Regulation evaluation, bulb presets and the run-folder/GLB writers are *injected* as
:class:`~.live.ViewHooks` by ``lightsim.luminaires.live`` (the engine must not import
``luminaires``/``validation``/``cli``).
"""
