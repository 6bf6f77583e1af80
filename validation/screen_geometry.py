"""Screen geometry of a photo: which wall position each photo pixel shows.

A photo of a measuring screen is a view of a **plane**, so photo pixels and wall positions
(in metres) are related by a homography. Control points come either from the user
(``--points "x,y=H,V; …"``: photo pixel ↔ screen angle in degrees) or from fiducial
markers found on the photo (:mod:`~lightsim.validation.screen_target`). Angles are turned
into wall metres with the conventions' ``h = D·tan(H)``, ``v = D·tan(V)`` (H right, V up
of H-V, ``docs/reference/conventions.md``), so a homography holds exactly for a pinhole camera.

With four points the homography is exact (no residual to check it); with more it is the
least-squares fit (direct linear transform on normalised coordinates, OpenCV
:func:`cv2.findHomography`, method 0) and the **residual** says how well the points agree:
in photo pixels (wall points mapped into the photo vs the given pixels) and in degrees
(photo points mapped onto the wall vs the given angles). Lens distortion is not modelled;
it shows up in the residual.

The angular uncertainty of a mapped position comes from the fit: the residual (in wall
metres, with the 8 parameters' degrees of freedom taken out, ``s² = RSS / (2n − 8)``)
gives the parameters' covariance ``s²·(JᵀJ)⁻¹`` (J the Jacobian of the control points'
mapped positions), which is carried to any photo position (:meth:`ScreenGeometry.sigma_at`)
— so a position far from the control points (an extrapolation) gets the larger σ it
deserves. ``sigma_deg`` is the RMS residual scaled the same way, ``rms·sqrt(2n/(2n − 8))``.
With exactly four points nothing checks the fit and σ is unknown (``None``).

Parameters
----------
==============  ====  =======  =============================================================
name            unit  default  meaning
==============  ====  =======  =============================================================
points          –     –        "x,y=H,V; …": photo px (x = column, y = row) ↔ angles (deg)
distance_m      m     25       lamp → screen distance D
min_points      –     4        fewest control points
==============  ====  =======  =============================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lightsim.errors import InputError
from lightsim.validation.photo_register import apply_matrix
from lightsim.wall import WallFrame, deg_from_wall_m, wall_m_from_deg

__all__ = [
    "ScreenGeometry",
    "fit_screen",
    "parse_points",
    "sim_matrix",
]


@dataclass
class ScreenGeometry:
    """Photo pixels ↔ screen (wall) positions.

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        Homogeneous map photo px (x, y) → wall metres (h right, v up, relative to H-V).
    distance_m : float
        Lamp → screen distance D (m).
    source : str
        ``"points"`` (given by the user) or ``"markers"`` (found on the photo).
    photo_xy : ndarray, shape (n, 2)
        Control points in the photo (px).
    screen_deg : ndarray, shape (n, 2)
        Their screen positions (H, V) in degrees.
    residual_px : tuple of float
        RMS and maximum distance (photo px) between the given pixels and the wall points
        mapped into the photo.
    residual_deg : tuple of float
        RMS and maximum angular distance (deg) between the given angles and the photo points
        mapped onto the wall.
    sigma_deg : float or None
        Angular uncertainty of a mapped position (deg); None with only four points.
    details : dict
        More facts (marker ids found, …).
    """

    matrix: NDArray
    distance_m: float
    source: str
    photo_xy: NDArray
    screen_deg: NDArray
    residual_px: tuple[float, float]
    residual_deg: tuple[float, float]
    sigma_deg: float | None
    details: dict[str, Any] = field(default_factory=dict)
    param_cov: NDArray | None = None

    def sigma_at(self, x: NDArray, y: NDArray) -> tuple[NDArray, NDArray] | None:
        """1-σ uncertainty (deg) of the H and V a photo pixel maps to, or None (4 points).

        Parameters
        ----------
        x, y : ndarray
            Photo pixels (px).
        """
        if self.param_cov is None:
            return None
        x = np.atleast_1d(np.asarray(x, np.float64))
        y = np.atleast_1d(np.asarray(y, np.float64))
        jac = _jacobian(self.matrix, x, y)                    # (2N, 8) in wall m
        var = np.einsum("ij,jk,ik->i", jac, self.param_cov, jac).reshape(-1, 2)
        h, v = apply_matrix(self.matrix, x, y)
        d = self.distance_m
        # d(angle)/d(m) = D / (D² + m²), in degrees
        kh, kv = np.degrees(d / (d**2 + h**2)), np.degrees(d / (d**2 + v**2))
        return kh * np.sqrt(var[:, 0]), kv * np.sqrt(var[:, 1])

    def photo_to_deg(self, x: NDArray, y: NDArray) -> tuple[NDArray, NDArray]:
        """Screen angles (H, V) in degrees of photo pixels (x, y)."""
        h, v = apply_matrix(self.matrix, x, y)
        return deg_from_wall_m(h, self.distance_m), deg_from_wall_m(v, self.distance_m)

    def deg_to_photo(self, h_deg: NDArray, v_deg: NDArray) -> tuple[NDArray, NDArray]:
        """Photo pixels (x, y) of screen angles (deg)."""
        return apply_matrix(np.linalg.inv(self.matrix), wall_m_from_deg(h_deg, self.distance_m),
                            wall_m_from_deg(v_deg, self.distance_m))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description."""
        return {"source": self.source, "distance_m": self.distance_m,
                "points": len(self.photo_xy),
                "matrix_photo_px_to_wall_m": [[float(v) for v in row] for row in
                                              self.matrix / self.matrix[2, 2]],
                "residual_px": {"rms": self.residual_px[0], "max": self.residual_px[1]},
                "residual_deg": {"rms": self.residual_deg[0], "max": self.residual_deg[1]},
                "sigma_deg": self.sigma_deg, **self.details}


