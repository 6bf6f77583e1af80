"""Memory of a run: bytes per stored photon, a pre-flight estimate, the check against RAM.

``simulate``'s default run keeps no photon: what its outputs read is accumulated per
frame (the ICI lattice, detector apertures, and the kNN estimates at the cut-off scans
in :mod:`lightsim.engine.pointstore`), so its estimate does not grow with the photons
(:attr:`MemoryEstimate.grows` empty; the point stores counted at their bound). A run
that keeps every photon (``--keep-photons``, the ``knn`` bandwidth, …; the estimate's
``keeper``) is modelled as below.

Such a run keeps every photon it stores on the wall (one photon map per interleave set, photons
accumulated by insertion, paper section 5.4), per-set images (bins or the ICI lattice and
the probe windows) and, per frame, the tracer's wavefront. The estimate adds these up
from the run's settings before any work, and :func:`check_fits` turns a run that cannot
fit into the available memory into one clear :class:`~lightsim.errors.InputError` (exit
code 2) instead of a swap storm or the kernel's OOM killer an hour later. A time or error
budget cannot be checked before the run: :meth:`~lightsim.engine.server.Session.run`
measures the photons its maps keep (:func:`kept_photon_bytes` each) against
:func:`photon_budget` before every frame and stops short of it, with a
:class:`~lightsim.engine.results.MemoryStop` saying so.

What one stored photon costs (``kdtree``, C power channels, with normals)
------------------------------------------------------------------------
==================  =====  =======================================================
item                bytes  why
==================  =====  =======================================================
position            12     float32 × 3
normal              12     float32 × 3 (the normal filter)
power               4 C    float32 × C
permutation         4      int32 slot → insertion index (int64 from 2³¹ photons)
nodes               ≤ 36   60 B per node (box 24, start/end 16, split 8, child, dim,
                           depth 12) × ≤ 0.6 nodes per photon (≈ 0.3 used, arrays
                           grown by doubling)
insertion peak      32+4C  while a batch is merged: the new slot layout (12 + 8) and
                           the reordered normals/powers (12 + 4 C) beside the old —
                           of one interleave set's map at a time (÷ M²)
==================  =====  =======================================================

``bench photonmap`` measures the stored bytes of real trees (``nbytes`` of their arrays)
next to :func:`bytes_per_photon`, and the peak RSS of a 16 M-photon ``simulate`` next to
:func:`estimate_run`. The estimate is an upper bound: it counts every photon shot as
kept (the wall's yield is not known before tracing; about a third of the shipped
headlight's flux reaches its wall), so a run it lets start fits, and one it refuses
may, by up to that yield, have fitted.

Parameters
----------
=========================  =====  ========  ============================================
name                       unit   default   meaning
=========================  =====  ========  ============================================
``BASE_BYTES``             B      400 MiB   interpreter, numpy/numba/embree, compiled
                                            kernels (peak RSS of a 200 k-photon 64 × 64
                                            headlight run: 390–395 MiB)
``PIXEL_BYTES``            B      16        per pixel, channel and interleave set
``FINAL_PIXEL_BYTES``      B      600       per pixel of the final map and its error
                                            (these two: 640 × 256 pixels added 212 MiB
                                            to the 200 k-photon headlight run)
``WAVEFRONT_BYTES``        B      200       per photon of one frame in flight (rays,
                                            hits, records, sample points)
``HEADROOM``               —      1.15      margin on the total
``KEPT_PEAK_FACTOR``       —      2         a kept photon's peak over the model, for
                                            the stop of open-ended runs
                                            (:func:`kept_photon_bytes`)
``KEEP_BELOW``             B      32 MiB    blocks up to this size come from the heap
                                            and are reused after being freed
                                            (:func:`keep_freed_memory`)
``KEEP_FREE``              B      512 MiB   free memory the heap keeps before it gives
                                            any back to the system
=========================  =====  ========  ============================================

Reusing freed memory
--------------------
A run allocates the same large arrays frame after frame (records, their sorted copies,
a photon map's merged layout, the final map's planes). glibc serves blocks above 128 KiB
by ``mmap`` and returns them on ``free``, so every new one is first-touched page by page:
on the 2-core VM this costs 0.2 ms per MiB (32 MB of fresh arrays written 7.9 ms, the
same written again 1.1 ms) — 20 % of a photon map's insertion, 30 % of the shipped
headlight's final map. :func:`keep_freed_memory` (called by the ``lightsim`` command and
the Ray clients, a process-wide policy) lets the heap serve and keep blocks up to
:data:`KEEP_BELOW` (glibc's largest allowed), so they are reused without faulting; the
peak RSS a run reaches is what it was (``bench photonmap`` measures it against the
estimate), the memory is only given back later.

Small pages for NumPy
---------------------
NumPy asks the kernel for transparent huge pages (``madvise``) on every array of 4 MiB
or more. On the project's VMs a fresh 2 MiB page is the expensive kind of fault: the
host backs it on first touch (the balloon driver hands free blocks back to the host),
so a new process writing 200 MB of fresh arrays spent 0.85–1.9 s in the kernel, and
0.1 s with normal 4 KiB pages. A run's first frame and first map touch that much: the
shipped headlight's default ``simulate`` (one 200 k-photon frame) spent 1.2–1.5 s of
system time with huge pages and 0.55–0.65 s without, its insertion 0.10–0.57 s against
0.07–0.10 s and its final map 0.57–0.73 s against 0.30–0.39 s (whole process 4.6–5.4
against 3.5–4.9 s); ``bench pipeline`` (1 M photons, warm, same hour) moved from 0.52–0.68
to 0.67–0.76 of the tracer on the same photons. :func:`small_pages` (the command's and
the Ray clients' policy, like :func:`keep_freed_memory`) turns NumPy's request off; a
``NUMPY_MADVISE_HUGEPAGE`` set by the user is left as it is.

Pages written ahead
-------------------
The sets' ICI lattice (one block above :data:`KEEP_BELOW`: 84 MB on the shipped
headlight's 640 × 256 wall) is new in every run, and its pages were first touched in
random order by the first frames' photons (0.4–0.55 µs per record against 0.1 µs once in).
:meth:`~lightsim.engine.photonset.PhotonSets._prefault_lattice` faults them in, in order,
on the second thread while the first frame traces, where a frame's photons could reach
every page: :func:`write_pages`, one ``madvise(MADV_POPULATE_WRITE)`` (34 ms of one core
for the 84 MB, against 43–85 ms for writing its zeros, which older kernels get).
"""

