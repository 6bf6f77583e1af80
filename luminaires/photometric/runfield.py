"""The intensity distribution a run measured, over the whole sphere, as one fine table.

A far-field file (``--ies``, ``--ldt``) is written from the run's own photons where the
run has them and from a far-field trace (the lamp without its wall) elsewhere:

1. **Beam bins** — inside the Imax raster of the run's detector apertures
   (:mod:`lightsim.engine.apertures`; a rule set's, or the one
   :func:`beam_raster_config` adds when no rule set asked for apertures) every interleave
   set counted the wall photons in bins of ``aperture`` × ``aperture / substeps`` degrees
   (0.15° × 0.03° by default): the flux per bin over its solid angle is the bin's mean
   intensity (cd), unbiased and unblurred. The bins' values are *histopolated*: node
   values on the half-bin lattice whose bilinear interpolant has exactly the bins' means
   and no negative value (:func:`histopolate`), so a file holding these nodes gives every
   bin, and every aperture made of bins, its measured value back, and keeps the flux.
2. **The wall map** — elsewhere on the wall the run's written lux map, as intensity
   ``I = E·r³/D`` towards each pixel centre (:meth:`lightsim.wall.WallFrame.sample`).
3. **The far field** — every other direction from the far-field trace, binned on a
   ``FAR_STEP_DEG`` Type C grid (:func:`~.farfield.farfield_from_photons`).

The three are sampled on the union of their own node angles, as a Type C
:class:`~.candela.CandelaGrid` over the whole sphere (:class:`RunField`); files are made
from it by :mod:`~.gridding`. Angles: Type A H (right), V (up) of a direction are the Type
C plane and elevation, C = −H mod 360°, γ = 90° + V (``docs/reference/conventions.md``).

Parameters
----------
====================  =====  ================  ==============================================
name                  unit   default           meaning
====================  =====  ================  ==============================================
BEAM_RASTER_DEG       deg    (−20, 20, −6, 4)  H lo, H hi, V lo, V hi of the bins added when
                                               no rule set measures the beam (a rule set's
                                               Imax raster is the same region)
BEAM_APERTURE_DEG     deg    0.15              their column width
BEAM_SUBSTEPS         1      5                 bins per column width in V (0.03° bins)
FAR_STEP_DEG          deg    1.0               far-field trace's grid step
====================  =====  ================  ==============================================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lightsim.engine.apertures import layout_from_config, raster_tiles, rect_solid_angle
from lightsim.render.frame import luminous

from .candela import CandelaGrid, directions_from_angles
from .farfield import farfield_from_photons

__all__ = ["BEAM_APERTURE_DEG", "BEAM_RASTER_DEG", "BEAM_SUBSTEPS", "FAR_STEP_DEG",
           "BeamBins", "RunField", "beam_bins", "beam_raster_config", "bin_averages",
           "histopolate", "run_field", "wall_points"]

BEAM_RASTER_DEG = (-20.0, 20.0, -6.0, 4.0)
"""Beam region (H lo, H hi, V lo, V hi in deg) counted in bins when no rule set does."""
BEAM_APERTURE_DEG = 0.15
"""Column width (deg) of those bins: a rule set's default aperture."""
BEAM_SUBSTEPS = 5
"""Bins per column width in V: a cut-off rises within a few hundredths of a degree."""
FAR_STEP_DEG = 1.0
"""Grid step (deg) of the far-field trace outside the wall."""
ANGLE_DECIMALS = 4
"""Decimals (deg) the table's angles are rounded to."""


def beam_raster_config(config: Any, frame: Any) -> Any:
    """``config`` with the beam bins a far-field file needs (before the run).

    A rule set that counts its test points in apertures already tiles the beam (its Imax
    raster): its layout is kept as it is, so its table stays the same. Without one, one
    aperture at H-V and a raster over :data:`BEAM_RASTER_DEG` (within the wall) are added;
    a rule set measured by kNN (``--aperture 0``) finds fewer apertures than its points
    and stays with kNN.
    """
    if config.apertures or config.aperture_raster is not None:
        return config
    h0, h1, v0, v1 = frame.extent_deg()
    r = BEAM_RASTER_DEG
    raster = (max(r[0], h0), min(r[1], h1), max(r[2], v0), min(r[3], v1))
    if raster[1] - raster[0] < BEAM_APERTURE_DEG or raster[3] - raster[2] < BEAM_APERTURE_DEG:
        return config
    return config.with_(apertures=((0.0, 0.0),), aperture_deg=BEAM_APERTURE_DEG,
                        aperture_shift_deg=0.0, aperture_substeps=BEAM_SUBSTEPS,
                        aperture_raster=raster)


