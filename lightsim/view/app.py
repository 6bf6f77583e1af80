"""The web app of ``lightsim view``: page, WebSocket fan-out, scene upload (starlette).

==============  =========  =================================================================
route           method     what
==============  =========  =================================================================
``/``           GET        the page (``static/index.html``)
``/static/…``   GET        the page's JS/CSS (served from the package: no CDN)
``/ws``         WebSocket  server → page: JSON ``hello``/``status``/``regulation``/
                           ``message``/``controls``, binary frames (:mod:`.encode`);
                           page → server: ``{"type": "set", "changes": {…}, "token": n}``,
                           ``{"type": "save"}``, ``{"type": "view", "tab": "wall"|"camera"}``
``/upload``     POST       a second scene as GLB bytes (checked before anything changes)
==============  =========  =================================================================

**Slow browsers.** Every connection has one slot per message kind holding only the
*latest* frame/status; a sender task waits for a slot to fill and sends it. A frame that
arrives while the previous one is still being sent replaces it in the slot: frames are
dropped, never queued (``dropped`` counts them per connection). Messages (errors, save
results) are kept in a short bounded queue instead, so none is lost.

**Several tabs** each get their own connection and slots; all watch the one session. A
dropped connection reconnects (the page retries) and receives ``hello``, the latest frame
and status at once: the session itself never depends on a connection.

The server binds 127.0.0.1 only, and refuses WebSocket handshakes and uploads whose
``Origin`` is another site.
"""

from __future__ import annotations

import asyncio
import json
import socket
import tempfile
import threading
from collections import deque
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

from lightsim.errors import InputError, LightsimError

HOST = "127.0.0.1"
MAX_UPLOAD = 512 * 1024 * 1024  # bytes
SLOTS = ("frame:wall", "frame:camera", "status", "regulation", "controls")


class Connection:
    """One page's WebSocket: latest-value slots plus a bounded message queue."""

    def __init__(self, ws: Any, cid: int) -> None:
        self.ws = ws
        self.id = cid
        self.slots: dict[str, Any] = {}
        self.messages: deque[dict[str, Any]] = deque(maxlen=64)
        self.event = asyncio.Event()
        self.sent = 0
        self.dropped = 0
        self.tab = "wall"

    def post(self, slot: str, payload: Any) -> None:
        if slot == "message":
            self.messages.append(payload)
        else:
            if slot in self.slots and slot.startswith("frame"):
                self.dropped += 1  # the previous frame was never sent: dropped
            self.slots[slot] = payload
        self.event.set()

    async def sender(self) -> None:
        while True:
            await self.event.wait()
            self.event.clear()
            while self.messages:
                await self.ws.send_text(json.dumps({"type": "message",
                                                    **self.messages.popleft()}))
            for slot in SLOTS:
                payload = self.slots.pop(slot, None)
                if payload is None:
                    continue
                if isinstance(payload, bytes):
                    await self.ws.send_bytes(payload)
                else:
                    await self.ws.send_text(json.dumps({"type": slot, **payload}))
                self.sent += 1


class Hub:
    """Fans the session's output out to every connection (thread-safe ``publish``)."""

    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None
        self.connections: dict[int, Connection] = {}
        self.latest: dict[str, Any] = {}
        self._next = 0
        self.on_tabs: Callable[[int], None] | None = None

    def publish(self, kind: str, payload: Any) -> None:
        """Called from the session thread."""
        slot = kind
        if slot != "message":
            self.latest[slot] = payload
        if self.loop is not None and not self.loop.is_closed():
            try:
                self.loop.call_soon_threadsafe(self._post, slot, payload)
            except RuntimeError:  # loop shutting down
                pass

    def _post(self, slot: str, payload: Any) -> None:
        for c in list(self.connections.values()):
            c.post(slot, payload)

    def add(self, ws: Any) -> Connection:
        self._next += 1
        c = Connection(ws, self._next)
        self.connections[c.id] = c
        for slot, payload in self.latest.items():  # a (re)connecting page catches up
            c.post(slot, payload)
        return c

    def remove(self, c: Connection) -> None:
        self.connections.pop(c.id, None)
        self.tabs_changed()

    def tabs_changed(self) -> None:
        if self.on_tabs is not None:
            self.on_tabs(sum(c.tab == "camera" for c in self.connections.values()))


