"""Who may use ``lightsim view``: the Host check, the Origin check and the access token,
tried from outside with raw HTTP and WebSocket clients and in the real browser.

Each refusal is tried with everything else right (the token known, the Host or Origin
the page's own), so a test fails if that one check is missing. The DNS-rebinding case is
the request a page of another site sends once its name points at 127.0.0.1: its own name
in ``Host`` and ``Origin`` (``evil.example:PORT``).
"""

from __future__ import annotations

import base64
import http.client
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest
import trimesh
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from lightsim.errors import InputError
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart
from lightsim.luminaires.live import start_view
from lightsim.view.app import (
    Access,
    allowed_hosts,
    check_glb_header,
    host_name,
    new_token,
    parse_message,
)
from lightsim.view.settings import ViewSettings

from support import run_cli, write_point_lamp

CHROMIUM = "/usr/bin/chromium"
EVIL = "evil.example"

try:
    from playwright.sync_api import sync_playwright
except ImportError:  # pragma: no cover
    sync_playwright = None


def _scene(path: Path) -> Path:
    m = trimesh.creation.box((0.05, 0.05, 0.002))
    m.apply_translation((0.0, 0.0, -0.03))
    mirror = GltfPart("reflector", np.asarray(m.vertices), np.asarray(m.faces), None,
                      GltfMaterial("chrome", base_color=(0.9, 0.9, 0.9), metallic=1.0))
    return write_point_lamp(path, mirror)


@pytest.fixture(scope="module")
def view(tmp_path_factory):
    """A running view (no warm-up: only the server's checks are tried here) with a
    64 kB upload limit."""
    d = tmp_path_factory.mktemp("view")
    scene = _scene(d / "lamp.glb")
    live, server = start_view(str(scene), ViewSettings(
        port=0, resolution=(32, 16), frame_photons=5000, camera=False, regulation=None,
        warm_up=False, max_upload_mb=0.064), folder=d / "session")
    live.ready.wait(120)
    try:
        yield live, server, d
    finally:
        server.stop()
        live.stop()


def _request(server, method: str, path: str, headers: dict[str, str] | None = None,
             body: bytes | None = None) -> tuple[int, dict[str, str], bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
    try:
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        for k, v in (headers or {}).items():
            conn.putheader(k, v)
        if body is not None:
            conn.putheader("Content-Length", str(len(body)))
        conn.endheaders(body)
        r = conn.getresponse()
        return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    finally:
        conn.close()


def _own(server) -> str:
    return f"127.0.0.1:{server.port}"


def _ws(server, headers: dict[str, str], query: str = ""):
    """A raw WebSocket to the view; ``headers["Host"]`` becomes the URI's host (the
    connection still goes to 127.0.0.1), ``headers["Origin"]`` the handshake's Origin."""
    headers = dict(headers)
    host = headers.pop("Host", _own(server))
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=20)
    return connect(f"ws://{host}/ws{query}", sock=sock, origin=headers.pop("Origin", None),
                   additional_headers=headers, open_timeout=20, close_timeout=5)


def _refused_ws(server, headers: dict[str, str], query: str = "") -> int:
    with pytest.raises(InvalidStatus) as exc, _ws(server, headers, query):
        pass
    return exc.value.response.status_code


def _glb(server_dir: Path) -> bytes:
    return (server_dir / "lamp.glb").read_bytes()


# -- HTTP ----------------------------------------------------------------------------------
def test_the_page_with_the_printed_token_and_its_cookie(view):
    _, server, _ = view
    token = server.token
    assert len(token) == 48 and server.url.endswith(f"/?token={token}")
    assert server.url.startswith("http://127.0.0.1:")
    status, headers, body = _request(server, "GET", f"/?token={token}",
                                     {"Host": _own(server)})
    assert status == 200 and b"<script" in body
    cookie = headers["set-cookie"].split(";")[0]
    assert token in cookie and "HttpOnly" in headers["set-cookie"]
    assert "SameSite=Strict" in headers["set-cookie"]
    # the page's own requests carry only the cookie
    for path in ("/static/view.js", "/stats"):
        status, _, _ = _request(server, "GET", path, {"Host": _own(server), "Cookie": cookie})
        assert status == 200, path
    status, _, body = _request(server, "GET", "/stats", {
        "Host": f"localhost:{server.port}", "Authorization": f"token {token}"})
    assert status == 200 and "edits_applied" in json.loads(body)


