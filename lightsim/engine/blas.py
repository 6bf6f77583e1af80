"""One BLAS thread: the run's cores belong to its own threads (tracer chunks, numba).

lightsim's BLAS calls are small — 3 × 3 transforms, Rec. 709 weights, the odd
``tensordot`` — and run next to its own threads. OpenBLAS splits even these over every
core and its threads then busy-wait for the next call, so each call leaves a core
spinning while the written map's second branch (or the tracer) wants it: on the 2-core
VM the held-out blur (then a ``tensordot`` and NumPy passes) took 53 ms of wall time and
105 ms of CPU, and the written map 142 ms / 269 ms; with one BLAS thread 53 / 53 and
121 / 204 ms. A BLAS product may round differently on one thread than on two (OpenBLAS's
``tensordot`` does), so nothing that feeds the error figure relies on BLAS's summation
order: the held-out blur sums Σ n_s E_s itself, in set order
(:func:`lightsim.render.ici.held_out_blur`).

:func:`single_blas_thread` is the ``lightsim`` command's and the Ray clients' policy
(like :func:`~lightsim.engine.memory.keep_freed_memory`), not the library's: a program
that imports ``lightsim`` keeps its own BLAS threads. An ``OPENBLAS_NUM_THREADS``,
``OMP_NUM_THREADS`` or ``MKL_NUM_THREADS`` set by the user is left as it is.

=============  ====================================================================
parameter      meaning
=============  ====================================================================
(none)         –
=============  ====================================================================
"""

from __future__ import annotations

import os
from typing import Any

from threadpoolctl import threadpool_limits

_USER_SET = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_LIMIT: Any = None  # threadpoolctl's limiter, kept so the limit holds for the process


def single_blas_thread() -> bool:
    """Limit every BLAS library of this process to one thread: those loaded now
    (threadpoolctl) and those loaded later (``OPENBLAS_NUM_THREADS=1`` in the
    environment, read when a library starts). Returns whether the limit is in force
    (False where the user set the thread count)."""
    global _LIMIT
    if any(k in os.environ for k in _USER_SET):
        return False
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    _LIMIT = threadpool_limits(limits=1, user_api="blas")
    return True