def check_glb(data: bytes) -> None:
    """Raise :class:`InputError` unless ``data`` looks like a binary glTF 2.0 file."""
    if len(data) < 20 or data[:4] != b"glTF":
        raise InputError("the upload is not a GLB file (binary glTF starts with 'glTF')")
    version = int.from_bytes(data[4:8], "little")
    length = int.from_bytes(data[8:12], "little")
    if version != 2:
        raise InputError(f"the upload is glTF version {version}; only version 2 is supported")
    if length != len(data):
        raise InputError(f"the upload is truncated: header says {length} bytes, got {len(data)}")


def same_origin(headers: Any) -> bool:
    """True unless a browser says the request comes from another site.

    Browsers send ``Origin`` with WebSocket handshakes and cross-site POSTs; a page of
    another site must not drive the session (cross-site WebSocket hijacking). Clients
    without ``Origin`` (scripts, curl) are local processes and are let through.
    """
    origin = headers.get("origin")
    return origin is None or origin == f"http://{headers.get('host', '')}"


def create_app(live: Any, hub: Hub, load_upload: Callable[[Path], Any]) -> Any:
    """The starlette application around a :class:`~lightsim.view.live.LiveSession`.

    ``load_upload(path)`` loads an uploaded GLB into a scene (raising
    :class:`InputError` on bad content).
    """
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import FileResponse, JSONResponse
    from starlette.routing import Mount, Route, WebSocketRoute
    from starlette.staticfiles import StaticFiles
    from starlette.websockets import WebSocket, WebSocketDisconnect

    static = Path(str(resources.files("lightsim.view") / "static"))

    async def index(request: Request) -> FileResponse:
        return FileResponse(static / "index.html", headers={"Cache-Control": "no-store"})

    async def upload(request: Request) -> JSONResponse:
        if not same_origin(request.headers):
            return JSONResponse({"level": "error", "text": "cross-origin upload refused"}, 403)
        body = b""
        async for chunk in request.stream():
            body += chunk
            if len(body) > MAX_UPLOAD:
                return JSONResponse({"level": "error", "text": "the upload is too large"}, 413)
        try:
            check_glb(body)
            scene = await asyncio.to_thread(_load_bytes, body, load_upload)
            live.replace_scene(scene)  # checks it has an emitter and a wall
        except LightsimError as exc:
            return JSONResponse({"level": "error", "text": str(exc)}, 400)
        return JSONResponse({"level": "info", "text": "scene accepted; restarting"})

    async def ws_endpoint(ws: WebSocket) -> None:
        if not same_origin(ws.headers):  # another web site in the same browser: refuse
            await ws.close(code=1008)
            return
        await ws.accept()
        hub.loop = asyncio.get_running_loop()
        conn = hub.add(ws)
        await ws.send_text(json.dumps({"type": "hello", "client": conn.id, **live.describe()}))
        task = asyncio.create_task(conn.sender())
        try:
            while True:
                msg = await ws.receive_text()
                reply = handle(conn, msg)
                if reply is not None:
                    conn.post("message", reply)
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            task.cancel()
            hub.remove(conn)

    def handle(conn: Connection, text: str) -> dict[str, Any] | None:
        try:
            msg = json.loads(text)
            if not isinstance(msg, dict):
                raise InputError("a message must be a JSON object")
        except (json.JSONDecodeError, InputError) as exc:
            return {"level": "error", "text": f"bad message: {exc}"}
        kind = msg.get("type")
        if kind == "set":
            try:
                live.submit(msg.get("changes"), {"client": conn.id, "n": msg.get("token")})
            except LightsimError as exc:
                conn.post("controls", live.describe())  # the page snaps back
                return {"level": "error", "text": str(exc)}
            return None
        if kind == "save":
            live.request_save()
            return {"level": "info", "text": "saving the run…"}
        if kind == "view":
            conn.tab = "camera" if msg.get("tab") == "camera" else "wall"
            hub.tabs_changed()
            return None
        return {"level": "error", "text": f"unknown message type {kind!r}"}

    async def stats(request: Request) -> JSONResponse:
        s = live.stats
        return JSONResponse({"frames": s.frames, "images": s.images,
                             "interaction_frames": s.interaction_frames,
                             "edits_applied": s.edits_applied,
                             "edits_coalesced": s.edits_coalesced,
                             "connections": {c.id: {"sent": c.sent, "dropped": c.dropped}
                                             for c in hub.connections.values()},
                             "status": live.last_status})

    def set_watchers(n: int) -> None:
        live.camera_watchers = n

    hub.on_tabs = set_watchers
    routes = [Route("/", index), Route("/upload", upload, methods=["POST"]),
              Route("/stats", stats), WebSocketRoute("/ws", ws_endpoint),
              Mount("/static", StaticFiles(directory=static), name="static")]
    return Starlette(routes=routes)


