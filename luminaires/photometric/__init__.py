"""Photometric data: goniometer grids, far fields from photons, IES and EULUMDAT files.

* :class:`CandelaGrid` — intensity (cd) on a Type C grid. Axes: the lamp shines along +Z
  with +Y up; γ is measured from the nadir (−Y), C about +Y counter-clockwise seen from
  above, **C = 0°, γ = 90° is straight ahead**, C = 90° the driver's left (+X).
* :class:`HVGrid` — intensity on a Type A (vehicle lamps: H right, V up, H = V = 0° ahead)
  or Type B grid (module ``hvgrid``).
* Both are **bilinear** between nodes; ``total_flux()`` is the interpolant's exact integral
  and ``intensity``/``intensity_towards``/``intensity_hv`` return the interpolant itself
  (module ``bilinear``).
* :func:`farfield_from_photons` — deposit escaping photons (directions, lm) on a Type C or
  Type A grid with bilinear weights; total lumens are conserved exactly.
* :func:`read_ies` / :func:`write_ies` — IES LM-63 Types A, B, C (reads 1986–2019, writes
  2002); :func:`resolve_ies_type` — which type ``--ies`` writes.
* :func:`read_ldt` / :func:`write_ldt` — EULUMDAT (uneven C angles, lamp sets).
* :func:`read_photometric` — either, by file suffix.
* :func:`sample_directions` — a file as a point source: directions drawn exactly from the
  interpolated intensity.
* ``simulate --ies/--ldt`` (module ``analysis``): the run's own wall photons and a
  far-field trace as one table over the sphere (``runfield``), written on auto angles
  fine where the beam changes fast or on equal steps (``gridding``: ``--ies-step``,
  ``--ldt-step``), and compared with the run's apertures (``reproduce``).

Shipped sample: ``interlight-ovni-60w-5300lm.ies`` (a measured LED high-bay, 5 300 lm; see
``SAMPLES.md`` for its source and licence).

Parameters
----------
============  =====  ========  ==================================================
name          unit   default   meaning
============  =====  ========  ==================================================
candela       cd     –         intensities, (nC, nG)
c_deg         deg    –         C-planes in [0, 360)
gamma_deg     deg    –         γ in [0, 180] from the nadir
lamp_lumens   lm     None      rated lamp flux (None = absolute photometry)
powers        lm     –         flux per escaping photon
dc_deg        deg    1.0       far-field C step
dgamma_deg    deg    1.0       far-field γ step
digits        1      7         significant digits written to IES/LDT
============  =====  ========  ==================================================
"""

from __future__ import annotations

import os
from pathlib import Path

from lightsim.errors import InputError

from .candela import (
    CandelaGrid,
    angles_from_directions,
    direction_from_hv,
    directions_from_angles,
    hv_from_directions,
)
from .farfield import farfield_from_photons, uniform_axes
from .hvgrid import HVGrid, hv_directions
from .ies import IES_TYPES, read_ies, resolve_ies_type, write_ies
from .ldt import read_ldt, write_ldt
from .sampling import sample_directions

SAMPLE_DIR = Path(__file__).resolve().parent
SAMPLE_IES = SAMPLE_DIR / "interlight-ovni-60w-5300lm.ies"
"""A published, measured IES file shipped with lightsim (see SAMPLES.md)."""

__all__ = [
    "IES_TYPES",
    "SAMPLE_IES",
    "CandelaGrid",
    "HVGrid",
    "angles_from_directions",
    "direction_from_hv",
    "directions_from_angles",
    "farfield_from_photons",
    "hv_directions",
    "hv_from_directions",
    "read_ies",
    "read_ldt",
    "read_photometric",
    "resolve_ies_type",
    "sample_directions",
    "uniform_axes",
    "write_ies",
    "write_ldt",
    "write_photometric",
]


def read_photometric(path: str | os.PathLike, *, lamp_set: int | None = None
                     ) -> CandelaGrid | HVGrid:
    """Read an ``.ies`` (Types A, B, C) or ``.ldt`` file (chosen by suffix) into a grid.

    ``lamp_set`` (1-based) chooses the lamp set of a EULUMDAT file with several; it makes no
    sense for IES files.
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".ies":
        if lamp_set is not None:
            raise InputError(f"--lamp-set applies to EULUMDAT (.ldt) files, not {path}")
        return read_ies(path)
    if suffix in (".ldt", ".eul"):
        return read_ldt(path, lamp_set=lamp_set)
    raise InputError(f"photometric file {path}: unknown suffix '{suffix}' (.ies or .ldt)")


def write_photometric(path: str | os.PathLike, grid: CandelaGrid, **kwargs: object) -> Path:
    """Write ``grid`` as ``.ies`` or ``.ldt`` (chosen by suffix), atomically."""
    suffix = Path(path).suffix.lower()
    if suffix == ".ies":
        return write_ies(path, grid, **kwargs)  # type: ignore[arg-type]
    if suffix in (".ldt", ".eul"):
        return write_ldt(path, grid, **kwargs)  # type: ignore[arg-type]
    raise InputError(f"photometric file {path}: unknown suffix '{suffix}' (.ies or .ldt)")
