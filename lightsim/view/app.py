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
``/stats``      GET        the session's counters as JSON (tests and benchmarks)
==============  =========  =================================================================

**Who may use it.** Every request and WebSocket handshake passes :class:`Guard` first,
as Jupyter's server does it:

* its ``Host`` must name the address the server listens on (127.0.0.1, localhost, or
  ``--host``): a web page whose own name was re-pointed at 127.0.0.1 (DNS rebinding)
  still sends its own name and is refused (400);
* a browser's ``Origin``, when sent, must be the page's own (``http://`` + ``Host``):
  another site's page in the same browser is refused (403);
* it must carry the session's access token (:func:`new_token`, printed in the URL as
  ``?token=…``), in the query, as ``Authorization: token …`` or in the cookie the page
  receives with the URL (HttpOnly, SameSite=Strict, per port), compared in constant time
  (403; the page itself gets a form to paste the token into).

Messages are checked before they act (:func:`parse_message`): only the fields of their
type, JSON numbers (no NaN), a save names no place — a run is always saved as a new
``run-…`` folder inside the session folder. A bad message gets one error line in the page.
Uploads larger than ``--max-upload`` are refused from their ``Content-Length`` or as soon
as the stream passes the limit, and a GLB header is checked before the rest is read.

**Slow browsers.** Every connection has one slot per message kind holding only the
*latest* frame/status; a sender task waits for a slot to fill and sends it. A frame that
arrives while the previous one is still being sent replaces it in the slot: frames are
dropped, never queued (``dropped`` counts them per connection). Messages (errors, save
results) are kept in a short bounded queue instead, so none is lost.

**Several tabs** each get their own connection and slots; all watch the one session. A
dropped connection reconnects (the page retries) and receives ``hello``, the latest frame
and status at once: the session itself never depends on a connection.

==================  =====  ==========  ========================================================
constant            unit   value       meaning
==================  =====  ==========  ========================================================
``HOST``            –      127.0.0.1   the default address (this machine only)
``TOKEN_BYTES``     B      24          random bytes of an access token (48 hex digits)
``MAX_MESSAGE``     B      2²⁰         largest WebSocket message (larger: connection closed)
``MAX_DEPTH``       –      32          deepest nesting of a message's JSON
``MAX_TEXT``        –      200         characters of a refused value quoted in a message
==================  =====  ==========  ========================================================
"""

from __future__ import annotations

import asyncio
import hmac
import json
import secrets
import socket
import tempfile
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from http.cookies import CookieError, SimpleCookie
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, quote

from lightsim.errors import InputError, LightsimError
from lightsim.view.settings import ViewSettings

HOST = "127.0.0.1"
LOOPBACK = ("127.0.0.1", "localhost", "::1")
WILDCARDS = ("0.0.0.0", "::")  # listen on every address of this machine
TOKEN_BYTES = 24
MAX_MESSAGE = 1 << 20  # bytes
MAX_DEPTH = 32
MAX_TEXT = 200
SLOTS = ("frame:wall", "frame:camera", "status", "regulation", "controls")
#: the fields each message type may carry (a save carries none: where runs go is fixed)
MESSAGE_FIELDS = {"set": {"changes", "token"}, "save": set(), "view": {"tab"}}
SAFE_INTEGER = 2 ** 53  # the page's edit counters are JavaScript numbers


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


def check_glb_header(head: bytes, limit: int) -> int:
    """The byte length a binary glTF 2.0 header (first 12 bytes) declares, at most
    ``limit``; :class:`InputError` (one line) if it is not one."""
    if len(head) < 12 or head[:4] != b"glTF":
        raise InputError("the upload is not a GLB file (binary glTF starts with 'glTF')")
    version = int.from_bytes(head[4:8], "little")
    length = int.from_bytes(head[8:12], "little")
    if version != 2:
        raise InputError(f"the upload is glTF version {version}; only version 2 is supported")
    if length > limit:
        raise InputError(f"the upload declares {length:,} bytes; at most {limit:,} bytes "
                         f"({limit / 1e6:g} MB) are accepted (--max-upload)")
    return length


def check_glb(data: bytes, limit: int | None = None) -> None:
    """Raise :class:`InputError` unless ``data`` looks like a binary glTF 2.0 file (of at
    most ``limit`` bytes)."""
    if len(data) < 20:
        raise InputError("the upload is not a GLB file (binary glTF starts with 'glTF')")
    length = check_glb_header(data[:12], 1 << 32 if limit is None else limit)
    if length != len(data):
        raise InputError(f"the upload is truncated: header says {length} bytes, got {len(data)}")


def new_token() -> str:
    """A session's access token: ``TOKEN_BYTES`` random bytes as hex (as Jupyter's)."""
    return secrets.token_hex(TOKEN_BYTES)


def host_name(value: str) -> str | None:
    """The host of a ``Host`` header (``name``, ``name:port``, ``[v6]:port``), lower case
    without a trailing dot; None when it is not of that form."""
    v = value.strip().lower()
    if v.startswith("["):
        end = v.find("]")
        name, rest = (v[1:end], v[end + 1:]) if end > 0 else ("", "")
    else:
        name, _, port = v.partition(":")
        rest = f":{port}" if _ else ""
    if not name or (rest and not (rest[:1] == ":" and rest[1:].isdigit())):
        return None
    return name.rstrip(".")


def allowed_hosts(host: str) -> frozenset[str]:
    """Host names a request may carry to a server listening on ``host``: the loopback
    names, ``host`` itself and what it resolves to; for a wildcard (0.0.0.0, ::) also
    this machine's name, full name and the addresses they resolve to."""
    names = {*LOOPBACK, host}
    lookups = [host]
    if host in WILDCARDS:
        names |= {socket.gethostname(), socket.getfqdn()}
        lookups = [socket.gethostname(), socket.getfqdn()]
    for name in lookups:
        try:
            infos = socket.getaddrinfo(name, None, type=socket.SOCK_STREAM)
        except (OSError, UnicodeError):
            continue
        names |= {str(info[4][0]) for info in infos}
    return frozenset(n.strip().lower().rstrip(".") for n in names if n and n not in WILDCARDS)


