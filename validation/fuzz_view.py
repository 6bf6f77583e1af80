"""Fuzzing ``lightsim view``: mutated ``state.json`` files and WebSocket messages, each tried
on the real command (a ``lightsim view`` process) and judged by the view's promise.

The promise, for the command: a bad ``--state`` file gives one stderr line ``lightsim:
error: …`` and exit 2 (progress lines ``lightsim view: …`` aside), no traceback and no
file in the session folder; a good one starts the session (the address with its access
token printed, the page's statistics answer with a finite status). For a running view:
a bad message gets one line in the page (a ``message`` of level ``error``, no line
break) and the session goes on; a good one is acted on — an edit's status arrives, a
saved run lands inside the session folder with a closed energy budget — and never a
traceback, a dead or hanging server, or a file outside the session folder.

======================  =====  =======  ======================================================
parameter               unit   default  meaning
======================  =====  =======  ======================================================
``START_TIMEOUT``       s      240      a view process prints its address within this
``REPLY_TIMEOUT``       s      60       a message's reply (an edit's status, a save) within
``QUIET_SECONDS``       s      1.5      a message with no reply due (a tab) is judged after
``VIEW_ARGS``           –      …        the view's options: a 32×16 wall, 5000 photons per
                                        frame, no rule set, no camera tab
======================  =====  =======  ======================================================
"""

from __future__ import annotations

import contextlib
import http.client
import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

START_TIMEOUT = 240.0
REPLY_TIMEOUT = 60.0
QUIET_SECONDS = 1.5
VIEW_ARGS = ("--port", "0", "--resolution", "32x16", "--frame-photons", "5000",
             "--regulation", "none", "--no-camera")
URL_RE = re.compile(r"http://([^/\s]+):(\d+)/\?token=([0-9a-f]+)")
CLOSURE_TOL = 1e-6


class ViewProcess:
    """A ``lightsim view SCENE`` process: its output lines (read as they come), its
    address and token once printed."""

    def __init__(self, scene: Path, folder: Path, state: Path | None = None) -> None:
        argv = [sys.executable, "-m", "lightsim.cli", "view", str(scene), *VIEW_ARGS,
                "--out", str(folder)]
        if state is not None:
            argv += ["--state", str(state)]
        self.folder = folder
        self.stdout: list[str] = []
        self.stderr: list[str] = []
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     stdin=subprocess.DEVNULL, text=True, errors="replace",
                                     env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.readers = [threading.Thread(target=self._read, args=(s, lines), daemon=True)
                        for s, lines in ((self.proc.stdout, self.stdout),
                                         (self.proc.stderr, self.stderr))]
        for r in self.readers:
            r.start()
        self.port = 0
        self.token = ""

    @staticmethod
    def _read(stream: Any, lines: list[str]) -> None:
        for line in stream:
            lines.append(line.rstrip("\n"))

    def wait_started(self, timeout: float = START_TIMEOUT) -> bool:
        """True once the address is printed; False when the process ended first (or the
        time ran out: see :meth:`alive`)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for line in list(self.stdout):
                m = URL_RE.search(line)
                if m:
                    self.port, self.token = int(m.group(2)), m.group(3)
                    return True
            if self.proc.poll() is not None:
                for r in self.readers:
                    r.join(5)
                return False
            time.sleep(0.05)
        return False

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stats(self, timeout: float = 20.0) -> dict[str, Any] | None:
        """The page's statistics (``/stats``) or None when the server does not answer."""
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)
        try:
            conn.request("GET", "/stats", headers={"Authorization": f"token {self.token}"})
            r = conn.getresponse()
            return json.loads(r.read()) if r.status == 200 else None
        except (OSError, ValueError, http.client.HTTPException):
            return None
        finally:
            conn.close()

    def stop(self, timeout: float = 60.0) -> int | None:
        """Ctrl-C, as a user stops it; the exit code (None: had to be killed)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
                return None
        for r in self.readers:
            r.join(5)
        return self.proc.returncode


def _error_lines(lines: list[str]) -> list[str]:
    """Stderr lines other than the view's progress lines (``lightsim view: …``)."""
    return [ln for ln in lines if not ln.startswith("lightsim view: ")]


