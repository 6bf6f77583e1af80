"""The estimate side of a client: illuminance of one interleave set from its photons.

Estimators (``RunConfig.estimator``, ``bandwidth``): ``knn`` — the k nearest photons
within [r_min, r_max] (paper section 5); with ``bandwidth=ici`` the written map instead
reads square windows of the half-pixel lattice (:mod:`lightsim.render.ici`); ``radius``
— one fixed radius (the IGI baseline); ``bin`` — photons counted per pixel. Two
modes: ``interleaved`` (each set its own pixels, box-filtered on the server: the radius
of the n × n filter window) and ``pooled`` (every set every pixel: the pixel's radius).

=====================  =====  ===========  ============================================
parameter              unit   default      meaning
=====================  =====  ===========  ============================================
``r_min`` (pooled)     m      √(A_px/π)    disk with the area of one pixel
``r_min`` (interl.)    m      √(n²A_px/π)  disk with the area of the n × n filter window
``r_max``              m      4 / 2 r_min  pooled / interleaved (``max_radius`` overrides)
``k``                  –      64           photons per kNN estimate of every set
=====================  =====  ===========  ============================================

Every estimate divides photon power by the set's emitted photons and an area in one
place, :func:`normalise_flux` (the ledger too: :meth:`Session.energy`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lightsim.engine.config import MAX_RADIUS_FACTOR, RunConfig
from lightsim.engine.photonset import SetState
from lightsim.engine.pointstore import PointSpec, floor_holds
from lightsim.engine.results import RenderRequest, SetFrame
from lightsim.render import ici
from lightsim.render.camera import eye_hits
from lightsim.render.ici import WindowGeometry, pixel_of
from lightsim.render.interleave import InterleavePattern
from lightsim.scene import Scene, WallFrame


def normalise_flux(power: np.ndarray, emitted: int, *area_m2: Any) -> np.ndarray:
    """Photon power sums → per emitted photon (lm) and per area (lx): the one place where
    flux is normalised.

    Every photon carries the whole emitted flux (lm), so a sum over photons divided by
    the photons emitted is lm, and divided further by the area factors (m², or
    per-query arrays, multiplied in the order given) it is lx.
    """
    denominator = emitted
    for a in area_m2:
        denominator = denominator * a
    return power / denominator


def default_min_radius(config: RunConfig, frame: WallFrame, mode: str | None = None) -> float:
    """Radius (m) of a disk with the area of one pixel (pooled) or of the n×n filter window
    (interleaved) on the wall."""
    dh, dv = frame.pixel_size_m
    n = 1 if (mode or config.final) == "pooled" else config.filter_n
    return math.sqrt(n * n * dh * dv / math.pi)


def effective_radii(config: RunConfig, frame: WallFrame, mode: str | None = None
                    ) -> tuple[float, float]:
    """(min, max) density-estimation radius in m for ``mode`` (default: the final image's)
    after applying the automatic defaults."""
    mode = mode or config.final
    r_min = (config.min_radius if config.min_radius is not None
             else default_min_radius(config, frame, mode))
    factor = MAX_RADIUS_FACTOR["pooled" if mode == "pooled" else "interleaved"]
    r_max = config.max_radius if config.max_radius is not None else factor * r_min
    return r_min, max(r_max, r_min)


def set_k(config: RunConfig) -> int:
    """Photons per kNN estimate of one set (k in both modes).

    Pooling M² sets with ⌈k/M²⌉ photons each would rest on about k photons, but a kNN
    estimate with few photons is biased by the treatment of the k-th one (±1/(2k)), so
    every set keeps the full k; the radius bounds keep the blur in check.
    """
    return config.k


def scene_scale(scene: Scene) -> float:
    """The largest |coordinate| (m) of the scene's surfaces and wall: no photon record
    lies farther out, so it bounds every photon map's radius floor."""
    return max((float(np.abs(p.vertices).max()) for p in scene.surfaces
                if len(p.vertices)), default=1.0)


def point_spec(config: RunConfig, frame: WallFrame, probes_hv: np.ndarray,
               scale_m: float) -> PointSpec | None:
    """The fixed points (the probes: wall h, v in m) where the sets accumulate their kNN
    estimates frame by frame instead of keeping every photon
    (:mod:`lightsim.engine.pointstore`), or None where the photons are kept: asked for
    (``keep_photons``), or read elsewhere than at points (the written map of the ``knn``
    bandwidth, of ``final="interleaved"``, of the ``radius`` and ``bin`` estimators), or
    a radius floor below the photon map's own (``scale_m``: the largest coordinate of the
    scene, m). The error grid's probes come first in ``probes_hv`` and are not among the
    points: the ICI figure reads the lattice, not their kNN estimates."""
    if config.keep_photons or not config.uses_ici or config.final != "pooled":
        return None  # the written map reads the photons at every pixel
    r_min, r_max = effective_radii(config, frame, config.final)
    if not floor_holds(r_min, scale_m):
        return None
    grid = int(np.prod(config.probe_grid))
    hv = np.asarray(probes_hv, dtype=np.float64).reshape(-1, 2)[grid:]
    return PointSpec(frame.to_world(hv[:, 0], hv[:, 1]), np.asarray(frame.normal, float),
                     set_k(config), r_max, r_min, config.kernel)


class SetEstimator:
    """Estimates of the sets of one client at wall pixels, probes and camera pixels.

    Parameters
    ----------
    scene : Scene
        The client's scene (its wall frame; its geometry for camera views).
    caster : RayCaster
        The client's embree scene (camera rays).
    config : RunConfig
    channels : int
    probes_hv : (P, 2) array
        Wall coordinates (h, v in m) of the probe points every set estimates: the
        regular grid first (``config.probe_grid``), then any extra points.
    """

    def __init__(self, scene: Scene, caster, config: RunConfig, channels: int,
                 probes_hv: np.ndarray) -> None:
        self.scene, self.caster = scene, caster
        self.config = config
        self.channels = channels
        self.frame = scene.wall
        W, H = self.frame.resolution
        self.pattern = InterleavePattern(config.interleave, W, H)
        self.radii = {m: effective_radii(config, self.frame, m)
                      for m in ("pooled", "interleaved")}
        self.probes_hv = np.asarray(probes_hv, dtype=np.float64).reshape(-1, 2)
        self._probe_points = self.frame.to_world(self.probes_hv[:, 0], self.probes_hv[:, 1])
        nh, nv = (int(n) for n in config.probe_grid)
        grid = self.probes_hv[:min(nh * nv, len(self.probes_hv))]
        self._grid_pixels = pixel_of(self.frame, grid[:, 0], grid[:, 1])
        self._window_geometry: dict[str, tuple] = {}  # key → (sides, WindowGeometry)
        self._wall_queries: dict[Any, np.ndarray] = {}  # set (, step) → points
        self._camera_cache: dict[Any, tuple] = {}
        self._normal = np.broadcast_to(self.frame.normal, (1, 3))

    # -- one set at points ---------------------------------------------------------------
    def estimate(self, st: SetState, points: np.ndarray, normals: np.ndarray,
                 mode: str | None = None) -> np.ndarray:
        """Illuminance (lx) of one set at world points with the given surface normals.

        ``mode`` ``pooled`` (every set at every pixel) or ``interleaved`` (one set per
        pixel, box-filtered afterwards) picks the radii; default: the final image's.
        """
        if st.emitted == 0:
            return np.zeros((len(points), self.channels))
        if st.bins is not None:
            h, v = self.frame.to_hv(points)
            dh, dv = self.frame.pixel_size_m
            row, col = self.frame.pixel_index(h, v, clip=True)
            return normalise_flux(st.bins[row, col], st.emitted, dh, dv)
        if len(st.photonmap) == 0:  # no photon on the wall yet (or ever)
            return np.zeros((len(points), self.channels))
        mode = mode or self.config.final
        r_min, r_max = self.radii[mode]
        if self.config.estimator == "radius":  # the IGI baseline: one fixed radius
            radius, floor = r_min, 0.0
        else:
            radius, floor = r_max, r_min
        res = st.photonmap.estimate(
            points.astype(np.float32), normals.astype(np.float32), k=set_k(self.config),
            max_radius=radius, min_radius=floor, kernel=self.config.kernel)
        return normalise_flux(np.asarray(res.E, dtype=np.float64), st.emitted)

    def ici_rungs(self, st: SetState, rows: np.ndarray, cols: np.ndarray,
                  key: str | None = None, geometry: WindowGeometry | None = None
                  ) -> np.ndarray:
        """The set's rung estimates (lx) at pixels: (J+1, Q, C) (see
        :mod:`lightsim.render.ici`): rung 0 the pixel, then squares 2, 3, … pixels a side.
        ``key`` names a fixed query set (the grid probes): its window bounds are computed
        once, not once per set and frame; ``geometry``: those bounds, already made (every
        pixel: :func:`lightsim.render.ici.raster_queries`)."""
        sides = ici.rung_sides(self.frame.pixel_size_m, self.radii["pooled"][1])
        W, H = self.frame.resolution
        if st.emitted == 0 or st.lattice is None:
            return np.zeros((len(sides), len(rows), self.channels))
        dh, dv = self.frame.pixel_size_m
        if geometry is None and key is not None:
            cached = self._window_geometry.get(key)
            if cached is None or cached[0] != tuple(sides):
                cached = (tuple(sides), WindowGeometry.of(H, W, rows, cols, sides))
                self._window_geometry[key] = cached
            geometry = cached[1]
        sums, cells = ici.window_sums(st.lattice.reshape(2 * H, 2 * W, self.channels),
                                      rows, cols, sides, geometry)
        return normalise_flux(sums, st.emitted, np.maximum(cells, 1.0)[..., None],
                           0.25 * dh * dv)

    def window(self, st: SetState) -> np.ndarray | None:
        """(G, C) lx in the pixel windows at the grid probes (the blur-bias reference)."""
        if st.windows is None or not st.emitted:
            return None
        dh, dv = self.frame.pixel_size_m
        return normalise_flux(st.windows, st.emitted, dh, dv)

    # -- query points ----------------------------------------------------------------------
    def coarse(self, step: int = 1) -> tuple[WallFrame, InterleavePattern]:
        """The wall frame and interleave pattern of an image at every ``step``-th pixel
        (⌈W/step⌉ × ⌈H/step⌉ pixels over the same extent; step 1: the wall's own)."""
        if step <= 1:
            return self.frame, self.pattern
        W, H = self.frame.resolution
        frame = self.frame.with_resolution(-(-W // step), -(-H // step))
        return frame, InterleavePattern(self.config.interleave, *frame.resolution)

    def _wall_points(self, s: int, step: int = 1) -> np.ndarray:
        key = s if step <= 1 else (s, step)
        if key not in self._wall_queries:
            frame, pattern = self.coarse(step)
            rows, cols = pattern.set_pixels(s)
            h_all, v_all = frame.pixel_centres()
            hh, vv = np.meshgrid(h_all[cols], v_all[rows])
            self._wall_queries[key] = frame.to_world(hh, vv).reshape(-1, 3)
        return self._wall_queries[key]

    def _camera_queries(self, s: int, camera, n_owned: int
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Diffuse points seen by the camera's pixels of set s (cached per camera)."""
        key = (camera, s)
        if key not in self._camera_cache:
            if len(self._camera_cache) > 4 * n_owned:  # walkthrough: forget old views
                self._camera_cache.clear()
            W, H = camera.resolution
            pattern = InterleavePattern(self.config.interleave, W, H)
            rows, cols = pattern.set_pixels(s)
            o, d = camera.rays(rows, cols)
            pts, nrm, weight, part = eye_hits(self.scene, self.caster, o, d,
                                              camera.max_specular)
            self._camera_cache[key] = (pts, nrm, weight, part >= 0)
        return self._camera_cache[key]

    # -- a frame ----------------------------------------------------------------------------
    def full_rungs(self, st: SetState) -> np.ndarray:
        """The set's rungs (lx) at every pixel of the wall, (J+1, H, W, C) float32: the
        written map's part of a set (GIL-free but for small steps, so the sets of a
        client can be summed on threads: :meth:`Client.render`)."""
        W, H = self.frame.resolution
        sides = ici.rung_sides(self.frame.pixel_size_m, self.radii["pooled"][1])
        if st.emitted and st.lattice is not None:  # :meth:`ici_rungs`' numbers, one pass
            dh, dv = self.frame.pixel_size_m
            r = ici.raster_lux(st.lattice.reshape(2 * H, 2 * W, self.channels), sides,
                               st.emitted, 0.25 * dh * dv)
            return r.reshape((len(r), H, W, self.channels))
        rows, cols, geometry = ici.raster_queries(H, W, tuple(int(m) for m in sides))
        r = self.ici_rungs(st, rows, cols, geometry=geometry)
        return r.reshape((len(r), H, W, self.channels)).astype(np.float32)

    def probe_rungs(self, st: SetState) -> np.ndarray:
        """The set's rungs (lx) at the grid probes' pixels, (J+1, G, C): what the ICI error
        figure of a frame reads (:meth:`ici_rungs`)."""
        return self.ici_rungs(st, *self._grid_pixels, key="grid probes")

    def render(self, st: SetState, request: RenderRequest, n_owned: int = 1,
               full_rungs: np.ndarray | None = None,
               probe_rungs: np.ndarray | None = None) -> SetFrame:
        """What ``request`` asks of set ``st`` (see :class:`SetFrame`), float32
        (``full_rungs``, ``probe_rungs``: :meth:`full_rungs` and :meth:`probe_rungs` of
        this set, when already computed)."""
        s = st.index
        out = SetFrame(s)
        normal = self._normal
        if request.image:
            step = max(1, int(request.image_step))
            pts = self._wall_points(s, step)
            est = self.estimate(st, pts, np.broadcast_to(normal, pts.shape), "interleaved")
            out.sub_image = est.reshape((*self.coarse(step)[1].sub_shape(s), self.channels))
        if request.full_image and self.config.uses_ici:  # the server picks each rung
            out.full_rungs = self.full_rungs(st) if full_rungs is None else full_rungs
            if st.wall_moments is not None:  # the map's rung choice needs ΣΦ² (q)
                out.moments = st.wall_moments.copy()
        elif request.full_image:
            h_all, v_all = self.frame.pixel_centres()
            hh, vv = np.meshgrid(h_all, v_all)
            pts = self.frame.to_world(hh, vv).reshape(-1, 3)
            est = self.estimate(st, pts, np.broadcast_to(normal, pts.shape), "pooled")
            out.full_image = est.reshape((*hh.shape, self.channels))
        if request.error and self.config.uses_ici and st.wall_moments is not None:
            out.probe_rungs = self.probe_rungs(st) if probe_rungs is None else probe_rungs
            out.moments = st.wall_moments.copy()
        if request.camera is not None:
            camera = request.camera
            pts, nrm, weight, seen = self._camera_queries(s, camera, n_owned)
            W, H = camera.resolution
            shape = InterleavePattern(self.config.interleave, W, H).sub_shape(s)
            lum = np.zeros((len(pts), self.channels))
            # L = ρ E / π (cd/m²) where the pixel sees a diffuse surface, else black
            lum[seen] = weight[seen] * self.estimate(st, pts[seen], nrm[seen], "interleaved")
            out.camera = lum.reshape((*shape, self.channels))
        if request.probes and len(self._probe_points):
            out.probes = self.estimate(st, self._probe_points,
                                       np.broadcast_to(normal, self._probe_points.shape))
            if request.error:
                out.window = self.window(st)
        return out.for_wire()

    def probe(self, st: SetState, points_hv: np.ndarray) -> np.ndarray:
        """The set's illuminance (lx) at wall points (h, v in m): (P, C)."""
        hv = np.asarray(points_hv, dtype=np.float64).reshape(-1, 2)
        pts = self.frame.to_world(hv[:, 0], hv[:, 1])
        return self.estimate(st, pts, np.broadcast_to(self.frame.normal, pts.shape))
