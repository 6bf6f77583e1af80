"""The ADB panel of ``lightsim view RUN_DIR``: toggle a matrix lamp's segments and drag a
road user across the screen; the page re-composes the map from the run's per-source maps
(:mod:`lightsim.persource`), it never re-traces.

The page receives every segment's map once (``/maps``) and composes Σ w_g E_g itself in
float32, in segment order, as :func:`lightsim.persource.compose` does (the same bits): a
toggle is drawn without a round trip. Dragging the road user (or a toggle) asks the server
for the mask that keeps its glare positions within the ADB limits (``/mask``: the
``solve`` function given to :func:`create_adb_app`, :mod:`lightsim.luminaires.adb`'s), then
composes again.

==============  ======  ====================================================================
route           method  what
==============  ======  ====================================================================
``/``           GET     the page (``static/adb.html``)
``/static/…``   GET     its JS (served from the package)
``/maps``       GET     uint32 header length, the JSON header (segment names, width,
                        height, extent in degrees, wall), padded to 4 bytes, then the maps
                        as float32 (G × H × W, row 0 the top), lx
``/mask``       POST    JSON ``{"vehicles": [{"kind", "distance_m", "h_deg"}],
                        "fixed": {name: level}}`` → the levels, verdicts and residual light
                        (one line and status 400 for bad input)
==============  ======  ====================================================================

Every request passes the view's :class:`~lightsim.view.app.Guard` (host names, access
token), as the live view's do.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import LightsimError
from lightsim.persource import PerSourceMaps
from lightsim.view.app import Access, Guard, ViewServer, allowed_hosts, new_token
from lightsim.wall import WallFrame

MAX_BODY = 1 << 16
"""Largest ``/mask`` request (bytes)."""


def maps_payload(maps: PerSourceMaps) -> bytes:
    """The ``/maps`` body (see the module table)."""
    f = WallFrame.from_dict(maps.wall)
    header = json.dumps({"names": list(maps.names), "width": f.width, "height": f.height,
                         "extent_deg": list(f.extent_deg()), "photons": maps.photons,
                         "max_lx": float(maps.all_on().max()) if maps.lux.size else 0.0,
                         "distance_m": f.distance_m}).encode("utf-8")
    header += b" " * (-len(header) % 4)
    return struct.pack("<I", len(header)) + header + np.ascontiguousarray(
        maps.lux, dtype="<f4").tobytes()


def create_adb_app(maps: PerSourceMaps, solve: Callable[[dict[str, Any]], dict[str, Any]],
                   access: Access) -> Any:
    """The starlette app of the panel behind :class:`Guard`."""
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import FileResponse, JSONResponse, Response
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    static = Path(str(resources.files("lightsim.view") / "static"))
    payload = maps_payload(maps)

    async def index(request: Request) -> FileResponse:
        return FileResponse(static / "adb.html", headers={"cache-control": "no-store"})

    async def maps_route(request: Request) -> Response:
        return Response(payload, media_type="application/octet-stream")

    async def mask(request: Request) -> JSONResponse:
        body = await request.body()
        if len(body) > MAX_BODY:
            return JSONResponse({"level": "error", "text": "request too large"}, 413)
        try:
            req = json.loads(body, parse_constant=_no_constant)
            if not isinstance(req, dict):
                raise ValueError("not a JSON object")
        except ValueError as exc:
            return JSONResponse({"level": "error", "text": f"not a mask request ({exc})"}, 400)
        try:
            return JSONResponse(solve(req))
        except LightsimError as exc:
            return JSONResponse({"level": "error", "text": str(exc)}, 400)

    app = Starlette(routes=[Route("/", index), Route("/maps", maps_route),
                            Route("/mask", mask, methods=["POST"]),
                            Mount("/static", StaticFiles(directory=static), name="static")])
    app.add_middleware(Guard, access=access)
    return app


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number")


def serve_adb(maps: PerSourceMaps, solve: Callable[[dict[str, Any]], dict[str, Any]],
              host: str = "127.0.0.1", port: int = 0) -> ViewServer:
    """Serve the panel on ``host``:``port`` (0: any free port) behind a new access token;
    returns the running server (its ``url`` carries the token)."""
    access = Access(new_token(), allowed_hosts(host))
    return ViewServer(create_adb_app(maps, solve, access), port, host=host,
                      token=access.token).start()
