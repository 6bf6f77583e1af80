"""A synthetic camera: "photograph" a simulated wall lux map with a known transform.

:func:`render_photo` looks at the wall as a camera would and :func:`write_photo` saves the
picture with a sidecar ``<name>.truth.json`` holding the true 3×3 transform from photo
pixels to simulation pixels, so a registration can be checked against the truth;
:func:`photograph_simulation` does both for a simulation's result (``lightsim photo``).
:func:`lowbeam_lux` makes a realistic synthetic passing-beam pattern (for tests and
examples until a simulation is at hand) and :func:`write_result` saves any lux map as a
result folder that ``lightsim compare`` and ``lightsim photo`` read.

Camera model, in order
    1. **Geometry**: the wall image is turned counter-clockwise by ``rotate_deg``,
       magnified by ``scale`` (photo px per simulation px), moved by ``shift_px`` from the
       photo's centre, then seen at an angle: a camera yawed by ``tilt_deg`` about the
       vertical axis (homography ``K·R_y·K⁻¹`` with focal length ``focal_px``, re-centred so
       the photo's centre stays put; positive tilt makes the right-hand side of the wall
       look larger). Photo pixels outside the simulated wall see 0 lx.
    2. **Vignetting**: × (1 − ``vignetting``·(r / r_corner)²), r from the photo's centre.
    3. **Optics blur**: Gaussian, σ = ``blur_px`` photo px.
    4. **Exposure**: x = E·2^``exposure_ev`` / (``saturate``·E_max), i.e. full scale at
       ``saturate`` × the simulation's peak; without ``saturate`` full scale is 1.05·E_max
       (nothing clips).
    5. **Noise**: Gaussian with σ(x) = ``noise``·√(x + 0.01) (shot noise plus a read-noise
       floor of ``noise``/10), then clipping to [0, 1].
    6. **Tone curve**: sRGB OETF by default, or x^(1/``gamma``).
    7. **Quantisation**: ``bits`` (8 or 16) per channel; grey written as R = G = B. EXR
       output skips 6 and 7 and stores the linear, clipped x.

Parameters
----------
=============  ====  ===========  ============================================================
name           unit  default      meaning
=============  ====  ===========  ============================================================
rotate_deg     deg   0            camera roll: pattern turned counter-clockwise in the photo
scale          1     1            magnification, photo px per simulation px (None: 1, or
                                  with markers the least whose markers span MARKER_MIN_PX)
shift_px       px    (0, 0)       pattern moved right/down from the photo's centre
tilt_deg       deg   0            camera yaw about the vertical axis (perspective)
focal_px       px    1.4·width    focal length used for the tilt
size           px    sim size     photo size (W, H); with markers and scale None the
                                  whole wall at that scale
blur_px        px    0            Gaussian optics blur σ
noise          1     0            noise σ at full scale (fraction of full scale)
vignetting     1     0            light fall-off in the corners (0–1)
gamma          1     None (sRGB)  tone curve x^(1/gamma) instead of the sRGB curve
exposure_ev    EV    0            exposure change (+1 = twice as bright)
saturate       1     None         full scale at this fraction of the peak (hotspot clips)
bits           bit   8            8 or 16 per channel (PNG/TIFF; JPEG is always 8)
seed           –     0            noise seed
=============  ====  ===========  ============================================================

Low-beam pattern (:class:`LowBeam`, angles in degrees on the wall, lux at the wall):
a narrow hot spot below H-V right of V-V, a wider spread and a broad foreground lobe, all
cut by the cut-off: log10 E falls by ``cutoff_decades`` along a tanh of half-width
``cutoff_width_deg`` centred on ``cutoff_v_deg`` left of the elbow, a line that rises at
``step_angle_deg`` (15°) on the traffic side up to ``step_rise_deg`` higher (the dark
region above keeps 10^−``cutoff_decades`` of the light, like scattered glare); optionally
a smooth photon-noise-like texture (relative standard deviation ``texture``).
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
import tifffile
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter, map_coordinates

from lightsim.errors import InputError
from lightsim.io.atomic import atomic_path
from lightsim.io.exr import wall_metadata, write_exr
from lightsim.io.summary import write_json
from lightsim.render.cutoff import apply_shift
from lightsim.validation.photo_io import Simulation, srgb_encode
from lightsim.validation.photo_png16 import write_png16
from lightsim.validation.photo_register import apply_matrix, decompose, level_matrix
from lightsim.validation.screen_target import DEFAULT_LAYOUT, board_reflectance
from lightsim.wall import WallFrame, wall_m_from_deg

__all__ = [
    "CameraSettings",
    "LowBeam",
    "SyntheticPhoto",
    "camera_matrix",
    "lowbeam_lux",
    "photograph_simulation",
    "render_photo",
    "ring_caustic_lux",
    "screen_scene",
    "truth_path",
    "two_spots_lux",
    "wall_frame",
    "write_photo",
    "write_result",
]

PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".dng")


# ---------------------------------------------------------------------------------------
# synthetic low beam
# ---------------------------------------------------------------------------------------

def wall_frame(resolution: tuple[int, int] = (400, 160), size_m: tuple[float, float] = (30.0, 12.0),
               distance_m: float = 25.0) -> dict[str, Any]:
    """A wall frame (``docs/reference/conventions.md``) centred on H-V, like
    ``lightsim simulate``'s.

    Parameters
    ----------
    resolution : tuple of int, default (400, 160)
        (W, H) in pixels.
    size_m : tuple of float, default (30, 12)
        Wall width and height in m.
    distance_m : float, default 25
        Lamp → wall distance in m.
    """
    w, h = size_m
    return {"centre": [0.0, 0.0, float(distance_m)], "h_axis": [-1.0, 0.0, 0.0],
            "v_axis": [0.0, 1.0, 0.0], "normal": [0.0, 0.0, -1.0],
            "h_range_m": [-w / 2, w / 2], "v_range_m": [-h / 2, h / 2],
            "distance_m": float(distance_m), "resolution": [int(resolution[0]), int(resolution[1])]}


@dataclass(frozen=True)
class LowBeam:
    """Shape of a synthetic passing beam (degrees on the wall; see the module docstring)."""

    peak_lx: float = 40.0
    hotspot_deg: tuple[float, float] = (1.5, -1.3)
    hotspot_sigma_deg: tuple[float, float] = (2.5, 0.9)
    spread_sigma_deg: tuple[float, float] = (10.0, 2.2)
    spread_level: float = 0.35
    foreground_sigma_deg: tuple[float, float] = (25.0, 4.0)
    foreground_level: float = 0.08
    cutoff_v_deg: float = -0.57
    elbow_h_deg: float = 0.0
    step_angle_deg: float = 15.0
    step_rise_deg: float = 1.0
    cutoff_width_deg: float = 0.1
    cutoff_decades: float = 2.3
    traffic: str = "right"
    texture: float = 0.0
    seed: int = 0


def _gauss(h: NDArray, v: NDArray, centre: tuple[float, float], sigma: tuple[float, float]
           ) -> NDArray:
    return np.exp(-0.5 * (((h - centre[0]) / sigma[0]) ** 2 + ((v - centre[1]) / sigma[1]) ** 2))


def lowbeam_lux(frame: Any, beam: LowBeam | None = None) -> NDArray:
    """Synthetic passing-beam illuminance on the wall.

    Parameters
    ----------
    frame : mapping or WallFrame
        Wall frame (pixel grid and distance).
    beam : LowBeam, optional
        Pattern shape (defaults: right-hand traffic, 40 lx peak at 25 m).

    Returns
    -------
    ndarray, shape (H, W)
        Illuminance in lx, row 0 on top.
    """
    b = beam or LowBeam()
    wf = WallFrame.from_any(frame)
    h = wf.h_deg()[None, :] * (1.0 if b.traffic == "right" else -1.0)
    v = wf.v_deg()[:, None]
    core = (_gauss(h, v, b.hotspot_deg, b.hotspot_sigma_deg)
            + b.spread_level * _gauss(h, v, (0.0, b.hotspot_deg[1] - 0.3), b.spread_sigma_deg)
            + b.foreground_level * _gauss(h, v, (0.0, -4.0), b.foreground_sigma_deg))
    rise = np.clip((h - b.elbow_h_deg) * math.tan(math.radians(b.step_angle_deg)),
                   0.0, b.step_rise_deg)
    edge = b.cutoff_v_deg + rise
    # the shield's shadow: log E drops by ``cutoff_decades`` across the edge (a tanh in
    # log space, as measured cut-offs look), steepest exactly at the edge
    cut = 10.0 ** (-0.5 * b.cutoff_decades * (1.0 + np.tanh((v - edge) / b.cutoff_width_deg)))
    intensity = core * cut
    hm = wall_m_from_deg(wf.h_deg(), wf.distance_m)[None, :]
    vm = wall_m_from_deg(wf.v_deg(), wf.distance_m)[:, None]
    d = wf.distance_m
    lux = intensity * d**3 / (d**2 + hm**2 + vm**2) ** 1.5    # E ∝ I·cos θ / r²
    if b.texture > 0:
        rng = np.random.default_rng(b.seed)
        field = gaussian_filter(rng.standard_normal(lux.shape), 1.0)
        lux = lux * np.maximum(1.0 + b.texture * field / max(field.std(), 1e-12), 0.0)
    return lux * (b.peak_lx / lux.max())


def two_spots_lux(frame: Any, peak_lx: float = 30.0) -> NDArray:
    """Two round spots of different size and brightness (like lamps on a sheet of paper).

    Discs of radius 3° at (−6°, −1°) and 2.2° at (7°, 1°), soft edges (logistic, 0.15°),
    the second at 2/3 of the first's level, over a 1 % floor; lux at the wall.
    """
    wf = WallFrame.from_any(frame)
    h, v = np.meshgrid(wf.h_deg(), wf.v_deg())

    def disc(h0: float, v0: float, r: float) -> NDArray:
        return 1.0 / (1.0 + np.exp((np.hypot(h - h0, v - v0) - r) / 0.15))

    return peak_lx * (disc(-6, -1, 3.0) + 2 / 3 * disc(7, 1, 2.2) + 0.01)


def ring_caustic_lux(frame: Any, peak_lx: float = 40.0) -> NDArray:
    """A ring's caustic (the paper's RING scene seen from above): a bright cardioid.

    Light reflected inside a ring focuses on a cardioid ``r = a(1 + cos φ)`` (a = 2.5°,
    centred on (1°, −0.5°)), brightest towards its cusp side, filled dimly inside, with
    the ring's own bright rim at 5.2°; lux at the wall.
    """
    wf = WallFrame.from_any(frame)
    h, v = np.meshgrid(wf.h_deg(), wf.v_deg())
    r, phi = np.hypot(h - 1.0, v + 0.5), np.arctan2(v + 0.5, h - 1.0)
    rc = 2.5 * (1.0 + np.cos(phi))
    e = (np.exp(-0.5 * ((r - rc) / 0.3) ** 2) * (0.6 + 0.4 * np.cos(phi / 2) ** 2)
         + 0.15 * (r < rc) + 0.3 * np.exp(-0.5 * ((r - 5.2) / 0.25) ** 2) + 0.005)
    return peak_lx * e / e.max()


def write_result(folder: str | os.PathLike, lux: NDArray, frame: dict[str, Any],
                 description: str = "synthetic pattern", extra: dict[str, Any] | None = None
                 ) -> Path:
    """Save a lux map as a result folder (``wall_lux.exr`` + ``summary.json``).

    Parameters
    ----------
    folder : path-like
        Output folder (created).
    lux : ndarray, shape (H, W)
        Illuminance in lx.
    frame : dict
        Wall frame (``docs/reference/conventions.md``).
    description : str
        Stored as ``source`` in the EXR and ``scene.source`` in the summary.
    extra : dict, optional
        More summary entries (e.g. the pattern's parameters).

    Returns
    -------
    Path
        The folder.
    """
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    meta = wall_metadata(frame, units="lx", quantity="illuminance", source=description)
    write_exr(out / "wall_lux.exr", {"Y": np.asarray(lux, np.float32)}, meta)
    summary = {"wall": frame, "scene": {"source": description, "synthetic": True},
               "units": {"illuminance": "lx", "length": "m", "angle": "deg"},
               "lux": {"max_lx": float(np.nanmax(lux))}, **(extra or {})}
    write_json(out / "summary.json", summary)
    return out


def screen_scene(lux: NDArray, frame: dict[str, Any], layout: Any = None, upsample: int = 4,
                 ambient_lx: float = 0.5, texture_seed: int | None = None
                 ) -> tuple[NDArray, dict[str, Any], NDArray]:
    """The wall as a camera sees it with a marker board on it (for synthetic photos).

    The lux map is resampled ``upsample`` times finer (bilinear between pixel centres) so
    the markers' modules are resolved, ``ambient_lx`` of room light is added everywhere (a
    camera needs some to see markers outside the beam) and the result is multiplied by the
    board's reflectance (:func:`lightsim.validation.screen_target.board_reflectance`):
    the wall's luminance up to the constant 1/π of a Lambertian screen.

    Parameters
    ----------
    lux : ndarray, shape (H, W)
        Illuminance on the wall (lx).
    frame : dict
        Its wall frame.
    layout : ScreenLayout, optional
        Board (default layout).
    upsample : int, default 4
        Fine-grid factor.
    ambient_lx : float, default 0.5
        Room light (lx).
    texture_seed : int, optional
        Give the wall a static texture (random grey rectangles, reflectance 0.45–0.9, like
        posters and bricks) for photo-against-photo alignment; ``layout=False`` leaves the
        markers off.

    Returns
    -------
    scene : ndarray, shape (u·H, u·W)
        Reflectance × illuminance (lx), to photograph with :func:`render_photo`.
    fine_frame : dict
        The fine grid's wall frame.
    to_sim : ndarray, shape (3, 3)
        Fine-grid px → ``frame`` px; a photo's true photo → simulation matrix is
        ``to_sim @ shot.matrix``.
    """
    u = int(upsample)
    if u < 1 or not math.isfinite(ambient_lx) or ambient_lx < 0:
        raise InputError("upsample must be ≥ 1 and ambient light ≥ 0 lx")
    arr = np.nan_to_num(np.asarray(lux, np.float64))
    hs, ws = arr.shape
    rows = (np.arange(hs * u) + 0.5) / u - 0.5
    cols = (np.arange(ws * u) + 0.5) / u - 0.5
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    fine = map_coordinates(arr, [rr, cc], order=1, mode="nearest")
    fine_frame = {**frame, "resolution": [ws * u, hs * u]}
    refl = (board_reflectance(layout or DEFAULT_LAYOUT, fine_frame) if layout is not False
            else np.full(fine.shape, 0.9))
    if texture_seed is not None:
        rng = np.random.default_rng(texture_seed)
        tex = np.ones_like(fine)
        h, w = fine.shape
        for _ in range(400):
            r0, c0 = rng.integers(0, h), rng.integers(0, w)
            dr, dc = rng.integers(4, max(5, h // 8)), rng.integers(4, max(5, w // 12))
            tex[r0:r0 + dr, c0:c0 + dc] = rng.uniform(0.5, 1.0)
        refl = np.where(refl >= 0.89, refl * tex, refl)     # markers stay as printed
    return (fine + ambient_lx) * refl, fine_frame, level_matrix(u)


# ---------------------------------------------------------------------------------------
# camera
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CameraSettings:
    """How the synthetic camera sees the wall (units in the module's table)."""

    rotate_deg: float = 0.0
    scale: float | None = 1.0
    shift_px: tuple[float, float] = (0.0, 0.0)
    tilt_deg: float = 0.0
    focal_px: float | None = None
    size: tuple[int, int] | None = None
    blur_px: float = 0.0
    noise: float = 0.0
    vignetting: float = 0.0
    gamma: float | None = None
    exposure_ev: float = 0.0
    saturate: float | None = None
    bits: int = 8
    seed: int = 0

    def check(self) -> None:
        """Raise :class:`InputError` for impossible settings."""
        if self.scale is not None and not (self.scale > 0 and math.isfinite(self.scale)):
            raise InputError(f"--scale must be positive, got {self.scale}")
        if not abs(self.tilt_deg) < 60:
            raise InputError(f"--tilt must be within ±60°, got {self.tilt_deg}")
        if self.blur_px < 0 or self.noise < 0:
            raise InputError("--blur and --noise must not be negative")
        if not 0 <= self.vignetting < 1:
            raise InputError(f"--vignetting must be in [0, 1), got {self.vignetting}")
        if self.gamma is not None and not self.gamma > 0:
            raise InputError(f"--gamma must be positive, got {self.gamma}")
        if self.saturate is not None and not 0 < self.saturate <= 1:
            raise InputError(f"--saturate must be in (0, 1], got {self.saturate}")
        if self.bits not in (8, 16):
            raise InputError(f"--bits must be 8 or 16, got {self.bits}")
        if self.size is not None and min(self.size) < 16:
            raise InputError(f"photo size must be at least 16×16 pixels, got {self.size}")


@dataclass
class SyntheticPhoto:
    """A rendered photo and its truth.

    Attributes
    ----------
    linear : ndarray, shape (H, W)
        Linear sensor value after noise and clipping (1 = full scale).
    encoded : ndarray, shape (H, W)
        Tone-mapped value in [0, 1] before quantisation (equals ``linear`` for EXR use).
    matrix : ndarray, shape (3, 3)
        True transform photo px → simulation px.
    full_scale_lx : float
        Illuminance (lx) that reaches full scale at the photo's centre.
    settings : CameraSettings
        The camera used.
    """

    linear: NDArray
    encoded: NDArray
    matrix: NDArray
    full_scale_lx: float
    settings: CameraSettings

    def truth(self) -> dict[str, Any]:
        """JSON-ready truth: matrix, its decomposition, exposure and camera settings."""
        shape = self.linear.shape
        out = decompose(self.matrix, shape)
        out.update({"matrix": [[float(x) for x in row] for row in self.matrix / self.matrix[2, 2]],
                    "maps": "photo pixels (x = column, y = row) → simulation pixels",
                    "photo_size": [int(shape[1]), int(shape[0])],
                    "full_scale_lx": self.full_scale_lx,
                    "clipped_fraction": float((self.linear >= 1.0).mean()),
                    "camera": asdict(self.settings)})
        return out


def _tilt_homography(tilt_deg: float, focal_px: float, centre: tuple[float, float]) -> NDArray:
    """Image-to-image homography of a camera yawed by ``tilt_deg``, centre kept fixed."""
    cx, cy = centre
    k = np.array([[focal_px, 0, cx], [0, focal_px, cy], [0, 0, 1.0]])
    a = math.radians(tilt_deg)
    r = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    h = k @ r @ np.linalg.inv(k)
    px, py = apply_matrix(h, np.array(cx), np.array(cy))
    back = np.array([[1.0, 0, cx - float(px)], [0, 1.0, cy - float(py)], [0, 0, 1.0]])
    return back @ h


def camera_matrix(sim_shape: tuple[int, int], photo_shape: tuple[int, int],
                  cam: CameraSettings) -> NDArray:
    """True transform photo pixels → simulation pixels for ``cam``.

    Parameters
    ----------
    sim_shape, photo_shape : tuple of int
        (H, W) of the simulation and of the photo in pixels.
    cam : CameraSettings
        Geometry settings (rotate, scale, shift, tilt, focal length).

    Returns
    -------
    ndarray, shape (3, 3)
        Homogeneous matrix, normalised so that the last element is 1.
    """
    hs, ws = sim_shape
    hp, wp = photo_shape
    cs = ((ws - 1) / 2.0, (hs - 1) / 2.0)
    cp = ((wp - 1) / 2.0, (hp - 1) / 2.0)
    a = math.radians(cam.rotate_deg)
    c, s = math.cos(a) * cam.scale, math.sin(a) * cam.scale
    # counter-clockwise on screen (y down): (1, 0) → (cos, −sin)
    sim_to_photo = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1.0]])
    sim_to_photo = (np.array([[1.0, 0, cp[0] + cam.shift_px[0]], [0, 1.0, cp[1] + cam.shift_px[1]],
                              [0, 0, 1.0]])
                    @ sim_to_photo @ np.array([[1.0, 0, -cs[0]], [0, 1.0, -cs[1]], [0, 0, 1.0]]))
    if cam.tilt_deg:
        focal = cam.focal_px if cam.focal_px else 1.4 * wp
        sim_to_photo = _tilt_homography(cam.tilt_deg, focal, cp) @ sim_to_photo
    m = np.linalg.inv(sim_to_photo)
    return m / m[2, 2]


