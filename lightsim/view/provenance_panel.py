"""The provenance panel of ``lightsim view RUN_DIR`` (a run of ``simulate --provenance``):
click a point or drag a box on the screen and see where its light comes from — the path
classes' mean illuminance with intervals — and the lamp seen from the screen, coloured by
where that light left it.

The page draws the run's coarse region raster (:mod:`lightsim.provenance`: mean
illuminance per cell, from ``/screen``); a click asks for the cell under it, a drag for
the box (``/breakdown``), then loads the lamp picture of the same box (``/lamp.png``). The
breakdown and the picture are the ``breakdown`` and ``picture`` functions given to
:func:`create_provenance_app` (:mod:`lightsim.luminaires.provenance_report`'s), exactly
what ``lightsim report --provenance-box`` prints and draws.

================  ======  ==================================================================
route             method  what
================  ======  ==================================================================
``/``             GET     the page (``static/provenance.html``)
``/static/…``     GET     its JS (served from the package)
``/screen``       GET     JSON: cell edges in degrees (``h_edges_deg`` increasing,
                          ``v_edges_deg`` decreasing), ``lx`` rows × columns (row 0 the
                          top), ``max_lx``, ``run``
``/breakdown``    GET     ``?box=H0,H1,V0,V1`` (deg) → JSON of the region's classes (one
                          line and status 400 for a bad box)
``/lamp.png``     GET     ``?box=H0,H1,V0,V1`` → the lamp picture of that box (PNG)
================  ======  ==================================================================

Every request passes the view's :class:`~lightsim.view.app.Guard` (host names, access
token), as the live view's do.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

from lightsim.errors import LightsimError
from lightsim.view.app import Access, Guard, ViewServer, allowed_hosts, new_token

Box = tuple[float, float, float, float]


def parse_box_query(text: str | None) -> Box:
    """``H0,H1,V0,V1`` of a query → four floats (ValueError otherwise)."""
    try:
        parts = [float(x) for x in (text or "").split(",")]
    except ValueError:
        parts = []
    if len(parts) != 4:
        raise ValueError(f"box must be H0,H1,V0,V1 in degrees, got '{text}'")
    return parts[0], parts[1], parts[2], parts[3]


def create_provenance_app(screen: dict[str, Any], breakdown: Callable[[Box], dict[str, Any]],
                          picture: Callable[[Box], bytes], access: Access) -> Any:
    """The starlette app of the panel behind :class:`Guard` (``screen``: the ``/screen``
    body; ``breakdown``/``picture``: a box's table and lamp PNG, raising
    :class:`~lightsim.errors.LightsimError` for a bad box)."""
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import FileResponse, JSONResponse, Response
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    static = Path(str(resources.files("lightsim.view") / "static"))

    async def index(request: Request) -> FileResponse:
        return FileResponse(static / "provenance.html", headers={"cache-control": "no-store"})

    async def screen_route(request: Request) -> JSONResponse:
        return JSONResponse(screen)

    def _box(request: Request) -> Box:
        return parse_box_query(request.query_params.get("box"))

    async def breakdown_route(request: Request) -> JSONResponse:
        try:
            box = _box(request)
            # the table reads the run's raster: off the event loop
            return JSONResponse(await asyncio.to_thread(breakdown, box))
        except (ValueError, LightsimError) as exc:
            return JSONResponse({"level": "error", "text": str(exc)}, 400)

    async def lamp_route(request: Request) -> Response:
        try:
            box = _box(request)
            png = await asyncio.to_thread(picture, box)
        except (ValueError, LightsimError) as exc:
            return JSONResponse({"level": "error", "text": str(exc)}, 400)
        return Response(png, media_type="image/png", headers={"cache-control": "no-store"})

    app = Starlette(routes=[Route("/", index), Route("/screen", screen_route),
                            Route("/breakdown", breakdown_route),
                            Route("/lamp.png", lamp_route),
                            Mount("/static", StaticFiles(directory=static), name="static")])
    app.add_middleware(Guard, access=access)
    return app


def serve_provenance(screen: dict[str, Any], breakdown: Callable[[Box], dict[str, Any]],
                     picture: Callable[[Box], bytes], host: str = "127.0.0.1",
                     port: int = 0) -> ViewServer:
    """Serve the panel on ``host``:``port`` (0: any free port) behind a new access token;
    returns the running server (its ``url`` carries the token)."""
    access = Access(new_token(), allowed_hosts(host))
    return ViewServer(create_provenance_app(screen, breakdown, picture, access), port,
                      host=host, token=access.token).start()