from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from lightsim.errors import InputError

try:  # NumPy's switch for transparent huge pages (:func:`small_pages`)
    from numpy._core.multiarray import _set_madvise_hugepage
except ImportError:  # pragma: no cover - NumPy 1.x keeps it in numpy.core
    try:
        from numpy.core.multiarray import _set_madvise_hugepage
    except ImportError:
        _set_madvise_hugepage = None
try:  # optional: the available memory where /proc/meminfo does not tell
    import psutil
except ImportError:  # pragma: no cover
    psutil = None

NODE_BYTES = 60
NODES_PER_PHOTON = 0.6
BASE_BYTES = 400 * 2**20
PIXEL_BYTES = 16
FINAL_PIXEL_BYTES = 600
WAVEFRONT_BYTES = 200
HEADROOM = 1.15
KEPT_PEAK_FACTOR = 2.0


def bytes_per_photon(channels: int = 1, normals: bool = True, peak: bool = False) -> float:
    """Bytes one stored photon takes in a kd-tree map (``peak``: during an insertion)."""
    stored = 12.0 + (12.0 if normals else 0.0) + 4.0 * channels + 4.0 \
        + NODE_BYTES * NODES_PER_PHOTON
    return stored + (32.0 + 4.0 * channels if peak else 0.0)


def index_bytes(index: Any) -> int:
    """Bytes held by the numpy arrays of a photon index (its attributes, measured)."""
    return int(sum(v.nbytes for v in vars(index).values() if isinstance(v, np.ndarray)))


@dataclass
class MemoryEstimate:
    """Pre-flight estimate of a run's peak memory (bytes).

    ``keeper`` names the option that makes the run keep every photon (None: it keeps
    none, its photon bytes are the bounded point stores of
    :mod:`lightsim.engine.pointstore`, the same at any photon count)."""

    photons: int           # photons the run shoots (an upper bound of those it keeps)
    photon_bytes: float    # photon maps at their peak, or the bounded point stores
    image_bytes: float     # per-set images and the final map's query buffers
    frame_bytes: float     # one frame's wavefront
    base_bytes: float      # the process itself
    keeper: str | None = "--keep-photons"

    @property
    def total(self) -> float:
        return HEADROOM * (self.photon_bytes + self.image_bytes + self.frame_bytes
                           + self.base_bytes)

    @property
    def grows(self) -> tuple[str, ...]:
        """The parts that grow with the photons (none when no photon is kept)."""
        return ("photon maps",) if self.keeper is not None and self.photon_bytes else ()

    def describe(self) -> str:
        gb = 1e9
        kept = (f"{self.photons:,} photons × {self.photon_bytes / max(self.photons, 1):.0f}"
                f" B kept = {self.photon_bytes / gb:.2f} GB" if self.grows else
                f"no photon kept, point stores ≤ {self.photon_bytes / gb:.2f} GB")
        return (f"about {self.total / gb:.1f} GB ({kept}, images "
                f"{self.image_bytes / gb:.2f} GB, frame {self.frame_bytes / gb:.2f} GB, "
                f"process {self.base_bytes / gb:.2f} GB, ×{HEADROOM:g} margin)")

    def explain(self) -> list[str]:
        """Lines for ``simulate --explain``: what grows with the photons, the peak."""
        grows = (f"{', '.join(self.grows)} ({self.keeper} keeps every photon)"
                 if self.grows else "nothing (photons dropped after each frame)")
        return [f"grows with photons: {grows}",
                f"predicted peak: {self.describe()}"]


