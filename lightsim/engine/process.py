"""The process policy of the ``lightsim`` command and of its Ray clients.

A program that imports lightsim keeps its process as it is. The ``lightsim`` command's
process, and every Ray client (a worker process of its own), is tuned for a run
(:func:`tune_process`):

- freed memory is kept for reuse (:func:`lightsim.engine.memory.keep_freed_memory`: the
  same large arrays are made frame after frame, and fresh pages are slow faults);
- NumPy asks for no huge pages (:func:`lightsim.engine.memory.small_pages`);
- BLAS runs on one thread (:func:`lightsim.engine.blas.single_blas_thread`: the cores are
  the run's threads', not BLAS's spinning ones).

The command (:func:`command_process`) also starts its plot process before it imports
any sub-command (:func:`lightsim.io.plot_worker.prestart`: it imports matplotlib while
the command imports the engine), and when it ends moves every live object out of the
cyclic collector's reach (:func:`skip_final_collection`).

=============  ====================================================================
parameter      meaning
=============  ====================================================================
(none)         –
=============  ====================================================================
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager

from lightsim.engine.blas import single_blas_thread
from lightsim.engine.memory import keep_freed_memory, small_pages
from lightsim.io import plot_worker


def tune_process() -> None:
    """Keep freed memory, small pages, one BLAS thread: a run's process policy (see the
    module docstring)."""
    keep_freed_memory()
    small_pages()
    single_blas_thread()


def skip_final_collection() -> None:
    """Move every live object out of the cyclic collector's reach before the interpreter
    exits: its final collections walk every object numba and llvmlite created (0.27–0.31 s
    after any cached kernel ran, against 0.02–0.03 s frozen), on every command. Reference
    counting still frees them and atexit handlers still run; only the console script does
    it (an in-process caller's garbage stays collectable)."""
    gc.freeze()


@contextmanager
def command_process(argv: list[str]) -> Iterator[None]:
    """The ``lightsim`` console script's process around its command (``argv``: its
    arguments): the plot process started first, then :func:`tune_process`; on the way out
    :func:`skip_final_collection`."""
    plot_worker.prestart(argv)
    tune_process()
    try:
        yield
    finally:
        skip_final_collection()
