"""One second thread for work that runs beside the calling thread.

Three stages use it, never at the same time: the written map's second branch
(:func:`lightsim.render.ici.written_map`), the second half of a frame's insertion
(:meth:`lightsim.engine.photonset.PhotonSets.shoot`) and the second half of the sets'
window sums of a frame's estimate (:meth:`lightsim.engine.client.Client.render`). Each
hands it compiled kernels that run without the GIL, so the two halves of their work
proceed on both cores; the results are the same as doing both halves in turn.

=============  ====================================================================
parameter      meaning
=============  ====================================================================
(none)         the thread is made on first use; a forked child makes its own (the
               parent's thread does not exist there)
=============  ====================================================================
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

_POOL: ThreadPoolExecutor | None = None


def second_thread() -> ThreadPoolExecutor:
    """The process's second thread (an executor of one worker)."""
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="lightsim-second")
    return _POOL


def _forget() -> None:
    global _POOL
    _POOL = None


os.register_at_fork(after_in_child=_forget)