def estimate_run(photons: int, resolution: tuple[int, int], channels: int = 1,
                 n_sets: int = 16, frame_photons: int = 200_000, photon_map: bool = True,
                 keeper: str | None = "--keep-photons", point_bytes: float = 0.0,
                 ) -> MemoryEstimate:
    """Peak memory of a run that shoots ``photons`` photons (all assumed kept: the wall
    yield is not known before tracing, and a photon is stored at most once on the wall).

    Parameters
    ----------
    photons : int
        Photons shot in total.
    resolution : (W, H)
        Wall pixels.
    channels : int
        Power channels C (1 or 3).
    n_sets : int
        Interleave sets M².
    frame_photons : int
        Photons per frame (all sets).
    photon_map : bool
        False for the ``bin`` estimator, which stores no photons.
    keeper : str or None
        The option that keeps every photon; None: none is kept (the sets accumulate
        point stores of ``point_bytes`` bytes in all instead).
    point_bytes : float
        Bytes of all sets' point stores (:meth:`~lightsim.engine.pointstore.PointSpec.
        peak_bytes`), when no photon is kept.
    """
    W, H = resolution
    px = float(W) * float(H)
    kept = int(photons) if photon_map and keeper is not None else 0
    photon_bytes = (kept * stored_photon_bytes(channels, n_sets) if keeper is not None
                    else float(point_bytes) if photon_map else 0.0)
    return MemoryEstimate(
        int(photons), photon_bytes,
        px * channels * PIXEL_BYTES * n_sets + px * FINAL_PIXEL_BYTES,
        min(int(photons), int(frame_photons)) * WAVEFRONT_BYTES, BASE_BYTES,
        keeper if photon_map else None)


KEEP_BELOW = 32 * 2**20
KEEP_FREE = 512 * 2**20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters


def keep_freed_memory() -> bool:
    """Let the C heap serve and keep blocks up to :data:`KEEP_BELOW`, giving memory back
    to the system only beyond :data:`KEEP_FREE` free (glibc ``mallopt``; see the module
    docstring). Returns whether the policy is in force (False where the C library is not
    glibc)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, KEEP_BELOW)) and bool(
        mallopt(_M_TRIM_THRESHOLD, KEEP_FREE))


def small_pages() -> bool:
    """Stop NumPy asking for transparent huge pages for its new arrays (see the module
    docstring). Returns whether the policy is in force (False where the user set
    ``NUMPY_MADVISE_HUGEPAGE`` or this NumPy has no switch)."""
    if "NUMPY_MADVISE_HUGEPAGE" in os.environ or _set_madvise_hugepage is None:
        return False
    _set_madvise_hugepage(False)
    return True


_MADV_POPULATE_WRITE = 23  # Linux ≥ 5.14: fault a range's pages in, writable, in one call


def write_pages(array: np.ndarray) -> None:
    """Fault in every page of ``array`` now, in order (see "Pages written ahead" in the
    module docstring): one ``madvise(MADV_POPULATE_WRITE)`` over its whole pages where
    Linux has it (34 ms for 84 MB on the 2-core VM, against 43–85 ms for writing zeros
    over it), else one element of every page written with its own value. The values are
    left as they are."""
    if not array.flags.c_contiguous or array.nbytes == 0:
        return
    flat = array.reshape(-1)  # a view of a C-contiguous array
    step = max(1, 4096 // array.itemsize)
    start = (array.ctypes.data + 4095) & ~4095  # whole pages only: the array's own memory
    end = (array.ctypes.data + array.nbytes) & ~4095
    done = False
    if end > start:
        try:
            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            madvise = libc.madvise
            madvise.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
            madvise.restype = ctypes.c_int
            done = madvise(start, end - start, _MADV_POPULATE_WRITE) == 0
        except (OSError, AttributeError):
            done = False
    # written from copies: NumPy may skip a copy of memory onto itself
    if done:  # the partial pages at either end (shared with other memory) by writing
        head = (start - array.ctypes.data) // array.itemsize
        tail = (end - array.ctypes.data) // array.itemsize
        flat[:head] = flat[:head].copy()
        flat[tail:] = flat[tail:].copy()
    else:
        flat[::step] = flat[::step].copy()
        flat[-1:] = flat[-1:].copy()


def available_bytes() -> int | None:
    """Memory available to a new allocation (``MemAvailable`` of /proc/meminfo, else
    psutil), or None when neither can tell."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    if psutil is None:
        return None
    return int(psutil.virtual_memory().available)