def _sample_wall(lux: NDArray, matrix: NDArray, photo_shape: tuple[int, int]) -> NDArray:
    """Illuminance (lx) each photo pixel sees, anti-aliased when the wall is demagnified."""
    hp, wp = photo_shape
    yy, xx = np.mgrid[0:hp, 0:wp].astype(np.float64)
    sx, sy = apply_matrix(matrix, xx, yy)
    step = decompose(matrix, photo_shape)["scale"]            # sim px per photo px
    src = np.nan_to_num(np.asarray(lux, np.float64), nan=0.0)
    if step > 1.0:
        src = gaussian_filter(src, (step - 1.0) / 2.0, mode="nearest")
    hs, ws = src.shape
    # the wall image covers pixel edges −0.5 … W − 0.5; beyond them the photo sees 0 lx
    inside = (np.isfinite(sx) & np.isfinite(sy) & (sx >= -0.5) & (sx <= ws - 0.5)
              & (sy >= -0.5) & (sy <= hs - 0.5))
    out = map_coordinates(src, [np.where(inside, sy, 0.0), np.where(inside, sx, 0.0)],
                          order=1, mode="nearest")
    return np.where(inside, out, 0.0)


def render_photo(lux: NDArray, cam: CameraSettings | None = None) -> SyntheticPhoto:
    """Photograph a wall lux map with the synthetic camera.

    Parameters
    ----------
    lux : ndarray, shape (Hs, Ws)
        Simulated illuminance in lx.
    cam : CameraSettings, optional
        Camera (module table); default: an ideal camera, same size, sRGB, 8 bit.

    Returns
    -------
    SyntheticPhoto
        Linear and encoded images and the true transform.

    Raises
    ------
    InputError
        Impossible settings or a map without light.
    """
    cam = cam or CameraSettings()
    cam.check()
    if cam.scale is None:
        cam = replace(cam, scale=1.0)
    lux = np.asarray(lux, np.float64)
    e_max = float(np.nanmax(lux)) if np.any(np.isfinite(lux)) else 0.0
    if not e_max > 0:
        raise InputError("the simulation has no light to photograph")
    photo_shape = (cam.size[1], cam.size[0]) if cam.size else lux.shape
    m = camera_matrix(lux.shape, photo_shape, cam)
    e = _sample_wall(lux, m, photo_shape)
    hp, wp = photo_shape
    if cam.vignetting:
        yy, xx = np.mgrid[0:hp, 0:wp].astype(np.float64)
        r2 = ((xx - (wp - 1) / 2) ** 2 + (yy - (hp - 1) / 2) ** 2) / (((wp - 1) / 2) ** 2
                                                                    + ((hp - 1) / 2) ** 2)
        e = e * (1.0 - cam.vignetting * r2)
    if cam.blur_px:
        e = gaussian_filter(e, cam.blur_px, mode="nearest")
    full_scale = (cam.saturate if cam.saturate else 1.05) * e_max / 2.0**cam.exposure_ev
    x = e / full_scale
    if cam.noise:
        rng = np.random.default_rng(cam.seed)
        x = x + cam.noise * np.sqrt(np.maximum(x, 0.0) + 0.01) * rng.standard_normal(x.shape)
    x = np.clip(x, 0.0, 1.0)
    encoded = srgb_encode(x) if cam.gamma is None else x ** (1.0 / cam.gamma)
    return SyntheticPhoto(x, encoded, m, float(full_scale), cam)