def parse_points(text: str) -> tuple[NDArray, NDArray]:
    """Parse ``"x,y=H,V; x,y=H,V; …"`` into photo pixels and screen angles.

    Parameters
    ----------
    text : str
        Semicolon-separated pairs; x, y in photo px (column, row), H, V in degrees.

    Returns
    -------
    photo_xy, screen_deg : ndarray, shape (n, 2)

    Raises
    ------
    InputError
        A malformed or non-finite entry, or a repeated point.
    """
    xy, hv = [], []
    for i, part in enumerate(p for p in text.split(";") if p.strip()):
        try:
            left, right = part.split("=")
            x, y = (float(t) for t in left.split(","))
            h, v = (float(t) for t in right.split(","))
        except ValueError:
            raise InputError(f"--points entry {i + 1} must be 'x,y=H,V', got {part.strip()!r}"
                             ) from None
        if not all(math.isfinite(t) for t in (x, y, h, v)):
            raise InputError(f"--points entry {i + 1} is not finite: {part.strip()!r}")
        if not (abs(h) < 89 and abs(v) < 89):
            raise InputError(f"--points entry {i + 1}: screen angles must lie within ±89°")
        xy.append((x, y))
        hv.append((h, v))
    a, b = np.array(xy, float).reshape(-1, 2), np.array(hv, float).reshape(-1, 2)
    return a, b


def _collinear(pts: NDArray, tol: float) -> bool:
    """Whether every triple of ``pts`` is (nearly) on one line: rank of the centred cloud."""
    c = pts - pts.mean(axis=0)
    sv = np.linalg.svd(c, compute_uv=False)
    return bool(sv[-1] <= tol * max(sv[0], 1e-300))


def _jacobian(matrix: NDArray, x: NDArray, y: NDArray) -> NDArray:
    """∂(h, v)/∂(8 homography entries) at photo points, rows (h₀, v₀, h₁, v₁, …)."""
    m = matrix / matrix[2, 2]
    den = m[2, 0] * x + m[2, 1] * y + 1.0
    h = (m[0, 0] * x + m[0, 1] * y + m[0, 2]) / den
    v = (m[1, 0] * x + m[1, 1] * y + m[1, 2]) / den
    one, zero = np.ones_like(x), np.zeros_like(x)
    jh = np.stack([x, y, one, zero, zero, zero, -h * x, -h * y], axis=1) / den[:, None]
    jv = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y], axis=1) / den[:, None]
    out = np.empty((2 * len(x), 8))
    out[0::2], out[1::2] = jh, jv
    return out


def _line_dist(p: NDArray, a: NDArray, b: NDArray) -> NDArray:
    """Distance of points ``p`` from the line through ``a`` and ``b``."""
    d = b - a
    n = math.hypot(*d)
    return np.abs(d[0] * (p[:, 1] - a[1]) - d[1] * (p[:, 0] - a[0])) / max(n, 1e-300)