def usable_bytes(available: int | None = None) -> int | None:
    """The memory a run may use: ``available`` (default :func:`available_bytes`) capped
    by ``LIGHTSIM_MEMORY_LIMIT`` (bytes; e.g. a container's limit that /proc/meminfo
    does not show); None when nothing tells."""
    avail = available if available is not None else available_bytes()
    limit = os.environ.get("LIGHTSIM_MEMORY_LIMIT")
    if limit:
        try:
            cap = int(float(limit))
        except ValueError:
            raise InputError(f"LIGHTSIM_MEMORY_LIMIT must be a number of bytes, got "
                             f"'{limit}'") from None
        avail = cap if avail is None else min(avail, cap)
    return avail


def stored_photon_bytes(channels: int = 1, n_sets: int = 16) -> float:
    """Bytes one kept photon adds to a run's peak: every set has its own map and a
    batch is merged into one map at a time, so of the insertion peak only one set's
    share counts."""
    peak = bytes_per_photon(channels, peak=True) - bytes_per_photon(channels)
    return bytes_per_photon(channels) + peak / max(n_sets, 1)


def kept_photon_bytes(channels: int = 1, n_sets: int = 16) -> float:
    """Bytes a kept photon may take at a run's peak, for the stop of open-ended runs:
    :data:`KEPT_PEAK_FACTOR` × :func:`stored_photon_bytes`. The model counts the built
    maps; a run also holds batches waiting for their map (and their concatenated copy
    while it is built), the frame's records and the final image's work arrays. Measured
    on the paraboloid (peak RSS growth per kept photon over 0.7–2.9 M kept): ``knn``
    M = 4 62–82 B (model 70), ``radius`` 94–107 B (model 70), ``knn`` M = 1 142–261 B
    (model 104; 183 at 2.9 M), the default run 94 B (model 70)."""
    return KEPT_PEAK_FACTOR * stored_photon_bytes(channels, n_sets)


def photon_budget(resolution: tuple[int, int], config: Any, channels: int = 1,
                  available: int | None = None) -> float | None:
    """Bytes the photon maps of a run may take in all (:func:`estimate_run`'s model):
    the usable memory over the headroom, less the images, one frame's wavefront and the
    process. None when the memory is not known or the run keeps no photons (``bin``).

    A run measured against it (:meth:`~lightsim.engine.server.Session.run`) stops before
    its kept photons would pass it: a time or error budget cannot be checked before it
    starts, and would otherwise run on into the kernel's OOM killer.
    """
    if config.estimator == "bin" or not config.keep_photons:
        return None
    avail = usable_bytes(available)
    if avail is None:
        return None
    fixed = estimate_run(0, resolution, channels, config.n_sets, config.frame_photons)
    fixed_bytes = (fixed.image_bytes + int(config.frame_photons) * WAVEFRONT_BYTES
                   + fixed.base_bytes)
    return max(0.0, avail / HEADROOM - fixed_bytes)


def check_fits(photons: int | None, resolution: tuple[int, int], config: Any,
               channels: int = 1, available: int | None = None,
               keeper: str | None = "--keep-photons", point_bytes: float = 0.0,
               ) -> MemoryEstimate | None:
    """Raise :class:`InputError` (one line) when the run cannot fit in memory.

    ``photons`` None (a time or error budget) checks one frame. ``config`` is the run's
    :class:`~lightsim.engine.config.RunConfig`. ``LIGHTSIM_MEMORY_LIMIT`` (bytes) caps
    the available memory (e.g. a container's limit that /proc/meminfo does not show).
    ``keeper``: the option that keeps every photon (named in the refusal), None when
    the run keeps none (then ``point_bytes``: its point stores, which do not grow).
    """
    n = int(photons) if photons is not None else int(config.frame_photons)
    keeps = keeper if config.keep_photons else None
    est = estimate_run(n, resolution, channels, config.n_sets, config.frame_photons,
                       photon_map=config.estimator != "bin", keeper=keeps,
                       point_bytes=point_bytes)
    avail = usable_bytes(available)
    if avail is not None and est.total > avail:
        if est.grows:
            raise InputError(f"{est.keeper} keeps every photon and this run would not fit "
                             f"in memory: it needs {est.describe()}, but only "
                             f"{avail / 1e9:.1f} GB is available; shoot fewer --photons, "
                             f"leave out {est.keeper} or use --estimator bin")
        raise InputError(f"this run would not fit in memory: it needs {est.describe()}, "
                         f"but only {avail / 1e9:.1f} GB is available; use a smaller "
                         "--resolution or fewer --interleave sets")
    return est
