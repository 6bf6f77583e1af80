"""What travels between the server and its clients, and what a frame gives back.

A frame of the distributed renderer (paper sections 3.3, 4.2) asks every client for
some quantities of every interleave set it owns (:class:`RenderRequest`); each set
answers with a :class:`SetFrame` — already divided by its photons, so in lx (cd/m² for a
camera view), float32 on the wire, never photons. The server combines them into one
:class:`FrameResult`.

==================  ============  ===============================================
field               unit          meaning
==================  ============  ===============================================
``sub_image``       lx            the set's interleaved pixels (x mod M = a, …)
``full_image``      lx            every wall pixel (pooled kNN or binning)
``full_rungs``      lx            ICI rung estimates at every wall pixel
``camera``          cd/m²         the set's interleaved pixels of a camera view
``probes``          lx            estimates at the probe points (grid, then extra)
``window``          lx            pixel-window counts at the grid probes (blur bias)
``probe_rungs``     lx            ICI rung estimates at the grid probes' pixels
``moments``         lm, lm², –    ΣΦ, ΣΦ², count of the set's luminous wall photons
==================  ============  ===============================================
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from lightsim.render.frame import ErrorEstimate, ProbeStats


@dataclass(frozen=True)
class RenderRequest:
    """Which quantities a frame asks every set for.

    Attributes
    ----------
    image : bool
        The interleaved sub-images (the paper's frame).
    full_image : bool
        Every pixel of every set (the pooled map; ICI rungs with ``bandwidth=ici``).
    probes : bool
        Estimates at the probe points (the error estimate, regulation points).
    error : bool
        What the error figure needs besides the probes: pixel windows at the grid probes
        (kNN blur bias) or the ICI rungs there and the wall-photon moments.
    camera : PinholeCamera, optional
        A camera view to render (interleaved, cd/m²).
    image_step : int
        The interleaved image at every ``image_step``-th pixel: a wall of
        ⌈W/step⌉ × ⌈H/step⌉ pixels over the same extent (``lightsim view``'s interaction
        frames: step² times fewer queries; 1 = the wall's own pixels).
    """

    image: bool = False
    full_image: bool = False
    probes: bool = True
    error: bool = True
    camera: Any = None
    image_step: int = 1


_ARRAYS = ("sub_image", "full_image", "full_rungs", "camera", "probes", "window",
           "probe_rungs")


@dataclass
class SetFrame:
    """One interleave set's answer to a :class:`RenderRequest` (see the module table)."""

    index: int
    sub_image: np.ndarray | None = None  # (rows, cols, C) lx
    full_image: np.ndarray | None = None  # (H, W, C) lx
    full_rungs: np.ndarray | None = None  # (J+1, H, W, C) lx
    camera: np.ndarray | None = None  # (rows, cols, C) cd/m²
    probes: np.ndarray | None = None  # (P, C) lx
    window: np.ndarray | None = None  # (G, C) lx
    probe_rungs: np.ndarray | None = None  # (J+1, G, C) lx
    moments: np.ndarray | None = None  # (3,) ΣΦ lm, ΣΦ² lm², count

    def for_wire(self) -> SetFrame:
        """float32 copies of the images and estimates (the lux map is float32 anyway):
        half the bytes per frame."""
        for name in _ARRAYS:
            value = getattr(self, name)
            if value is not None:  # (a float32 array already is one: no copy)
                setattr(self, name, value.astype(np.float32, copy=False))
        return self

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays this set sends."""
        return sum(getattr(self, f.name).nbytes for f in fields(self)
                   if isinstance(getattr(self, f.name), np.ndarray))


@dataclass
class ClientFrame:
    """A client's answer: its sets' frames in set order, and the time it took (s)."""

    sets: list[SetFrame]
    seconds: float = 0.0


@dataclass
class ShootResult:
    """What one client's shoot did (counts, s)."""

    photons: int
    records: int
    rays: int
    seconds: float
    sample_s: float = 0.0  # of ``seconds``: the sample points (Halton, SPT passes)
    trace_s: float = 0.0   # of ``seconds``: the tracer (emission, rays, shading)


@dataclass(frozen=True)
class MemoryStop:
    """A run that stopped before its budget because more photons would not fit in
    memory (:func:`lightsim.engine.memory.photon_budget`)."""

    photons: int          # photons emitted when the run stopped
    kept: int             # photon records the maps keep
    kept_bytes: float     # what they may take at the peak (B, memory.kept_photon_bytes)
    budget_bytes: float   # what the photon maps may take (B)

    def message(self) -> str:
        gb = 1e9
        return (f"the run stopped at {self.photons:,} photons, before its budget: the "
                f"photon maps keep {self.kept:,} photons (up to {self.kept_bytes / gb:.2f} GB) "
                f"and another frame would pass the {self.budget_bytes / gb:.2f} GB they may "
                "take in this machine's memory (LIGHTSIM_MEMORY_LIMIT caps it); the outputs "
                "are for these photons")

    def to_json(self) -> dict[str, float | int]:
        return {"photons": self.photons, "kept": self.kept, "kept_bytes": self.kept_bytes,
                "budget_bytes": self.budget_bytes}


@dataclass
class SetFrames:
    """Every set's frame of one render, keyed by set index (the server's view)."""

    by_set: dict[int, SetFrame]

    @classmethod
    def gather(cls, clients: list[ClientFrame]) -> SetFrames:
        return cls({f.index: f for c in clients for f in c.sets})

    def collect(self, name: str) -> dict[int, np.ndarray]:
        """{set: array} of one :class:`SetFrame` field, for the sets that sent it."""
        return {s: getattr(f, name) for s, f in self.by_set.items()
                if getattr(f, name) is not None}


@dataclass
class FrameResult:
    """What the server knows after a frame.

    Attributes
    ----------
    lux : (H, W, C) float64 or None
        Filtered illuminance image (lx), if an image was rendered.
    raw : (H, W, C) float64 or None
        The assembled image before filtering.
    probes : ProbeStats or None
        Probe estimates over the sets (None when the frame did not ask for them).
    rel_error : float or None
        Estimated relative error over the lit region: √(noise² + blur bias²) (see
        :mod:`lightsim.render.frame`); None when it cannot be estimated or was not.
    photons : int
        Photons emitted over all sets so far.
    seconds : float
        Time since the session's clock started (s).
    timings : dict
        Seconds spent in this frame's steps (``shoot``, ``render``, ``assemble``).
    camera : (H, W, C) float64 or None
        Luminance (cd/m²) of a camera view.
    error : ErrorEstimate or None
        rel_error's parts: noise and blur bias.
    rungs : (H, W) int or None
        ICI rung of every written pixel (0 = the pixel).
    error_photons : int or None
        Photons at which ``error`` was estimated (earlier than ``photons`` on a frame of
        :meth:`Session.run` that only shot).
    """

    lux: np.ndarray | None
    raw: np.ndarray | None
    probes: ProbeStats | None
    rel_error: float | None
    photons: int
    seconds: float
    timings: dict[str, float] = field(default_factory=dict)
    camera: np.ndarray | None = None
    error: ErrorEstimate | None = None
    rungs: np.ndarray | None = None
    error_photons: int | None = None

    def error_entry(self) -> dict[str, Any]:
        """The error-vs-time log entry of this estimate (fractions, s)."""
        e = self.error
        return {"seconds": self.seconds, "photons": self.photons, "rel_error": self.rel_error,
                "rel_noise": None if e is None else e.noise,
                "rel_bias": None if e is None else e.bias,
                "rel_bias_upper": None if e is None else e.bias_upper}


Estimate = FrameResult  # the name callers used before the typed results