def _finite_status(status: dict[str, Any]) -> bool:
    for key in ("photons", "rel_error", "rel_noise", "rel_bias"):
        v = status.get(key)
        if v is not None and not (isinstance(v, int | float) and math.isfinite(v)):
            return False
    return True


def judge_state(scene: Path, state: Path, folder: Path) -> tuple[int | None, list[str],
                                                                   str, str]:
    """Run ``lightsim view SCENE --state STATE`` into ``folder``; (exit code, stderr
    lines, verdict, detail) by the promise of the module docstring."""
    view = ViewProcess(scene, folder, state)
    try:
        started = view.wait_started()
        if not started and view.alive():
            return None, view.stderr, "timeout", "no address printed"
        if started:
            end = time.monotonic() + REPLY_TIMEOUT
            stats = view.stats()
            while stats is not None and time.monotonic() < end and not (
                    stats.get("status") or {}).get("photons"):
                time.sleep(0.25)
                stats = view.stats()
            if stats is None:
                return None, view.stderr, "timeout", "the started view does not answer"
            status = stats.get("status") or {}
            if not status.get("photons"):
                return None, view.stderr, "incomplete", "no photons traced"
            if not _finite_status(status):
                return None, view.stderr, "nonfinite", json.dumps(status)[:120]
    finally:
        code = view.stop()
    lines = view.stderr
    if any("Traceback" in ln for ln in lines):
        return code, lines, "traceback", lines[-1][:120]
    if started:
        # Ctrl-C's own lines: a blank line after the terminal's ^C, then "aborted"
        stray = [ln for ln in _error_lines(lines) if ln.strip() and not ln.startswith(
            "lightsim: warning: ") and ln not in ("lightsim: aborted", "lightsim: interrupted")]
        if code not in (0, 130):
            return code, lines, "exit", f"exit code {code} after Ctrl-C"
        if stray:
            return code, lines, "stray", stray[0][:120]
        return 0, lines, "ran", ""
    errors = _error_lines(lines)
    if code != 2:
        return code, lines, "exit", f"exit code {code}"
    if len(errors) != 1 or not errors[0].startswith("lightsim: error: "):
        return code, lines, "lines", f"{len(errors)} lines"
    left = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()) \
        if folder.is_dir() else []
    if left:
        return code, lines, "leftover", ", ".join(left[:4])
    return code, lines, "rejected", ""