def _degenerate(pts: NDArray, tol: float = 1e-3) -> bool:
    """Whether no four points are in general position (a homography needs four with no
    three on a line). Greedy: the two farthest points, the point farthest from their line,
    then the point farthest from all three lines through those."""
    d2 = ((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1)
    i, j = np.unravel_index(int(np.argmax(d2)), d2.shape)
    span = math.sqrt(float(d2[i, j]))
    if span <= 0:
        return True
    a, b = pts[i], pts[j]
    k = int(np.argmax(_line_dist(pts, a, b)))
    if _line_dist(pts[k:k + 1], a, b)[0] <= tol * span:
        return True
    c = pts[k]
    m = np.minimum(np.minimum(_line_dist(pts, a, b), _line_dist(pts, a, c)),
                   _line_dist(pts, b, c))
    return bool(m.max() <= tol * span)


def fit_screen(photo_xy: NDArray, screen_deg: NDArray, distance_m: float = 25.0,
               source: str = "points", details: dict[str, Any] | None = None
               ) -> ScreenGeometry:
    """Fit the photo px → wall m homography to control points and measure its residual.

    Parameters
    ----------
    photo_xy : ndarray, shape (n, 2)
        Photo pixels (x = column, y = row).
    screen_deg : ndarray, shape (n, 2)
        Screen angles (H right, V up) in degrees.
    distance_m : float, default 25
        Lamp → screen distance (m).
    source : str, default "points"
        Where the points come from (reported).
    details : dict, optional
        More facts for the report.

    Returns
    -------
    ScreenGeometry

    Raises
    ------
    InputError
        Fewer than four points, repeated or collinear points, or a degenerate fit.
    """
    import cv2

    xy = np.asarray(photo_xy, np.float64).reshape(-1, 2)
    hv = np.asarray(screen_deg, np.float64).reshape(-1, 2)
    n = len(xy)
    if n < 4 or len(hv) != n:
        raise InputError(f"screen geometry needs at least 4 control points, got {n}")
    if not (np.all(np.isfinite(xy)) and np.all(np.isfinite(hv))):
        raise InputError("control points must be finite")
    if not math.isfinite(distance_m) or distance_m <= 0:
        raise InputError(f"screen distance must be > 0 m, got {distance_m!r}")
    wall = wall_m_from_deg(hv, distance_m)
    span = max(float(np.ptp(xy, axis=0).max()), 1e-300)
    if _collinear(xy, 1e-6) or _collinear(wall, 1e-6):
        raise InputError("control points are collinear: they do not fix the screen plane")
    if len(np.unique(np.round(xy / span, 9), axis=0)) < n:
        raise InputError("control points repeat a photo pixel")
    if _degenerate(xy) or _degenerate(wall):
        raise InputError("control points do not fix the screen: no four of them are in "
                         "general position (three or more on one line)")
    matrix, _ = cv2.findHomography(xy, wall, 0)
    if matrix is None or not np.all(np.isfinite(matrix)) or abs(np.linalg.det(matrix)) < 1e-300:
        raise InputError("control points do not define a screen homography (degenerate)")
    matrix = matrix / matrix[2, 2]
    # residual in degrees: photo → wall; in px: wall → photo
    h, v = apply_matrix(matrix, xy[:, 0], xy[:, 1])
    dd = np.hypot(deg_from_wall_m(h, distance_m) - hv[:, 0],
                  deg_from_wall_m(v, distance_m) - hv[:, 1])
    px, py = apply_matrix(np.linalg.inv(matrix), wall[:, 0], wall[:, 1])
    dp = np.hypot(px - xy[:, 0], py - xy[:, 1])
    if not (np.all(np.isfinite(dd)) and np.all(np.isfinite(dp))):
        raise InputError("control points put the screen's horizon inside the photo")
    rms_deg = float(np.sqrt(np.mean(dd**2)))
    sigma = rms_deg * math.sqrt(2 * n / (2 * n - 8)) if n > 4 else None
    cov = None
    if n > 4:
        jac = _jacobian(matrix, xy[:, 0], xy[:, 1])
        res = np.column_stack([h - wall[:, 0], v - wall[:, 1]]).ravel()
        s2 = float(res @ res) / (2 * n - 8)
        try:
            cov = s2 * np.linalg.inv(jac.T @ jac)
        except np.linalg.LinAlgError:
            cov = None
    return ScreenGeometry(matrix, float(distance_m), source, xy, hv,
                          (float(np.sqrt(np.mean(dp**2))), float(dp.max())),
                          (rms_deg, float(dd.max())), sigma, dict(details or {}), cov)


def sim_matrix(geometry: ScreenGeometry, frame: Any) -> NDArray:
    """Photo px → simulation px of ``frame`` through the screen.

    The simulation's wall pixel grid is affine in wall metres
    (:meth:`WallFrame.pixel_of`); a different distance of the simulated wall is handled
    by going through angles (the two walls are scaled copies seen from the lamp).

    Parameters
    ----------
    geometry : ScreenGeometry
        Photo → screen map.
    frame : WallFrame or dict
        The simulation's wall frame.

    Returns
    -------
    ndarray, shape (3, 3)
        Homogeneous photo px → simulation px matrix.
    """
    wf = WallFrame.from_any(frame)
    dh, dv = wf.pixel_size_m
    k = wf.distance_m / geometry.distance_m      # screen m → simulated-wall m (same angles)
    to_px = np.array([[k / dh, 0.0, (wf.hv_offset_m[0] - wf.h_range_m[0]) / dh - 0.5],
                      [0.0, -k / dv, (wf.v_range_m[1] - wf.hv_offset_m[1]) / dv - 0.5],
                      [0.0, 0.0, 1.0]])
    m = to_px @ geometry.matrix
    return m / m[2, 2]
