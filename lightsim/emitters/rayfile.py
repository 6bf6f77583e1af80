"""A ray file as an emitter: photons drawn from the file's rays.

Photon i takes ray ``j = F⁻¹(u)`` (u the photon's first sample dimension, F the
cumulative flux of the rays in file order), so rays are drawn with probability ∝ their
flux and every photon carries the same share Φ/N of the source's flux — with
replacement: more photons than rays reuse rays, fewer take a stratified subset. The flux
is conserved exactly (it is set, not estimated), and the file's own rays are the source:
no smoothing, no interpolation. Equal-flux files (the usual case) need no table; others
keep one float64 cumulative sum per ray. Rays are read from the memory-mapped file only
when drawn.

The file's frame is placed in the scene by a rotation taking its +Z to ``axis`` (the
smallest such rotation) and a translation to ``position``; positions are converted to
metres by the file's unit.

==============  =====  =========  =================================================
parameter       unit   default    meaning
==============  =====  =========  =================================================
``path``        –      –          TM-25 or Zemax ray file (:mod:`lightsim.io.rayfile`)
``position``    m      (0, 0, 0)  where the file's origin goes
``axis``        –      (0, 0, 1)  where the file's +Z points
``flux_lm``     lm     the file's total luminous flux (sum of per-ray lumens, else
                                  the header's); required for radiant-only files
``ORDER_CELLS`` –      64         direction cells per side of the guide's ray order
==============  =====  =========  =================================================
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.rayfile import CHUNK, RayFile, read_rayfile

EQUAL_FLUX_RTOL = 1e-6  # rays whose fluxes agree to this are drawn without a table
ORDER_CELLS = 64  # octahedral direction cells per side of the guide's ray order


def direction_key(k: np.ndarray, cells: int = ORDER_CELLS) -> np.ndarray:
    """Cell of unit directions ``k`` (n, 3) in a ``cells``² octahedral grid (+Z at the
    centre), as a Z-order (Morton) key: near directions get near keys (int64)."""
    k = np.asarray(k, dtype=np.float64)
    norm = np.abs(k).sum(axis=1)
    norm = np.where(norm > 0, norm, 1.0)
    x, y, z = k[:, 0] / norm, k[:, 1] / norm, k[:, 2] / norm
    back = z < 0  # the lower half folded out to the corners
    fx = np.where(back, (1 - np.abs(y)) * np.sign(x + 0.0), x)
    fy = np.where(back, (1 - np.abs(x)) * np.sign(y + 0.0), y)
    i = np.clip(((fx + 1) * 0.5 * cells).astype(np.int64), 0, cells - 1)
    j = np.clip(((fy + 1) * 0.5 * cells).astype(np.int64), 0, cells - 1)
    key = np.zeros(len(k), np.int64)
    for b in range(int(cells - 1).bit_length()):
        key |= ((i >> b) & 1) << (2 * b) | ((j >> b) & 1) << (2 * b + 1)
    return key


def rotation_z_to(axis: np.ndarray) -> np.ndarray:
    """The 3×3 rotation taking +Z to the unit vector ``axis`` (smallest angle)."""
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if not (np.all(np.isfinite(a)) and n > 0):
        raise InputError(f"ray file axis must be a non-zero vector, got {tuple(axis)}")
    a = a / n
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ a)
    if c > 1.0 - 1e-15:
        return np.eye(3)
    if c < -1.0 + 1e-15:  # half turn about X
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(z, a)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


class RaySource:
    """Draw photon origins and directions from a ray file (see the module docstring)."""

    def __init__(self, path: str | Path, position: tuple[float, float, float] = (0, 0, 0),
                 axis: tuple[float, float, float] = (0.0, 0.0, 1.0),
                 flux_lm: float | None = None) -> None:
        self.path = str(path)
        self.position = np.asarray(position, dtype=np.float64)
        if self.position.shape != (3,) or not np.all(np.isfinite(self.position)):
            raise InputError(f"ray file position must be X,Y,Z in metres, got {position}")
        self.axis = tuple(float(x) for x in axis)
        self.rotation = rotation_z_to(np.asarray(axis, float))
        rf = self.file
        self.n_rays = rf.n_rays
        self._check_flux_column()  # a NaN or negative ray flux is named as such, first
        own = rf.luminous_flux()
        if flux_lm is not None:
            if not (math.isfinite(flux_lm) and flux_lm > 0):
                raise InputError(f"flux must be a positive number of lumens, got {flux_lm}")
            self.flux_lm = float(flux_lm)
        elif own is not None and math.isfinite(own) and own > 0:
            self.flux_lm = float(own)
        else:
            raise InputError(f"{rf.path}: the ray file gives no luminous flux (radiant "
                             "only): give --flux LM")

    # -- state not pickled (Ray ships scenes): the memmap and the table are rebuilt -------
    def __getstate__(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items()
                if k not in ("_file", "_cdf", "_perm", "_perm_cdf")}

    @property
    def file(self) -> RayFile:
        if "_file" not in self.__dict__:
            self._file = read_rayfile(self.path)
        return self._file

    def _check_flux_column(self) -> None:
        """Scan the flux column once (streamed): finite, non-negative, not all zero; note
        whether all rays carry the same flux (then no table is needed)."""
        mm = self.file.rays()
        j = self.file.column(self.file.flux_item)
        lo, hi, total = math.inf, -math.inf, 0.0
        for i in range(0, self.n_rays, CHUNK):
            f = np.asarray(mm[i:i + CHUNK, j], dtype=np.float64)
            if not np.all(np.isfinite(f)) or np.any(f < 0):
                raise InputError(f"{self.path}: ray flux must be finite and ≥ 0 "
                                 f"(bad value near ray {i})")
            lo, hi, total = min(lo, f.min()), max(hi, f.max()), total + f.sum()
        if not total > 0:
            raise InputError(f"{self.path}: all rays have zero flux")
        self.equal_flux = bool(hi - lo <= EQUAL_FLUX_RTOL * hi)

    def _table(self) -> np.ndarray:
        if "_cdf" not in self.__dict__:
            mm = self.file.rays()
            j = self.file.column(self.file.flux_item)
            cdf = np.empty(self.n_rays, dtype=np.float64)
            acc = 0.0
            for i in range(0, self.n_rays, CHUNK):
                part = np.cumsum(np.asarray(mm[i:i + CHUNK, j], dtype=np.float64)) + acc
                cdf[i:i + len(part)] = part
                acc = float(part[-1])
            cdf /= acc
            cdf[-1] = 1.0
            self._cdf = cdf
        return self._cdf

    def ray_indices(self, u: np.ndarray) -> np.ndarray:
        """Ray index per sample u in [0, 1): flux-weighted, with replacement."""
        u = np.asarray(u, dtype=np.float64)
        if self.equal_flux:
            idx = np.floor(u * self.n_rays).astype(np.int64)
        else:
            idx = np.searchsorted(self._table(), u, side="right")
        return np.clip(idx, 0, self.n_rays - 1)

    def direction_order(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The rays in direction order, for importance-driven emission
        (:mod:`lightsim.engine.guiding`): (permutation, its cumulative flux or None for
        equal-flux files). Rays are keyed by the cell of their scene direction in a
        :data:`ORDER_CELLS`² octahedral grid, cells in Z (Morton) order so that near
        directions lie near in the order; a cell's rays keep their file order."""
        if "_perm" not in self.__dict__:
            mm = self.file.rays()
            keys = np.empty(self.n_rays, np.int64)
            for i in range(0, self.n_rays, CHUNK):
                k = np.asarray(mm[i:i + CHUNK, 3:6], dtype=np.float64) @ self.rotation.T
                keys[i:i + len(k)] = direction_key(k, ORDER_CELLS)
            perm = np.argsort(keys, kind="stable")
            cdf = None
            if not self.equal_flux:
                j = self.file.column(self.file.flux_item)
                cdf = np.cumsum(np.asarray(mm[:, j], dtype=np.float64)[perm])
                cdf /= cdf[-1]
                cdf[-1] = 1.0
            self._perm, self._perm_cdf = perm, cdf
        return self._perm, self._perm_cdf

    def file_sample(self, u_ordered: np.ndarray) -> np.ndarray:
        """Sample values u₀ in direction order (:meth:`direction_order`) carried to file
        order: the ray u_ordered draws from the ordered rays is the ray the returned value
        draws in :meth:`ray_indices`. Flux-preserving: uniform u_ordered gives every ray
        with probability ∝ its flux, as uniform u does."""
        perm, pcdf = self.direction_order()
        u = np.asarray(u_ordered, dtype=np.float64)
        if pcdf is None:
            j = np.clip(np.floor(u * self.n_rays).astype(np.int64), 0, self.n_rays - 1)
            return (perm[j] + 0.5) / self.n_rays
        j = np.clip(np.searchsorted(pcdf, u, side="right"), 0, self.n_rays - 1)
        ray = perm[j]
        cdf = self._table()
        lo = np.where(ray > 0, cdf[np.maximum(ray - 1, 0)], 0.0)
        return 0.5 * (lo + cdf[ray])

    def sample_rays(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins (n, 3) m and unit directions (n, 3) for sample points u (n, ≥ 1)."""
        u = np.asarray(u, dtype=np.float64)
        idx = self.ray_indices(u[:, 0] if u.ndim == 2 else u)
        order = np.argsort(idx, kind="stable")  # read the file front to back
        rows = np.empty((len(idx), 6))
        rows[order] = self.file.rays()[idx[order], :6]
        pos = rows[:, :3] * self.file.unit_m
        k = rows[:, 3:6]
        norm = np.linalg.norm(k, axis=1, keepdims=True)
        if np.any(~((norm > 0) & np.isfinite(norm))) or not np.all(np.isfinite(pos)):
            raise InputError(f"{self.path}: a drawn ray has a zero or invalid direction")
        k = k / norm
        if not np.array_equal(self.rotation, np.eye(3)):
            pos, k = pos @ self.rotation.T, k @ self.rotation.T
        return pos + self.position, k

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The :class:`~lightsim.emitters.base.Emitter` protocol: :meth:`sample_rays`."""
        return self.sample_rays(u)

    def describe(self) -> str:
        return (f"ray file {Path(self.path).name}: {self.file.describe()}, "
                f"{self.flux_lm:.6g} lm used")