def truth_path(photo_path: str | os.PathLike) -> Path:
    """Sidecar of a synthetic photo: ``photo.png`` → ``photo.truth.json``."""
    p = Path(photo_path)
    return p.with_name(p.stem + ".truth.json")


def _quantise(encoded: NDArray, bits: int) -> NDArray:
    full = 255 if bits == 8 else 65535
    codes = np.round(np.clip(encoded, 0.0, 1.0) * full).astype(np.uint8 if bits == 8 else
                                                                np.uint16)
    return np.repeat(codes[..., None], 3, axis=-1)


def _write_raster(path: Path, codes: NDArray, suffix: str) -> None:
    with atomic_path(path) as tmp:
        if suffix in (".jpg", ".jpeg"):
            iio.imwrite(tmp, codes, extension=suffix, quality=95)
        else:
            iio.imwrite(tmp, codes, extension=suffix)


#: Sensor levels and EXIF of the synthetic raw camera (12-bit, as many DSLRs).
DNG_BLACK, DNG_WHITE = 256, 4095
DNG_EXPOSURE = {"exposure_time_s": 1 / 50, "f_number": 2.8, "iso": 200}


def write_dng(path: str | os.PathLike, linear: NDArray, black: int = DNG_BLACK,
              white: int = DNG_WHITE, exposure: dict[str, float] | None = None) -> Path:
    """Write a linear grey image as a raw DNG (RGGB mosaic, 2×2 sensor px per photo px).

    The file is a TIFF with the DNG 1.4 tags LibRaw needs (CFA pattern, black and white
    levels, an identity colour matrix, as-shot neutral) and EXIF-style exposure tags,
    written by :mod:`tifffile`; every CFA sample of a cell holds the pixel's value, so a
    reader that bins 2×2 cells gets the photo back.

    Parameters
    ----------
    path : path-like
        ``.dng`` file (written atomically).
    linear : ndarray, shape (H, W)
        Linear values, 1 = the white level (clipped to [0, 1]).
    black, white : int
        Sensor black and white levels (codes).
    exposure : dict, optional
        ``exposure_time_s``, ``f_number``, ``iso`` (default :data:`DNG_EXPOSURE`).
    """
    ex = {**DNG_EXPOSURE, **(exposure or {})}
    x = np.clip(np.asarray(linear, np.float64), 0.0, 1.0)
    codes = np.round(black + x * (white - black)).astype(np.uint16)
    mosaic = np.kron(codes, np.ones((2, 2), np.uint16))
    t_num, t_den = 1, round(1 / ex["exposure_time_s"])
    tags = [
        (50706, "B", 4, (1, 4, 0, 0), True),            # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),            # DNGBackwardVersion
        (50708, "s", 0, "lightsim synthetic camera", True),   # UniqueCameraModel
        (33421, "H", 2, (2, 2), True),                  # CFARepeatPatternDim
        (33422, "B", 4, (0, 1, 1, 2), True),            # CFAPattern: R G / G B
        (50710, "B", 3, (0, 1, 2), True),               # CFAPlaneColor
        (50711, "H", 1, 1, True),                       # CFALayout: rectangular
        (50714, "H", 1, int(black), True),              # BlackLevel
        (50717, "H", 1, int(white), True),              # WhiteLevel
        (50721, "2i", 9, (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1), True),
        (50778, "H", 1, 21, True),                      # CalibrationIlluminant1: D65
        (50728, "2I", 3, (1, 1, 1, 1, 1, 1), True),     # AsShotNeutral
        (33434, "2I", 1, (t_num, t_den), True),         # ExposureTime
        (33437, "2I", 1, (round(10 * ex["f_number"]), 10), True),   # FNumber
        (34855, "H", 1, int(ex["iso"]), True),          # ISOSpeedRatings
    ]
    p = Path(path)
    with atomic_path(p) as tmp:
        tifffile.imwrite(tmp, mosaic, photometric=32803, compression=None, subfiletype=0,
                         extratags=tags, metadata=None)
    return p