def _headers(scope: dict[str, Any], name: bytes) -> list[str]:
    return [v.decode("latin-1") for k, v in scope.get("headers", []) if k.lower() == name]


def _cookie_name(scope: dict[str, Any]) -> str:
    """The token's cookie name: cookies are per host, not per port, so two sessions on
    one machine each have their own (as Jupyter names them)."""
    server = scope.get("server") or ("", 0)
    return f"lightsim-view-{server[1] or 0}"


@dataclass(frozen=True)
class Access:
    """Who may use the app: the ``Host`` names of the listening address and the
    session's access token (see the module docstring)."""

    token: str
    hosts: frozenset[str]

    def tokens(self, scope: dict[str, Any]) -> tuple[list[str], bool]:
        """(tokens the request presents, whether one came from the cookie)."""
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        found = list(query.get("token", []))
        for value in _headers(scope, b"authorization"):
            kind, _, rest = value.strip().partition(" ")
            if kind.lower() in ("token", "bearer") and rest.strip():
                found.append(rest.strip())
        cookies: list[str] = []
        jar: SimpleCookie = SimpleCookie()
        for value in _headers(scope, b"cookie"):
            try:
                jar.load(value)
            except CookieError:
                continue
        morsel = jar.get(_cookie_name(scope))
        if morsel is not None:
            cookies.append(morsel.value)
        return found + cookies, bool(cookies)

    def token_ok(self, presented: list[str]) -> bool:
        """Whether one of ``presented`` is the token (each compared in constant time)."""
        want = self.token.encode("utf-8")
        ok = False
        for t in presented:
            ok |= hmac.compare_digest(t.encode("utf-8", "surrogateescape"), want)
        return ok

    def refusal(self, scope: dict[str, Any]) -> tuple[int, str] | None:
        """(status, one line) why this request is refused, or None when it may pass."""
        hosts = _headers(scope, b"host")
        name = host_name(hosts[0]) if len(hosts) == 1 else None
        if name is None or name not in self.hosts:
            shown = hosts[0][:MAX_TEXT] if hosts else "none"
            return 400, f"refused: the request is addressed to host {shown!r}, not this server"
        origins = _headers(scope, b"origin")
        if origins:
            origin = origins[0].strip().lower()
            own = hosts[0].strip().lower()
            if len(origins) > 1 or origin not in (f"http://{own}", f"https://{own}"):
                return 403, f"refused: a page of another site ({origins[0][:MAX_TEXT]!r})"
        presented, _ = self.tokens(scope)
        if not presented:
            return 403, "refused: no access token (open the address lightsim view printed)"
        if not self.token_ok(presented):
            return 403, "refused: wrong access token"
        return None