def serve(live: Any, hub: Hub, load_upload: Callable[[Path], Any], port: int = 0
          ) -> ViewServer:
    """Serve ``live`` (its output published through ``hub``) on 127.0.0.1:``port`` (0 =
    any free port), then start its session thread; returns the running server.

    ``load_upload(path)`` loads an uploaded GLB (see :func:`create_app`).
    """
    server = ViewServer(create_app(live, hub, load_upload), port)
    server.start()
    live.start()
    return server


def _load_bytes(data: bytes, load_upload: Callable[[Path], Any]) -> Any:
    with tempfile.TemporaryDirectory(prefix="lightsim-upload-") as d:
        path = Path(d) / "upload.glb"
        path.write_bytes(data)
        try:
            return load_upload(path)
        except LightsimError:
            raise
        except Exception as exc:  # a GLB header with broken content: one line
            raise InputError(f"the uploaded GLB cannot be read: {type(exc).__name__}: "
                             f"{exc}") from None


class ViewServer:
    """uvicorn serving the app on 127.0.0.1 in a background thread (port 0 = any free)."""

    def __init__(self, app: Any, port: int = 0) -> None:
        import uvicorn

        self.config = uvicorn.Config(app, host=HOST, port=port, log_level="warning",
                                     ws="websockets-sansio", lifespan="off", ws_max_size=1 << 20)
        self.server = uvicorn.Server(self.config)
        self.thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        return int(self.server.servers[0].sockets[0].getsockname()[1])

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.port}/"

    def start(self, timeout: float = 30.0) -> ViewServer:
        if self.config.port:  # a taken port: one line, before uvicorn logs its own
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
                try:
                    probe.bind((HOST, self.config.port))
                except OSError as exc:
                    raise InputError(f"cannot listen on {HOST}:{self.config.port}: "
                                     f"{exc.strerror or exc}") from None
        self.thread = threading.Thread(target=self.server.run, name="lightsim-view-http",
                                       daemon=True)
        self.thread.start()
        waited = 0.0
        while not self.server.started and waited < timeout:
            if not self.thread.is_alive():
                raise LightsimError(f"the web server could not start on {HOST}:"
                                    f"{self.config.port}")
            threading.Event().wait(0.05)
            waited += 0.05
        if not self.server.started:
            raise LightsimError("the web server did not start")
        return self

    def stop(self, timeout: float = 10.0) -> None:
        self.server.should_exit = True
        if self.thread is not None:
            self.thread.join(timeout)
