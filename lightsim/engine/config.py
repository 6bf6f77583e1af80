"""Run configuration shared by the server and every client.

Each setting is declared once, below, as a field of :class:`RunConfig` with its
:class:`~lightsim.options.Option` record (unit, default, range, help, flag): that
declaration is this module's parameter table, and ``lightsim simulate --help``, the range
checks, the checkpoint and ``summary.json["config"]`` all come from it
(:mod:`lightsim.options`). Settings without a flag are set by the plan or by the
regulation check (``internal`` says which).

Notes on the radii and the written map (detail the one-line help cannot hold):

- ``min_radius`` auto = the radius of a disk with the area of one pixel (pooled) or of the
  n×n filter window (interleaved: finer detail cannot survive the filter); it also caps a
  point focus at a finite estimate. The ``radius`` estimator's fixed radius is the min
  radius.
- ``max_radius`` auto = :data:`MAX_RADIUS_FACTOR` × the min radius, so light is not
  smeared far into dark regions (glare points next to a cut-off stay honest); ``inf`` =
  the paper's unlimited kNN.
- ``bandwidth`` ``ici``: per pixel, the largest of the nested estimates (the pixel itself,
  disks r_min·2^(j/2) … r_max) whose confidence interval overlaps all smaller ones'
  (:mod:`lightsim.render.ici`, :mod:`lightsim.render.written_map`): the radius shrinks
  as photons grow wherever blur would show, so the map converges to the pixel means (or
  the plain pixel counts when their estimated error is the lower one); ``knn`` = r_k
  clamped to [r_min, r_max] (the paper; its error levels off).
- ``final`` ``pooled``: every set estimates every pixel (radius ≥ the pixel's own disk),
  the mean is the estimate at pixel resolution and the sets' spread its honest error;
  ``interleaved``: the paper's frame (each set its pixels, then the box filter: M² times
  cheaper, blurred over n×n).
- The estimator settings (``estimator``, ``bandwidth``, ``final``, ``kernel``,
  ``structure``) multiply out to 144 combinations; :data:`SUPPORTED` names the few that
  are run and tested, and any other is refused with one line (exit code 2). The photon
  map's other kernels and structures stay available to :mod:`lightsim.photonmap`'s
  callers.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from lightsim import options
from lightsim.errors import InputError
from lightsim.options import option
from lightsim.render.region import REGIONS

ESTIMATORS = ("knn", "bin", "radius")
BANDWIDTHS = ("ici", "knn")
KERNELS = ("box", "cone", "epanechnikov")
STRUCTURES = ("middle", "median", "grid-lo", "grid-hi")
FINALS = ("pooled", "interleaved")

#: The estimator settings a run may have, as (estimator, bandwidth, final, kernel,
#: structure) — the combinations ``simulate``, ``validate``/``converge``, the benches, the
#: view and the tests run; None: that estimator does not read the setting. Every other
#: combination is refused (:meth:`RunConfig.__post_init__`).
SUPPORTED: tuple[tuple[str | None, ...], ...] = (
    ("knn", "ici", "pooled", "box", "middle"),       # the written map (the default)
    ("knn", "ici", "interleaved", "box", "middle"),  # the paper's filtered frame as the map
    ("knn", "knn", "pooled", "box", "middle"),       # the paper's r_k (validate's checks)
    ("radius", None, "pooled", "box", None),         # the IGI baseline (a hashed grid)
    ("radius", None, "interleaved", "box", None),
    ("bin", None, None, None, None),                 # photons counted per pixel
)
SUPPORTED_FIELDS = ("estimator", "bandwidth", "final", "kernel", "structure")


def supported_text() -> str:
    """The supported set in one line, as --help and the refusal name it."""
    rows = ", ".join("/".join("–" if v is None else v for v in row) for row in SUPPORTED)
    return f"{'/'.join(SUPPORTED_FIELDS)}: {rows} (–: not read)"


def is_supported(settings: tuple[str, ...]) -> bool:
    """Whether (estimator, bandwidth, final, kernel, structure) is in :data:`SUPPORTED`."""
    return any(all(want is None or want == got for want, got in zip(row, settings,
                                                                     strict=True))
               for row in SUPPORTED)

MAX_RADIUS_FACTOR = {"pooled": 4.0, "interleaved": 2.0}
"""Automatic largest kNN radius as a multiple of the smallest, per final-image mode."""

_PLAN = "set by the plan (lightsim.engine.plan)"
_APERTURES = "set by --aperture/--aim/--spt-points for a regulation check"


@dataclass(frozen=True)
class RunConfig:
    """Settings of a run; each field's record says its unit, default, range and flag."""

    seed: int = option(
        1, "Every photon is a function of (seed, interleave set, photon index).",
        flag=("--seed",), low=0)
    interleave: int = option(
        4, "M: M×M interleave sets, each with its own photons and photon map "
        "(paper section 3.3).", flag=("--interleave", "-M"), low=1, high=16)
    estimator: str = option(
        "knn", "Density estimator on the wall: knn (photon map, exact k nearest), bin "
        "(photons counted per pixel), radius (fixed-radius hashed grid, the IGI baseline). "
        f"Supported {supported_text()}.",
        flag=("--estimator",), choices=ESTIMATORS)
    k: int = option(64, "Photons per kNN estimate.", flag=("-k",), low=1)
    max_radius: float | None = option(
        None, "Largest kNN radius; auto = "
        + " or ".join(f"{f:g} × ({m})" for m, f in MAX_RADIUS_FACTOR.items())
        + " the min radius; inf = unlimited (the paper's kNN).", unit="m",
        flag=("--max-radius",), low=0, low_open=True, allow_inf=True, default_text="auto")
    min_radius: float | None = option(
        None, "Smallest kNN radius (and the radius estimator's radius); auto = the disk "
        "of one pixel's area (pooled) or of the n×n filter window's (interleaved).",
        unit="m", flag=("--min-radius",), low=0, default_text="auto")
    kernel: str = option("box", "Density-estimate weights (supported: see --estimator).",
                         flag=("--kernel",), choices=KERNELS)
    bandwidth: str = option(
        "ici", "Written map's radius: ici = per pixel, the largest window the photon "
        "counts do not contradict (consistent); knn = r_k in [min radius, max radius] "
        "(supported: see --estimator).", flag=("--bandwidth",), choices=BANDWIDTHS)
    ici_gamma: float = option(2.0, "Γ: ICI interval half-width in standard errors.",
                              low=0, low_open=True, internal="fixed by the ICI study")
    filter_size: int | None = option(
        None, "Box filter size n (window n×n; paper: 3 … 6).", unit="px",
        flag=("--filter",), low=1, high=32, default_text="M")
    final: str = option(
        "pooled", "Written lux map: every set at every pixel (full resolution, honest "
        "error) or the paper's interleaved + box-filtered frame (fast, blurred; supported: "
        "see --estimator).", flag=("--final",), choices=FINALS)
    error_region: str = option(
        "lit", "Pixels the error figure (and --target-error's stop) covers: lit = every "
        "lit pixel (≥ 10 % of the map's maximum), edges included; interior = the lit "
        "pixels deeper than 0.2 × √(lit area/π) inside the lit region's edge (a round "
        "beam's inner 80 %; lightsim.render.region).", flag=("--error-region",),
        choices=REGIONS)
    frame_photons: int = option(200_000, "Photons per frame (all sets).",
                                flag=("--frame-photons",), low=1)
    structure: str = option(
        "middle", "Photon map index: middle (unbalanced kd-tree, incremental), median, "
        "grid-lo, grid-hi (supported: see --estimator).", flag=("--structure",),
        choices=STRUCTURES)
    spt: bool | None = option(None, "Force Selective Photon Tracing on/off.",
                              flag=("--spt/--no-spt",), kind="onoff",
                              default_text="auto (the plan)")
    record: str | None = option(None, "Photons recorded on the wall or on all diffuse "
                                "surfaces.", choices=(None, "wall", "all"), internal=_PLAN)
    max_depth: int = option(32, "Bounces per photon.", low=1, high=1000,
                            internal="fixed: deeper paths carry no measurable flux")
    probe_grid: tuple[int, int] = option(
        (64, 32), "Points on the wall where every set estimates E: their spread over the "
        "sets is the error estimate.", kind="pair", low=1,
        internal="fixed: the error estimate's sample")
    channels: int | None = option(None, "1 (luminous) or 3 (RGB).", choices=(None, 1, 3),
                                  internal=_PLAN)
    threads: int | None = option(None, "numba threads per client.", low=1,
                                 internal="set by the Ray backend per actor")
    keep_photons: bool = option(
        True, "Keep every photon for kNN estimates anywhere after the run; off: only what "
        "the estimates at the probe points read (lightsim.engine.pointstore), in memory "
        "that does not grow with the photons.", internal="set by simulate (--keep-photons)")
    extra_probes: tuple[tuple[float, float], ...] = option(
        (), "More probe points (h, v).", unit="m", kind="tuple",
        internal="set by callers (view, tests)")
    apertures: tuple[tuple[float, float], ...] = option(
        (), "(H, V) of detector apertures every set counts photons in "
        "(lightsim.engine.apertures).", unit="deg", kind="tuple", internal=_APERTURES)
    aperture_deg: float = option(0.15, "Side of the square aperture (≈ 65 mm at 25 m).",
                                 unit="deg", low=0, high=10, low_open=True, high_open=True,
                                 internal=_APERTURES)
    aperture_shift_deg: float = option(0.0, "Strip reach for aiming after the run.",
                                       unit="deg", internal=_APERTURES)
    aperture_substeps: int = option(1, "Strip bins per aperture side.", low=1,
                                    internal=_APERTURES)
    aperture_targets: tuple[int, ...] = option(
        (), "Aperture indices that Selective Photon Tracing refines.", kind="tuple",
        internal=_APERTURES)
    aperture_spt_share: float = option(0.5, "Share of each SPT pass given to refined "
                                       "cells.", low=0, high=1, low_open=True,
                                       high_open=True, internal=_APERTURES)
    guide: str = option(
        "off", "Importance-driven emission: points = send extra photons towards the "
        "requested rule sets' test points and zones until each is counted well "
        "(lightsim.engine.guiding); weights keep every estimate unbiased.",
        flag=("--guide",), choices=("off", "points"))
    guide_targets: tuple[tuple[float, ...], ...] = option(
        (), "Guide targets as rows (first frame, H0, H1, V0, V1, importance).",
        unit="deg", kind="tuple", internal="set by --guide or Session.guide")
    guide_share: float = option(0.5, "Share of photons drawn from the learned density "
                                "(the rest uniform: a defensive mixture).", low=0, high=1,
                                low_open=True, high_open=True,
                                internal="fixed: every photon weighs at most 1/(1 − share)")
    guide_photons: float = option(400.0, "Effective photons (pooled over the sets) at which "
                                  "a guide target stops drawing photons.", low=1,
                                  internal="fixed: about ±10 % at 95 %")
    guide_window_deg: float = option(1.0, "Side of the learning window around a guide "
                                     "target.", unit="deg", low=0, high=10, low_open=True,
                                     internal="fixed by the guiding study")
    aperture_raster: tuple[float, float, float, float] | None = option(
        None, "(H lo, H hi, V lo, V hi) tiled with apertures for the beam maximum Imax.",
        unit="deg", kind="tuple", internal=_APERTURES)
    path_length: int = option(
        0, "Surface events each wall photon's path signature keeps (0: none); the sets "
        "count every path class's flux in the detector apertures (lightsim.provenance).",
        low=0, high=64, internal="set by --provenance")
    path_map: str = option(
        "", "With path signatures: the sets also bin the wall photons whose path class "
        "names this text into a wall map (lightsim.provenance.matches); empty: none.",
        internal="set by --provenance-map")

    def __post_init__(self) -> None:
        options.check_fields(self)  # choices and ranges, from the declarations above
        settings = tuple(getattr(self, f) for f in SUPPORTED_FIELDS)
        if not is_supported(settings):
            raise InputError(f"the estimator settings {'/'.join(settings)} are not "
                             f"supported; supported {supported_text()}")
        for row in self.guide_targets:
            if len(row) != 6 or not all(isinstance(x, int | float) and x == x
                                        and abs(x) != float("inf") for x in row):
                raise InputError("a guide target is (first frame, H0, H1, V0, V1, "
                                 f"importance) in finite numbers, got {row}")
            if row[0] < 0 or row[5] < 0 or row[2] <= row[1] or row[4] <= row[3]:
                raise InputError(f"a guide target needs a first frame ≥ 0, H0 < H1, V0 < V1 "
                                 f"and importance ≥ 0, got {row}")
        if self.frame_photons < self.n_sets:
            raise InputError(f"photons per frame ({self.frame_photons}) must be at least the "
                             f"number of interleave sets ({self.n_sets})")

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
        """Every setting as JSON values (``summary.json["config"]``, checkpoints)."""
        return options.to_json(self)

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> RunConfig:
        """The config :meth:`to_dict` wrote (or any subset of its settings)."""
        return cls(**options.from_json(cls, doc))
