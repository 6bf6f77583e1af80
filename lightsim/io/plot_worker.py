"""A run's plots drawn in a second process while the run and its other outputs go on.

``lightsim simulate``'s default outputs include four PNG plots (``wall_lux.png``,
``error_vs_time.png``, ``isolux.png``, ``road.png``). Drawn in the run's own process after
the map they took 1.9–2.6 s of the shipped headlight's ~4.3 s command (matplotlib's import
0.4–0.6 s, its fonts and first contour ~0.4 s, then ~0.9 s of drawing), on one core: the
drawing is Python holding the GIL, so a thread would not overlap it with anything.

:class:`PlotProcess` starts the plot process, ``python -m lightsim.io.plot_worker``, when
the command starts (:func:`prestart`, before the command's own imports). The plot process
lowers its priority (nice :data:`NICE`: it takes a core only where the run leaves one idle,
e.g. while the scene loads), imports matplotlib, draws a small warm-up plot and then asks
for work.
The run's outputs hand over the plots by name (:data:`JOBS`, the same functions with the
same arguments) and write the OpenEXR map, the cut-off and the regulation analyses in the
meantime. The files are the ones the functions write in-process, byte for byte (tested).

The plot process *pulls* its plots, one at a time, so a plot is drawn by exactly one
process:

* a plot the plot process has not taken when the caller asks for it
  (:meth:`Pending.result`) is drawn by the caller — on the shipped headlight the plot
  process draws ``wall_lux.png``, ``error_vs_time.png`` and ``road.png`` while the run
  draws ``isolux.png`` (which waits for the regulation analyses); on a loaded machine,
  where the low-priority plot process is still starting, the run draws its plots itself;
* a plot the plot process took but has not answered within :data:`PATIENCE_S`, or a plot
  process that died or sent something unreadable, ends the plot process (killed, so no
  file lands later) and the caller draws that plot and every other one left.

:class:`InProcess` is the same interface drawing at once (library callers, a one-core
machine, ``LIGHTSIM_PLOT_PROCESS=0``).

=========================  =====  =======  ==============================================
parameter                  unit   default  meaning
=========================  =====  =======  ==============================================
``NICE``                   –      10       the plot process's niceness increment (POSIX)
``PATIENCE_S``             s      5        longest wait for a plot the plot process took (one
                                           takes 0.15–0.6 s on the shipped headlight)
``LIGHTSIM_PLOT_PROCESS``  –      1        environment: 0 draws every plot in-process
=========================  =====  =======  ==============================================
"""

from __future__ import annotations

import atexit
import collections
import ctypes
import importlib
import os
import pickle
import queue
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, BinaryIO

import lightsim

NICE = 10
PATIENCE_S = 5.0
#: the plots the plot process may draw: name → "module:function" (the first argument is
#: the path of the file written)
JOBS = {
    "lux_png": "lightsim.io.png:write_lux_png",
    "wall_lux": "lightsim.io.plots:wall_lux_plot",
    "error_vs_time": "lightsim.io.errorplot:error_vs_time_plot",
    "isolux": "lightsim.io.plots:isolux_plot",
    "road": "lightsim.io.plots:road_view_plot",
}
#: what the plot process draws into memory before its first plot ("module:function")
WARM_UP = "lightsim.io.plots:warm_up"
#: the ``simulate --outputs`` names that are plots
PLOT_OUTPUTS = ("png", "error_vs_time", "isolux", "road")
_HEADER = struct.Struct("<Q")
_READY = "ready"  # the plot process's request for its next plot


def _function(target: str):
    """The function named ``"module:function"`` (its module imported by name)."""
    mod, fn = target.split(":")
    return getattr(importlib.import_module(mod), fn)


def _job(name: str):
    return _function(JOBS[name])


class Pending:
    """One plot: :meth:`result` gives what its function returned, or raises what it
    raised; a plot the plot process has not taken (or could not finish) is drawn there, in
    the calling thread."""

    def __init__(self, name: str, args: tuple, kwargs: dict[str, Any],
                 owner: PlotProcess | None = None) -> None:
        self.name, self.args, self.kwargs = name, args, kwargs
        self._owner = owner
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._ok = False
        self._value: Any = None
        self.remote = False  # drawn by the plot process

    def _set(self, ok: bool, value: Any, remote: bool) -> bool:
        """Record the outcome once (the first one wins); False if it was already set."""
        with self._lock:
            if self._done.is_set():
                return False
            self._ok, self._value, self.remote = ok, value, remote
            self._done.set()
            return True

    def _run_here(self) -> None:
        try:
            outcome = (True, _job(self.name)(*self.args, **self.kwargs))
        except Exception as exc:  # re-raised by result()
            outcome = (False, exc)
        self._set(*outcome, remote=False)

    def result(self, patience: float = PATIENCE_S) -> Any:
        if not self._done.is_set():
            owner = self._owner
            if owner is None or owner._claim(self):
                if not self._done.is_set():
                    self._run_here()  # not taken by the plot process: drawn here
            elif not self._wait(patience):
                owner.abandon()  # taken but not answered: the plot process ends, drawn here
                self._run_here()
        if not self._ok:
            raise self._value
        return self._value

    def _wait(self, patience: float) -> bool:
        """Wait for the plot process's answer; False after ``patience`` s or as soon as
        the plot process is gone (its plots are then left to their callers)."""
        step = 0.05
        waited = 0.0
        while not self._done.wait(step):
            waited += step
            if self._owner is None or waited >= patience:
                return self._done.is_set()
        return True