LOGIN_PAGE = """<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>lightsim view</title></head><body style="font-family: sans-serif; margin: 3em">
<p><b>lightsim view</b>: {why}.</p>
<p>Open the address <code>lightsim view</code> printed (it ends in <code>?token=…</code>),
or paste its token:</p>
<form method="get" action="/"><input name="token" size="52" autocomplete="off">
<button>open</button></form></body></html>
"""


class Guard:
    """ASGI middleware in front of every route: refuses what :meth:`Access.refusal`
    refuses (HTTP: one line, the page a token form; WebSocket: closed before it opens,
    which the client sees as HTTP 403), and hands a token given in the URL or a header
    to the browser as a cookie so that the page's own requests carry it."""

    def __init__(self, app: Any, access: Access) -> None:
        self.app = app
        self.access = access

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        refused = self.access.refusal(scope)
        if scope["type"] == "websocket":
            if refused is not None:
                await receive()  # websocket.connect
                await send({"type": "websocket.close", "code": 1008,
                            "reason": refused[1][:120]})
                return
            await self.app(scope, receive, send)
            return
        if refused is not None:
            await self._refuse(scope, send, *refused)
            return
        _, from_cookie = self.access.tokens(scope)
        cookie = None if from_cookie else (
            f"{_cookie_name(scope)}={self.access.token}; Path=/; HttpOnly; SameSite=Strict")

        async def send_with_headers(message: dict[str, Any]) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers += [(b"referrer-policy", b"no-referrer"),
                            (b"x-frame-options", b"DENY")]
                if cookie is not None:
                    headers.append((b"set-cookie", cookie.encode("latin-1")))
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, send_with_headers)

    @staticmethod
    async def _refuse(scope: dict[str, Any], send: Any, status: int, why: str) -> None:
        page = scope.get("method") == "GET" and scope.get("path") == "/" and status == 403
        if page:
            body = LOGIN_PAGE.format(why=why.replace("<", "&lt;")).encode("utf-8")
            kind = b"text/html; charset=utf-8"
        else:
            body = json.dumps({"level": "error", "text": why}).encode("utf-8")
            kind = b"application/json"
        await send({"type": "http.response.start", "status": status,
                    "headers": [(b"content-type", kind),
                                (b"content-length", str(len(body)).encode()),
                                (b"referrer-policy", b"no-referrer"),
                                (b"x-frame-options", b"DENY")]})
        await send({"type": "http.response.body", "body": body})


def _no_constant(name: str) -> Any:
    raise InputError(f"{name} is not a JSON number")


def _depth(obj: Any) -> int:
    """Nesting depth of a parsed JSON value (iterative: any depth is safe)."""
    deepest, stack = 0, [(obj, 1)]
    while stack:
        o, d = stack.pop()
        deepest = max(deepest, d)
        if d > MAX_DEPTH:
            break
        if isinstance(o, dict):
            stack += [(v, d + 1) for v in o.values()]
        elif isinstance(o, list):
            stack += [(v, d + 1) for v in o]
    return deepest


def parse_message(text: str) -> dict[str, Any]:
    """A page's message, checked: a JSON object of a known type with only that type's
    fields (:data:`MESSAGE_FIELDS`); :class:`InputError` (one line) otherwise."""
    if text.count("[") + text.count("{") > 4 * MAX_DEPTH:  # no deep recursion in json
        nested = _nesting(text)
        if nested > MAX_DEPTH:
            raise InputError(f"bad message: nested {nested} deep (at most {MAX_DEPTH})")
    try:
        msg = json.loads(text, parse_constant=_no_constant)
    except ValueError as exc:
        raise InputError(f"bad message: not JSON ({str(exc)[:MAX_TEXT]})") from None
    if not isinstance(msg, dict):
        raise InputError("bad message: a message must be a JSON object")
    if _depth(msg) > MAX_DEPTH:
        raise InputError(f"bad message: nested more than {MAX_DEPTH} deep")
    kind = msg.get("type")
    if not isinstance(kind, str) or kind not in MESSAGE_FIELDS:
        raise InputError(f"unknown message type {_short(kind)}")
    extra = sorted(str(k) for k in msg if k != "type" and k not in MESSAGE_FIELDS[kind])
    if extra:
        where = " (runs are saved in the session folder)" if kind == "save" else ""
        raise InputError(f"a {kind} message has no field {_short(', '.join(extra))}{where}")
    if kind == "set":
        changes = msg.get("changes")
        if not isinstance(changes, dict) or not changes:
            raise InputError("a set message needs changes: an object of control: value")
        n = msg.get("token")
        if n is not None and (isinstance(n, bool) or not isinstance(n, int)
                              or abs(n) > SAFE_INTEGER):
            raise InputError(f"a set message's token must be a whole number, got {_short(n)}")
    if kind == "view" and msg.get("tab") not in ("wall", "camera"):
        raise InputError(f"tab must be 'wall' or 'camera', got {_short(msg.get('tab'))}")
    return msg


