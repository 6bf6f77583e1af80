"""Several lamps in one photo: find the beams' hot spots and keep one lamp's side.

A photo of a car's low beams on a wall shows two overlapping patterns; a simulation is
one lamp. :func:`find_lamps` looks at the brightest band of the photo (the rows where the
smoothed image reaches ``band_level`` of its maximum, clipped pixels counted as maximum),
takes the column profile of that band (each column's 90th percentile within it) and finds
its peaks (:func:`scipy.signal.find_peaks`) with a prominence of at least ``prominence``
of the maximum and at least ``min_separation`` of the width apart. Two or more peaks are
reported as lamps, left to right, each with the valley column towards its neighbour.

:func:`keep_lamp` marks every pixel beyond the valley on the other lamp's side as unusable
(like a clipped pixel), so registration and metrics see one lamp. The other lamp's spill
on this side stays; place the screen's H-V in front of the lamp you keep.

Parameters
----------
==============  ====  =======  ================================================================
name            unit  default  meaning
==============  ====  =======  ================================================================
smooth          1     0.01     Gaussian σ as a fraction of the photo width
band_level      1     0.5      rows of the hot band: smoothed maximum ≥ this × the overall one
prominence      1     0.08     least peak prominence, relative to the profile's maximum
min_separation  1     0.1      least distance of two lamps, fraction of the width
==============  ====  =======  ================================================================
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.signal import find_peaks

from lightsim.errors import InputError
from lightsim.validation.photo_io import PhotoImage

__all__ = ["LampSplit", "find_lamps", "keep_lamp"]


@dataclass(frozen=True)
class LampSplit:
    """Lamps found on a photo.

    Attributes
    ----------
    peaks_px : tuple of float
        Hot-spot columns (px), left to right.
    split_px : float or None
        Valley column between the two lamps nearest the middle (None for one lamp).
    """

    peaks_px: tuple[float, ...]
    split_px: float | None

    @property
    def count(self) -> int:
        """Number of lamps found."""
        return len(self.peaks_px)


def find_lamps(photo: PhotoImage, smooth: float = 0.01, band_level: float = 0.5,
               prominence: float = 0.08, min_separation: float = 0.1) -> LampSplit:
    """Find the lamps' hot spots (module docstring)."""
    lum = np.where(photo.clipped, np.nanmax(photo.luminance), photo.luminance)
    w = lum.shape[1]
    sm = gaussian_filter(lum, max(1.0, smooth * w), mode="nearest")
    rows = sm.max(axis=1) >= band_level * sm.max()
    profile = np.percentile(sm[rows], 90, axis=0)
    if not profile.max() > 0:
        return LampSplit((), None)
    peaks, _ = find_peaks(profile, prominence=prominence * profile.max(),
                          distance=max(1, int(min_separation * w)))
    if len(peaks) < 2:
        return LampSplit(tuple(float(p) for p in peaks) or (float(np.argmax(profile)),), None)
    # the valley between the two highest neighbours nearest the middle
    best = max(range(len(peaks) - 1), key=lambda i: min(profile[peaks[i]], profile[peaks[i + 1]]))
    a, b = peaks[best], peaks[best + 1]
    split = float(a + np.argmin(profile[a:b + 1]))
    return LampSplit(tuple(float(p) for p in peaks), split)


def keep_lamp(photo: PhotoImage, side: str, split: LampSplit) -> PhotoImage:
    """The photo with the other lamp's side marked unusable.

    Raises
    ------
    InputError
        ``side`` is not "left"/"right", or the photo shows one lamp only.
    """
    if side not in ("left", "right"):
        raise InputError(f"--lamp must be 'left' or 'right', got {side!r}")
    if split.split_px is None:
        raise InputError("--lamp: the photo shows one lamp only (no second hot spot found)")
    cols = np.arange(photo.shape[1])
    other = cols > split.split_px if side == "left" else cols < split.split_px
    mask = np.broadcast_to(other[None, :], photo.shape)
    info = {**photo.info, "lamp": side, "lamp_split_px": split.split_px}
    return replace(photo, clipped=photo.clipped | mask, info=info)