class InProcess:
    """Draws every plot at once, in this process."""

    def draw(self, name: str, *args: Any, **kwargs: Any) -> Pending:
        p = Pending(name, args, kwargs)
        p._run_here()
        return p

    def abandon(self) -> None:
        pass

    def settle(self, patience: float = PATIENCE_S) -> None:
        pass

    def close(self) -> None:
        pass


class PlotProcess:
    """The plot process drawing plots (see the module docstring); every plot it does not
    draw is drawn in this process."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._queue: collections.deque[tuple[int, Pending]] = collections.deque()
        self._taken: dict[int, Pending] = {}  # sent to the plot process, not answered
        self._idle = False  # the plot process asked for a plot and got none
        self._next = 0
        self._out: queue.Queue[bytes | None] = queue.Queue()
        self.alive = False
        self._proc: subprocess.Popen | None = None
        package = Path(__file__).resolve().parents[1]  # this lightsim
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
                   MKL_NUM_THREADS="1")
        try:
            # -P: no current folder on the plot process's path; the package is checked there
            self._proc = subprocess.Popen(
                [sys.executable, "-P", "-c", _BOOT, str(package.parent), str(package),
                 str(os.getpid())],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                env=env)
        except Exception:  # no plot process: every plot is drawn here
            return
        self.alive = True
        threading.Thread(target=self._read, daemon=True, name="lightsim-plots-in").start()
        threading.Thread(target=self._write, daemon=True, name="lightsim-plots-out").start()

    def draw(self, name: str, *args: Any, **kwargs: Any) -> Pending:
        """Queue a plot for the plot process (its path made absolute: the plot process's
        folder is not the caller's to change)."""
        if name not in JOBS:
            raise ValueError(f"unknown plot {name!r}")
        if args:
            args = (os.path.abspath(args[0]), *args[1:])
        p = Pending(name, args, kwargs, self)
        with self._lock:
            if not self.alive:
                p._owner = None
            else:
                self._queue.append((self._next, p))
                self._next += 1
                if self._idle:
                    self._send_next()
        return p

    def _send_next(self) -> None:
        """Hand the plot process its next plot (the lock held): pickled here, written by the
        writer thread; one that cannot be pickled is left to the caller."""
        while self._queue:
            key, p = self._queue.popleft()
            try:
                msg = pickle.dumps((key, p.name, p.args, p.kwargs),
                                   protocol=pickle.HIGHEST_PROTOCOL)
            except Exception:
                p._owner = None  # drawn by the caller
                continue
            self._taken[key] = p
            self._idle = False
            self._out.put(msg)
            return
        self._idle = True

    def _claim(self, p: Pending) -> bool:
        """Take ``p`` back if the plot process has not taken it; True when the caller draws
        it."""
        with self._lock:
            for i, (_, q) in enumerate(self._queue):
                if q is p:
                    del self._queue[i]
                    return True
            return not any(q is p for q in self._taken.values())

    def _write(self) -> None:
        stdin = self._proc.stdin
        while True:
            msg = self._out.get()
            if msg is None:
                break
            try:
                _write_message(stdin, msg)
            except (OSError, ValueError):
                self.abandon()
                return
        try:
            stdin.close()  # EOF: the plot process exits
        except (OSError, ValueError):
            pass

    def _read(self) -> None:
        stdout = self._proc.stdout
        while True:
            try:
                msg = _read_message(stdout)
                reply = pickle.loads(msg) if msg is not None else None
            except Exception:
                reply = None
            if reply is None:  # gone, or a reply this process cannot read
                self.abandon()
                return
            with self._lock:
                if reply != _READY:
                    key, ok, value = reply
                    p = self._taken.pop(key, None)
                    if p is not None:
                        p._set(bool(ok), value, remote=True)
                self._send_next()

    def abandon(self) -> None:
        """End the plot process at once (killed: an output set being given up must not
        receive a file afterwards); every plot it has not answered is drawn by its
        caller."""
        with self._lock:
            self.alive = False
            left = [p for _, p in self._queue] + list(self._taken.values())
            self._queue.clear()
            self._taken.clear()
            for p in left:
                p._owner = None
        if self._proc is not None and self._proc.poll() is None:
            try:
                self._proc.kill()
            except OSError:
                pass
            self._proc.wait()

    def settle(self, patience: float = PATIENCE_S) -> None:
        """Hand out no more plots and wait (at most ``patience`` s) for the one the plot
        process is drawing: where the caller gives up in a folder that is kept (``lightsim
        report``), no file is cut short there by :meth:`close`."""
        with self._lock:
            for _, p in self._queue:
                p._owner = None
            self._queue.clear()
        t0 = time.monotonic()
        while time.monotonic() - t0 < patience:
            with self._lock:
                if not (self._taken and self.alive):
                    return
            time.sleep(0.02)

    def close(self) -> None:
        """Kill the plot process. A finished run's outputs have their plots by then (they
        wait for them), so nothing is cut short; an idle or warming plot process just
        ends."""
        if self._proc is None:
            return
        self._out.put(None)
        self.abandon()
        for f in (self._proc.stdin, self._proc.stdout):
            try:
                f.close()
            except (OSError, ValueError):
                pass


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _can_help() -> bool:
    return _cores() >= 2 and os.environ.get("LIGHTSIM_PLOT_PROCESS", "1") != "0"


_early: PlotProcess | None = None  # started by prestart, taken by start


def prestart(argv: list[str]) -> None:
    """Start the plot process before the command's own imports, for ``lightsim report`` and
    for ``lightsim simulate`` with plots among its outputs (read from ``argv``:
    ``--outputs`` absent or naming a plot or ``all``); :func:`start` then takes it. A plot
    process nobody takes ends with this process."""
    global _early
    if _early is not None or not argv or not _can_help():
        return
    if argv[0] == "report":
        if any(a in ("--list-rulesets", "--help", "-h") for a in argv):
            return
    elif argv[0] != "simulate":
        return
    for i, a in enumerate(argv):
        if a == "--outputs" or a.startswith("--outputs="):
            value = a.partition("=")[2] if "=" in a else (argv[i + 1] if i + 1 < len(argv)
                                                           else "")
            names = {n.strip() for n in value.split(",")}
            if not names & {*PLOT_OUTPUTS, "all"}:
                return
    plots = PlotProcess()
    if plots.alive:
        atexit.register(plots.close)
        _early = plots


def start(wanted: bool = True) -> PlotProcess | InProcess:
    """A :class:`PlotProcess` where it can help (plots are wanted, at least two cores,
    ``LIGHTSIM_PLOT_PROCESS`` not 0), else :class:`InProcess`; the plot process
    :func:`prestart` started, if any."""
    global _early
    early, _early = _early, None
    if early is not None and (not wanted or not _can_help() or not early.alive):
        early.close()
        early = None
    if not wanted or not _can_help():
        return InProcess()
    plots = early if early is not None else PlotProcess()
    return plots if plots.alive else InProcess()


def _read_message(f: BinaryIO) -> bytes | None:
    head = f.read(_HEADER.size)
    if len(head) < _HEADER.size:
        return None
    (n,) = _HEADER.unpack(head)
    body = f.read(n)
    return body if len(body) == n else None


def _write_message(f: BinaryIO, data: bytes) -> None:
    f.write(_HEADER.pack(len(data)))
    f.write(data)
    f.flush()


def _warm_up() -> None:
    """Import the plot modules (by name, as :data:`JOBS` lists them) and draw the warm-up
    plot (:data:`WARM_UP`) before the first real plot."""
    for name in JOBS:
        _job(name)
    _function(WARM_UP)()


def _die_with_parent() -> None:
    """Linux: the plot process is killed when the process that started it dies (a killed
    run must not get a plot into its folder afterwards)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG
    except Exception:
        pass


def _serve(inp: BinaryIO, out: BinaryIO, parent: int | None = None) -> None:
    """The plot process's loop: ask for a plot, draw it, send back (key, ok, value)."""
    _die_with_parent()
    if parent is not None and os.getppid() != parent:
        return  # the parent died before the line above took effect
    # Ctrl-C reaches the whole process group: the run stops at its frame's end and ends
    # the plot process itself
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(os, "nice"):
        try:
            os.nice(NICE)
        except OSError:
            pass
    try:
        _warm_up()
    except Exception:  # the plots themselves will say what is wrong
        pass
    _write_message(out, pickle.dumps(_READY))
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
        _write_message(out, data)


def main(package: str, parent: int | None = None) -> None:
    """The plot process (see :data:`_BOOT`) of the process ``parent``: replies on a copy
    of file descriptor 1, which itself is pointed at standard error, so nothing else can
    write into the pipe."""
    if Path(lightsim.__file__).resolve().parent != Path(package):
        return  # another lightsim came first on this path: the caller draws its plots
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    _serve(sys.stdin.buffer, out, parent)


#: the plot process's start: this very lightsim first on the path (``argv``: its parent folder,
#: the package folder, the parent's process id), unless that folder is on the path
#: already (an installed package: the path keeps Python's own order)
_BOOT = (
    "import sys\n"
    "root, package, parent = sys.argv[1], sys.argv[2], int(sys.argv[3])\n"
    "if root not in sys.path:\n"
    "    sys.path.insert(0, root)\n"
    "from lightsim.io.plot_worker import main\n"
    "main(package, parent)\n"
)


if __name__ == "__main__":
    main(str(Path(__file__).resolve().parents[1]), os.getppid())
