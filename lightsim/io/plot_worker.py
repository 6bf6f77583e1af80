"""A run's plots drawn in a second process while the run and its other outputs go on.

``lightsim simulate``'s default outputs include four PNG plots (``wall_lux.png``,
``error_vs_time.png``, ``isolux.png``, ``road.png``). Drawn in the run's own process after
the map they took 1.7–2.2 s of the shipped headlight's 4.4 s command (matplotlib's import
0.4–0.6 s, its fonts and first contour ~0.4 s, then ~0.9 s of drawing), on one core: the
drawing is Python holding the GIL, so a thread would not overlap it with anything.

:class:`PlotProcess` starts ``python -m lightsim.io.plot_worker`` when the command starts
(:func:`prestart`, before the command's own imports);
the child lowers its priority (nice :data:`NICE`: it takes a core only where the run
leaves one idle, e.g. while the scene loads) and imports and warms matplotlib up. The
run's outputs hand it the plots by name (:data:`JOBS`, the same functions with the same
arguments, pickled over a pipe) and write the OpenEXR map, the cut-off and the regulation
analyses in the meantime. The files are the ones the functions write in-process, byte for
byte (tested); where the child cannot start, dies or does not answer in time, the plot is
drawn in-process instead, so a run never loses a plot to the helper.

:class:`InProcess` is the same interface drawing at once (library callers, a one-core
machine, ``LIGHTSIM_PLOT_PROCESS=0``).

=====================  =====  =======  ==================================================
parameter              unit   default  meaning
=====================  =====  =======  ==================================================
``NICE``               –      10       the child's niceness increment (POSIX)
``TIMEOUT_S``          s      120      longest wait for one plot before it is drawn here
``LIGHTSIM_PLOT_PROCESS``  –  1        environment: 0 draws every plot in-process
=====================  =====  =======  ==================================================
"""

from __future__ import annotations

import importlib
import os
import pickle
import queue
import struct
import subprocess
import sys
import threading
from typing import Any, BinaryIO

NICE = 10
TIMEOUT_S = 120.0
#: the plots a helper may draw: name → "module:function"
JOBS = {
    "lux_png": "lightsim.io.png:write_lux_png",
    "error_vs_time": "lightsim.io.errorplot:error_vs_time_plot",
    "isolux": "lightsim.io.plots:isolux_plot",
    "road": "lightsim.io.plots:road_view_plot",
}
#: the ``simulate --outputs`` names that are plots
PLOT_OUTPUTS = ("png", "error_vs_time", "isolux", "road")
_HEADER = struct.Struct("<Q")


def _job(name: str):
    mod, fn = JOBS[name].split(":")
    return getattr(importlib.import_module(mod), fn)


class Pending:
    """One plot: :meth:`result` gives what its function returned, or raises what it
    raised. A plot the helper could not draw (it died, or did not answer within
    ``timeout``) is drawn by :meth:`result`, in the calling thread."""

    def __init__(self, name: str, args: tuple, kwargs: dict[str, Any],
                 owner: PlotProcess | None = None) -> None:
        self.name, self.args, self.kwargs = name, args, kwargs
        self._owner = owner
        self._done = threading.Event()
        self._ok = False
        self._value: Any = None
        self._here = False  # to be drawn in this process
        self.remote = False  # drawn by the helper process

    def _set(self, ok: bool, value: Any) -> None:
        self._ok, self._value, self.remote = ok, value, True
        self._done.set()

    def _fall_back(self) -> None:
        self._here = True
        self._done.set()

    def _run_here(self) -> None:
        try:
            self._ok, self._value = True, _job(self.name)(*self.args, **self.kwargs)
        except Exception as exc:  # re-raised by result()
            self._ok, self._value = False, exc
        self._here = False
        self.remote = False
        self._done.set()

    def result(self, timeout: float = TIMEOUT_S) -> Any:
        if not self._done.wait(timeout) and self._owner is not None:
            self._owner.abandon()  # no answer: stop the helper, draw it here
        if self._here or not self._done.is_set():
            self._run_here()
        if not self._ok:
            raise self._value
        return self._value


class InProcess:
    """Draws every plot at once, in this process."""

    alive = False

    def draw(self, name: str, *args: Any, **kwargs: Any) -> Pending:
        p = Pending(name, args, kwargs)
        p._run_here()
        return p

    def abandon(self) -> None:
        pass

    def close(self) -> None:
        pass