def _nesting(text: str) -> int:
    """Deepest bracket nesting of ``text`` outside strings (bounded work, no recursion)."""
    depth = deepest = 0
    in_string = escaped = False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    return deepest


def _short(value: Any) -> str:
    """``value`` quoted for a one-line message, cut at ``MAX_TEXT`` characters."""
    text = repr(value)
    return text if len(text) <= MAX_TEXT else text[:MAX_TEXT] + "…"


def create_app(live: Any, hub: Hub, load_upload: Callable[[Path], Any],
               settings: ViewSettings | None = None, access: Access | None = None) -> Any:
    """The starlette application around a :class:`~lightsim.view.live.LiveSession`,
    behind :class:`Guard` (``access``: the token and host names; default a new token and
    ``settings.host``'s names).

    ``load_upload(path)`` loads an uploaded GLB into a scene (raising
    :class:`InputError` on bad content); ``settings.max_upload_mb`` limits uploads.
    """
    from starlette.applications import Starlette
    from starlette.requests import Request
    from starlette.responses import FileResponse, JSONResponse
    from starlette.routing import Mount, Route, WebSocketRoute
    from starlette.staticfiles import StaticFiles
    from starlette.websockets import WebSocket, WebSocketDisconnect

    settings = settings if settings is not None else ViewSettings()
    if access is None:
        access = Access(new_token(), allowed_hosts(settings.host))
    limit = int(settings.max_upload_mb * 1e6)
    static = Path(str(resources.files("lightsim.view") / "static"))

    def error(text: str, status: int) -> JSONResponse:
        return JSONResponse({"level": "error", "text": text}, status)

    async def index(request: Request) -> FileResponse:
        return FileResponse(static / "index.html", headers={"Cache-Control": "no-store"})

    async def upload(request: Request) -> JSONResponse:
        declared = request.headers.get("content-length")
        if declared is not None:
            if not declared.strip().isdigit():
                return error("the upload has a bad Content-Length", 400)
            if int(declared) > limit:
                return error(f"the upload is {int(declared) / 1e6:.1f} MB; at most "
                             f"{limit / 1e6:g} MB are accepted (--max-upload)", 413)
        body = bytearray()
        length = None
        try:
            async for chunk in request.stream():
                body += chunk
                if length is None and len(body) >= 12:
                    length = check_glb_header(bytes(body[:12]), limit)  # before the rest
                if len(body) > limit:
                    return error(f"the upload is larger than {limit / 1e6:g} MB "
                                 f"(--max-upload)", 413)
            check_glb(bytes(body), limit)
            scene = await asyncio.to_thread(_load_bytes, bytes(body), load_upload)
            live.replace_scene(scene)  # checks it has an emitter and a wall
        except LightsimError as exc:
            return error(str(exc), 400)
        return JSONResponse({"level": "info", "text": "scene accepted; restarting"})

    async def ws_endpoint(ws: WebSocket) -> None:
        await ws.accept()
        hub.loop = asyncio.get_running_loop()
        conn = hub.add(ws)
        await ws.send_text(json.dumps({"type": "hello", "client": conn.id, **live.describe()}))
        task = asyncio.create_task(conn.sender())
        try:
            while True:
                message = await ws.receive()
                if message["type"] == "websocket.disconnect":
                    break
                text = message.get("text")
                if text is None:
                    reply: dict[str, Any] | None = {
                        "level": "error", "text": "bad message: messages are JSON text, "
                        "not binary"}
                else:
                    reply = handle(conn, text)
                if reply is not None:
                    conn.post("message", reply)
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            task.cancel()
            hub.remove(conn)

    def handle(conn: Connection, text: str) -> dict[str, Any] | None:
        try:
            msg = parse_message(text)
        except InputError as exc:
            return {"level": "error", "text": str(exc)}
        kind = msg["type"]
        if kind == "set":
            try:
                live.submit(msg["changes"], {"client": conn.id, "n": msg.get("token")})
            except LightsimError as exc:
                conn.post("controls", live.describe())  # the page snaps back
                return {"level": "error", "text": _cut(str(exc))}
            return None
        if kind == "save":
            live.request_save()
            return {"level": "info", "text": "saving the run…"}
        conn.tab = msg["tab"]
        hub.tabs_changed()
        return None

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
    app = Starlette(routes=routes)
    app.add_middleware(Guard, access=access)
    return app


