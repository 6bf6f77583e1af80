"""M×M interleaved sampling: pixel sets, their sub-images and their static assignment.

Following the paper (sections 3.3 and 4.3), the image is split into M² *interleave sets*:
pixel (x, y) — column x, row y, row 0 at the top — belongs to set ``s = b·M + a`` with
``a = x mod M`` and ``b = y mod M``. Each set gets its own photon map (N photons), so a
client evaluates a downscaled, shifted copy of the image from its own map; the server
scatters the sub-images back into the full image and box-filters it with n = M
(:mod:`lightsim.render.boxfilter`), which estimates what one map of M²·N photons would give.

Sets are assigned to clients *statically* and round-robin (paper 4.3): client k gets sets
k, k + n_clients, k + 2·n_clients, … — deterministic, and the number of sets per client
differs by at most one. More clients than sets is an error by default (a client without a
set would idle; the paper limits the clients to the number of sets), or gives those
clients empty lists with ``allow_idle=True``.

Parameters (user documentation)
-------------------------------
==============  ======  ========  ====================================================
name            unit    default   meaning
==============  ======  ========  ====================================================
``M``           pixels  required  interleave size; M² sets (paper: 3…6; 1 = no
                                  interleaving, one set)
``width``       pixels  required  image width W (need not be a multiple of M)
``height``      pixels  required  image height H (need not be a multiple of M)
``n_clients``   –       required  number of clients for :meth:`InterleavePattern.assign`
``allow_idle``  –       False     allow more clients than sets (extra ones get no set)
``h_range_m``   m       –         wall frame: [h_min, h_max] of the image (conventions)
``v_range_m``   m       –         wall frame: [v_min, v_max] of the image
==============  ======  ========  ====================================================

Set s has the sub-image ``full[b::M, a::M]`` of shape
``(ceil((H − b)/M), ceil((W − a)/M))``; its pixel (i, j) is image pixel
(row b + i·M, column a + j·M). Wall coordinates follow ``docs/reference/conventions.md``: column 0
is the smallest H, row 0 the largest V, pixel centres at ``h_min + (c + 0.5)·dh`` and
``v_max − (r + 0.5)·dv`` with ``dh = (h_max − h_min)/W``, ``dv = (v_max − v_min)/H``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lightsim.errors import InputError, LightsimError
from lightsim.wall import WallFrame

__all__ = ["InterleavePattern"]


@dataclass(frozen=True)
class InterleavePattern:
    """The M×M interleave sets of a W×H image (see the module docstring).

    Parameters
    ----------
    M : int
        Interleave size in pixels (≥ 1); there are M² sets.
    width, height : int
        Image size in pixels (≥ 1).
    """

    M: int
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("M", "width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ValueError(f"InterleavePattern: {name} must be an integer ≥ 1, "
                                 f"got {value!r}")
            object.__setattr__(self, name, int(value))

    @classmethod
    def from_wall(cls, M: int, wall: Mapping[str, Any]) -> InterleavePattern:
        """Pattern for the image of a wall frame (``wall["resolution"] = [W, H]``)."""
        W, H = _resolution(wall)
        return cls(M, W, H)

    # -- sets --------------------------------------------------------------------------

    @property
    def n_sets(self) -> int:
        """Number of interleave sets, M²."""
        return self.M * self.M

    @property
    def shape(self) -> tuple[int, int]:
        """Full image shape (H, W)."""
        return self.height, self.width

    def _check_set(self, s: int) -> tuple[int, int]:
        if isinstance(s, bool) or not isinstance(s, int | np.integer) or not 0 <= s < self.n_sets:
            raise ValueError(f"interleave set must be 0…{self.n_sets - 1}, got {s!r}")
        b, a = divmod(int(s), self.M)
        return a, b

    def set_offset(self, s: int) -> tuple[int, int]:
        """(a, b): column and row of the set's first pixel; ``s = b·M + a``."""
        return self._check_set(s)

    def set_of(self, x: int | np.ndarray, y: int | np.ndarray) -> int | np.ndarray:
        """Set index of pixel column x, row y (scalars or arrays)."""
        s = (np.asarray(y) % self.M) * self.M + np.asarray(x) % self.M
        return int(s) if s.ndim == 0 else s

    def set_index_image(self) -> np.ndarray:
        """(H, W) int32 image of every pixel's set index."""
        ys = np.arange(self.height, dtype=np.int32)[:, None] % self.M
        xs = np.arange(self.width, dtype=np.int32)[None, :] % self.M
        return (ys * self.M + xs).astype(np.int32)

    def sub_shape(self, s: int) -> tuple[int, int]:
        """Shape (rows, cols) of set s's sub-image: (ceil((H − b)/M), ceil((W − a)/M))."""
        a, b = self._check_set(s)
        return -(-(self.height - b) // self.M), -(-(self.width - a) // self.M)

    def set_pixels(self, s: int) -> tuple[np.ndarray, np.ndarray]:
        """Image rows and columns of set s: 1-D int64 arrays (rows, cols).

        Sub-image pixel (i, j) is image pixel (rows[i], cols[j]).
        """
        a, b = self._check_set(s)
        return (np.arange(b, self.height, self.M, dtype=np.int64),
                np.arange(a, self.width, self.M, dtype=np.int64))

    def n_pixels(self, s: int) -> int:
        """Number of pixels in set s."""
        r, c = self.sub_shape(s)
        return r * c

    # -- gather / scatter ----------------------------------------------------------------

    def gather(self, full: np.ndarray) -> list[np.ndarray]:
        """Split a full image (H, W[, C]) into its M² sub-images (contiguous copies)."""
        full = np.asarray(full)
        if full.shape[:2] != self.shape:
            raise ValueError(f"image has shape {full.shape[:2]}, pattern is {self.shape}")
        return [self.gather_set(full, s) for s in range(self.n_sets)]

    def gather_set(self, full: np.ndarray, s: int) -> np.ndarray:
        """Sub-image of set s from a full image (H, W[, C]) (contiguous copy)."""
        a, b = self._check_set(s)
        return np.ascontiguousarray(np.asarray(full)[b::self.M, a::self.M])

    def scatter(self, sub_images: Sequence[np.ndarray], out: np.ndarray | None = None
                ) -> np.ndarray:
        """Assemble the M² sub-images (in set order) into the full image.

        Parameters
        ----------
        sub_images : sequence of M² arrays
            Sub-image of set s at position s, shape :meth:`sub_shape` (+ channels).
        out : ndarray, optional
            Full image to fill (H, W[, C]); allocated with the sub-images' common dtype
            otherwise.

        Returns
        -------
        ndarray, shape (H, W[, C])
        """
        if len(sub_images) != self.n_sets:
            raise ValueError(f"need {self.n_sets} sub-images, got {len(sub_images)}")
        subs = [np.asarray(x) for x in sub_images]
        extra = subs[0].shape[2:]
        if out is None:
            dtype = np.result_type(*subs)
            out = np.empty(self.shape + extra, dtype=dtype)
        for s, sub in enumerate(subs):
            self.insert(out, s, sub)
        return out

    def insert(self, out: np.ndarray, s: int, sub: np.ndarray) -> None:
        """Write set s's sub-image into the full image ``out`` in place (as it arrives)."""
        a, b = self._check_set(s)
        sub = np.asarray(sub)
        want = self.sub_shape(s) + out.shape[2:]
        if sub.shape != want:
            raise ValueError(f"sub-image of set {s} must have shape {want}, got {sub.shape}")
        out[b::self.M, a::self.M] = sub

    # -- static assignment ------------------------------------------------------------------

    def assign(self, n_clients: int, *, allow_idle: bool = False) -> list[list[int]]:
        """Static round-robin assignment of the sets to clients.

        Parameters
        ----------
        n_clients : int
            Number of clients (≥ 1).
        allow_idle : bool, default False
            With more clients than sets, give the extra clients empty lists instead of
            raising.

        Returns
        -------
        list of n_clients lists of int
            Client k gets sets ``k, k + n_clients, …`` (ascending); list lengths differ by
            at most one.

        Raises
        ------
        LightsimError
            More clients than sets (unless ``allow_idle``), or n_clients < 1.
        """
        if isinstance(n_clients, bool) or not isinstance(n_clients, int | np.integer) \
                or n_clients < 1:
            raise LightsimError(f"number of clients must be ≥ 1, got {n_clients!r}")
        n_clients = int(n_clients)
        if n_clients > self.n_sets and not allow_idle:
            raise LightsimError(
                f"{n_clients} clients but only {self.n_sets} interleave sets (M={self.M}): "
                f"use at most {self.n_sets} clients or a larger interleave size")
        return [list(range(k, self.n_sets, n_clients)) for k in range(n_clients)]

    # -- wall coordinates -----------------------------------------------------------------

    def pixel_size(self, h_range_m: Sequence[float], v_range_m: Sequence[float]
                   ) -> tuple[float, float]:
        """(dh, dv): pixel width and height on the wall in metres."""
        return self._frame(h_range_m, v_range_m).pixel_size_m

    def _frame(self, h_range_m: Sequence[float], v_range_m: Sequence[float],
               wall: Mapping[str, Any] | None = None) -> WallFrame:
        """The core wall frame of this pattern's image (only the pixel grid matters)."""
        (h0, h1), (v0, v1) = _ranges(h_range_m, v_range_m)
        desc = {"distance_m": 1.0, **(wall or {}), "h_range_m": [h0, h1],
                "v_range_m": [v0, v1]}
        try:
            return WallFrame.from_any(desc, resolution=(self.width, self.height))
        except InputError as exc:
            raise ValueError(str(exc)) from None

    def set_wall_coords(self, s: int, h_range_m: Sequence[float],
                        v_range_m: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """Wall coordinates (m) of the pixel centres of set s.

        Parameters
        ----------
        s : int
            Set index.
        h_range_m, v_range_m : [min, max] in m
            Wall frame extent relative to its centre (``wall["h_range_m"]`` …).

        Returns
        -------
        h, v : ndarray, float64, shape :meth:`sub_shape`
            H (m, to the right) and V (m, up) of each sub-image pixel centre:
            ``h = h_min + (col + 0.5)·dh``, ``v = v_max − (row + 0.5)·dv``
            (:meth:`lightsim.wall.WallFrame.cell_centres`).
        """
        rows, cols = self.set_pixels(s)
        h, v = self._frame(h_range_m, v_range_m).cell_centres(rows, cols)
        return np.broadcast_to(h[None, :], (rows.size, cols.size)).copy(), \
            np.broadcast_to(v[:, None], (rows.size, cols.size)).copy()

    def set_wall_points(self, s: int, wall: Mapping[str, Any]) -> np.ndarray:
        """World positions (m) of set s's pixel centres on the wall, shape (rows, cols, 3).

        ``p = centre + h·h_axis + v·v_axis`` with the wall frame's ``centre``, ``h_axis``,
        ``v_axis``, ``h_range_m``, ``v_range_m``; ``wall["resolution"]`` must equal
        [W, H] of this pattern.
        """
        W, H = _resolution(wall)
        if (W, H) != (self.width, self.height):
            raise ValueError(f"wall resolution {[W, H]} does not match the pattern "
                             f"{[self.width, self.height]}")
        h, v = self.set_wall_coords(s, wall["h_range_m"], wall["v_range_m"])
        return self._frame(wall["h_range_m"], wall["v_range_m"], wall).to_world(h, v)


def _ranges(h_range_m: Sequence[float], v_range_m: Sequence[float]
            ) -> tuple[tuple[float, float], tuple[float, float]]:
    h0, h1 = (float(x) for x in h_range_m)
    v0, v1 = (float(x) for x in v_range_m)
    if not (h1 > h0 and v1 > v0):
        raise ValueError(f"wall ranges must be increasing [min, max], got h={[h0, h1]}, "
                         f"v={[v0, v1]}")
    return (h0, h1), (v0, v1)


def _resolution(wall: Mapping[str, Any]) -> tuple[int, int]:
    try:
        W, H = (int(x) for x in wall["resolution"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"wall frame needs resolution [W, H], got "
                         f"{wall.get('resolution')!r}") from exc
    return W, H