class PlotProcess:
    """A helper process drawing the plots (see the module docstring); falls back to
    drawing in this process wherever it cannot."""

    def __init__(self) -> None:
        self._pending: dict[int, Pending] = {}
        self._lock = threading.Lock()
        self._next = 0
        self._out: queue.Queue[bytes | None] = queue.Queue()
        self.alive = False
        # the child imports this very lightsim, wherever it was imported from
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "lightsim.io.plot_worker"], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env)
        except OSError:
            self._proc = None
            return
        self.alive = True
        self._reader = threading.Thread(target=self._read, daemon=True,
                                        name="lightsim-plots-in")
        self._writer = threading.Thread(target=self._write, daemon=True,
                                        name="lightsim-plots-out")
        self._reader.start()
        self._writer.start()

    def draw(self, name: str, *args: Any, **kwargs: Any) -> Pending:
        if name not in JOBS:
            raise ValueError(f"unknown plot {name!r}")
        p = Pending(name, args, kwargs, self)
        with self._lock:
            alive = self.alive
            if alive:
                key = self._next
                self._next += 1
                self._pending[key] = p
        if not alive:
            p._run_here()
            return p
        try:
            msg = pickle.dumps((key, name, args, kwargs), protocol=pickle.HIGHEST_PROTOCOL)
        except Exception:  # what cannot be sent is drawn here
            with self._lock:
                self._pending.pop(key, None)
            p._run_here()
            return p
        self._out.put(msg)  # written by the writer thread: the caller goes on at once
        return p

    def _write(self) -> None:
        stdin = self._proc.stdin
        while True:
            msg = self._out.get()
            if msg is None:
                break
            try:
                stdin.write(_HEADER.pack(len(msg)))
                stdin.write(msg)
                stdin.flush()
            except (OSError, ValueError):
                self._failed()
                return
        try:
            stdin.close()  # EOF: the child exits
        except OSError:
            pass

    def _read(self) -> None:
        stdout = self._proc.stdout
        while True:
            try:
                msg = _read_message(stdout)
                key, ok, value = pickle.loads(msg) if msg is not None else (None, 0, 0)
            except Exception:  # a broken reply ends the helper
                msg = None
            if msg is None:
                self._failed()
                return
            with self._lock:
                p = self._pending.pop(key, None)
            if p is not None:
                p._set(bool(ok), value)

    def _failed(self) -> None:
        """The helper is gone: every plot it had not answered is left to be drawn here."""
        with self._lock:
            self.alive = False
            left = list(self._pending.values())
            self._pending.clear()
        for p in left:
            p._fall_back()

    def abandon(self) -> None:
        """Kill the helper at once (an output set being given up must not receive a file
        afterwards); its unanswered plots are left to be drawn here."""
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        self._failed()

    def close(self) -> None:
        """Stop the helper. Every plot of a finished run has been answered by then (the
        outputs wait for them), so nothing is cut short; an idle or warming helper is
        simply killed."""
        if self._proc is None:
            return
        self._out.put(None)
        self.abandon()
        for f in (self._proc.stdin, self._proc.stdout):
            try:
                f.close()
            except (OSError, ValueError):
                pass

    def __enter__(self) -> PlotProcess:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _can_help() -> bool:
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return cores >= 2 and os.environ.get("LIGHTSIM_PLOT_PROCESS", "1") != "0"


_early: PlotProcess | None = None  # started by prestart, taken by start


def prestart(argv: list[str]) -> None:
    """Start the helper before the command's own imports, for ``lightsim simulate`` with
    plots among its outputs (read from ``argv``: ``--outputs`` absent or naming a plot or
    ``all``); :func:`start` then takes it. A helper nobody takes ends with this process."""
    global _early
    if _early is not None or not argv or argv[0] != "simulate" or not _can_help():
        return
    for i, a in enumerate(argv):
        if a == "--outputs" or a.startswith("--outputs="):
            value = a.partition("=")[2] if "=" in a else (argv[i + 1] if i + 1 < len(argv)
                                                           else "")
            names = {n.strip() for n in value.split(",")}
            if not names & {*PLOT_OUTPUTS, "all"}:
                return
    helper = PlotProcess()
    if helper.alive:
        import atexit

        atexit.register(helper.close)
        _early = helper


def start(wanted: bool = True) -> PlotProcess | InProcess:
    """A :class:`PlotProcess` where it can help (plots are wanted, at least two cores,
    ``LIGHTSIM_PLOT_PROCESS`` not 0), else :class:`InProcess`; the helper
    :func:`prestart` started, if any."""
    global _early
    early, _early = _early, None
    if not wanted or not _can_help():
        if early is not None:
            early.close()
        return InProcess()
    helper = early if early is not None and early.alive else PlotProcess()
    return helper if helper.alive else InProcess()


def _read_message(f: BinaryIO) -> bytes | None:
    head = f.read(_HEADER.size)
    if len(head) < _HEADER.size:
        return None
    (n,) = _HEADER.unpack(head)
    body = f.read(n)
    return body if len(body) == n else None


def _warm_up() -> None:
    """Import the plot modules and draw a small contour plot with text into memory: the
    fonts, the text layout and the contouring are loaded before the first real plot."""
    import io

    import numpy as np

    from lightsim.io.plots import _new_figure

    for name in JOBS:
        _job(name)
    fig = _new_figure((3.0, 2.0))
    ax = fig.add_subplot(1, 1, 1)
    z = np.outer(np.hanning(16), np.hanning(16))
    cs = ax.contour(z, levels=[0.25, 0.5])
    ax.clabel(cs, fmt="%g lx", fontsize=7)
    ax.set_title("warm-up")
    fig.colorbar(ax.contourf(z, levels=[0.1, 0.5, 1.0]), ax=ax, location="bottom")
    fig.savefig(io.BytesIO(), format="png", dpi=50)


def _serve(inp: BinaryIO, out: BinaryIO) -> None:
    """The helper's loop: read a job, draw it, send back (key, ok, value)."""
    import signal

    # Ctrl-C reaches the whole process group: the run stops at its frame's end and closes
    # this helper itself
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(os, "nice"):
        try:
            os.nice(NICE)
        except OSError:
            pass
    try:
        _warm_up()
    except Exception:  # the jobs themselves will say what is wrong
        pass
    while True:
        msg = _read_message(inp)
        if msg is None:
            return
        key, name, args, kwargs = pickle.loads(msg)
        try:
            reply = (key, True, _job(name)(*args, **kwargs))
        except Exception as exc:  # sent back, raised by the caller
            reply = (key, False, exc)
        try:
            data = pickle.dumps(reply, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # an unpicklable result or error
            data = pickle.dumps((key, False, RuntimeError(f"plot {name}: {exc!r}")))
        out.write(_HEADER.pack(len(data)))
        out.write(data)
        out.flush()


if __name__ == "__main__":
    _stdin, _stdout = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # nothing but replies on the pipe
    _serve(_stdin, _stdout)