@dataclass(frozen=True)
class BeamBins:
    """The run's beam bins (see the module docstring).

    Attributes
    ----------
    h_deg : ndarray, shape (nc,)
        Column centres, wall angle atan(h/D) from the wall centre (deg), equally spaced.
    v_deg : ndarray, shape (nb,)
        Bin centres, atan(v/D) (deg), equally spaced.
    cd : ndarray, shape (nc, nb)
        Mean intensity of every bin (cd), over the sets.
    nodes : ndarray, shape (2nc + 1, 2nb + 1)
        Histopolated node values (cd) on the half-bin lattice (:func:`histopolate`).
    tiles : ndarray, shape (S, nc, nt)
        Every set's aperture-sized tiles (cd): the run's Imax candidates.
    tile_v_deg : ndarray, shape (nt,)
        Tile centres in V (deg).
    width_deg, height_deg : float
        Bin size (deg).
    photon_cd : float
        One average photon's worth in a bin (cd): the run's resolution in intensity.
    """

    h_deg: NDArray
    v_deg: NDArray
    cd: NDArray
    nodes: NDArray
    tiles: NDArray
    tile_v_deg: NDArray
    width_deg: float
    height_deg: float
    photon_cd: float

    @property
    def node_h_deg(self) -> NDArray:
        """H of the half-bin lattice (deg): bin edges and centres."""
        return self.h_deg[0] - 0.5 * self.width_deg + 0.5 * self.width_deg * np.arange(
            2 * len(self.h_deg) + 1)

    @property
    def node_v_deg(self) -> NDArray:
        """V of the half-bin lattice (deg)."""
        return self.v_deg[0] - 0.5 * self.height_deg + 0.5 * self.height_deg * np.arange(
            2 * len(self.v_deg) + 1)