def test_missing_or_wrong_token_is_refused(view):
    _, server, _ = view
    token = server.token
    wrong = token[:-1] + ("0" if token[-1] != "0" else "1")  # same length, last digit off
    for path in ("/", "/stats", "/static/view.js"):
        status, _, _ = _request(server, "GET", path, {"Host": _own(server)})
        assert status == 403, path
        status, _, _ = _request(server, "GET", f"{path}?token={wrong}", {"Host": _own(server)})
        assert status == 403, path
    status, headers, body = _request(server, "GET", "/", {"Host": _own(server)})
    assert b"<form" in body and "set-cookie" not in headers  # the page asks for the token
    status, _, _ = _request(server, "GET", "/stats", {
        "Host": _own(server), "Cookie": f"lightsim-view-{server.port}={wrong}"})
    assert status == 403
    status, _, body = _request(server, "POST", "/upload", {"Host": _own(server)},
                               _glb(view[2]))
    assert status == 403 and b"no access token" in body


def test_foreign_host_is_refused_even_with_the_token(view):
    _, server, _ = view
    t = server.token
    for host in (f"{EVIL}:{server.port}", EVIL, f"127.0.0.1.{EVIL}:{server.port}",
                 f"localhost.:{server.port}x", ""):
        status, _, body = _request(server, "GET", f"/stats?token={t}", {"Host": host})
        assert status == 400, (host, body)
    status, _, _ = _request(server, "GET", f"/stats?token={t}", {})  # no Host at all
    assert status == 400


def test_foreign_origin_is_refused_even_with_the_token(view):
    _, server, d = view
    t = server.token
    for origin in (f"http://{EVIL}", f"http://{EVIL}:{server.port}", "null",
                   f"http://127.0.0.1:{server.port + 1}"):
        status, _, _ = _request(server, "POST", f"/upload?token={t}",
                                {"Host": _own(server), "Origin": origin}, _glb(d))
        assert status == 403, origin


def test_dns_rebinding_is_refused(view):
    """A page of evil.example rebound to 127.0.0.1: its own name as Host and Origin."""
    live, server, d = view
    rebound = {"Host": f"{EVIL}:{server.port}", "Origin": f"http://{EVIL}:{server.port}"}
    applied = live.stats.edits_applied
    status, _, body = _request(server, "POST", "/upload", rebound, _glb(d))
    assert status == 400 and b"not this server" in body
    status, _, _ = _request(server, "GET", "/stats", rebound)
    assert status == 400
    # even a page that somehow learnt the token
    status, _, _ = _request(server, "GET", f"/stats?token={server.token}", rebound)
    assert status == 400
    assert _refused_ws(server, rebound) == 403
    assert _refused_ws(server, rebound, f"?token={server.token}") == 403
    assert live.stats.edits_applied == applied


# -- WebSocket -----------------------------------------------------------------------------
def test_websocket_needs_host_origin_and_token(view):
    _, server, _ = view
    t = server.token
    own = {"Host": _own(server), "Origin": f"http://{_own(server)}"}
    assert _refused_ws(server, own) == 403  # no token
    assert _refused_ws(server, own, f"?token={t[:-2]}") == 403  # wrong token
    assert _refused_ws(server, {**own, "Origin": f"http://{EVIL}"}, f"?token={t}") == 403
    assert _refused_ws(server, {**own, "Host": f"{EVIL}:{server.port}"}, f"?token={t}") == 403
    # the page's way: the cookie; a script's way: the query
    for headers, query in (({**own, "Cookie": f"lightsim-view-{server.port}={t}"}, ""),
                           (own, f"?token={t}")):
        with _ws(server, headers, query) as ws:
            hello = _next_json(ws, "hello")
            assert "controls" in hello


def _next_json(ws, kind: str | None = None, level: str | None = None,
               timeout: float = 30.0) -> dict:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = ws.recv(timeout=max(end - time.monotonic(), 0.01))
        if isinstance(msg, bytes):
            continue
        data = json.loads(msg)
        if kind is not None and data.get("type") != kind:
            continue
        if level is not None and data.get("level") != level:
            continue
        return data
    raise AssertionError(f"no {kind or level} message in {timeout} s")


