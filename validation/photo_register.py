"""Register a photo of a beam pattern to the simulated wall view (photo px → simulation px).

Representation
    Beam patterns are smooth blobs with one sharp feature, the cut-off; corner detectors
    find few repeatable points on them (and a photo adds wall texture and clutter that the
    simulation does not have), so the registration is intensity-based and works on **log
    luminance**: an unknown exposure (gain) becomes an additive constant and an unknown
    gamma a factor, so the zero-normalised cross-correlation (ZNCC) of log images is blind
    to both, and the cut-off — log E falls by about two decades within a fraction of a
    degree — is the strongest edge at every scale. Images are averaged down in *linear*
    light (Gaussian anti-aliasing, σ = (f − 1)/2 for a factor f) before the logarithm, so
    every pyramid level looks like a blurrier photo of the same wall. Clipped photo pixels
    (and everything their blur touches) and pixels outside either image never count.

Coarse search (global)
    On a small copy of the simulation (longest side ``coarse_size`` px; both images floored
    at ``log_floor`` × their 99.5th percentile before the log) every rotation in
    ±``max_rotation_deg`` (step ``rotation_step_deg``) and every scale in ``scale_range``
    (relative to "photo width = simulation width", ``scale_steps_per_octave`` per octave)
    is tried: the photo is rotated and scaled onto a canvas and the **masked normalised
    cross-correlation** (Padfield 2012) over all translations comes from FFTs, requiring
    an overlap of at least ``min_overlap`` of the smaller image. The best ``candidates``
    clearly different results are refined for ``screen_iter`` iterations on the coarsest
    level; the one with the best ZNCC goes on.

Refinement (local, coarse to fine)
    On a pyramid of the simulation (factors 2^k down to 1, the finest level at most
    ``finest_size`` px on its longest side; the photo at the power-of-two level whose
    pixels best match) a Levenberg–Marquardt solver with iteratively reweighted (soft-L1)
    least squares maximises the ZNCC, i.e. minimises over the simulation's lit pixels x

        a·L(H x) + d·L(H x)² + b + c·ρ²(H x) − T_t(x)

    with L the photo's log luminance (lightly smoothed, σ = ``photo_blur_px``; floored at
    ``photo_floor``), H the 4 similarity or 8 homography parameters (compositional
    updates in isotropically normalised coordinates, analytic Jacobian from the photo's
    gradients), a, d, b a tone curve in log space, c·ρ² a vignetting fall-off and T_t
    the standardised log of the simulation blurred by a Gaussian of variance 2t — the
    photo is blurrier than the simulation and blur moves edges in log space, so t is
    fitted too (at most ``MAX_BLUR`` level px).

    *Lit* pixels are those with E ≥ ``lit_level`` × the simulation's 99.5th percentile,
    at least ``BORDER`` px from the image border (the border cuts the pattern, it is no
    feature of it) and — because the log of a noisy dim value is both noisy and biased,
    which pulls the fitted scale — above the lowest level at which the photo's measured
    pixel noise stays under 5 % (:func:`usable_level`). Dim pixels are down-weighted by
    E/(E + ``noise_level`` × reference). Only pixels inside the photo count and the set is
    updated after every step; a step is refused if it halves the level's overlap (or
    leaves less than 60 % of the first level's), mirrors, rescales by more than 1.5× or
    turns by more than 20° from the level's start, or stretches one direction twice as
    much as the other. The coarsest level fits a similarity; a homography (if asked)
    follows on every level. (A hand-made solver rather than
    :func:`scipy.optimize.least_squares`: the pixel set and the blurred target change
    between iterations, and it runs about ten times faster here.)

Transforms are 3×3 matrices on homogeneous pixel coordinates (x = column, y = row, pixel
centres at integers, as in :mod:`skimage.transform`); :func:`decompose` reports rotation,
scale and translation.

Parameters
----------
=======================  ====  ==========  ================================================
name                     unit  default     meaning
=======================  ====  ==========  ================================================
model                    –     similarity  ``"similarity"`` (rotation, scale, shift) or
                                           ``"homography"`` (photo taken at an angle)
max_rotation_deg         deg   20          coarse search: rotations in ± this
rotation_step_deg        deg   5           coarse search: rotation step
scale_range              1     (0.5, 2)    coarse search: scales relative to equal widths
scale_steps_per_octave   –     3           coarse search: scale steps per factor 2
log_floor                1     0.01        coarse search: floor of E before the log,
                                           relative to the 99.5th percentile
coarse_size              px    112         longest side of the coarse-search image
finest_size              px    1024        longest side of the finest refinement level
min_overlap              1     0.5         least overlap (fraction of the smaller image)
candidates               –     6           coarse results screened (the best of each
                                           scale step first, so that not all share a scale)
screen_iter              –     10          solver iterations per screened candidate
lit_level                1     0.01        refinement: simulation pixels used, relative
                                           to its 99.5th percentile
photo_floor              1     0.001       refinement: floor of the photo before the log
photo_blur_px            px    0.5         refinement: smoothing of the photo (level px)
noise_level              1     0.05        refinement: dim-pixel down-weighting level
max_iter                 –     50          solver iterations per level
=======================  ====  ==========  ================================================
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import fft as sfft
from scipy.ndimage import gaussian_filter, laplace, map_coordinates

from lightsim.errors import InputError

__all__ = [
    "MODELS",
    "Registration",
    "RegistrationOptions",
    "apply_matrix",
    "decompose",
    "downsample",
    "level_matrix",
    "log_luminance",
    "register",
    "registration_dict",
    "usable_level",
]

#: Transform models the registration can fit.
MODELS = ("similarity", "homography")
#: Largest blur (Gaussian σ, pyramid-level px) fitted to make the simulation look like the photo.
MAX_BLUR = 4.0
#: Simulation pixels this close to the image border (level px) take no part in refinement.
BORDER = 3


@dataclass(frozen=True)
class RegistrationOptions:
    """Settings of :func:`register` (units and meaning in the module's table)."""

    model: str = "similarity"
    max_rotation_deg: float = 20.0
    rotation_step_deg: float = 5.0
    scale_range: tuple[float, float] = (0.5, 2.0)
    scale_steps_per_octave: int = 3
    log_floor: float = 0.01
    coarse_size: int = 112
    finest_size: int = 1024
    min_overlap: float = 0.5
    candidates: int = 6
    lit_level: float = 0.01
    photo_floor: float = 1e-3
    photo_blur_px: float = 0.5
    noise_level: float = 0.05
    max_iter: int = 50
    screen_iter: int = 10

    def check(self) -> None:
        """Raise :class:`InputError` for settings that cannot work."""
        if self.model not in MODELS:
            raise InputError(f"registration model must be one of {MODELS}, got {self.model!r}")
        lo, hi = self.scale_range
        if not (0 < lo <= hi and math.isfinite(hi)):
            raise InputError(f"scale range must be 0 < min ≤ max, got {self.scale_range}")
        if not (0 <= self.max_rotation_deg <= 180 and self.rotation_step_deg > 0):
            raise InputError("rotation search: 0 ≤ max_rotation_deg ≤ 180 and a positive step "
                             "are required")
        if not (0 < self.log_floor < 1 and 0 < self.min_overlap < 1):
            raise InputError("log_floor and min_overlap must lie between 0 and 1")


@dataclass
class Registration:
    """Result of :func:`register`.

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        Homogeneous map from photo pixels (x, y) to simulation pixels.
    model : str
        ``"similarity"``, ``"homography"`` or ``"given"`` (a transform supplied by the user).
    score : float
        ZNCC of the log-luminance images over the overlap at the finest level (1).
    overlap : float
        Fraction of the simulation's pixels covered by usable photo pixels (1).
    coarse : dict
        Best coarse-search result (rotation_deg, scale, score, tried).
    levels : list of dict
        Per refinement level: factor, size, pixels used, ZNCC, iterations, blur.
    blur_px : float
        How much blurrier the photo is than the simulation: Gaussian σ in simulation px
        (the smoothing the registration itself applies is taken out).
    blur_at_cap : bool
        The blur fit ended at its cap (``MAX_BLUR`` level px on the finest level): the
        blur, and the cut-off offsets that depend on it, are then only a lower bound.
    """

    matrix: NDArray
    model: str
    score: float
    overlap: float
    coarse: dict[str, Any] = field(default_factory=dict)
    levels: list[dict[str, Any]] = field(default_factory=list)
    blur_px: float = 0.0
    blur_at_cap: bool = False


# ---------------------------------------------------------------------------------------
# matrices
# ---------------------------------------------------------------------------------------

def apply_matrix(matrix: NDArray, x: NDArray, y: NDArray) -> tuple[NDArray, NDArray]:
    """Map pixel coordinates through a 3×3 homogeneous transform.

    Parameters
    ----------
    matrix : ndarray, shape (3, 3)
        Transform on (x, y, 1) (pixels).
    x, y : ndarray
        Column and row coordinates (px), same shape.

    Returns
    -------
    tuple of ndarray
        Mapped (x, y) in pixels; NaN where the point maps to infinity.
    """
    m = np.asarray(matrix, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    w = m[2, 0] * x + m[2, 1] * y + m[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(np.abs(w) < 1e-12, np.nan, w)
        return ((m[0, 0] * x + m[0, 1] * y + m[0, 2]) / w,
                (m[1, 0] * x + m[1, 1] * y + m[1, 2]) / w)


def level_matrix(factor: float) -> NDArray:
    """Full-resolution pixel → pixel of a copy downsampled by ``factor``.

    Pixel centres are at integers in both images: ``x_l = (x + 0.5) / f − 0.5``.
    """
    f = float(factor)
    return np.array([[1 / f, 0, 0.5 / f - 0.5], [0, 1 / f, 0.5 / f - 0.5], [0, 0, 1.0]])


def _translate(tx: float, ty: float) -> NDArray:
    return np.array([[1.0, 0, tx], [0, 1.0, ty], [0, 0, 1.0]])


def _rot_scale(angle_deg: float, scale: float) -> NDArray:
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    return np.array([[scale * c, -scale * s, 0], [scale * s, scale * c, 0], [0, 0, 1.0]])


def _normalise(m: NDArray) -> NDArray:
    return m / m[2, 2]


def decompose(matrix: NDArray, photo_shape: tuple[int, int]) -> dict[str, Any]:
    """Rotation, scale and translation of a photo → simulation transform.

    For a homography the rotation and scale are those of its linearisation at the photo's
    centre (exact for a similarity).

    Parameters
    ----------
    matrix : ndarray, shape (3, 3)
        Photo pixels → simulation pixels.
    photo_shape : tuple of int
        (H, W) of the photo in pixels.

    Returns
    -------
    dict
        ``rotation_deg`` (deg; in pixel axes, x right and y down, positive turns +x towards
        +y: the photo shows the pattern turned this much counter-clockwise),
        ``scale`` (simulation px per photo px), ``translation_px`` (where photo pixel (0, 0)
        lands, simulation px), ``photo_centre_to_px`` (where the photo's centre lands),
        ``anisotropy`` (ratio of the linearisation's singular values, 1 for a similarity),
        ``perspective`` (the matrix's bottom row terms, 1/px).
    """
    m = _normalise(np.asarray(matrix, dtype=np.float64))
    h, w = photo_shape
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    den = m[2, 0] * cx + m[2, 1] * cy + m[2, 2]
    px = (m[0, 0] * cx + m[0, 1] * cy + m[0, 2]) / den
    py = (m[1, 0] * cx + m[1, 1] * cy + m[1, 2]) / den
    jac = np.array([[m[0, 0] - px * m[2, 0], m[0, 1] - px * m[2, 1]],
                    [m[1, 0] - py * m[2, 0], m[1, 1] - py * m[2, 1]]]) / den
    sv = np.linalg.svd(jac, compute_uv=False)
    return {
        "rotation_deg": math.degrees(math.atan2(jac[1, 0] - jac[0, 1], jac[0, 0] + jac[1, 1])),
        "scale": math.sqrt(abs(float(np.linalg.det(jac)))),
        "translation_px": [float(m[0, 2]), float(m[1, 2])],
        "photo_centre_to_px": [float(px), float(py)],
        "anisotropy": float(sv[0] / sv[1]) if sv[1] > 0 else math.inf,
        "perspective": [float(m[2, 0]), float(m[2, 1])],
    }


# ---------------------------------------------------------------------------------------
# images
# ---------------------------------------------------------------------------------------

def downsample(image: NDArray, factor: float) -> NDArray:
    """Anti-aliased copy of ``image`` smaller by ``factor`` (≥ 1), exact pixel grid.

    The image is blurred with a Gaussian of σ = (f − 1)/2 px and sampled bilinearly at
    ``x = (x_l + 0.5)·f − 0.5``, matching :func:`level_matrix`.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Image (any unit).
    factor : float
        Downsampling factor f ≥ 1.

    Returns
    -------
    ndarray
        Shape (max(1, round(H/f)), max(1, round(W/f))), same unit.
    """
    f = float(factor)
    img = np.asarray(image, dtype=np.float64)
    if f <= 1.0 + 1e-9:
        return img.copy()
    blurred = gaussian_filter(img, sigma=(f - 1) / 2, mode="nearest")
    h, w = img.shape
    rows = (np.arange(max(1, round(h / f))) + 0.5) * f - 0.5
    cols = (np.arange(max(1, round(w / f))) + 0.5) * f - 0.5
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    return map_coordinates(blurred, [rr, cc], order=1, mode="nearest")


def log_luminance(image: NDArray, valid: NDArray, floor_rel: float,
                  reference: float | None = None) -> NDArray:
    """``ln(max(E, floor))`` with the floor relative to the valid pixels' 99.5th percentile.

    Parameters
    ----------
    image : ndarray
        Linear luminance or illuminance (any unit).
    valid : ndarray of bool
        Pixels that count for the reference level.
    floor_rel : float
        Floor relative to the reference level (1).
    reference : float, optional
        Reference level in the unit of ``image`` (default: 99.5th percentile of ``valid``).

    Returns
    -------
    ndarray
        Natural log of the floored image (ln of the image's unit).
    """
    img = np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0)
    if reference is None:
        vals = img[valid] if np.any(valid) else img.ravel()
        reference = float(np.percentile(vals, 99.5))
    floor = max(float(reference) * floor_rel, 1e-30)
    return np.log(np.maximum(img, floor))


@dataclass
class _Pyramid:
    """Linear image with validity, and cached log levels with their gradients."""

    linear: NDArray
    valid: NDArray
    reference: float
    cache: dict[tuple[float, float], tuple[NDArray, NDArray, NDArray, NDArray]] = field(
        default_factory=dict)
    linear_cache: dict[float, NDArray] = field(default_factory=dict)

    @classmethod
    def build(cls, linear: NDArray, valid: NDArray) -> _Pyramid:
        lin = np.maximum(np.nan_to_num(np.asarray(linear, np.float64), nan=0.0), 0.0)
        vals = lin[valid] if np.any(valid) else lin.ravel()
        ref = float(np.percentile(vals, 99.5))
        if not ref > 0:
            ref = float(vals.max()) if vals.size and vals.max() > 0 else 1.0
        return cls(lin, valid.astype(bool), ref)

    def linear_level(self, factor: float) -> NDArray:
        """The linear image downsampled by ``factor`` (cached)."""
        key = round(float(factor), 6)
        if key not in self.linear_cache:
            self.linear_cache[key] = downsample(self.linear, factor)
        return self.linear_cache[key]

    def level(self, factor: float, floor_rel: float, blur_px: float = 0.0
              ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """(log image, valid mask, d/dy, d/dx) downsampled by ``factor``.

        The log is floored at ``floor_rel`` × the full image's 99.5th percentile; with
        ``blur_px`` the level is first smoothed by a Gaussian of that σ (level px).
        """
        key = (round(float(factor), 6), float(floor_rel), float(blur_px))
        if key not in self.cache:
            lin = self.linear_level(factor)
            if blur_px > 0:
                lin = gaussian_filter(lin, blur_px, mode="nearest")
            valid = downsample(self.valid.astype(np.float64), factor) > 0.99
            log = log_luminance(lin, valid, floor_rel, self.reference)
            gy, gx = np.gradient(log)
            self.cache[key] = (log, valid, gy, gx)
        return self.cache[key]


# ---------------------------------------------------------------------------------------
# coarse search
# ---------------------------------------------------------------------------------------

@dataclass
class _Reference:
    """The fixed image of the masked NCC with its FFTs cached per transform size."""

    image: NDArray
    mask: NDArray
    ffts: dict[tuple[int, int], list[NDArray]] = field(default_factory=dict)

    def spectra(self, shape: tuple[int, int]) -> list[NDArray]:
        if shape not in self.ffts:
            m = self.mask.astype(np.float64)
            f = np.where(self.mask, self.image, 0.0)
            self.ffts[shape] = [sfft.rfft2(a, shape) for a in (m, f, f * f)]
        return self.ffts[shape]


def _masked_ncc(ref: _Reference, mov: NDArray, mov_mask: NDArray, min_count: float
                ) -> NDArray:
    """Masked normalised cross-correlation for all integer shifts (Padfield 2012).

    Returns the NCC map, −inf where the overlap is below ``min_count`` pixels or either
    side is flat; entry ``k`` is the shift ``t = k − (mov.shape − 1)`` with
    ``ref(x) ↔ mov(x − t)``.
    """
    rs = ref.image.shape
    shape = (sfft.next_fast_len(rs[0] + mov.shape[0] - 1, real=True),
             sfft.next_fast_len(rs[1] + mov.shape[1] - 1, real=True))
    fr = ref.spectra(shape)
    mm = mov_mask[::-1, ::-1].astype(np.float64)
    g = np.where(mov_mask, mov, 0.0)[::-1, ::-1]
    fm = [sfft.rfft2(a, shape) for a in (mm, g, g * g)]
    out = (rs[0] + mov.shape[0] - 1, rs[1] + mov.shape[1] - 1)

    def corr(a: NDArray, b: NDArray) -> NDArray:
        return sfft.irfft2(a * b, shape)[: out[0], : out[1]]

    n = np.round(corr(fr[0], fm[0]))
    s_f, s_g = corr(fr[1], fm[0]), corr(fr[0], fm[1])
    s_fg = corr(fr[1], fm[1])
    s_ff, s_gg = corr(fr[2], fm[0]), corr(fr[0], fm[2])
    with np.errstate(divide="ignore", invalid="ignore"):
        num = s_fg - s_f * s_g / n
        var_f = s_ff - s_f**2 / n
        var_g = s_gg - s_g**2 / n
        ncc = num / np.sqrt(var_f * var_g)
    eps = 1e-6 * np.maximum(n, 1.0)
    ok = (n >= min_count) & (var_f > eps) & (var_g > eps) & np.isfinite(ncc)
    return np.where(ok, ncc, -np.inf)


def _canvas(photo: _Pyramid, photo_factor: float, angle_deg: float, zoom: float,
            floor_rel: float) -> tuple[NDArray, NDArray, NDArray]:
    """Photo level rotated by ``angle_deg`` and scaled by ``zoom`` onto a tight canvas.

    Returns the canvas, its mask and the 3×3 map photo-level px → canvas px.
    """
    log, valid, _, _ = photo.level(photo_factor, floor_rel)
    h, w = log.shape
    a = _rot_scale(angle_deg, zoom) @ _translate(-(w - 1) / 2, -(h - 1) / 2)
    cx, cy = apply_matrix(a, np.array([0, w - 1, 0, w - 1.0]), np.array([0, 0, h - 1, h - 1.0]))
    x0, y0 = math.floor(cx.min()) - 1, math.floor(cy.min()) - 1
    cw, ch = math.ceil(cx.max()) - x0 + 2, math.ceil(cy.max()) - y0 + 2
    a = _translate(-x0, -y0) @ a
    inv = np.linalg.inv(a)
    yy, xx = np.mgrid[0:ch, 0:cw].astype(np.float64)
    sx, sy = apply_matrix(inv, xx, yy)
    img = map_coordinates(log, [sy, sx], order=1, mode="nearest")
    msk = (sx >= 0) & (sx <= w - 1) & (sy >= 0) & (sy <= h - 1)
    if not valid.all():
        msk &= map_coordinates(valid.astype(np.float64), [sy, sx], order=1, cval=0.0) > 0.99
    return img, msk, a


def _photo_factor(sim_factor: float, scale: float) -> float:
    """Power-of-two photo level whose pixels are closest to (not above) the sim level's."""
    ratio = sim_factor / max(scale, 1e-12)          # photo px per sim-level px
    return float(2 ** max(0, math.floor(math.log2(max(ratio, 1.0)) + 1e-9)))


def _candidate(ref: _Reference, photo: _Pyramid, sim_factor: float, scale: float,
               angle: float, opts: RegistrationOptions) -> dict[str, Any] | None:
    """Best translation for one (scale, rotation): masked NCC peak and its full matrix."""
    g = _photo_factor(sim_factor, scale)
    zoom = scale * g / sim_factor                       # canvas px per photo-level px
    img, msk, a = _canvas(photo, g, angle, zoom, opts.log_floor)
    min_count = opts.min_overlap * min(int(ref.mask.sum()), int(msk.sum()))
    ncc = _masked_ncc(ref, img, msk, max(min_count, 16))
    kmax = np.unravel_index(int(np.argmax(ncc)), ncc.shape)
    best = float(ncc[kmax])
    if not np.isfinite(best):
        return None
    ty, tx = kmax[0] - (img.shape[0] - 1), kmax[1] - (img.shape[1] - 1)
    m = np.linalg.inv(level_matrix(sim_factor)) @ _translate(tx, ty) @ a @ level_matrix(g)
    return {"score": best, "rotation_deg": angle, "scale": scale, "matrix": _normalise(m)}


def _coarse_search(sim: _Pyramid, photo: _Pyramid, opts: RegistrationOptions
                   ) -> list[dict[str, Any]]:
    """Grid over rotation × scale with an FFT search over translation; best candidates."""
    sh, sw = sim.linear.shape
    f_s = max(1.0, max(sh, sw) / opts.coarse_size)
    s_log, s_valid, _, _ = sim.level(f_s, opts.log_floor)
    ref = _Reference(s_log, s_valid)
    s0 = sw / photo.linear.shape[1]                     # sim px per photo px, equal widths
    lo, hi = (math.log2(x) for x in opts.scale_range)
    n_steps = opts.scale_steps_per_octave
    ks = range(math.floor(lo * n_steps + 1e-9), math.ceil(hi * n_steps - 1e-9) + 1)
    n_rot = math.floor(opts.max_rotation_deg / opts.rotation_step_deg + 1e-9)
    angles = [k * opts.rotation_step_deg for k in range(-n_rot, n_rot + 1)]
    results = [_candidate(ref, photo, f_s, s0 * 2 ** (k / n_steps), angle, opts)
               for k in ks for angle in angles]
    ranked = sorted((r for r in results if r is not None), key=lambda r: -r["score"])
    return _distinct(ranked, opts.candidates, photo.linear.shape)


def _distinct(ranked: list[dict[str, Any]], n: int, photo_shape: tuple[int, int]
              ) -> list[dict[str, Any]]:
    """Up to ``n`` clearly different results: the best of each scale step first (in order
    of score), then the next best; a smooth pattern's NCC peaks at several scales and the
    screening on the refinement level decides."""
    def same(r: dict[str, Any], k: dict[str, Any]) -> bool:
        c = decompose(r["matrix"], photo_shape)["photo_centre_to_px"]
        ck = decompose(k["matrix"], photo_shape)["photo_centre_to_px"]
        return (abs(r["rotation_deg"] - k["rotation_deg"]) < 4
                and abs(math.log(r["scale"] / k["scale"])) < 0.2
                and math.hypot(c[0] - ck[0], c[1] - ck[1]) < 0.05 * sum(photo_shape))

    per_scale: dict[float, dict[str, Any]] = {}
    for r in ranked:
        per_scale.setdefault(round(math.log2(r["scale"]), 3), r)
    first = sorted(per_scale.values(), key=lambda r: -r["score"])[: max(1, n // 2)]
    kept: list[dict[str, Any]] = []
    for r in [*first, *ranked]:
        if len(kept) >= n:
            break
        if not any(same(r, k) for k in kept):
            kept.append(r)
    return kept


# ---------------------------------------------------------------------------------------
# refinement
# ---------------------------------------------------------------------------------------

def _norm_matrix(shape: tuple[int, int]) -> NDArray:
    """Pixel → isotropic normalised coordinates (centre 0, half the longer side 1)."""
    h, w = shape
    r = max(h, w) / 2.0
    return np.array([[1 / r, 0, -(w - 1) / 2 / r], [0, 1 / r, -(h - 1) / 2 / r], [0, 0, 1.0]])


def _increment(p: NDArray, model: str) -> NDArray:
    """3×3 update matrix, identity at p = 0."""
    if model == "similarity":
        a, b, tx, ty = p
        return np.array([[1 + a, -b, tx], [b, 1 + a, ty], [0, 0, 1.0]])
    return np.array([[1 + p[0], p[1], p[2]], [p[3], 1 + p[4], p[5]], [p[6], p[7], 1.0]])


def _dz_dp(w: NDArray, model: str) -> NDArray:
    """∂z/∂p of z = increment(p)·w (linear in p, so the same for every p): (3, n_par, N)."""
    w1, w2, w3 = w
    zero = np.zeros_like(w1)
    if model == "similarity":
        return np.array([[w1, -w2, w3, zero], [w2, w1, zero, w3], [zero] * 4])
    return np.array([[w1, w2, w3, zero, zero, zero, zero, zero],
                     [zero, zero, zero, w1, w2, w3, zero, zero],
                     [zero, zero, zero, zero, zero, zero, w1, w2]])


def _zncc(a: NDArray, b: NDArray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(np.dot(a, a)) * float(np.dot(b, b)))
    return float(np.dot(a, b) / den) if den > 0 else 0.0


def _usable(ux: NDArray, uy: NDArray, valid: NDArray, margin: float) -> NDArray:
    """Points inside ``valid`` (bilinear validity > 0.99) and ``margin`` px from the edge."""
    h, w = valid.shape
    inside = ((ux >= margin) & (ux <= w - 1 - margin) & (uy >= margin)
              & (uy <= h - 1 - margin) & np.isfinite(ux) & np.isfinite(uy))
    ok = np.zeros(ux.shape, dtype=bool)
    if inside.any():
        ok[inside] = map_coordinates(valid.astype(np.float64), [uy[inside], ux[inside]],
                                     order=1) > 0.99
    return ok


def _soft_l1(r: NDArray, f: float) -> float:
    return float(np.sum(2.0 * (np.sqrt(1.0 + (r / f) ** 2) - 1.0)))


@dataclass
class _Level:
    """Photometric + geometric fit on one pyramid level.

    Model of the log images: ``a·L(u) + d·L(u)² + b + c·ρ²(u) ≈ T_t(x)``, where ``L`` is
    the photo's log luminance at the photo-level pixel ``u`` that the transform ``g``
    (normalised sim → normalised photo coordinates) sends simulation pixel ``x`` to; the
    quadratic term absorbs a tone curve that is not a pure power, ``ρ²`` (distance from
    the photo's centre relative to the corner, squared) a vignetting fall-off, and ``T_t``
    is the standardised log of the simulation blurred by a Gaussian of variance 2t
    (sim-level px²) — the photo is usually blurrier than the simulation, and blur moves
    edges in log space, so the blur is fitted too. Only lit simulation pixels (the fixed
    set ``xs``) take part.
    """

    s_lin: NDArray
    rows: NDArray
    cols: NDArray
    xs: NDArray
    shift: float
    spread: float
    photo: NDArray
    valid: NDArray
    gy: NDArray
    gx: NDArray
    np_inv: NDArray
    weight: NDArray
    _t_cache: dict[float, tuple[NDArray, NDArray]] = field(default_factory=dict)

    def target(self, t: float) -> tuple[NDArray, NDArray]:
        """Standardised log of the blurred simulation at the lit pixels, and d/dt."""
        key = round(max(float(t), 0.0), 9)
        if key not in self._t_cache:
            img = (gaussian_filter(self.s_lin, math.sqrt(2 * key), mode="nearest")
                   if key > 0 else self.s_lin)
            vals = np.maximum(img[self.rows, self.cols], 1e-30)
            lap = laplace(img, mode="nearest")[self.rows, self.cols]
            self._t_cache.clear()
            self._t_cache[key] = ((np.log(vals) - self.shift) / self.spread,
                                  lap / vals / self.spread)
        return self._t_cache[key]

    def coords(self, g: NDArray, sel: NDArray | slice = slice(None)
               ) -> tuple[NDArray, NDArray, NDArray]:
        """Photo-level (ux, uy) and homogeneous z = g·xs of the selected pixels."""
        z = g @ self.xs[:, sel]
        z3 = np.where(np.abs(z[2]) < 1e-9, 1e-9, z[2])
        r = self.np_inv[0, 0]
        return r * z[0] / z3 + self.np_inv[0, 2], r * z[1] / z3 + self.np_inv[1, 2], z

    def _rho2(self, ux: NDArray, uy: NDArray) -> tuple[NDArray, float, float, float]:
        h, w = self.photo.shape
        cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
        r2 = max(cx * cx + cy * cy, 1.0)
        return ((ux - cx) ** 2 + (uy - cy) ** 2) / r2, cx, cy, r2

    def model(self, ux: NDArray, uy: NDArray, phot: NDArray) -> NDArray:
        """``a·L + d·L² + b + c·ρ²`` at photo-level points."""
        vals = map_coordinates(self.photo, [uy, ux], order=1, mode="nearest")
        a, d, b, c, _ = phot
        return a * vals + d * vals**2 + b + c * self._rho2(ux, uy)[0]

    def residual(self, g: NDArray, phot: NDArray, sel: NDArray) -> NDArray:
        ux, uy, _ = self.coords(g, sel)
        return self.model(ux, uy, phot) - self.target(phot[4])[0][sel]

    def linearise(self, g: NDArray, phot: NDArray, sel: NDArray, model: str
                  ) -> tuple[NDArray, NDArray]:
        """Residual and Jacobian (geometric increment, then a, d, b, c, t)."""
        ux, uy, z = self.coords(g, sel)
        vals = map_coordinates(self.photo, [uy, ux], order=1, mode="nearest")
        gx = map_coordinates(self.gx, [uy, ux], order=1, mode="nearest")
        gy = map_coordinates(self.gy, [uy, ux], order=1, mode="nearest")
        rho2, cx, cy, r2 = self._rho2(ux, uy)
        a, d, b, c, t = phot
        tgt, dtgt = self.target(t)
        res = a * vals + d * vals**2 + b + c * rho2 - tgt[sel]
        dl = a + 2.0 * d * vals                                     # ∂model/∂L
        ex = dl * gx + c * 2.0 * (ux - cx) / r2                     # ∂res/∂ux
        ey = dl * gy + c * 2.0 * (uy - cy) / r2                     # ∂res/∂uy
        r = self.np_inv[0, 0]
        z3 = np.where(np.abs(z[2]) < 1e-9, 1e-9, z[2])
        dz = np.array([r * ex / z3, r * ey / z3, -r * (ex * z[0] + ey * z[1]) / z3**2])
        geo = np.einsum("kn,kpn->np", dz, _dz_dp(z, model))
        cols = [geo, vals, vals**2, np.ones_like(vals), rho2, -dtgt[sel]]
        return res, np.column_stack(cols)


def _jacobian2(g: NDArray, y: NDArray) -> tuple[NDArray, float]:
    """2×2 Jacobian of the projective map ``g`` at the normalised point ``y`` and z3 there."""
    z = g @ np.array([y[0], y[1], 1.0])
    q = z[:2] / z[2]
    return (g[:2, :2] - np.outer(q, g[2, :2])) / z[2], float(z[2])


def _plausible(g: NDArray, start: NDArray, centre: NDArray, xs: NDArray) -> bool:
    """Whether ``g`` is still a sensible view of the wall compared with ``start``.

    Rejects mirror images, a scale that changed by more than 1.5× or a rotation by more
    than 20° during refinement, an anisotropy above 2 (a camera more than ~60° off the
    wall's normal) and a horizon crossing the lit pixels.
    """
    jac, z3 = _jacobian2(g, centre)
    jac0, _ = _jacobian2(start, centre)
    det, det0 = float(np.linalg.det(jac)), float(np.linalg.det(jac0))
    if z3 <= 0 or det <= 0 or det0 <= 0 or not 1 / 2.25 <= det / det0 <= 2.25:
        return False
    sv = np.linalg.svd(jac, compute_uv=False)
    if sv[0] > 2.0 * sv[1]:
        return False
    rot = math.atan2(jac[1, 0] - jac[0, 1], jac[0, 0] + jac[1, 1])
    rot0 = math.atan2(jac0[1, 0] - jac0[0, 1], jac0[0, 0] + jac0[1, 1])
    if abs((rot - rot0 + math.pi) % (2 * math.pi) - math.pi) > math.radians(20):
        return False
    return bool(np.all(g[2] @ xs > 0))


def _solve_level(lvl: _Level, g: NDArray, phot: NDArray | None, model: str, max_iter: int,
                 min_pixels: int) -> tuple[NDArray, NDArray, float, int, int]:
    """Levenberg–Marquardt with IRLS (soft-L1) weights; compositional updates of ``g``.

    Steps that make the transform implausible (:func:`_plausible`), halve the overlap or
    blur the simulation by more than ``MAX_BLUR`` level px count as failed steps.
    Returns the refined ``g``, the photometric/blur parameters (a, d, b, c, t), the ZNCC
    of the fitted log images, the pixels used and the iterations run.
    """
    n_geo = 4 if model == "similarity" else 8
    lam, f_scale, iters = 1e-4, 0.5, 0
    t_max = 0.5 * MAX_BLUR**2
    start, centre = g.copy(), lvl.xs[:2].mean(axis=1)
    ux, uy, _ = lvl.coords(g)
    sel = _usable(ux, uy, lvl.valid, margin=1.0)
    n_start = int(sel.sum())
    if n_start < min_pixels:
        raise InputError("no overlap between the photo and the simulation after "
                         "registration (check that both show the same beam pattern)")
    if phot is None:
        vals = map_coordinates(lvl.photo, [uy[sel], ux[sel]], order=1, mode="nearest")
        a, b = _affine_fit(vals, lvl.target(0.0)[0][sel])
        phot = np.array([a, 0.0, b, 0.0, 0.0])
    phot[4] = min(max(phot[4], 0.0), t_max)
    while iters < max_iter:
        iters += 1
        res, jac = lvl.linearise(g, phot, sel, model)
        wts = lvl.weight[sel] / np.sqrt(1.0 + (res / f_scale) ** 2)
        a_mat = jac.T @ (jac * wts[:, None])
        grad = jac.T @ (wts * res)
        cost = _soft_l1(res, f_scale)
        moved = math.inf
        for _ in range(12):
            step = np.linalg.solve(a_mat + lam * np.diag(np.diag(a_mat) + 1e-12), -grad)
            g_new = _normalise(_increment(step[:n_geo], model) @ g)
            phot_new = phot + step[n_geo:]
            phot_new[4] = min(max(phot_new[4], 0.0), t_max)
            ok = (_plausible(g_new, start, centre, lvl.xs)
                  and _soft_l1(lvl.residual(g_new, phot_new, sel), f_scale) <= cost)
            if ok:
                ux2, uy2, _ = lvl.coords(g_new)
                sel_new = _usable(ux2, uy2, lvl.valid, margin=1.0)
                ok = int(sel_new.sum()) >= max(min_pixels, n_start // 2)
            if ok:
                moved = float(np.max(np.hypot(ux2[sel] - ux[sel], uy2[sel] - uy[sel])))
                moved = max(moved, abs(math.sqrt(2 * phot_new[4]) - math.sqrt(2 * phot[4])))
                g, phot, sel, ux, uy = g_new, phot_new, sel_new, ux2, uy2
                lam = max(lam / 4.0, 1e-7)
                break
            lam *= 8.0
        else:
            break                       # no acceptable step lowers the cost: converged
        if moved < 0.01:
            break
    fitted = lvl.model(ux[sel], uy[sel], phot)
    return g, phot, _zncc(fitted, lvl.target(phot[4])[0][sel]), int(sel.sum()), iters


def _refine_level(sim: _Pyramid, photo: _Pyramid, matrix: NDArray, sim_factor: float,
                  model: str, opts: RegistrationOptions,
                  prior: tuple[NDArray, float] | None = None, max_iter: int | None = None,
                  quiet_level: float = 0.0, min_overlap: float = 0.0
                  ) -> tuple[NDArray, NDArray, dict[str, Any]]:
    """Refine photo→sim ``matrix`` on one level.

    ``prior`` is (photometric/blur parameters, factor of the level they were fitted on);
    ``quiet_level`` is the photo's lowest quiet level (:func:`usable_level`) at full
    resolution: simulation pixels darker than it (relative, divided by the photo's
    downsampling factor, which averages noise away) are left out, within
    [``opts.lit_level``, 0.1]; ``min_overlap`` is the least fraction of the lit pixels
    the photo must keep covering (so that a poor match cannot shrink the overlap to a
    small, well-fitting corner level by level). Returns the new matrix, the
    photometric/blur parameters and the level's facts.
    """
    scale = decompose(matrix, photo.linear.shape)["scale"]
    g_fac = _photo_factor(sim_factor, scale)
    lit_level = min(max(opts.lit_level, quiet_level / g_fac), 0.1)
    s_lin = sim.linear_level(sim_factor)
    s_valid = downsample(sim.valid.astype(np.float64), sim_factor) > 0.99
    p_log, p_valid, gy, gx = photo.level(g_fac, opts.photo_floor, opts.photo_blur_px)
    ds, dp = level_matrix(sim_factor), level_matrix(g_fac)
    h_lvl = dp @ np.linalg.inv(matrix) @ np.linalg.inv(ds)       # sim-level → photo-level
    ns, npm = _norm_matrix(s_lin.shape), _norm_matrix(p_log.shape)
    lit = s_valid & (s_lin >= lit_level * sim.reference)
    # the simulation's border is an arbitrary cut through the pattern, not a feature
    lit[:BORDER], lit[-BORDER:], lit[:, :BORDER], lit[:, -BORDER:] = False, False, False, False
    yy, xx = np.nonzero(lit)
    if yy.size < 64:
        raise InputError("the simulation has too few lit pixels to register against")
    xs = ns @ np.vstack([xx, yy, np.ones_like(xx)]).astype(np.float64)
    log_s = np.log(s_lin[yy, xx])
    rel = s_lin[yy, xx] / sim.reference
    weight = rel / (rel + opts.noise_level) if opts.noise_level > 0 else np.ones_like(rel)
    lvl = _Level(s_lin, yy, xx, xs, float(log_s.mean()), float(log_s.std()) or 1.0,
                 p_log, p_valid, gy, gx, np.linalg.inv(npm), weight)
    phot = None
    if prior is not None:       # the blur carries over as a variance in sim-level px²
        phot = prior[0].copy()
        phot[4] *= (prior[1] / sim_factor) ** 2
    g0 = _normalise(npm @ h_lvl @ np.linalg.inv(ns))
    min_pixels = max(64, int(max(0.02, min_overlap) * yy.size))
    g, phot, score, used, iters = _solve_level(lvl, g0, phot, model, max_iter or opts.max_iter,
                                               min_pixels)
    h_new = np.linalg.inv(npm) @ g @ ns
    m_new = _normalise(np.linalg.inv(np.linalg.inv(dp) @ h_new @ ds))
    facts = {"sim_factor": sim_factor, "photo_factor": g_fac, "model": model,
             "size": [int(s_lin.shape[1]), int(s_lin.shape[0])], "pixels": used,
             "zncc_log": score, "iterations": iters, "lit_level": lit_level,
             "overlap": used / yy.size,
             "sim_blur_px": math.sqrt(2 * phot[4]) * sim_factor,
             "blur_at_cap": bool(phot[4] >= 0.999 * 0.5 * MAX_BLUR**2)}
    return m_new, phot, facts


def _affine_fit(x: NDArray, y: NDArray) -> tuple[float, float]:
    """Least-squares ``y ≈ a·x + b`` (a = 1, b = 0 for a flat x)."""
    vx = float(np.var(x))
    if vx <= 1e-12:
        return 1.0, float(np.mean(y) - np.mean(x))
    a = float(np.mean((x - x.mean()) * (y - y.mean())) / vx)
    return a, float(np.mean(y) - a * np.mean(x))


def _sim_factors(shape: tuple[int, int], opts: RegistrationOptions) -> list[float]:
    """Pyramid factors 2^k, coarse (≈ coarse_size) to fine (≤ finest_size)."""
    longest = max(shape)
    k_max = max(0, math.floor(math.log2(max(longest / opts.coarse_size, 1.0)) + 1e-9))
    k_min = max(0, math.ceil(math.log2(max(longest / opts.finest_size, 1.0)) - 1e-9))
    return [float(2**k) for k in range(max(k_max, k_min), k_min - 1, -1)]


def _overlap(matrix: NDArray, photo_valid: NDArray, sim_shape: tuple[int, int]) -> float:
    """Fraction of simulation pixels covered by usable photo pixels."""
    h, w = sim_shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    ux, uy = apply_matrix(np.linalg.inv(matrix), xx, yy)
    return float(_usable(ux.ravel(), uy.ravel(), photo_valid, 0.0).mean())


def usable_level(photo: NDArray, valid: NDArray, reference: float,
                 max_noise: float = 0.05) -> float:
    """Lowest photo level (relative to ``reference``) whose pixel noise is ≤ ``max_noise``.

    The noise is measured, not assumed: the photo minus a Gaussian-smoothed copy (σ = 1
    px) is a high-pass image that holds mostly noise; its robust spread (1.4826·MAD, /0.87
    for the filter's own share) is taken in bands of brightness of a smoothed copy, and
    the relative noise σ/level of each band is compared with ``max_noise``. In log space
    dim, noisy pixels are both noisy and biased (the log of a noisy value is on average too
    low), which would pull the fitted scale; the registration therefore uses only
    simulation pixels that the photo shows above this level.

    Parameters
    ----------
    photo : ndarray
        Linear photo luminance (relative).
    valid : ndarray of bool
        Usable (unclipped) pixels.
    reference : float
        Level the result is relative to (the photo's 99.5th percentile), same unit.
    max_noise : float, default 0.05
        Largest acceptable relative noise per pixel (1).

    Returns
    -------
    float
        Relative level in [0, 1]; 0 when every band is quiet enough.
    """
    smooth = gaussian_filter(photo, 1.5, mode="nearest")
    high = photo - gaussian_filter(photo, 1.0, mode="nearest")
    edges = reference * np.logspace(-3, 0, 16)
    for lo, hi in itertools.pairwise(edges):
        band = valid & (smooth >= lo) & (smooth < hi)
        if band.sum() < 200:
            continue
        sigma = 1.4826 * float(np.median(np.abs(high[band] - np.median(high[band])))) / 0.87
        if sigma <= max_noise * math.sqrt(lo * hi):
            return float(lo / reference)
    return 1.0


def register(photo: NDArray, photo_valid: NDArray, sim: NDArray,
             options: RegistrationOptions | None = None, initial: NDArray | None = None
             ) -> Registration:
    """Find the transform from photo pixels to simulation pixels.

    Parameters
    ----------
    photo : ndarray, shape (Hp, Wp)
        Linear luminance of the photo (relative units; exposure and gamma unknown).
    photo_valid : ndarray of bool, shape (Hp, Wp)
        Usable photo pixels (False where clipped).
    sim : ndarray, shape (Hs, Ws)
        Simulated illuminance in lx (NaN where not computed).
    options : RegistrationOptions, optional
        Search and refinement settings (module table).
    initial : ndarray, shape (3, 3), optional
        Starting transform (photo → sim px); skips the coarse search.

    Returns
    -------
    Registration
        The transform, its log-ZNCC score, the overlap and per-level facts.

    Raises
    ------
    InputError
        The photo has no usable pixels, or no overlap with the simulation is found.
    """
    opts = options or RegistrationOptions()
    opts.check()
    valid = np.asarray(photo_valid, bool) & np.isfinite(photo)
    if valid.mean() < 0.01:
        raise InputError("photo has almost no usable pixels (clipped or invalid everywhere)")
    ppyr = _Pyramid.build(np.asarray(photo, np.float64), valid)
    quiet = usable_level(ppyr.linear, valid, ppyr.reference)
    sim_arr = np.asarray(sim, np.float64)
    spyr = _Pyramid.build(sim_arr, np.isfinite(sim_arr))
    factors = _sim_factors(sim_arr.shape, opts)
    if initial is not None:
        starts = [{"score": math.nan, "rotation_deg": math.nan, "scale": math.nan,
                   "matrix": _normalise(np.asarray(initial, np.float64))}]
    else:
        starts = _coarse_search(spyr, ppyr, opts)
        if not starts:
            raise InputError("no overlap between the photo and the simulation at any tried "
                             "rotation and scale")
    best = None
    for start in starts:
        try:
            m, phot, facts = _refine_level(spyr, ppyr, start["matrix"], factors[0],
                                           "similarity", opts, max_iter=opts.screen_iter,
                                           quiet_level=quiet)
        except InputError:
            continue
        if best is None or facts["zncc_log"] > best[3][0]["zncc_log"]:
            best = (start, m, phot, [facts])
    if best is None:
        raise InputError("no overlap between the photo and the simulation after "
                         "registration (check that both show the same beam pattern)")
    start, m, phot, levels = best
    prev, keep = factors[0], 0.6 * levels[0]["overlap"]
    schedule = [(f, opts.model) for f in factors]
    if opts.model == "homography":
        schedule.insert(0, (factors[0], "similarity"))
    for f, model in schedule:
        m, phot, facts = _refine_level(spyr, ppyr, m, f, model, opts, (phot, prev),
                                       quiet_level=quiet, min_overlap=keep)
        levels.append(facts)
        prev = f
    overlap = _overlap(m, valid, sim_arr.shape)
    coarse = {k: v for k, v in start.items() if k != "matrix"}
    coarse["tried"] = len(starts)
    last = levels[-1]
    own = opts.photo_blur_px * last["photo_factor"] * decompose(m, ppyr.linear.shape)["scale"]
    blur = math.sqrt(max(last["sim_blur_px"] ** 2 - own**2, 0.0))
    return Registration(m, opts.model, float(last["zncc_log"]), overlap, coarse, levels, blur,
                        bool(last["blur_at_cap"]))


def registration_dict(reg: Registration, photo_shape: tuple[int, int]) -> dict[str, Any]:
    """JSON-ready description: decomposition, matrix, model, score, levels."""
    out = decompose(reg.matrix, photo_shape)
    out.update({"matrix": [[float(v) for v in row] for row in _normalise(reg.matrix)],
                "model": reg.model, "zncc_log": reg.score, "overlap": reg.overlap,
                "photo_blur_px": reg.blur_px, "blur_at_cap": reg.blur_at_cap,
                "blur_cap_px": MAX_BLUR * (reg.levels[-1]["sim_factor"] if reg.levels else 1.0),
                "coarse": reg.coarse, "levels": reg.levels})
    return out