def beam_bins(session: Any) -> BeamBins | None:
    """The beam bins of a finished session, or None when the run counted none."""
    cfg = session.config
    if not cfg.apertures or cfg.aperture_raster is None:
        return None
    layout = layout_from_config(cfg, session.scene.wall.distance_m)
    cols, nb = layout.raster_columns()
    if len(cols) < 2 or nb < 2:
        return None
    stats = session.backend.stats()
    sets = sorted(stats)
    per_set = session.backend.apertures()
    counts = np.stack([per_set[s] for s in sets])
    emitted = np.array([stats[s]["emitted"] for s in sets], dtype=np.float64)
    first = len(layout) * layout.n_bins
    flux = counts[:, first:first + len(cols) * nb, :-1].reshape(len(sets), len(cols), nb, -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        flux = np.where(emitted[:, None, None, None] > 0,
                        flux / emitted[:, None, None, None], 0.0)
    step = layout.step_deg
    a = 0.5 * layout.size_deg
    v = layout.raster[2] + (np.arange(nb) + 0.5) * step
    omega = rect_solid_angle(cols[:, None] - a, cols[:, None] + a, v[None, :] - 0.5 * step,
                             v[None, :] + 0.5 * step)
    cd = luminous(flux).mean(axis=0) / omega
    tiles = raster_tiles(counts, emitted, layout)
    power = np.stack([stats[s]["emitted_power"] for s in sets])
    photon_lm = float(np.mean(luminous(power) / np.maximum(emitted, 1.0) ** 2)) / len(sets)
    return BeamBins(cols, v, cd, histopolate(cd), luminous(tiles.values), tiles.v_deg,
                    float(layout.size_deg), float(step), photon_lm / float(omega.mean()))


def histopolate(means: NDArray) -> NDArray:
    """Node values on the half-bin lattice of equal bins whose bilinear interpolant has
    exactly the bins' ``means`` as its bin averages, never negative.

    Bin (i, j) of an (n, m) array has nodes at its centre (2i+1, 2j+1), its edge
    midpoints and its corners in the (2n+1, 2m+1) result. Edge and corner nodes start as
    the mean of the bins that share them; a bin whose edges and corners would carry more
    than its own mean (``Σ edges/8 + Σ corners/16 > mean``: next to a brighter bin) scales
    them down to fit, a shared node taking the smallest scale of its bins, so one pass
    fits every bin. The centre node takes the rest:
    ``centre = 4·(mean − Σ edges/8 − Σ corners/16) ≥ 0``. Smooth regions get a smooth
    surface; a dim bin beside a bright one rises towards it (a cut-off inside a bin); a bin
    that counted nothing stays dark; the flux is each bin's own.
    """
    t = np.asarray(means, dtype=np.float64)
    n, m = t.shape
    pad = np.pad(t, 1, mode="edge")  # beyond the last bin: the bin itself
    out = np.zeros((2 * n + 1, 2 * m + 1))
    out[::2, 1::2] = 0.5 * (pad[:-1, 1:-1] + pad[1:, 1:-1])       # edges across H
    out[1::2, ::2] = 0.5 * (pad[1:-1, :-1] + pad[1:-1, 1:])       # edges across V
    out[::2, ::2] = 0.25 * (pad[:-1, :-1] + pad[1:, :-1] + pad[:-1, 1:] + pad[1:, 1:])
    rim = _rim(out)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(rim > t, t / rim, 1.0)
    f = np.pad(scale, 1, constant_values=1.0)
    out[::2, 1::2] *= np.minimum(f[:-1, 1:-1], f[1:, 1:-1])
    out[1::2, ::2] *= np.minimum(f[1:-1, :-1], f[1:-1, 1:])
    out[::2, ::2] *= np.minimum(np.minimum(f[:-1, :-1], f[1:, :-1]),
                                np.minimum(f[:-1, 1:], f[1:, 1:]))
    out[1::2, 1::2] = np.maximum(4.0 * (t - _rim(out)), 0.0)
    return out


def _rim(nodes: NDArray) -> NDArray:
    """Σ edges/8 + Σ corners/16 of every bin: its average without its centre node."""
    q = nodes
    return ((q[:-2:2, 1::2] + q[2::2, 1::2] + q[1::2, :-2:2] + q[1::2, 2::2]) / 8.0
            + (q[:-2:2, :-2:2] + q[2::2, :-2:2] + q[:-2:2, 2::2] + q[2::2, 2::2]) / 16.0)


def bin_averages(nodes: NDArray) -> NDArray:
    """Average over every bin of the bilinear interpolant of half-bin-lattice ``nodes``
    (the inverse of :func:`histopolate`): weights 1/4 centre, 1/8 edges, 1/16 corners."""
    q = np.asarray(nodes, dtype=np.float64)
    return q[1::2, 1::2] / 4.0 + _rim(q)


def wall_points(frame: Any, directions: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Where directions from the lamp (at the origin) meet the wall plane.

    Returns
    -------
    h, v : ndarray
        Wall coordinates (m) from the wall centre (NaN where the ray misses the plane).
    hits : ndarray of bool
        The ray meets the plane in front of the lamp.
    """
    d = np.asarray(directions, dtype=np.float64)
    normal = np.asarray(frame.normal, dtype=np.float64)
    centre = np.asarray(frame.centre, dtype=np.float64)
    denom = d @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = float(centre @ normal) / denom
        hits = np.isfinite(t) & (t > 0)
        p = np.where(hits[..., None], np.where(hits, t, 0.0)[..., None] * d, np.nan)
    h, v = frame.to_hv(p)
    return h, v, hits


@dataclass(frozen=True)
class RunField:
    """The run's intensity over the sphere (see the module docstring).

    Attributes
    ----------
    grid : CandelaGrid
        Type C table on the union of the sources' node angles (cd).
    source : ndarray of int8, shape (nC, nG)
        Where each node's value came from: 0 far field, 1 wall map, 2 beam bins.
    bins : BeamBins or None
        The beam bins (None when the run counted none).
    floor_cd : float
        Intensity below which differences are noise at the run's photon count (cd):
        one photon's worth in a beam bin, else in a far-field cell.
    """

    grid: CandelaGrid
    source: NDArray
    bins: BeamBins | None
    floor_cd: float


def _bilinear(x: NDArray, y: NDArray, values: NDArray, xq: NDArray, yq: NDArray) -> NDArray:
    """Bilinear interpolation on a grid of equally spaced nodes (queries inside it)."""
    fx = np.clip((xq - x[0]) / (x[1] - x[0]), 0.0, len(x) - 1.0)
    fy = np.clip((yq - y[0]) / (y[1] - y[0]), 0.0, len(y) - 1.0)
    i = np.minimum(fx.astype(np.int64), len(x) - 2)
    j = np.minimum(fy.astype(np.int64), len(y) - 2)
    s, t = fx - i, fy - j
    return ((values[i, j] * (1 - t) + values[i, j + 1] * t) * (1 - s)
            + (values[i + 1, j] * (1 - t) + values[i + 1, j + 1] * t) * s)


def _axis(nodes: NDArray, lo: float, hi: float, inner: NDArray) -> NDArray:
    """``nodes`` outside [lo, hi] and ``inner`` inside it, sorted and unique."""
    keep = nodes[(nodes < lo) | (nodes > hi)]
    return np.unique(np.round(np.concatenate([keep, inner]), 9))


def run_field(frame: Any, lux: NDArray, bins: BeamBins | None, directions: NDArray,
              power_lm: NDArray, photons: int) -> RunField:
    """The run's intensity over the sphere as one Type C table (module docstring).

    Parameters
    ----------
    frame : WallFrame
        The run's wall.
    lux : ndarray, shape (H, W)
        The run's luminous wall map (lx).
    bins : BeamBins or None
        The run's beam bins (:func:`beam_bins`).
    directions, power_lm : ndarray, shapes (n, 3), (n,)
        The far-field trace's escaping photons (world directions; lm each).
    photons : int
        Photons of the far-field trace.
    """
    far, far_err = farfield_from_photons(directions, power_lm, photons, dc_deg=FAR_STEP_DEG,
                                         dgamma_deg=FAR_STEP_DEG, return_error=True)
    h_far = -np.concatenate([far.c_deg[far.c_deg <= 180.0], far.c_deg[far.c_deg > 180.0]
                             - 360.0])  # H of the far-field planes, in (−180, 180]
    v_far = far.gamma_deg - 90.0
    # the wall's span in H, V (deg): its corners and edge midpoints seen from the lamp
    hs = np.linspace(*frame.h_range_m, 9)
    vs = np.linspace(*frame.v_range_m, 9)
    edge = np.concatenate([frame.to_world(hs, np.full(9, v)) for v in frame.v_range_m]
                          + [frame.to_world(np.full(9, h), vs) for h in frame.h_range_m])
    e_h = np.degrees(np.arctan2(-edge[:, 0], edge[:, 2]))
    e_v = np.degrees(np.arctan2(edge[:, 1], np.hypot(edge[:, 0], edge[:, 2])))
    h_map = frame.h_deg()
    v_map = frame.v_deg()[::-1]
    h_axis = _axis(h_far, e_h.min(), e_h.max(), h_map)
    v_axis = _axis(v_far, e_v.min(), e_v.max(), v_map)
    if bins is not None:
        hn, vn = bins.node_h_deg, bins.node_v_deg
        h_axis = _axis(h_axis, hn[0], hn[-1], hn)
        v_axis = _axis(v_axis, vn[0], vn[-1], vn)
    # angles to 0.0001° (files write 7 digits): no two nodes closer than that
    h_axis = np.concatenate([h_axis[(h_axis > -180.0) & (h_axis <= 180.0)],
                             [-90.0, 0.0, 90.0, 180.0]])
    c_deg = np.unique(np.round((-h_axis) % 360.0, ANGLE_DECIMALS) % 360.0)
    gamma = np.unique(np.clip(np.round(np.concatenate([v_axis + 90.0, [0.0, 90.0, 180.0]]),
                                       ANGLE_DECIMALS), 0.0, 180.0))
    cc, gg = np.meshgrid(c_deg, gamma, indexing="ij")
    d = directions_from_angles(cc, gg)
    cd = far.intensity_towards(d)
    source = np.zeros(cc.shape, dtype=np.int8)
    h, v, hits = wall_points(frame, d)
    hd, vd = frame.degrees(np.where(hits, h, 0.0), np.where(hits, v, 0.0))
    on_map = frame.sample(lux, hd, vd)
    on_map = np.where(hits, on_map, np.nan)
    ok = np.isfinite(on_map)
    cd = np.where(ok, np.maximum(on_map, 0.0), cd)
    source[ok] = 1
    photon_far = float(np.max(far_err)) if far_err.size else 0.0
    floor = photon_far
    if bins is not None:
        dist = float(frame.distance_m)
        hb = np.degrees(np.arctan2(h, dist))
        vb = np.degrees(np.arctan2(v, dist))
        hn, vn = bins.node_h_deg, bins.node_v_deg
        inside = hits & (hb >= hn[0]) & (hb <= hn[-1]) & (vb >= vn[0]) & (vb <= vn[-1])
        cd[inside] = _bilinear(hn, vn, bins.nodes, hb[inside], vb[inside])
        source[inside] = 2
        floor = bins.photon_cd
    meta = {"test": f"lightsim simulation: wall photons of the run, far field of "
                    f"{photons} photons"}
    return RunField(CandelaGrid(c_deg, gamma, cd, None, meta), source, bins, floor)