def test_bad_messages_get_one_line_in_the_page(view):
    live, server, _ = view
    with _ws(server, {"Host": _own(server)}, f"?token={server.token}") as ws:
        for text, words in (("not json", "not JSON"), ('{"type": "set", "changes": '
                            '{"k": NaN}}', "not a JSON number"),
                            ("[" * 100000 + "]" * 100000, "nested"),
                            ('{"type": "launch"}', "unknown message type"),
                            ('{"type": "set", "changes": {"k": "x"}}', "k"),
                            ('{"type": "view", "tab": "../../etc"}', "tab"),
                            ('{"type": "set", "changes": {}, "token": 1e400}', "changes")):
            ws.send(text)
            msg = _next_json(ws, "message", "error")
            assert words in msg["text"] and "\n" not in msg["text"], (text[:40], msg)
        ws.send(b"\x00binary")
        assert "binary" in _next_json(ws, "message", "error")["text"]
        ws.send(json.dumps({"type": "view", "tab": "wall"}))  # still served
        ws.send(json.dumps({"type": "set", "changes": {"k": 32}, "token": 1}))
    end = time.monotonic() + 60
    while live.controls.k != 32 and time.monotonic() < end:
        time.sleep(0.1)
    assert live.controls.k == 32


def test_a_saved_run_stays_in_the_session_folder(view, tmp_path):
    _, server, d = view
    session = d / "session"
    outside = tmp_path / "elsewhere"
    with _ws(server, {"Host": _own(server)}, f"?token={server.token}") as ws:
        for extra in ({"path": str(outside)}, {"folder": "../../x"}, {"name": "/etc/x"}):
            ws.send(json.dumps({"type": "save", **extra}))
            msg = _next_json(ws, "message", "error")
            assert "no field" in msg["text"] and "session folder" in msg["text"]
        ws.send(json.dumps({"type": "save"}))
        msg = _next_json(ws, "message", timeout=120)
        while "saving" in msg["text"]:
            msg = _next_json(ws, "message", timeout=120)
        assert msg["level"] == "info" and msg.get("saved"), msg
    assert not outside.exists() and not (d / "x").exists()
    runs = [p for p in session.iterdir() if p.is_dir()]
    assert len(runs) == 1 and runs[0].name.startswith("run-")
    assert (runs[0] / "summary.json").is_file()


# -- uploads -------------------------------------------------------------------------------
def test_uploads_are_limited_before_they_are_read(view):
    _, server, _ = view
    auth = {"Host": _own(server), "Authorization": f"token {server.token}"}
    big = b"glTF" + (2).to_bytes(4, "little") + (10**6).to_bytes(4, "little") + \
        bytes(100_000 - 12)
    status, _, body = _request(server, "POST", "/upload", auth, big)
    assert status == 413 and b"--max-upload" in body
    # a small body whose header declares more than the limit: refused from the header
    status, _, body = _request(server, "POST", "/upload", auth, big[:4000])
    assert status == 400 and b"declares" in body
    # a stream without Content-Length is cut once it passes the limit
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
    conn.putrequest("POST", "/upload", skip_host=True)
    for k, v in {**auth, "Transfer-Encoding": "chunked"}.items():
        conn.putheader(k, v)
    conn.endheaders()
    chunk = bytes(16_384)
    try:
        for _ in range(8):
            conn.send(b"%x\r\n%s\r\n" % (len(chunk), chunk))
        conn.send(b"0\r\n\r\n")
    except OSError:
        pass  # the server may close as soon as it refuses
    r = conn.getresponse()
    assert r.status in (400, 413)  # zeros: not a GLB header, or past the limit
    conn.close()
    status, _, body = _request(server, "POST", "/upload", auth, b"not a glb at all")
    assert status == 400 and b"not a GLB" in body


def test_check_glb_header_and_settings():
    head = b"glTF" + (2).to_bytes(4, "little") + (5000).to_bytes(4, "little")
    assert check_glb_header(head, 10_000) == 5000
    with pytest.raises(InputError, match="declares"):
        check_glb_header(head, 1000)
    with pytest.raises(InputError, match="version 1"):
        check_glb_header(b"glTF" + (1).to_bytes(4, "little") + bytes(4), 10_000)
    for bad in ("", "a b", "http://x", "x/y", "user@host"):
        with pytest.raises(InputError, match="--host"):
            ViewSettings(host=bad)
    with pytest.raises(InputError, match="--max-upload"):
        ViewSettings(max_upload_mb=0)


