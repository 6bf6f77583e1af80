"""A goniometer table as a continuous distribution: bilinear intensity, exact flux, exact sampling.

Every photometric type (IES Types A, B, C; EULUMDAT) is a *polar web*: intensities I_ji (cd)
at nodes (φ_j, θ_i) where θ is the polar angle from a pole ``p`` (0…180°) and φ the angle of
the half-plane about that pole, measured from ``e0`` towards ``e1``. A direction is

    d(φ, θ) = cos θ · p + sin θ · (cos φ · e0 + sin φ · e1).

Between nodes the intensity is **bilinear in (φ, θ)** (an affine change of the file's own
angles, so it is also bilinear in the file's H/V or C/γ). Outside the listed θ range, and —
for a table that does not wrap around (Types A/B) — outside the listed φ range, it is 0.

What is exact here (no quadrature):

* :meth:`PolarTable.total_flux` — ∫ I dΩ = ∫∫ I(φ, θ) sin θ dθ dφ of the interpolant, in
  closed form per cell (``α_i = ∫(1−t) sin θ dθ``, ``β_i = ∫ t sin θ dθ``);
* :meth:`PolarTable.node_weights` — the same integral as Σ I_ji·Ω_ji (Ω: each node's
  share, sr), so a far field binned with these weights conserves flux exactly;
* :func:`sample_table` — directions drawn from the density I(φ, θ)·sin θ / Φ itself:
  u1 picks φ from its marginal (a φ-cell, then the linear-in-s density inside it, solved in
  closed form), u2 picks θ from the conditional (a θ-cell by the blended cumulative
  integrals, then a safeguarded Newton solve of the cell's CDF to 1e-13 in the cell
  coordinate). The map is continuous and monotone in u1 and u2, so stratified/Halton inputs
  stay stratified.

Parameters
----------
=========  =====  =======  =================================================================
name       unit   default  meaning
=========  =====  =======  =================================================================
phi_deg    deg    –        (nP,) plane angles, strictly increasing
theta_deg  deg    –        (nT,) polar angles, strictly increasing in [0, 180], nT ≥ 2
candela    cd     –        (nP, nT) intensities ≥ 0
periodic   –      –        True: φ wraps (Type C; one plane = axial symmetry)
pole       1      –        unit vector of θ = 0 (world axes)
e0, e1     1      –        unit vectors of φ = 0° and φ = 90° at θ = 90°
u1, u2     1      –        uniform numbers in [0, 1] for sampling
=========  =====  =======  =================================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

__all__ = ["PolarTable", "sample_table"]

_SERIES_X = 0.05  # below this |x| the moment integrals use their Taylor series (rounding)


@njit(cache=True, inline="always")
def _f1(x: float) -> float:
    """∫₀¹ u·cos(u x) du."""
    if abs(x) < _SERIES_X:
        x2 = x * x
        return 0.5 - x2 / 8.0 + x2 * x2 / 144.0 - x2 * x2 * x2 / 5760.0 + x2**4 / 403200.0
    return (np.cos(x) + x * np.sin(x) - 1.0) / (x * x)


@njit(cache=True, inline="always")
def _f2(x: float) -> float:
    """∫₀¹ u·sin(u x) du."""
    if abs(x) < _SERIES_X:
        x2 = x * x
        return x / 3.0 - x * x2 / 30.0 + x * x2 * x2 / 840.0 - x * x2**3 / 45360.0
    return (np.sin(x) - x * np.cos(x)) / (x * x)


@njit(cache=True, inline="always")
def _cell_cdf(t: float, s0: float, c0s: float, dth: float, c0: float, c1: float
              ) -> tuple[float, float]:
    """(F, dF/dt) of F(t) = ∫ over θ ∈ [θ0, θ0 + tΔ] of (c0(1−τ) + c1 τ)·sin θ dθ.

    ``s0``, ``c0s`` = sin θ0, cos θ0; τ is the cell coordinate.
    """
    x = t * dth
    sx = np.sin(x)
    cx = np.cos(x)
    half = np.sin(0.5 * x)
    a = c0s * 2.0 * half * half + s0 * sx  # ∫ sin θ dθ = cos θ0 − cos(θ0 + x)
    if abs(x) < _SERIES_X:
        f1 = _f1(x)
        f2 = _f2(x)
    else:
        f1 = (cx + x * sx - 1.0) / (x * x)
        f2 = (sx - x * cx) / (x * x)
    b = dth * t * t * (s0 * f1 + c0s * f2)  # ∫ τ sin θ dθ
    dfdt = dth * (c0 + (c1 - c0) * t) * (s0 * cx + c0s * sx)
    return c0 * a + (c1 - c0) * b, dfdt


@njit(cache=True)
def _band_moments(theta_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = len(theta_rad) - 1
    alpha = np.empty(n)
    beta = np.empty(n)
    for i in range(n):
        th0 = theta_rad[i]
        dth = theta_rad[i + 1] - th0
        band = 2.0 * np.sin(th0 + 0.5 * dth) * np.sin(0.5 * dth)
        beta[i] = dth * (np.sin(th0) * _f1(dth) + np.cos(th0) * _f2(dth))
        alpha[i] = band - beta[i]
    return alpha, beta


@njit(cache=True)
def _search(cum: np.ndarray, x: float, hi: int) -> int:
    """Largest k in [0, hi] with cum[k] <= x (cum non-decreasing)."""
    lo = 0
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if cum[mid] <= x:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(cache=True, inline="always")
def _blend(cum: np.ndarray, j: int, jn: int, s: float, i: int) -> float:
    return (1.0 - s) * cum[j, i] + s * cum[jn, i]


@njit(cache=True)
def _search_blend(cum: np.ndarray, j: int, jn: int, s: float, x: float, hi: int) -> int:
    """Largest i in [0, hi] with blend(i) <= x (blend non-decreasing in i)."""
    lo = 0
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if _blend(cum, j, jn, s, mid) <= x:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(cache=True)
def _sample_kernel(u1, u2, cum_phi, nxt, phi, dphi, plane, cum_theta, theta, cd, frame,
                   out_phi, out_theta, out_dir, out_val):
    ncell = len(cum_phi) - 1
    nt = len(theta)
    for k in range(len(u1)):
        a = min(max(u1[k], 0.0), 1.0)
        j = _search(cum_phi, a, ncell - 1)
        while j > 0 and cum_phi[j + 1] <= cum_phi[j]:  # u1 = 1 on trailing empty cells
            j -= 1
        pj = cum_phi[j + 1] - cum_phi[j]
        r = min(max((a - cum_phi[j]) / pj, 0.0), 1.0) if pj > 0 else 0.5
        jn = nxt[j]
        lft = plane[j]
        rgt = plane[jn]
        den = lft + np.sqrt(max(lft * lft + r * (rgt * rgt - lft * lft), 0.0))
        s = r * (lft + rgt) / den if den > 0 else r  # inverse of the linear-in-s CDF
        s = min(max(s, 0.0), 1.0)
        target = min(max(u2[k], 0.0), 1.0) * _blend(cum_theta, j, jn, s, nt - 1)
        i = _search_blend(cum_theta, j, jn, s, target, nt - 2)
        while i > 0 and _blend(cum_theta, j, jn, s, i + 1) <= _blend(cum_theta, j, jn, s, i):
            i -= 1
        b_lo = _blend(cum_theta, j, jn, s, i)
        rem = target - b_lo
        c0 = (1.0 - s) * cd[j, i] + s * cd[jn, i]
        c1 = (1.0 - s) * cd[j, i + 1] + s * cd[jn, i + 1]
        th0 = theta[i]
        dth = theta[i + 1] - th0
        full = _blend(cum_theta, j, jn, s, i + 1) - b_lo
        lo, hi = 0.0, 1.0
        t = min(max(rem / full, 0.0), 1.0) if full > 0 else 0.5
        tol = 1e-15 * full
        s0 = np.sin(th0)
        c0s = np.cos(th0)
        for _ in range(60):  # safeguarded Newton on the cell CDF
            f, dfdt = _cell_cdf(t, s0, c0s, dth, c0, c1)
            f -= rem
            if abs(f) <= tol:
                break
            if f > 0:
                hi = t
            else:
                lo = t
            step_ok = False
            if dfdt > 0:
                tn = t - f / dfdt
                if lo < tn < hi:
                    step_ok = True
            if not step_ok:
                tn = 0.5 * (lo + hi)
            if abs(tn - t) < 1e-13 or hi - lo < 1e-13:
                t = tn
                break
            t = tn
        th = th0 + t * dth
        ph = np.radians(phi[j] + s * dphi[j])
        out_theta[k] = th
        out_phi[k] = phi[j] + s * dphi[j]
        ct, st, cp, sp = np.cos(th), np.sin(th), np.cos(ph), np.sin(ph)
        for m in range(3):
            out_dir[k, m] = ct * frame[0, m] + st * (cp * frame[1, m] + sp * frame[2, m])
        out_val[k] = c0 * (1.0 - t) + c1 * t


@dataclass(frozen=True)
class PolarTable:
    """Intensities on a polar web with the frame that places it in world axes.

    Attributes
    ----------
    phi_deg, theta_deg : ndarray
        Node angles in degrees (see the module docstring).
    candela : ndarray, shape (nP, nT)
        Intensity in cd at the nodes.
    periodic : bool
        φ wraps around 360° (Type C); otherwise the table covers [φ_first, φ_last] only.
    pole, e0, e1 : ndarray, shape (3,)
        World unit vectors of θ = 0, (φ = 0°, θ = 90°) and (φ = 90°, θ = 90°).
    """

    phi_deg: NDArray
    theta_deg: NDArray
    candela: NDArray
    periodic: bool
    pole: NDArray
    e0: NDArray
    e1: NDArray

    # ---- cells ---------------------------------------------------------------------------
    @cached_property
    def _cells(self) -> tuple[NDArray, NDArray]:
        """φ cells: (next-plane index, width in degrees) of every cell."""
        n = len(self.phi_deg)
        if self.periodic:
            ends = np.concatenate([self.phi_deg[1:], [self.phi_deg[0] + 360.0]])
            return (np.arange(1, n + 1) % n).astype(np.int64), ends - self.phi_deg
        return np.arange(1, n, dtype=np.int64), np.diff(self.phi_deg)

    @cached_property
    def _moments(self) -> tuple[NDArray, NDArray]:
        return _band_moments(np.radians(np.asarray(self.theta_deg, dtype=np.float64)))

    @cached_property
    def _plane_cumulative(self) -> NDArray:
        """(nP, nT) cumulative ∫ I_j(θ) sin θ dθ of every plane from θ_first to θ_i."""
        alpha, beta = self._moments
        cd = self.candela
        per_cell = cd[:, :-1] * alpha[None, :] + cd[:, 1:] * beta[None, :]
        return np.concatenate([np.zeros((cd.shape[0], 1)), np.cumsum(per_cell, axis=1)],
                              axis=1)

    def cell_fluxes(self) -> NDArray:
        """Flux (lm) of every φ cell, shape (number of φ cells,)."""
        nxt, width = self._cells
        plane = self._plane_cumulative[:, -1]
        return np.radians(width) * 0.5 * (plane[: len(width)] + plane[nxt])

    def cell_flux_matrix(self) -> NDArray:
        """Flux (lm) of every (φ-cell, θ-cell) rectangle, shape (φ cells, nT − 1); exact."""
        alpha, beta = self._moments
        nxt, width = self._cells
        cd = self.candela
        lo = np.arange(len(width))
        per = (cd[lo, :-1] + cd[nxt, :-1]) * alpha + (cd[lo, 1:] + cd[nxt, 1:]) * beta
        return np.radians(width)[:, None] * 0.5 * per

    def refined(self, k_phi: int, k_theta: int) -> PolarTable:
        """The same interpolant on a web with every cell split k_phi × k_theta times.

        Bilinear on a cell is bilinear on each sub-rectangle, so the function (and its
        integral) is unchanged; useful for binning samples finer than the table.
        """
        _, width = self._cells
        f = np.arange(k_phi) / k_phi
        phi = (self.phi_deg[: len(width), None] + width[:, None] * f[None, :]).ravel()
        if not self.periodic:
            phi = np.concatenate([phi, self.phi_deg[-1:]])
        tn = self.theta_deg
        g = np.arange(k_theta) / k_theta
        theta = np.concatenate([(tn[:-1, None] + np.diff(tn)[:, None] * g[None, :]).ravel(),
                                tn[-1:]])
        ph, th = np.meshgrid(phi, theta, indexing="ij")
        return PolarTable(phi, theta, self.evaluate(ph, th), self.periodic, self.pole,
                          self.e0, self.e1)

    def total_flux(self) -> float:
        """∫ I dΩ of the bilinear interpolant in lm (exact)."""
        return float(np.sum(self.cell_fluxes()))

    def flux_below(self, theta_cut_deg: float) -> float:
        """Flux (lm) of the interpolant over θ < ``theta_cut_deg`` (exact: a node inserted
        at the cut leaves the piecewise-linear θ profile unchanged)."""
        tn = np.asarray(self.theta_deg, dtype=float)
        if theta_cut_deg <= tn[0]:
            return 0.0
        if theta_cut_deg >= tn[-1]:
            return self.total_flux()
        k = int(np.searchsorted(tn, theta_cut_deg, side="left"))
        if tn[k] != theta_cut_deg:
            t = (theta_cut_deg - tn[k - 1]) / (tn[k] - tn[k - 1])
            col = self.candela[:, k - 1] * (1 - t) + self.candela[:, k] * t
            tn = np.concatenate([tn[:k], [theta_cut_deg]])
            cd = np.concatenate([self.candela[:, :k], col[:, None]], axis=1)
        else:
            tn, cd = tn[: k + 1], self.candela[:, : k + 1]
        if len(tn) < 2:
            return 0.0
        part = PolarTable(self.phi_deg, tn, cd, self.periodic, self.pole, self.e0, self.e1)
        return part.total_flux()

    def node_weights(self) -> NDArray:
        """Ω_ji (sr) with ``total_flux() = Σ I_ji Ω_ji``; Σ Ω = the solid angle covered."""
        alpha, beta = self._moments
        tau = np.concatenate([alpha, [0.0]]) + np.concatenate([[0.0], beta])
        nxt, width = self._cells
        w = np.radians(width) * 0.5
        sigma = np.zeros(len(self.phi_deg))
        np.add.at(sigma, np.arange(len(width)), w)
        np.add.at(sigma, nxt, w)
        return sigma[:, None] * tau[None, :]

    # ---- geometry ------------------------------------------------------------------------
    def directions(self, phi_deg: ArrayLike, theta_deg: ArrayLike) -> NDArray:
        """World unit directions (…, 3) of table angles in degrees."""
        ph = np.radians(np.asarray(phi_deg, dtype=float))
        th = np.radians(np.asarray(theta_deg, dtype=float))
        ph, th = np.broadcast_arrays(ph, th)
        st = np.sin(th)[..., None]
        return (np.cos(th)[..., None] * self.pole + st * np.cos(ph)[..., None] * self.e0
                + st * np.sin(ph)[..., None] * self.e1)

    def angles(self, directions: ArrayLike) -> tuple[NDArray, NDArray]:
        """Table angles (φ in (−180, 180], θ in [0, 180]) in degrees of world directions."""
        d = np.asarray(directions, dtype=float)
        norm = np.linalg.norm(d, axis=-1)
        norm = np.where(norm > 0, norm, 1.0)
        cz = np.clip((d @ self.pole) / norm, -1.0, 1.0)
        theta = np.degrees(np.arccos(cz))
        phi = np.degrees(np.arctan2(d @ self.e1, d @ self.e0))
        return phi, theta

    def locate(self, phi_deg: ArrayLike, theta_deg: ArrayLike
               ) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
        """Cell indices and coordinates: (j, jn, s, i, t) and ``inside`` folded into j ≥ 0.

        Points outside the table get ``j = −1``.
        """
        ph = np.asarray(phi_deg, dtype=float)
        th = np.asarray(theta_deg, dtype=float)
        ph, th = np.broadcast_arrays(ph, th)
        nodes = self.phi_deg
        nxt, width = self._cells
        if self.periodic:
            rel = (ph - nodes[0]) % 360.0
            starts = nodes - nodes[0]
            j = np.clip(np.searchsorted(starts, rel, side="right") - 1, 0, len(width) - 1)
            s = np.clip((rel - starts[j]) / width[j], 0.0, 1.0)
            ok_phi = np.isfinite(rel)
        else:
            j = np.clip(np.searchsorted(nodes, ph, side="right") - 1, 0, len(width) - 1)
            s = np.clip((ph - nodes[j]) / width[j], 0.0, 1.0)
            ok_phi = (ph >= nodes[0] - 1e-9) & (ph <= nodes[-1] + 1e-9)
        tn = self.theta_deg
        i = np.clip(np.searchsorted(tn, th, side="right") - 1, 0, len(tn) - 2)
        t = np.clip((th - tn[i]) / (tn[i + 1] - tn[i]), 0.0, 1.0)
        ok = ok_phi & (th >= tn[0] - 1e-9) & (th <= tn[-1] + 1e-9)
        return np.where(ok, j, -1), nxt[j], s, i, t

    def evaluate(self, phi_deg: ArrayLike, theta_deg: ArrayLike) -> NDArray:
        """Bilinear intensity (cd) at table angles in degrees; 0 outside the table."""
        j, jn, s, i, t = self.locate(phi_deg, theta_deg)
        jj = np.maximum(j, 0)
        cd = self.candela
        a = cd[jj, i] * (1 - t) + cd[jj, i + 1] * t
        b = cd[jn, i] * (1 - t) + cd[jn, i + 1] * t
        return np.where(j >= 0, a * (1 - s) + b * s, 0.0)

    def evaluate_towards(self, directions: ArrayLike) -> NDArray:
        """Bilinear intensity (cd) towards world directions (…, 3)."""
        return self.evaluate(*self.angles(directions))

    # ---- sampling --------------------------------------------------------------------------
    @cached_property
    def _sampler(self) -> tuple[NDArray, ...]:
        cells = self.cell_fluxes()
        total = float(cells.sum())
        cum = np.concatenate([[0.0], np.cumsum(cells)]) / (total if total > 0 else 1.0)
        cum[-1] = 1.0
        nxt, width = self._cells
        return (cum, nxt, np.asarray(self.phi_deg, dtype=np.float64),
                np.asarray(width, dtype=np.float64),
                np.ascontiguousarray(self._plane_cumulative[:, -1]),
                np.ascontiguousarray(self._plane_cumulative),
                np.radians(np.asarray(self.theta_deg, dtype=np.float64)),
                np.ascontiguousarray(self.candela, dtype=np.float64),
                np.ascontiguousarray(np.stack([self.pole, self.e0, self.e1]), dtype=np.float64))


def sample_table(table: PolarTable, u1: ArrayLike, u2: ArrayLike
                 ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Angles drawn from the density I(φ, θ)·sin θ / Φ, with their directions and intensity.

    ``u1`` chooses φ (marginal), ``u2`` θ (conditional on φ); both in [0, 1]. The caller makes
    sure the table emits flux (Φ > 0).

    Returns
    -------
    phi_deg, theta_deg : ndarray, shape (n,)
        Table angles in degrees.
    directions : ndarray, shape (n, 3)
        World unit directions.
    candela : ndarray, shape (n,)
        The interpolated intensity (cd) at each sample (``evaluate`` there).
    """
    a = np.ascontiguousarray(np.asarray(u1, dtype=np.float64).reshape(-1))
    b = np.ascontiguousarray(np.asarray(u2, dtype=np.float64).reshape(-1))
    phi = np.empty(a.size)
    theta = np.empty(a.size)
    dirs = np.empty((a.size, 3))
    val = np.empty(a.size)
    if a.size:
        _sample_kernel(a, b, *table._sampler, phi, theta, dirs, val)
    return phi, np.degrees(theta), dirs, val
