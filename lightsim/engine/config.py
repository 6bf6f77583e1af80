"""Run configuration shared by the server and every client.

======================  =====  ==========  ==================================================
parameter               unit   default     meaning
======================  =====  ==========  ==================================================
``seed``                –      1           every photon is a function of (seed, set, index)
``interleave``          –      4           M: M×M interleave sets, each with its own photons
                                           and photon map (paper section 3.3)
``estimator``           –      ``knn``     ``knn`` (photon map, exact k nearest), ``bin``
                                           (photons counted per wall pixel), ``radius``
                                           (fixed-radius hashed grid, the IGI baseline)
``k``                   –      64          photons per kNN estimate
``min_radius``          m      auto        smallest kNN radius; auto = the radius of a disk
                                           with the area of one pixel (pooled) or of the
                                           n×n filter window (interleaved: finer detail
                                           cannot survive the filter); it also caps a point
                                           focus at a finite estimate
``max_radius``          m      auto        largest kNN radius; auto = 4 × (pooled) or 2 ×
                                           (interleaved) the min radius, so light is not
                                           smeared far into dark regions (glare points next
                                           to a cut-off stay honest); ``inf`` = the paper's
                                           unlimited kNN. The ``radius`` estimator's fixed
                                           radius is the min radius
``bandwidth``           –      ``ici``     how the written (pooled) kNN map picks its radius:
                                           ``ici`` = per pixel, the largest of the nested
                                           estimates (the pixel itself, disks r_min·2^(j/2)
                                           … r_max) whose confidence interval overlaps all
                                           smaller ones' (:mod:`lightsim.render.ici`):
                                           the radius shrinks as photons grow wherever
                                           blur would show, so the map converges to the
                                           pixel means (or the plain pixel counts when
                                           their estimated error is the lower one);
                                           ``knn`` = r_k clamped to [r_min, r_max] (the
                                           paper; its error levels off)
``ici_gamma``           –      2.0         Γ: interval half-width in standard errors
``kernel``              –      ``box``     ``box``, ``cone`` or ``epanechnikov`` weights
``final``               –      ``pooled``  the written lux map: ``pooled`` = every set
                                           estimates every pixel (radius ≥ the pixel's own
                                           disk), the mean is the estimate at pixel
                                           resolution and the sets' spread its honest
                                           error; ``interleaved`` = the paper's
                                           frame (each set its pixels, then the box
                                           filter: M² times cheaper, blurred over n×n)
``filter_size``         px     M           box filter window n×n (paper: 3×3 … 6×6)
``frame_photons``       –      200 000     photons shot per frame over all sets
``structure``           –      ``middle``  photon-map index: ``middle`` (unbalanced kd-tree,
                                           incremental), ``median``, ``grid-lo``, ``grid-hi``
``spt``                 –      auto        Selective Photon Tracing on/off; auto = plan
``record``              –      auto        ``wall`` or ``all`` diffuse surfaces; auto = plan
``max_depth``           –      32          bounces per photon
``probe_grid``          –      64 × 32     points on the wall where every set estimates E:
                                           their spread over the sets is the error estimate
``channels``            –      auto        1 (luminous) or 3 (RGB); auto = plan
``apertures``           deg    none        (H, V) of detector apertures every set counts
                                           photons in (``lightsim.engine.apertures``)
``aperture_deg``        deg    0.15        side of the square aperture (≈ 65 mm at 25 m)
``aperture_shift_deg``  deg    0           strip reach for aiming after the run
``aperture_substeps``   –      1           strip bins per aperture side
``aperture_targets``    –      none        aperture indices that Selective Photon Tracing
                                           refines (photons landing there mark their cell)
``aperture_spt_share``  1      0.5         share of each SPT pass given to refined cells
``aperture_raster``     deg    none        (H lo, H hi, V lo, V hi) tiled with apertures
                                           for the beam maximum Imax
======================  =====  ==========  ==================================================
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from lightsim.errors import InputError

ESTIMATORS = ("knn", "bin", "radius")
BANDWIDTHS = ("ici", "knn")
KERNELS = ("box", "cone", "epanechnikov")
STRUCTURES = ("middle", "median", "grid-lo", "grid-hi")


@dataclass(frozen=True)
class RunConfig:
    """Settings of a run (see the module docstring for units and defaults)."""

    seed: int = 1
    interleave: int = 4
    estimator: str = "knn"
    k: int = 64
    max_radius: float | None = None
    min_radius: float | None = None
    kernel: str = "box"
    bandwidth: str = "ici"
    ici_gamma: float = 2.0
    filter_size: int | None = None
    final: str = "pooled"
    frame_photons: int = 200_000
    structure: str = "middle"
    spt: bool | None = None
    record: str | None = None
    max_depth: int = 32
    probe_grid: tuple[int, int] = (64, 32)
    channels: int | None = None
    threads: int | None = None
    extra_probes: tuple[tuple[float, float], ...] = field(default_factory=tuple)
    apertures: tuple[tuple[float, float], ...] = field(default_factory=tuple)
    aperture_deg: float = 0.15
    aperture_shift_deg: float = 0.0
    aperture_substeps: int = 1
    aperture_targets: tuple[int, ...] = field(default_factory=tuple)
    aperture_spt_share: float = 0.5
    aperture_raster: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.estimator not in ESTIMATORS:
            raise InputError(f"estimator must be one of {', '.join(ESTIMATORS)}, "
                             f"got '{self.estimator}'")
        if self.kernel not in KERNELS:
            raise InputError(f"kernel must be one of {', '.join(KERNELS)}, got '{self.kernel}'")
        if self.structure not in STRUCTURES:
            raise InputError(f"structure must be one of {', '.join(STRUCTURES)}, "
                             f"got '{self.structure}'")
        if not 1 <= self.interleave <= 16:
            raise InputError(f"interleave M must be between 1 and 16, got {self.interleave}")
        if self.k < 1:
            raise InputError(f"k must be at least 1, got {self.k}")
        if self.bandwidth not in BANDWIDTHS:
            raise InputError(f"bandwidth must be one of {', '.join(BANDWIDTHS)}, "
                             f"got '{self.bandwidth}'")
        if not (0 < self.ici_gamma < math.inf):
            raise InputError(f"ICI gamma must be positive and finite, got {self.ici_gamma}")
        if self.max_radius is not None and not (self.max_radius > 0):
            raise InputError(f"max radius must be positive, got {self.max_radius}")
        if self.min_radius is not None and not (0 <= self.min_radius < math.inf):
            raise InputError(f"min radius must be ≥ 0 and finite, got {self.min_radius}")
        if self.final not in ("pooled", "interleaved"):
            raise InputError(f"final must be 'pooled' or 'interleaved', got '{self.final}'")
        if self.filter_size is not None and not 1 <= self.filter_size <= 32:
            raise InputError(f"filter size must be between 1 and 32, got {self.filter_size}")
        if self.frame_photons < self.n_sets:
            raise InputError(f"photons per frame ({self.frame_photons}) must be at least the "
                             f"number of interleave sets ({self.n_sets})")
        if not 1 <= self.max_depth <= 1000:
            raise InputError(f"max depth must be between 1 and 1000, got {self.max_depth}")
        if self.record not in (None, "wall", "all"):
            raise InputError(f"record must be 'wall' or 'all', got '{self.record}'")
        if self.channels not in (None, 1, 3):
            raise InputError(f"channels must be 1 or 3, got {self.channels}")
        if not (math.isfinite(self.aperture_deg) and 0 < self.aperture_deg < 10):
            raise InputError(f"aperture must be between 0 and 10 degrees, "
                             f"got {self.aperture_deg}")
        if not 0 < self.aperture_spt_share < 1:
            raise InputError(f"aperture SPT share must lie in (0, 1), "
                             f"got {self.aperture_spt_share}")

    @property
    def n_sets(self) -> int:
        return self.interleave * self.interleave

    @property
    def photons_per_set(self) -> int:
        """Photons each set shoots per frame (plain sampling; SPT passes aim at it)."""
        return max(1, self.frame_photons // self.n_sets)

    @property
    def uses_ici(self) -> bool:
        """Whether the written (pooled) map picks its radius by ICI."""
        return self.estimator == "knn" and self.bandwidth == "ici"

    @property
    def filter_n(self) -> int:
        return self.filter_size or self.interleave

    def with_(self, **changes: Any) -> RunConfig:
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if self.max_radius is not None and math.isinf(self.max_radius):
            d["max_radius"] = "inf"
        d["extra_probes"] = [list(p) for p in self.extra_probes]
        d["apertures"] = [list(p) for p in self.apertures]
        d["aperture_targets"] = list(self.aperture_targets)
        return d