# -- names and tokens ----------------------------------------------------------------------
def test_host_names_and_token_checks():
    assert host_name("LocalHost.:8765") == "localhost"
    assert host_name("[::1]:80") == "::1"
    assert host_name("evil.example:80:81") is None and host_name("a:b") is None
    assert allowed_hosts("127.0.0.1") >= {"127.0.0.1", "localhost", "::1"}
    assert EVIL not in allowed_hosts("127.0.0.1")
    wild = allowed_hosts("0.0.0.0")
    assert socket.gethostname().lower() in wild and "0.0.0.0" not in wild
    a, b = new_token(), new_token()
    assert a != b and len(a) == 48 and int(a, 16) >= 0
    access = Access(a, allowed_hosts("127.0.0.1"))
    scope = {"type": "http", "headers": [(b"host", b"127.0.0.1:1")], "server": ("", 1),
             "query_string": f"token={a}".encode()}
    assert access.refusal(scope) is None
    scope["query_string"] = "token=\udcff".encode("utf-8", "surrogateescape")
    assert access.refusal(scope)[0] == 403
    scope["headers"] = [(b"host", b"127.0.0.1:1"), (b"host", b"evil.example")]
    assert access.refusal(scope)[0] == 400  # two Host headers: refused


def test_parse_message_accepts_only_known_fields():
    assert parse_message('{"type": "save"}') == {"type": "save"}
    assert parse_message('{"type": "view", "tab": "camera"}')["tab"] == "camera"
    assert parse_message('{"type": "set", "changes": {"k": 8}, "token": 3}')["token"] == 3
    for bad in ('{"type": "save", "out": "/tmp"}', '{"type": "set", "changes": {"k": 8}, '
                '"token": true}', '"save"', '{"type": ["save"]}', "Infinity"):
        with pytest.raises(InputError):
            parse_message(bad)


# -- remote use (--host) -------------------------------------------------------------------
def test_host_option_listens_where_asked_and_keeps_the_checks(tmp_path):
    scene = _scene(tmp_path / "lamp.glb")
    live, server = start_view(str(scene), ViewSettings(
        host="0.0.0.0", port=0, resolution=(32, 16), frame_photons=5000, camera=False,
        regulation=None, warm_up=False), folder=tmp_path / "session")
    try:
        assert not server.loopback
        assert server.server.servers[0].sockets[0].getsockname()[0] == "0.0.0.0"
        name = socket.gethostname()
        assert server.url.startswith(f"http://{name}:")
        t = server.token
        for host in (name, "127.0.0.1", "localhost"):
            status, _, _ = _request(server, "GET", f"/stats?token={t}",
                                    {"Host": f"{host}:{server.port}"})
            assert status == 200, host
        status, _, _ = _request(server, "GET", "/stats", {"Host": f"{name}:{server.port}"})
        assert status == 403  # remote use needs the token too
        status, _, _ = _request(server, "GET", f"/stats?token={t}",
                                {"Host": f"{EVIL}:{server.port}"})
        assert status == 400
    finally:
        server.stop()
        live.stop()


@pytest.mark.timeout(240)
def test_view_command_prints_the_token_url_and_the_unencrypted_line(tmp_path):
    scene = _scene(tmp_path / "lamp.glb")
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "lightsim.cli", "view", str(scene), "--host", "0.0.0.0",
         "--port", "0", "--resolution", "32x16", "--frame-photons", "5000", "--regulation",
         "none", "--out", str(tmp_path / "session")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    lines: list[str] = []

    def read(stream) -> None:
        for line in stream:
            lines.append(line.rstrip("\n"))

    readers = [threading.Thread(target=read, args=(s,), daemon=True)
               for s in (proc.stdout, proc.stderr)]
    for r in readers:
        r.start()
    try:
        end = time.monotonic() + 200
        while time.monotonic() < end and proc.poll() is None and not any(
                "unencrypted" in ln for ln in lines):
            time.sleep(0.2)
        url = [ln for ln in lines if "?token=" in ln]
        assert url, lines
        assert [ln for ln in lines if "unencrypted unless tunnelled" in ln], lines
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    assert not any("Traceback" in ln for ln in lines), lines


