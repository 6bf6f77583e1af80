"""A rendering client: owns interleave sets, their photons, photon maps and counters.

The paper's client (sections 3.3, 4.3, 5): every set (a, b) of the M×M interleave pattern
has its own photons — disjoint sample indices, its own scramble — and its own photon map,
and computes only its pixels (x mod M = a, y mod M = b) plus the shared probe points that
give the error estimate. A client holds any number of sets (static assignment); frames
*accumulate*: each frame adds photons to every set's map by incremental insertion.

A set's state is a pure function of (scene, config, seed, set index, frames shot), so a
lost client can be rebuilt by replaying its frames (:meth:`Client.replay`), and a run is
bit-identical however the sets are spread over clients.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.engine.plan import Plan
from lightsim.render.interleave import InterleavePattern
from lightsim.sampling import SelectiveSampler, digit_permutations, halton_points, photon_keys
from lightsim.scene import Scene, WallFrame
from lightsim.tracer import LEDGER, PhotonRecords, PhotonTracer


@dataclass
class SetState:
    """Accumulated state of one interleave set.

    Attributes
    ----------
    emitted : int
        Photons emitted so far, N_s (the estimate divides by it).
    next_index : int
        Next Halton index (plain sampling).
    ledger : (len(LEDGER), C) float64
        Bookkeeping, unnormalised (divide by ``emitted`` for lm).
    emitted_power : (C,) float64
        Sum of emitted photon powers (unnormalised).
    caustic : int
        Emitted photons whose path produced a caustic record (yield numerator).
    """

    index: int
    channels: int
    emitted: int = 0
    next_index: int = 0
    frames: int = 0
    caustic: int = 0
    records: int = 0
    ledger: np.ndarray = field(default=None)  # type: ignore[assignment]
    emitted_power: np.ndarray = field(default=None)  # type: ignore[assignment]
    sampler: SelectiveSampler | None = None
    photonmap: Any = None
    bins: np.ndarray | None = None
    windows: np.ndarray | None = None  # (G, C) power in the pixel window of each grid probe
    apertures: Any = None  # ApertureCounter of the run's detector apertures, if any
    aperture_hits: np.ndarray | None = None  # sources of this frame's target-aperture photons
    lattice: np.ndarray | None = None  # (2H·2W, C) power per half-pixel cell (ICI windows)
    wall_moments: np.ndarray | None = None  # ΣΦ (lm), ΣΦ² (lm²), count of wall photons

    def __post_init__(self) -> None:
        if self.ledger is None:
            self.ledger = np.zeros((len(LEDGER), self.channels))
        if self.emitted_power is None:
            self.emitted_power = np.zeros(self.channels)


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
    factor = 4.0 if mode == "pooled" else 2.0
    r_max = config.max_radius if config.max_radius is not None else factor * r_min
    return r_min, max(r_max, r_min)


def set_k(config: RunConfig, mode: str | None = None) -> int:
    """Photons per kNN estimate of one set (k in both modes).

    Pooling M² sets with ⌈k/M²⌉ photons each would rest on about k photons, but a kNN
    estimate with few photons is biased by the treatment of the k-th one (±1/(2k)), so
    every set keeps the full k; the radius bounds keep the blur in check.
    """
    return config.k


def apply_changes(scene: Scene, changes: list[tuple]) -> tuple[Scene, bool]:
    """Apply interaction changes to a scene: returns (new scene, geometry changed).

    Changes: ``("scene", Scene)``, ``("material", part, {"ior"|"reflectance"|"albedo"|
    "rgb"|"sigma": value})``, ``("transform", part, 4×4)``, ``("light", 4×4)`` (moves
    every emitter; emitters are not traced, so the embree scene stays).
    """
    from dataclasses import replace as dc_replace

    from lightsim.errors import InputError

    geometry = False
    for change in changes:
        kind = change[0]
        if kind == "scene":
            scene, geometry = change[1], True
        elif kind == "material":
            _, name, values = change
            part = next((p for p in scene.parts if p.name == name), None)
            if part is None:
                raise InputError(f"no part named '{name}'")
            kw: dict[str, Any] = {}
            if "ior" in values:
                kw["ior"] = float(values["ior"])
            for key in ("reflectance", "albedo", "rgb"):
                if key in values:
                    kw["rgb"] = np.broadcast_to(np.asarray(values[key], float), (3,)).copy()
            if "sigma" in values:
                kw["sigma"] = np.broadcast_to(np.asarray(values["sigma"], float), (3,)).copy()
            scene = scene.replace_part(name, material=dc_replace(part.material, **kw))
        elif kind == "transform":
            scene, geometry = scene.transform_part(change[1], change[2]), True
        elif kind == "light":
            for p in scene.emitters:
                scene = scene.transform_part(p.name, change[1])
        else:
            raise ValueError(f"unknown change {kind!r}")
    return scene, geometry


class Client:
    """Holds a group of interleave sets and computes their part of every frame.

    Parameters
    ----------
    scene : Scene
    config : RunConfig
    plan : Plan
        Which stages run (SPT, channels, recording, camera).
    set_indices : list of int
        The interleave sets this client owns (static assignment).
    probes_hv : (P, 2) array
        Wall coordinates (h, v in m) of the probe points every set estimates.
    """

    def __init__(self, scene: Scene, config: RunConfig, plan: Plan, set_indices: list[int],
                 probes_hv: np.ndarray) -> None:
        self.config = config
        self.plan = plan
        self.set_indices = list(set_indices)
        self.probes_hv = np.asarray(probes_hv, dtype=np.float64).reshape(-1, 2)
        self._set_scene(scene)
        self.reset()

    # -- scene and state ------------------------------------------------------------------
    def _set_scene(self, scene: Scene, caster=None) -> None:
        if self.plan.channels != scene.channels:
            scene = Scene(scene.parts, scene.wall, scene.source, scene.warnings,
                          self.plan.channels)
        self.scene = scene
        self.frame = scene.wall
        self.channels = self.plan.channels
        self.tracer = PhotonTracer(scene, max_depth=self.config.max_depth,
                                   record=self.plan.record, threads=self.config.threads,
                                   caster=caster)
        W, H = self.frame.resolution
        self.pattern = InterleavePattern(self.config.interleave, W, H)
        self._radii = {m: effective_radii(self.config, self.frame, m)
                       for m in ("pooled", "interleaved")}
        self._wall_queries: dict[int, np.ndarray] = {}
        self._wall_part_ids = np.flatnonzero([p.role == "wall" for p in scene.surfaces])
        self._probe_points = self.frame.to_world(self.probes_hv[:, 0], self.probes_hv[:, 1])
        self._grid_shape = tuple(int(n) for n in self.config.probe_grid)
        from lightsim.render.ici import pixel_of

        grid = self.probes_hv[:self._grid_count()]
        self._grid_pixels = pixel_of(self.frame, grid[:, 0], grid[:, 1])

    def reset(self) -> None:
        """Discard all photons (interaction mode: the next frame starts afresh)."""
        self.sets: dict[int, SetState] = {s: self._new_set(s) for s in self.set_indices}

    def _new_set(self, s: int) -> SetState:
        st = SetState(s, self.channels)
        if self.plan.spt or self.config.aperture_targets:
            share = None if self.plan.spt else self.config.aperture_spt_share
            st.sampler = SelectiveSampler(self.config.seed, s, refine_share=share,
                                          pass_photons=self.config.photons_per_set)
        if self.config.apertures:
            from lightsim.engine.apertures import counter_from_config

            st.apertures = counter_from_config(self.config, self.frame, self.channels)
        if self.config.estimator == "bin":
            W, H = self.frame.resolution
            st.bins = np.zeros((H, W, self.channels))
        else:
            st.photonmap = self._new_map()
            nh, nv = self._grid_shape
            st.windows = np.zeros((nh * nv, self.channels))
            st.wall_moments = np.zeros(3)
        return st

    def _new_map(self):
        from lightsim.photonmap.density import PhotonMap

        structure = "hash" if self.config.estimator == "radius" else self.config.structure
        return PhotonMap(structure=structure, channels=self.channels)

    def update(self, scene: Scene, geometry_changed: bool = True) -> None:
        """Interaction: a changed scene discards the accumulated photons.

        The embree scene is rebuilt only when geometry changed (materials alone reuse it).
        """
        caster = None if geometry_changed else self.tracer.caster
        self._set_scene(scene, caster)
        self.reset()

    def apply(self, changes: list[tuple]) -> None:
        """Apply interaction changes (see :func:`apply_changes`) and discard the photons."""
        scene, geometry = apply_changes(self.scene, changes)
        self.update(scene, geometry)

    # -- shooting ------------------------------------------------------------------------
    def frame_share(self, s: int, total: int | None) -> int:
        """Photons set ``s`` shoots in a frame of ``total`` photons over all sets (None: a
        full frame). A partial frame splits ``total`` exactly: every set gets
        ``total // n_sets``, the first ``total % n_sets`` sets one more."""
        full = self.config.photons_per_set
        if total is None:
            return full
        n_sets = self.config.n_sets
        return min(full, int(total) // n_sets + (1 if s < int(total) % n_sets else 0))

    def shoot(self, total: int | None = None) -> dict[str, float]:
        """Shoot one frame of photons for every owned set and insert them into the maps.

        ``total`` (photons over all sets) makes this a partial last frame (plain sampling;
        an SPT pass is always whole, since a cut pass would leave cells unsampled).
        """
        t0 = time.perf_counter()
        pts, keys, weights, groups, owners = [], [], [], [], []
        for g, s in enumerate(self.set_indices):
            st = self.sets[s]
            if st.sampler is not None:
                pass_index, idx, p, w = st.sampler.next_pass()
                # key space: pass 0 is plain sampling, SPT passes are 1, 2, ...
                k = photon_keys(self.config.seed, s, pass_index + 1, idx)
            else:
                n = self.frame_share(s, total)
                idx = np.arange(st.next_index, st.next_index + n, dtype=np.int64)
                p = halton_points(idx, self._perms(s))
                k = photon_keys(self.config.seed, s, 0, idx)
                w = None
                st.next_index += n
            pts.append(p)
            keys.append(k)
            weights.append(np.ones(len(idx)) if w is None else w)
            groups.append(np.full(len(idx), g, np.int64))
            owners.append(idx)
        points = np.concatenate(pts)
        group = np.concatenate(groups)
        res = self.tracer.trace_points(points, np.concatenate(keys), np.concatenate(weights),
                                       group=group, n_groups=len(self.set_indices))
        rec = res.records
        rec_group = group[rec.source] if len(rec) else np.zeros(0, np.int64)
        offsets = np.cumsum([0] + [len(o) for o in owners])
        for g, s in enumerate(self.set_indices):
            st = self.sets[s]
            lo, hi = offsets[g], offsets[g + 1]
            sel = np.flatnonzero(rec_group == g)
            # a stable order (photon index, then bounce) keeps maps identical across batching
            sel = sel[np.argsort(rec.source[sel], kind="stable")]
            part = PhotonRecords(rec.position[sel], rec.normal[sel], rec.power[sel],
                                 rec.part[sel], rec.flags[sel], rec.source[sel] - lo)
            self._insert(st, part)
            st.emitted += hi - lo
            st.frames += 1
            st.ledger += res.ledger[g]
            st.emitted_power += res.emitted[g]
            caustic = res.caustic_source[lo:hi]
            st.caustic += int(caustic.sum())
            st.records += len(part)
            if st.sampler is not None:
                trigger = caustic if self.plan.spt else np.zeros(hi - lo, np.bool_)
                if st.aperture_hits is not None:  # SPT aimed at test points
                    trigger = trigger.copy()
                    trigger[st.aperture_hits] = True
                st.sampler.update(owners[g], trigger)
        return {"photons": float(len(points)), "records": float(len(rec)),
                "rays": float(res.rays), "seconds": time.perf_counter() - t0}

    def _perms(self, s: int) -> np.ndarray:
        cache = self.__dict__.setdefault("_perm_cache", {})
        if s not in cache:
            cache[s] = digit_permutations(self.config.seed, s, None)
        return cache[s]

    def _insert(self, st: SetState, rec: PhotonRecords) -> None:
        if st.apertures is not None:  # detector apertures count every wall photon directly
            on_wall = np.isin(rec.part, self._wall_part_ids)
            h, v = self.frame.to_hv(rec.position[on_wall])
            hit = st.apertures.add(h, v, rec.power[on_wall])
            st.aperture_hits = rec.source[on_wall][hit]
        if st.bins is not None:
            W, H = self.frame.resolution
            h, v = self.frame.to_hv(rec.position)
            row, col = self.frame.pixel_index(h, v)
            ok = ((col >= 0) & (col < W) & (row >= 0) & (row < H)
                  & np.isin(rec.part, self._wall_part_ids))
            flat = row[ok] * W + col[ok]
            for c in range(self.channels):
                st.bins[..., c].reshape(-1)[:] += np.bincount(
                    flat, weights=rec.power[ok, c].astype(np.float64), minlength=W * H)
            return
        if len(rec):
            st.photonmap.add(rec.position, rec.normal, rec.power)
            self._add_to_windows(st, rec)
            self._keep_for_ici(st, rec)

    def _keep_for_ici(self, st: SetState, rec: PhotonRecords) -> None:
        """Add the wall photons to the set's half-pixel lattice (the ICI windows) and to
        ΣΦ, ΣΦ² (their standard errors)."""
        from lightsim.render import ici
        from lightsim.render.frame import luminous

        if not self.config.uses_ici:
            return
        on_wall = np.isin(rec.part, self._wall_part_ids)
        if not on_wall.any():
            return
        h, v = self.frame.to_hv(rec.position[on_wall])
        flat, ok = ici.lattice_index(h, v, self.frame)
        power = rec.power[on_wall][ok].astype(np.float64)
        W, H = self.frame.resolution
        if st.lattice is None:
            st.lattice = np.zeros((4 * H * W, self.channels))
        for c in range(self.channels):
            st.lattice[:, c] += np.bincount(flat[ok], weights=power[:, c],
                                            minlength=4 * H * W)
        lum = luminous(power)
        st.wall_moments += (float(lum.sum()), float((lum * lum).sum()), float(ok.sum()))

    def ici_rungs(self, st: SetState, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """The set's rung estimates (lx) at pixels: (J+1, Q, C) (see
        :mod:`lightsim.render.ici`): rung 0 the pixel, then squares 2, 3, … pixels a side."""
        from lightsim.render import ici

        sides = ici.rung_sides(self.frame.pixel_size_m, self._radii["pooled"][1])
        W, H = self.frame.resolution
        if st.emitted == 0 or st.lattice is None:
            return np.zeros((len(sides), len(rows), self.channels))
        dh, dv = self.frame.pixel_size_m
        sums, cells = ici.window_sums(st.lattice.reshape(2 * H, 2 * W, self.channels),
                                      rows, cols, sides)
        return sums / (st.emitted * np.maximum(cells, 1.0)[..., None] * (0.25 * dh * dv))

    def _add_to_windows(self, st: SetState, rec: PhotonRecords) -> None:
        """Add the wall photons to the pixel-sized windows centred on the grid probes.

        The probe grid (:func:`~lightsim.render.frame.probe_grid`) has cell pitch Δ; a
        window is one pixel (dh × dv, half-open) around a cell centre. Windows overlap only
        when pixels are coarser than the grid, hence the loop over neighbouring cells.
        """
        on_wall = np.isin(rec.part, self._wall_part_ids)
        if not on_wall.any():
            return
        h, v = self.frame.to_hv(rec.position[on_wall])
        power = rec.power[on_wall].astype(np.float64)
        (h0, h1), (v0, v1) = self.frame.h_range_m, self.frame.v_range_m
        nh, nv = self._grid_shape
        pitch_h, pitch_v = (h1 - h0) / nh, (v1 - v0) / nv
        dh, dv = self.frame.pixel_size_m
        uh, uv = (h - h0) / pitch_h - 0.5, (v - v0) / pitch_v - 0.5  # in cell-centre units
        reach_h, reach_v = 0.5 * dh / pitch_h, 0.5 * dv / pitch_v
        for i in range(int(np.floor(-reach_h)), int(np.ceil(reach_h)) + 1):
            ci = np.round(uh).astype(np.int64) + i
            oh = (uh - ci) * pitch_h  # offset from the window centre (m), half-open
            in_h = (ci >= 0) & (ci < nh) & (oh >= -0.5 * dh) & (oh < 0.5 * dh)
            for j in range(int(np.floor(-reach_v)), int(np.ceil(reach_v)) + 1):
                cj = np.round(uv).astype(np.int64) + j
                ov = (uv - cj) * pitch_v
                ok = in_h & (cj >= 0) & (cj < nv) & (ov >= -0.5 * dv) & (ov < 0.5 * dv)
                if ok.any():
                    flat = cj[ok] * nh + ci[ok]
                    for c in range(self.channels):
                        st.windows[:, c] += np.bincount(flat, weights=power[ok, c],
                                                        minlength=nh * nv)

    # -- estimates -----------------------------------------------------------------------
    def _estimate(self, st: SetState, points: np.ndarray, normals: np.ndarray,
                  mode: str | None = None) -> np.ndarray:
        """Illuminance (lx) of one set at world points with the given surface normals.

        ``mode`` ``pooled`` (every set at every pixel) or ``interleaved`` (one set per
        pixel, box-filtered afterwards) picks the radii and k; default: the final image's.
        """
        if st.emitted == 0:
            return np.zeros((len(points), self.channels))
        if st.bins is not None:
            h, v = self.frame.to_hv(points)
            dh, dv = self.frame.pixel_size_m
            row, col = self.frame.pixel_index(h, v, clip=True)
            return st.bins[row, col] / (st.emitted * dh * dv)
        if len(st.photonmap) == 0:  # no photon on the wall yet (or ever)
            return np.zeros((len(points), self.channels))
        mode = mode or self.config.final
        r_min, r_max = self._radii[mode]
        if self.config.estimator == "radius":  # the IGI baseline: one fixed radius
            radius, floor = r_min, 0.0
        else:
            radius, floor = r_max, r_min
        res = st.photonmap.estimate(points.astype(np.float32), normals.astype(np.float32),
                                    k=set_k(self.config, mode), max_radius=radius,
                                    min_radius=floor, kernel=self.config.kernel)
        return np.asarray(res.E, dtype=np.float64) / st.emitted

    def _wall_points(self, s: int) -> np.ndarray:
        if s not in self._wall_queries:
            rows, cols = self.pattern.set_pixels(s)
            h_all, v_all = self.frame.pixel_centres()
            hh, vv = np.meshgrid(h_all[cols], v_all[rows])
            self._wall_queries[s] = self.frame.to_world(hh, vv).reshape(-1, 3)
        return self._wall_queries[s]

    def _camera_queries(self, s: int, camera
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Diffuse points seen by the camera's pixels of set s (cached per camera)."""
        from lightsim.render.camera import eye_hits

        cache = self.__dict__.setdefault("_camera_cache", {})
        key = (camera, s)
        if key not in cache:
            if len(cache) > 4 * len(self.set_indices):  # walkthrough: forget old views
                cache.clear()
            W, H = camera.resolution
            pattern = InterleavePattern(self.config.interleave, W, H)
            rows, cols = pattern.set_pixels(s)
            o, d = camera.rays(rows, cols)
            pts, nrm, weight, part = eye_hits(self.scene, self.tracer.caster, o, d,
                                              camera.max_specular)
            cache[key] = (pts, nrm, weight, part >= 0)
        return cache[key]

    def render(self, image: bool = True, probes: bool = True, full_image: bool = False,
               camera=None) -> dict[str, Any]:
        """Estimates of every owned set.

        Returns
        -------
        dict with ``sub_images`` {set: (rows, cols, C) lux} (interleaved pixels only),
        ``full_images`` {set: (H, W, C) lux} (every pixel, with ``full_image``),
        ``camera_sub_images`` {set: (rows, cols, C) cd/m²} (with ``camera``),
        ``probes`` {set: (P, C) lux}, ``windows`` {set: (G, C) lux} (pixel-window counts at
        the grid probes, for the blur-bias estimate), ``seconds``. ``probes="ici"``: only
        the ICI rungs at the grid probes (the consistent estimator's error figure), no
        kNN probe estimates.
        """
        t0 = time.perf_counter()
        out: dict[str, Any] = {"sub_images": {}, "probes": {}, "full_images": {},
                               "camera_sub_images": {}, "windows": {}, "full_rungs": {},
                               "probe_rungs": {}, "moments": {}}
        ici = self.config.uses_ici
        normal = np.broadcast_to(self.frame.normal, (1, 3))
        for s in self.set_indices:
            st = self.sets[s]
            if image:
                pts = self._wall_points(s)
                shape = self.pattern.sub_shape(s)
                est = self._estimate(st, pts, np.broadcast_to(normal, pts.shape),
                                     "interleaved")
                out["sub_images"][s] = est.reshape((*shape, self.channels))
            if full_image and ici:  # the server picks each pixel's rung from all sets
                W, H = self.frame.resolution
                rows, cols = np.divmod(np.arange(H * W), W)
                r = self.ici_rungs(st, rows, cols)
                out["full_rungs"][s] = r.reshape((len(r), H, W, self.channels))
            elif full_image:
                h_all, v_all = self.frame.pixel_centres()
                hh, vv = np.meshgrid(h_all, v_all)
                pts = self.frame.to_world(hh, vv).reshape(-1, 3)
                est = self._estimate(st, pts, np.broadcast_to(normal, pts.shape), "pooled")
                out["full_images"][s] = est.reshape((*hh.shape, self.channels))
            if ici and probes and st.wall_moments is not None:
                out["probe_rungs"][s] = self.ici_rungs(st, *self._grid_pixels)
                out["moments"][s] = st.wall_moments.copy()
            if camera is not None:
                pts, nrm, weight, seen = self._camera_queries(s, camera)
                W, H = camera.resolution
                shape = InterleavePattern(self.config.interleave, W, H).sub_shape(s)
                lum = np.zeros((len(pts), self.channels))
                # L = ρ E / π (cd/m²) where the pixel sees a diffuse surface, else black
                lum[seen] = weight[seen] * self._estimate(st, pts[seen], nrm[seen],
                                                          "interleaved")
                out["camera_sub_images"][s] = lum.reshape((*shape, self.channels))
            if probes and probes != "ici" and len(self._probe_points):
                out["probes"][s] = self._estimate(
                    st, self._probe_points, np.broadcast_to(normal, self._probe_points.shape))
                if st.windows is not None and st.emitted:
                    dh, dv = self.frame.pixel_size_m
                    out["windows"][s] = st.windows / (st.emitted * dh * dv)
        # float32 over the wire (the lux map is float32 anyway): half the bytes per frame
        for key in ("sub_images", "full_images", "camera_sub_images", "probes", "windows",
                    "full_rungs", "probe_rungs"):
            out[key] = {s: v.astype(np.float32) for s, v in out[key].items()}
        out["seconds"] = time.perf_counter() - t0
        return out

    def _grid_count(self) -> int:
        """The probes are the regular grid first, then any extra points."""
        nh, nv = self._grid_shape
        return min(nh * nv, len(self.probes_hv))

    def probe(self, points_hv: np.ndarray) -> dict[int, np.ndarray]:
        """Every owned set's illuminance (lx) at wall points (h, v in m): {set: (P, C)}."""
        hv = np.asarray(points_hv, dtype=np.float64).reshape(-1, 2)
        pts = self.frame.to_world(hv[:, 0], hv[:, 1])
        normal = np.broadcast_to(self.frame.normal, pts.shape)
        return {s: self._estimate(self.sets[s], pts, normal) for s in self.set_indices}

    # -- statistics, checkpoints ---------------------------------------------------------
    def stats(self) -> dict[int, dict[str, Any]]:
        """Per-set counters and bookkeeping (unnormalised ledger)."""
        return {s: {"emitted": st.emitted, "frames": st.frames, "caustic": st.caustic,
                    "records": st.records, "ledger": st.ledger.copy(),
                    "emitted_power": st.emitted_power.copy()}
                for s, st in self.sets.items()}

    def apertures(self) -> dict[int, np.ndarray | None]:
        """Per-set detector-aperture counts (:mod:`lightsim.engine.apertures`), or None."""
        return {s: None if st.apertures is None else st.apertures.counts.copy()
                for s, st in self.sets.items()}

    def counters(self) -> dict[int, int]:
        """Frames shot per set: with the seed, all that is needed to replay a set."""
        return {s: st.frames for s, st in self.sets.items()}

    def replay(self, frames: dict[int, int], partial: dict[int, int] | None = None) -> None:
        """Rebuild the sets' state by re-shooting ``frames`` frames (deterministic);
        ``partial`` maps a frame index (0-based) to the photons (over all sets) of a
        partial frame such as the last one of ``--photons N``."""
        self.reset()
        n = max(frames.values(), default=0)
        if any(f != n for f in frames.values()):
            raise ValueError("sets of one client must have shot the same number of frames")
        partial = {int(k): int(v) for k, v in (partial or {}).items()}
        for i in range(n):
            self.shoot(partial.get(i))
