"""numba's first kernel load without its import of scipy.linalg.

Loading a cached kernel makes numba set up its CPU target (``BaseContext.refresh``),
which imports every lowering module, among them ``numba.np.arraymath``. That module asks
at import time whether a BLAS exists (``_HAVE_BLAS = _check_blas()``) by importing
``scipy.linalg.cython_blas`` — about 0.2 s of a whole ``simulate`` process on this
project's machines, for kernels none of which call BLAS. :func:`defer_blas_probe`
answers that question from the installed scipy's presence instead
(``importlib.util.find_spec``), and leaves numba's own ``ensure_blas`` in place for
everything else: a kernel that does use ``np.dot`` or ``np.linalg`` still imports
scipy.linalg when numba compiles it, and numba's compiled BLAS wrappers import it when
first called.

It only acts before ``numba.np.arraymath`` is imported (otherwise the probe already ran)
and only when scipy is installed (otherwise numba's own probe says no BLAS, as before).

=============  ====================================================================
parameter      meaning
=============  ====================================================================
(none)         –
=============  ====================================================================
"""

from __future__ import annotations

import importlib.util
import sys


def defer_blas_probe() -> bool:
    """Import ``numba.np.arraymath`` with its import-time BLAS probe answered by whether
    scipy is installed, numba's ``ensure_blas`` restored afterwards. True if it did so
    (False: arraymath was already imported, scipy is absent, or numba's layout differs)."""
    if "numba.np.arraymath" in sys.modules or importlib.util.find_spec("scipy") is None:
        return False
    try:
        from numba.np import linalg
    except ImportError:  # pragma: no cover - another numba layout: leave it alone
        return False
    real = getattr(linalg, "ensure_blas", None)
    if real is None:  # pragma: no cover
        return False

    def scipy_is_installed() -> None:  # the probe's question: ImportError means no BLAS
        return None

    linalg.ensure_blas = scipy_is_installed
    try:
        from numba.np import arraymath
    finally:
        linalg.ensure_blas = real
    if getattr(arraymath, "ensure_blas", None) is scipy_is_installed:
        arraymath.ensure_blas = real  # later typing checks are numba's own again
    return True