def test_view_command_bad_host_is_one_line(capsys, tmp_path):
    scene = _scene(tmp_path / "lamp.glb")
    for host, words in (("no-such-host.invalid", "cannot listen"), ("a b", "--host"),
                        ("192.0.2.1", "cannot listen")):
        code, _, err = run_cli(["view", str(scene), "--host", host, "--port", "0", "--out",
                                str(tmp_path / "s"), "--regulation", "none"], capsys)
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err


# -- the real browser ----------------------------------------------------------------------
class _EvilPage(BaseHTTPRequestHandler):
    """Another site's page that tries to drive the view at ``target`` (WebSocket, upload,
    read the statistics) and writes what it got into the page's title."""

    target = ""
    glb = b""

    def do_GET(self) -> None:
        body = f"""<!doctype html><html><body><script>
        const out = [];
        const done = () => {{ document.title = "done:" + out.join(","); }};
        const ws = new WebSocket("ws://{self.target}/ws");
        ws.onopen = () => {{ out.push("ws-open"); ws.send('{{"type":"save"}}'); finish(); }};
        ws.onerror = () => {{ out.push("ws-refused"); finish(); }};
        let left = 3;
        function finish() {{ if (--left === 0) done(); }}
        const glb = Uint8Array.from(atob("{base64.b64encode(self.glb).decode()}"),
                                    c => c.charCodeAt(0));
        fetch("http://{self.target}/upload", {{method: "POST", body: glb,
              mode: "no-cors"}}).then(() => {{ out.push("upload-sent"); finish(); }},
              () => {{ out.push("upload-failed"); finish(); }});
        fetch("http://{self.target}/stats").then(r => r.text()).then(
              t => {{ out.push("stats-read"); finish(); }},
              () => {{ out.push("stats-refused"); finish(); }});
        </script></body></html>""".encode()
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args) -> None:
        pass


@pytest.mark.timeout(240)
def test_browser_page_works_and_other_sites_are_refused(view):
    if sync_playwright is None or not Path(CHROMIUM).exists():
        pytest.skip("playwright or Debian's chromium is missing")
    live, server, d = view
    saved = sorted(p.name for p in (d / "session").iterdir())
    evil = ThreadingHTTPServer(("127.0.0.1", 0), _EvilPage)
    _EvilPage.target = _own(server)
    _EvilPage.glb = _glb(d)  # a good scene: accepted, it would replace the session's
    threading.Thread(target=evil.serve_forever, daemon=True).start()
    evil_port = evil.server_address[1]
    try:
        with sync_playwright() as p:
            # evil.example resolves to 127.0.0.1 in this browser: the rebinding case
            browser = p.chromium.launch(executable_path=CHROMIUM, args=[
                "--no-sandbox", f"--host-resolver-rules=MAP {EVIL} 127.0.0.1"])
            ctx = browser.new_context()
            page = ctx.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            # the page with the printed address works (its requests carry the cookie)
            page.goto(server.url)
            page.wait_for_function("window.lightsimView && window.lightsimView.connected "
                                   "&& window.lightsimView.wallFrames >= 1", timeout=120_000)
            assert not errors, errors
            # the same address without the token: the token form, no session
            other = browser.new_context().new_page()
            r = other.goto(f"http://{_own(server)}/")
            assert r.status == 403 and other.locator("form input[name=token]").count() == 1
            # the page of another site, in the browser that holds the cookie
            attacker = ctx.new_page()
            attacker.goto(f"http://127.0.0.1:{evil_port}/")
            attacker.wait_for_function("document.title.startsWith('done:')", timeout=60_000)
            got = attacker.title()
            assert "ws-refused" in got and "ws-open" not in got, got
            assert "stats-refused" in got, got
            # DNS rebinding: evil.example now points at the view's address and port
            rebound = ctx.new_page()
            r = rebound.goto(f"http://{EVIL}:{server.port}/?token={server.token}")
            assert r.status == 400 and "not this server" in rebound.content()
            browser.close()
    finally:
        evil.shutdown()
    # nothing the other site sent was acted upon
    assert sorted(p.name for p in (d / "session").iterdir()) == saved
    assert live.editor.base.source.endswith("lamp.glb")