class MessageTarget:
    """A running view that WebSocket message cases are sent to (restarted when a case
    kills it); its session folder is ``root/session``, and nothing else may appear
    under ``root``."""

    def __init__(self, scene: Path, root: Path) -> None:
        self.scene = scene
        self.root = root
        self.view: ViewProcess | None = None
        self.seen = 0  # stderr lines judged so far

    def ensure(self) -> ViewProcess | None:
        if self.view is not None and self.view.alive():
            return self.view
        if self.view is not None:
            self.view.stop()
        self.view = ViewProcess(self.scene, self.root / "session")
        self.seen = 0
        return self.view if self.view.wait_started() else None

    def close(self) -> None:
        if self.view is not None:
            self.view.stop()
            self.view = None

    def judge(self, text: str | bytes) -> tuple[int | None, list[str], str, str]:
        """Send one message; (0 or 2 as a command would exit, the lines the page got,
        verdict, detail)."""
        from websockets.exceptions import WebSocketException
        from websockets.sync.client import connect

        view = self.ensure()
        if view is None:
            return None, [], "crash", "the view did not start"
        before = set(_files(self.root))
        runs_before = {p.name for p in (self.root / "session").glob("run-*")}
        stats = view.stats()
        if stats is None:
            return None, [], "timeout", "the view does not answer before the case"
        edit = int((stats.get("status") or {}).get("edit", 0))
        page: list[str] = []
        verdict, detail = "", ""
        try:
            with connect(f"ws://127.0.0.1:{view.port}/ws?token={view.token}",
                         open_timeout=30, close_timeout=5, max_size=None) as ws:
                _wait_for(ws, lambda m: m.get("type") == "hello", 30)
                ws.send(text)
                kind = _kind(text)
                due = REPLY_TIMEOUT if kind in ("set", "save") else QUIET_SECONDS

                def done(m: dict[str, Any]) -> bool:
                    if m.get("type") == "message":
                        page.append(str(m.get("text")))
                        if m.get("level") == "error":
                            return True
                        return kind == "save" and bool(m.get("saved"))
                    return kind == "set" and m.get("type") == "status" and \
                        int(m.get("edit", 0)) > edit
                reply = _wait_for(ws, done, due)
        except (WebSocketException, OSError, TimeoutError) as exc:
            reply = None
            verdict, detail = "crash", f"connection lost: {type(exc).__name__}"
        lines = view.stderr[self.seen:]
        self.seen = len(view.stderr)
        if any("Traceback" in ln for ln in lines):
            return None, lines, "traceback", lines[-1][:120]
        if not view.alive():
            return None, lines, "crash", f"the view exited ({view.proc.returncode})"
        if view.stats() is None:
            return None, lines, "timeout", "the view does not answer after the case"
        stray = sorted(set(_files(self.root)) - before - {"session/state.json",
                                                          "session/edits.jsonl"})
        stray = [f for f in stray if not f.startswith("session/run-")]
        if stray:
            return None, lines, "leftover", ", ".join(stray[:4])
        if verdict:
            return None, page, verdict, detail
        if reply is not None and reply.get("level") == "error":
            text_ = str(reply.get("text", ""))
            if "\n" in text_ or not text_.strip():
                return 2, page, "lines", repr(text_[:80])
            return 2, page, "rejected", ""
        if kind == "save":
            runs = sorted({p.name for p in (self.root / "session").glob("run-*")}
                          - runs_before)
            if reply is None or len(runs) != 1:
                return None, page, "incomplete", f"save: {len(runs)} new run folder(s)"
            return (0, page, *_closed_run(self.root / "session" / runs[0]))
        if kind == "set" and reply is None:
            return None, page, "timeout", "no status of the edit"
        if kind == "set" and not _finite_status(reply):
            return None, page, "nonfinite", json.dumps(reply)[:120]
        return 0, page, "ran", ""


def _kind(text: str | bytes) -> str | None:
    try:
        msg = json.loads(text)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    return msg.get("type") if isinstance(msg, dict) and isinstance(msg.get("type"),
                                                                   str) else None


def _wait_for(ws: Any, pred: Any, timeout: float) -> dict[str, Any] | None:
    end = time.monotonic() + timeout
    while True:
        left = end - time.monotonic()
        if left <= 0:
            return None
        try:
            raw = ws.recv(timeout=left)
        except TimeoutError:
            return None
        if isinstance(raw, bytes):
            continue
        m = json.loads(raw)
        if pred(m):
            return m


def _files(root: Path) -> list[str]:
    return [str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()]


def _closed_run(run: Path) -> tuple[str, str]:
    """(verdict, detail) of a saved run folder: its summary with a closed energy budget."""
    with contextlib.suppress(OSError, ValueError):
        summary = json.loads((run / "summary.json").read_text())
        e = summary.get("energy_lm") or {}
        closure, emitted = e.get("closure_relative"), e.get("emitted")
        if not (isinstance(emitted, int | float) and math.isfinite(emitted) and emitted > 0):
            return "energy", f"emitted {emitted}"
        if not (isinstance(closure, int | float) and closure <= CLOSURE_TOL):
            return "energy", f"closure {closure}"
        return "ran", ""
    return "incomplete", f"{run.name}: no readable summary.json"