def _cut(text: str) -> str:
    return text if len(text) <= 2 * MAX_TEXT else text[:2 * MAX_TEXT] + "…"


def serve(live: Any, hub: Hub, load_upload: Callable[[Path], Any],
          settings: ViewSettings | None = None) -> ViewServer:
    """Serve ``live`` (its output published through ``hub``) on ``settings.host``:
    ``settings.port`` (0 = any free port) behind a new access token, then start its
    session thread; returns the running server (its ``url`` carries the token).

    ``load_upload(path)`` loads an uploaded GLB (see :func:`create_app`).
    """
    settings = settings if settings is not None else ViewSettings(port=0)
    access = Access(new_token(), allowed_hosts(settings.host))
    server = ViewServer(create_app(live, hub, load_upload, settings, access), settings.port,
                        host=settings.host, token=access.token)
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


def url_host(host: str) -> str:
    """``host`` as the host part of a URL: this machine's name for a wildcard, IPv6
    addresses in brackets."""
    if host in WILDCARDS:
        host = socket.gethostname()
    return f"[{host}]" if ":" in host else host


class ViewServer:
    """uvicorn serving the app on ``host``:``port`` in a background thread (port 0 = any
    free); ``token`` is the access token its ``url`` carries."""

    def __init__(self, app: Any, port: int = 0, *, host: str = HOST, token: str = "") -> None:
        import uvicorn

        self.host = host
        self.token = token
        self.config = uvicorn.Config(app, host=host, port=port, log_level="warning",
                                     ws="websockets-sansio", lifespan="off",
                                     ws_max_size=MAX_MESSAGE)
        self.server = uvicorn.Server(self.config)
        self.thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        return int(self.server.servers[0].sockets[0].getsockname()[1])

    @property
    def url(self) -> str:
        """The page's address with the access token (what the command prints)."""
        query = f"?token={quote(self.token)}" if self.token else ""
        return f"http://{url_host(self.host)}:{self.port}/{query}"

    @property
    def loopback(self) -> bool:
        """Whether only this machine can reach the server."""
        return self.host in ("127.0.0.1", "localhost", "::1") or self.host.startswith("127.")

    def start(self, timeout: float = 30.0) -> ViewServer:
        self._probe()
        self.thread = threading.Thread(target=self.server.run, name="lightsim-view-http",
                                       daemon=True)
        self.thread.start()
        waited = 0.0
        while not self.server.started and waited < timeout:
            if not self.thread.is_alive():
                raise LightsimError(f"the web server could not start on {self.host}:"
                                    f"{self.config.port}")
            threading.Event().wait(0.05)
            waited += 0.05
        if not self.server.started:
            raise LightsimError("the web server did not start")
        return self

    def _probe(self) -> None:
        """An unknown address, one of another machine or a taken port: one line, before
        uvicorn logs its own."""
        where = f"{self.host}:{self.config.port}"
        try:
            infos = socket.getaddrinfo(self.host, self.config.port, type=socket.SOCK_STREAM)
        except (OSError, UnicodeError) as exc:
            raise InputError(f"cannot listen on {where}: {getattr(exc, 'strerror', None) or exc}"
                             ) from None
        family, kind, proto, _, address = infos[0]
        with socket.socket(family, kind, proto) as probe:
            try:
                probe.bind(address)
            except OSError as exc:
                raise InputError(f"cannot listen on {where}: {exc.strerror or exc}") from None

    def stop(self, timeout: float = 10.0) -> None:
        self.server.should_exit = True
        if self.thread is not None:
            self.thread.join(timeout)