def write_photo(path: str | os.PathLike, photo: SyntheticPhoto,
                extra: dict[str, Any] | None = None) -> tuple[Path, Path]:
    """Write the photo (format from the suffix) and its ``.truth.json`` sidecar atomically.

    Parameters
    ----------
    path : path-like
        ``.png``, ``.jpg``/``.jpeg``, ``.tif``/``.tiff`` (sRGB-encoded, 8/16 bit RGB) or
        ``.exr`` (linear float R, G, B) or ``.dng`` (a raw file: :func:`write_dng`).
    photo : SyntheticPhoto
        From :func:`render_photo`.
    extra : dict, optional
        More entries for the sidecar (e.g. the simulation's path).

    Returns
    -------
    tuple of Path
        The photo and the sidecar.

    Raises
    ------
    InputError
        Unknown suffix, or a 16-bit JPEG.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in PHOTO_SUFFIXES:
        raise InputError(f"photo output must end in one of {', '.join(PHOTO_SUFFIXES)}, "
                         f"got {p.name}")
    bits = photo.settings.bits
    if suffix in (".jpg", ".jpeg") and bits != 8:
        raise InputError("JPEG photos are 8-bit; use --bits 8 or write PNG/TIFF")
    if suffix == ".dng":
        write_dng(p, photo.linear)
    elif suffix == ".exr":
        lin = photo.linear.astype(np.float32)
        write_exr(p, {"R": lin, "G": lin, "B": lin}, {"units": "relative (1 = full scale)"})
    else:
        codes = _quantise(photo.encoded, bits)
        if suffix == ".png" and bits == 16:
            write_png16(p, codes)
        else:
            _write_raster(p, codes, suffix)
    truth = photo.truth()
    truth["photo"] = p.name
    truth.update(extra or {})
    side = truth_path(p)
    write_json(side, truth)
    return p, side


MARKER_MIN_PX = 44.0
"""Marker edge (photo px) from which OpenCV's ArUco detector finds every marker of the
default board on a synthetic photo blurred by σ = 1 px with 0.5 % noise (4×4 cells plus
the border: about 7 px a cell)."""


def marker_scale(frame: Any, size_deg: float = DEFAULT_LAYOUT.size_deg,
                 min_px: float = MARKER_MIN_PX) -> float:
    """The least whole magnification (photo px per simulation px, ≥ 1) at which a marker
    ``size_deg`` wide spans ``min_px`` photo pixels on a wall of this frame."""
    wf = WallFrame.from_any(frame)
    h = wf.h_deg()
    px_per_deg = (len(h) - 1) / max(float(np.ptp(h)), 1e-9)
    return float(max(1.0, math.ceil(min_px / (size_deg * px_per_deg) - 1e-9)))


def photograph_simulation(sim: Simulation, path: str | os.PathLike, cam: CameraSettings,
                          reaim_deg: tuple[float, float] | None = None, markers: bool = False,
                          wall_texture: int | None = None, ambient_lx: float = 0.5
                          ) -> tuple[Path, Path, SyntheticPhoto]:
    """Photograph a simulation's wall (:func:`render_photo`) and write the photo and its
    truth (:func:`write_photo`).

    Parameters
    ----------
    sim : Simulation
        The simulated wall (:func:`lightsim.validation.photo_io.load_simulation`).
    path : path-like
        The photo (format from the suffix).
    cam : CameraSettings
        The camera (module table).
    reaim_deg : (float, float), optional
        Turn the lamp by (ΔH right, ΔV up) degrees first: a lamp aimed off.
    markers : bool
        Put the default screen-target marker board on the wall (:func:`screen_scene`, a
        4× finer wall grid; the camera's ``scale`` stays in simulation px).
    wall_texture : int, optional
        Seed of a static wall texture (random grey rectangles).
    ambient_lx : float
        Room light on the wall with markers or a texture, in lx.

    Returns
    -------
    photo, sidecar : Path
        The files written.
    shot : SyntheticPhoto
        The photo; ``shot.matrix`` maps photo px to the simulation's px.
    """
    lux, extra = sim.lux, {"simulation": sim.source}
    cam.check()
    if cam.scale is None:  # the default camera: 1, or close enough for the markers
        scale = marker_scale(sim.frame) if markers else 1.0
        size = cam.size or (None if not markers else (
            round(sim.lux.shape[1] * scale), round(sim.lux.shape[0] * scale)))
        cam = replace(cam, scale=scale, size=size)
    if reaim_deg is not None:
        lux = apply_shift(np.nan_to_num(lux), sim.frame, reaim_deg[0], reaim_deg[1])
        extra["reaim_deg"] = {"dh": reaim_deg[0], "dv": reaim_deg[1]}
    to_sim = None
    if markers or wall_texture is not None:
        lux, _, to_sim = screen_scene(lux, sim.frame, layout=None if markers else False,
                                      ambient_lx=ambient_lx, texture_seed=wall_texture)
        extra["screen"] = {"markers": "default layout" if markers else None,
                           "wall_texture_seed": wall_texture, "ambient_lx": ambient_lx}
        # the camera's scale and default size stay in simulation px on the 4× finer grid
        cam = replace(cam, size=cam.size or (sim.lux.shape[1], sim.lux.shape[0]),
                      scale=cam.scale / 4)
    shot = render_photo(lux, cam)
    if to_sim is not None:
        m = to_sim @ shot.matrix
        shot = replace(shot, matrix=m / m[2, 2])
    photo, side = write_photo(path, shot, extra)
    return photo, side, shot
