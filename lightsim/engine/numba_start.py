"""numba's cached kernels loaded without setting up its whole CPU target.

Loading a cached kernel (``Cache.load_overload``) first calls the CPU target's
``BaseContext.refresh``, which imports every lowering module (``numba.np.arrayobj``,
``numba.np.linalg``, ``numba.np.arraymath`` — whose import-time BLAS probe imports
``scipy.linalg`` — the typed containers, jitclass, …) and installs their registries:
0.3–0.5 s of a whole ``simulate`` process on this project's machines, spent so that a
*compiler* could lower code. Loading machine code from the cache needs none of it, only
numba's runtime (NRT: the allocator the kernels call; without it they crash).
:func:`lazy_target_setup` makes cache loads initialise the runtime alone. Compiling
still gets the full set-up: numba's compiler refreshes the target itself
(``CompilerBase.__init__``) before it types or lowers anything, so a cache miss, a new
signature or a kernel that uses BLAS compile exactly as before.

It acts once per process and only on the numba layout it knows (``Cache``'s private
``_load_overload`` and ``_guard_against_spurious_io_errors``, numba 0.5x–0.6x);
otherwise it leaves numba alone.

=============  ====================================================================
parameter      meaning
=============  ====================================================================
(none)         –
=============  ====================================================================
"""

from __future__ import annotations

try:  # numba's own modules (imported with numba itself)
    from numba.core import caching
    from numba.core.runtime import rtsys
except ImportError:  # pragma: no cover - another numba layout: leave it alone
    caching = rtsys = None


def lazy_target_setup() -> bool:
    """Make numba's cache loads initialise only its runtime, not the whole CPU target
    (see the module docstring). True if it did so now (False: already done, or a numba
    whose cache layout differs)."""
    if caching is None:  # pragma: no cover
        return False
    cache = caching.Cache
    if getattr(cache.load_overload, "lazy_target", False):
        return False
    if not all(hasattr(cache, a) for a in ("_load_overload",
                                           "_guard_against_spurious_io_errors")):
        return False  # pragma: no cover

    def load_overload(self, sig, target_context):
        """numba's ``Cache.load_overload`` with the runtime initialised instead of the
        target refreshed (the compiler refreshes it itself when it runs)."""
        rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)

    load_overload.lazy_target = True
    cache.load_overload = load_overload
    return True
