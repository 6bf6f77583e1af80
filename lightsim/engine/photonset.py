"""The photon side of a client: interleave sets, their samplers, photons and counters.

The paper's client (sections 3.3, 4.3, 5): every set (a, b) of the M×M interleave
pattern has its own photons — disjoint sample indices, its own scramble — and its own
photon map; frames *accumulate*: each frame adds photons to every set by incremental
insertion. A set's state is a pure function of (scene, config, seed, set index, frames
shot), so a lost client is rebuilt by replaying its frames (:meth:`PhotonSets.replay`)
and a run is bit-identical however the sets are spread over clients.

What a set accumulates depends on what the estimator reads
(:mod:`lightsim.engine.estimator`):

==================  ===========  ====================================================
store               unit         kept when
==================  ===========  ====================================================
``photonmap``       lm           kNN and radius estimators (built when first queried);
                                 with ``keep_photons`` off (``simulate``'s default) a
                                 :class:`~lightsim.engine.pointstore.PointStore`: the
                                 probes' kNN sums, photons dropped after each frame
``bins``            lm           ``estimator=bin``: power per wall pixel
``windows``         lm           kNN/radius without ICI: power in the pixel window of
                                 each grid probe (the kNN figure's blur reference)
``lattice``         lm           ``bandwidth=ici``: power per half-pixel cell
``wall_moments``    lm, lm², –   kNN/radius: ΣΦ, ΣΦ², count of luminous wall photons
``apertures``       lm           regulation detector apertures
``paths``           lm           ``--provenance``: aperture flux per path signature
``ledger``          lm           always: bookkeeping, unnormalised
==================  ===========  ====================================================
"""

from __future__ import annotations

import os
import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lightsim.engine.apertures import counter_from_config
from lightsim.engine.config import RunConfig
from lightsim.engine.frame_insert import insert_wall
from lightsim.engine.guiding import (
    EmissionGuide,
    guide_remap,
    guide_shape,
    run_targets,
    targets_at,
)
from lightsim.engine.memory import write_pages
from lightsim.engine.plan import Plan
from lightsim.engine.pointstore import PointSpec, PointStore
from lightsim.engine.results import ShootResult
from lightsim.persource import EmitterGroups, PerSourceSums
from lightsim.photonmap.common import r_floor
from lightsim.photonmap.density import PhotonMap
from lightsim.photonmap.near import NearGrid
from lightsim.provenance import (
    ClassMatcher,
    PathCounter,
    PathElements,
    RegionRaster,
    emitter_index,
    signature_rows,
)
from lightsim.render import ici
from lightsim.render.frame import luminous
from lightsim.sampling import (
    SelectiveSampler,
    digit_permutations,
    halton_points_grouped,
    photon_keys,
)
from lightsim.scene import Scene
from lightsim.threads import second_thread
from lightsim.tracer import LEDGER, PhotonRecords, PhotonTracer


def add_to_cells(store: np.ndarray, flat: np.ndarray, power: np.ndarray) -> None:
    """``store[flat[i]] += power[i]`` for every photon, touching only the cells hit.

    ``store`` (n_cells, C) float64; the same sums as adding ``np.bincount(flat, power,
    minlength=n_cells)`` (each cell's photons summed in order from 0, then added), so the
    stores are bit-identical to a whole-image bincount — but the work scales with the
    photons of the frame, not with the image.
    """
    if len(flat) == 0:
        return
    cells, inverse = np.unique(flat, return_inverse=True)
    for c in range(store.shape[1]):
        store[cells, c] += np.bincount(inverse, weights=power[:, c], minlength=len(cells))


def window_offsets(reach: float) -> tuple[int, int]:
    """(lo, hi): the grid-cell offsets from a photon's nearest probe centre whose window
    can hold it, for windows reaching ``reach`` cell pitches from their centre.

    A photon lies within half a pitch of its nearest centre, so the centre i cells away
    is at least |i| − ½ pitches off: only |i| ≤ reach + ½ can hold it (a little slack
    for rounding; never wider than ⌈reach⌉). On the shipped headlight (pixels a tenth
    of the pitch) that is the nearest centre alone instead of 3 × 3 — the same sums, as
    the other offsets' tests never pass.
    """
    hi = min(int(np.floor(reach + 0.5 + 1e-6)), int(np.ceil(reach)))
    return -hi, hi


#: a frame with at least this many records is inserted on two threads (two halves of the
#: sets): below it the hand-over costs more than the second core gives back
SPLIT_RECORDS = 20_000

#: the largest ICI lattice block (bytes) whose pages a run touches before its first frame
#: is inserted (:meth:`PhotonSets._prefault_lattice`)
PREFAULT_MAX_BYTES = 256 * 2**20


class DeferredPhotonMap:
    """A photon map that stores its batches until the first query needs them.

    The default (ICI) map reads the half-pixel lattice, not the kd-tree, so most frames
    never query the map: inserting every batch would be work for nothing. Batches are
    kept in order and added when :meth:`ready` is called — all pending ones as one batch
    (one build instead of many insertions). With the box kernel the kNN estimates are
    bit-identical to inserting batch by batch (the k nearest and their sum do not depend
    on the tree's shape).

    An estimate at a few points (:meth:`estimate`: the cut-off scans, test points) on a
    map not built yet reads a map of the photons near them only
    (:mod:`lightsim.photonmap.near`), unless those are more than :attr:`LOCAL_SHARE` of
    the photons: then the whole map is built, and kept for later queries. Estimates
    repeated as photons arrive (a probe every frame) switch to the built map once their
    selection passes have read :attr:`LOCAL_SCANS` times the photons stored (a pass costs
    a few ns per photon, a build about a hundred).
    """

    LOCAL_SHARE = 0.5
    LOCAL_SCANS = 8

    def __init__(self, structure: str, channels: int) -> None:
        self.map = PhotonMap(structure=structure, channels=channels)
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._n_pending = 0
        self._scanned = 0  # photons read by near-photon selections (class doc)

    def __len__(self) -> int:
        return len(self.map) + self._n_pending

    def add(self, positions: np.ndarray, normals: np.ndarray, powers: np.ndarray) -> None:
        self._pending.append((positions, normals, powers))
        self._n_pending += len(positions)

    def ready(self):
        """The photon map with every photon added so far."""
        if self._pending:
            batches, self._pending, self._n_pending = self._pending, [], 0
            self.map.add(*(np.concatenate(parts) for parts in zip(*batches, strict=True)))
        return self.map

    def estimate(self, points: np.ndarray, normals: np.ndarray | None, *, k: int = 64,
                 max_radius: float = np.inf, min_radius: float = 0.0, kernel: str = "box"):
        """:meth:`PhotonMap.estimate <lightsim.photonmap.density.PhotonMap.estimate>`
        over every photon added so far. On a map not built yet, with a finite
        ``max_radius``, from the photons within reach of ``points`` and with the whole
        map's density floor: the same photons, so the same estimates (bit for bit with
        the box kernel, as batching; to rounding with the others, whose sums follow the
        order a tree finds the photons in)."""
        near = self._near_map(points, max_radius)
        if near is None:
            return self.ready().estimate(points, normals, k=k, max_radius=max_radius,
                                         min_radius=min_radius, kernel=kernel)
        sub, bounds = near
        # the floor the whole map would use (it reads the photons' bounding box)
        floor = min(max(float(min_radius), r_floor(bounds[:3], bounds[3:])), float(max_radius))
        # no photon near: an empty map (it stores no normals to filter by) answers 0
        return sub.estimate(points, normals if len(sub) else None, k=k,
                            max_radius=max_radius, min_radius=floor, kernel=kernel)

    def _near_map(self, points: np.ndarray, max_radius: float):
        """(map of the photons near ``points``, bounds of all photons), or None where the
        whole map serves (built already, an unbounded radius, or most photons near)."""
        if len(self.map) or not self._n_pending or len(points) == 0:
            return None
        r = float(max_radius)
        if not (0.0 < r < np.inf) or not np.all(np.isfinite(points)):
            return None
        if self._scanned + self._n_pending > self.LOCAL_SCANS * self._n_pending:
            return None
        self._scanned += self._n_pending
        grid = NearGrid(points, r)
        bounds = np.array([np.inf] * 3 + [-np.inf] * 3)
        picks = [grid.select(b[0], bounds) for b in self._pending]
        n = sum(len(p) for p in picks)
        if n > self.LOCAL_SHARE * self._n_pending:
            return None
        sub = PhotonMap(structure=self.map.structure, channels=self.map.n_channels)
        if n:
            batches = list(zip(self._pending, picks, strict=True))
            sub.add(np.concatenate([b[0][p] for b, p in batches]),
                    None if batches[0][0][1] is None
                    else np.concatenate([b[1][p] for b, p in batches]),
                    np.concatenate([b[2][p] for b, p in batches]))
        return sub, bounds


def kept_records(st: SetState) -> int:
    """Wall records the set's map holds now: every one a photon map took, the pool of a
    point store (:attr:`PointStore.kept`), none for bins."""
    pm = st.photonmap
    if pm is None:
        return 0
    return int(pm.kept) if isinstance(pm, PointStore) else len(pm)


@dataclass
class SetState:
    """Accumulated state of one interleave set (stores: see the module table).

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
    photonmap: DeferredPhotonMap | PointStore | None = None
    bins: np.ndarray | None = None  # (H, W, C) power per wall pixel
    windows: np.ndarray | None = None  # (G, C) power in the pixel window of each grid probe
    apertures: Any = None  # ApertureCounter of the run's detector apertures, if any
    aperture_hits: np.ndarray | None = None  # sources of this frame's target-aperture photons
    lattice: np.ndarray | None = None  # (2H·2W, C) power per half-pixel cell (ICI windows)
    wall_moments: np.ndarray | None = None  # ΣΦ (lm), ΣΦ² (lm²), count of wall photons
    paths: PathCounter | None = None  # aperture flux per path signature (--provenance)
    path_map: np.ndarray | None = None  # (H·W, C) flux of one path class (--provenance-map)
    guide: EmissionGuide | None = None  # importance-driven emission (engine.guiding)

    def __post_init__(self) -> None:
        if self.ledger is None:
            self.ledger = np.zeros((len(LEDGER), self.channels))
        if self.emitted_power is None:
            self.emitted_power = np.zeros(self.channels)


class _WallHits:
    """The wall records of one frame: their positions in the frame's record arrays and
    their wall coordinates (h, v in m), computed once for all sets.

    h, v are evaluated element by element (no BLAS product), so a record's coordinates
    do not depend on which other records share the frame.
    """

    def __init__(self, sets: PhotonSets, rec: PhotonRecords) -> None:
        ids = sets._wall_part_ids
        on = rec.part == ids[0] if len(ids) == 1 else np.isin(rec.part, ids)
        self.index = np.flatnonzero(on)
        fr = sets.frame
        d = rec.position[self.index].astype(np.float64) - fr.centre
        ha, va = np.asarray(fr.h_axis, np.float64), np.asarray(fr.v_axis, np.float64)
        self.h = d[:, 0] * ha[0] + d[:, 1] * ha[1] + d[:, 2] * ha[2]
        self.v = d[:, 0] * va[0] + d[:, 1] * va[1] + d[:, 2] * va[2]

    def span(self, a: int, b: int) -> tuple[slice, np.ndarray]:
        """The wall records among records ``a:b``: their slice of ``h``, ``v`` and their
        record indices."""
        lo, hi = (int(x) for x in np.searchsorted(self.index, (a, b)))
        return slice(lo, hi), self.index[lo:hi]


class PhotonSets:
    """The interleave sets of one client: shoot, insert, count, replay.

    Parameters
    ----------
    scene : Scene
    config : RunConfig
    plan : Plan
        Which stages run (SPT, channels, recording).
    set_indices : list of int
        The interleave sets this client owns (static assignment).
    caster : RayCaster, optional
        The scene's embree scene when the caller already built it.
    points : PointSpec, optional
        Where the kNN estimates are read when the photons are not kept: every set then
        accumulates a :class:`~lightsim.engine.pointstore.PointStore` there instead of a
        photon map (None: every photon is kept).
    """

    def __init__(self, scene: Scene, config: RunConfig, plan: Plan,
                 set_indices: list[int], caster=None, points: PointSpec | None = None
                 ) -> None:
        self.config = config
        self.plan = plan
        self.points = points
        self.set_indices = list(set_indices)
        self._perm_cache: dict[int, np.ndarray] = {}
        self.set_scene(scene, caster)
        self.reset()

    # -- scene and state ------------------------------------------------------------------
    def set_config(self, config: RunConfig) -> None:
        """Use ``config`` from the next frame on; only the guide targets may differ (sets
        that had no guide get one now, knowing nothing yet)."""
        self.config = config
        self._guide_rows = run_targets(config)
        if self._guide_rows:
            for st in self.sets.values():
                if st.guide is None:
                    st.guide = EmissionGuide(self._guide_shape, config.guide_share,
                                             config.guide_photons, config.n_sets,
                                             config.guide_window_deg, self.frame.distance_m)

    def set_scene(self, scene: Scene, caster=None) -> None:
        """Use ``scene`` (keeping ``caster``, the embree scene, when only materials or
        emitters changed)."""
        if self.plan.channels != scene.channels:
            scene = Scene(scene.parts, scene.wall, scene.source, scene.warnings,
                          self.plan.channels)
        self.scene = scene
        self.frame = scene.wall
        self.channels = self.plan.channels
        self.tracer = PhotonTracer(scene, max_depth=self.config.max_depth,
                                   record=self.plan.record, threads=self.config.threads,
                                   caster=caster, path_length=self.config.path_length)
        self._elements = (PathElements.from_scene(scene) if self.config.path_length
                          else None)
        self._rows = np.zeros((0, 0), np.int32)  # the frame's path signatures
        self._raster = RegionRaster.of(scene.wall)  # where region breakdowns are counted
        self._match = (ClassMatcher(self._elements, self.config.path_map)
                       if self._elements is not None and self.config.path_map else None)
        self._matched = np.zeros(0, bool)  # the frame's records in the mapped class
        self._wall_part_ids = np.flatnonzero([p.role == "wall" for p in scene.surfaces])
        self._grid_shape = tuple(int(n) for n in self.config.probe_grid)
        # --per-source: every emitter group's wall photons per pixel (lightsim.persource)
        self.per_source = (PerSourceSums(EmitterGroups.of(scene, self.tracer.emitters),
                                         scene.wall) if self.plan.per_source else None)
        self._guide_shape = guide_shape(self.tracer.emitters)
        self._guide_remap = guide_remap(self.tracer.emitters)
        self._guide_rows = run_targets(self.config)

    def reset(self) -> None:
        """Discard all photons (interaction mode: the next frame starts afresh)."""
        self.sets: dict[int, SetState] = {s: self._new_set(s) for s in self.set_indices}
        self._blocks: dict[str, Any] = {}  # stores stacked over sets (_stacked), work arrays
        self._frames_inserted = 0  # frames inserted by _insert_frame
        if getattr(self, "per_source", None) is not None:
            self.per_source.reset()
        self._lattice_ready = self._prefault_lattice()

    def _prefault_lattice(self) -> Future | None:
        """Make the sets' ICI lattice block now and fault its pages in on the second thread
        (the first frame's tracing hides it): the pending work, or None.

        A fresh page costs a fault on first touch. Left to the insertion, the lattice's
        pages (84 MB on the shipped headlight's wall) were first touched in random order
        by the first frames' photons: their insertion took 0.4–0.55 µs per record against
        0.1 µs once the pages were in, ~0.1 s of a 1 M-photon run. Faulting them in, in
        order, takes ~34 ms of one core beside the tracer (writing the zeros 43–85 ms).
        Only where a frame's photons could reach every page (a set's photons per frame at
        least its lattice's 4 KiB pages: the default 200 k-photon frames, not the live
        view's 20 k, whose first frame would wait for the writing and would touch a few
        pages only); not for the ``bin`` estimator (no lattice), nor above
        :data:`PREFAULT_MAX_BYTES` (reading untouched zeros costs no memory). The block is
        made zero (``calloc``: pages untouched) and
        :func:`~lightsim.engine.memory.write_pages` faults them in.
        """
        if not self.config.uses_ici or self.config.estimator == "bin":
            return None
        W, H = self.frame.resolution
        set_bytes = 8 * 4 * H * W * self.channels  # one set's lattice, float64
        if (set_bytes * len(self.set_indices) > PREFAULT_MAX_BYTES
                or self.config.photons_per_set < set_bytes / 4096):
            return None
        block = np.zeros((len(self.set_indices), 4 * H * W, self.channels))  # lazy pages
        self._blocks["lattice"] = block
        return second_thread().submit(write_pages, block)

    def _new_set(self, s: int) -> SetState:
        st = SetState(s, self.channels)
        if self.plan.spt or self.config.aperture_targets:
            share = None if self.plan.spt else self.config.aperture_spt_share
            st.sampler = SelectiveSampler(self.config.seed, s, refine_share=share,
                                          pass_photons=self.config.photons_per_set)
        if self._guide_rows:
            c = self.config
            st.guide = EmissionGuide(self._guide_shape, c.guide_share, c.guide_photons,
                                     c.n_sets, c.guide_window_deg, self.frame.distance_m)
        if self.config.apertures:
            st.apertures = counter_from_config(self.config, self.frame, self.channels)
            if self.config.path_length:
                st.paths = PathCounter(self.channels)
        if self.config.estimator == "bin":
            W, H = self.frame.resolution
            st.bins = np.zeros((H, W, self.channels))
        else:
            structure = "hash" if self.config.estimator == "radius" else self.config.structure
            st.photonmap = (DeferredPhotonMap(structure, self.channels) if self.points is None
                            else self.points.store(self.channels))
            nh, nv = self._grid_shape
            if not self.config.uses_ici:  # the ICI figure reads the lattice instead
                st.windows = np.zeros((nh * nv, self.channels))
            st.wall_moments = np.zeros(3)
        return st

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

    def shoot(self, total: int | None = None) -> ShootResult:
        """Shoot one frame of photons for every owned set and insert them.

        ``total`` (photons over all sets) makes this a partial last frame (plain sampling;
        an SPT pass is always whole, since a cut pass would leave cells unsampled).
        """
        t0 = time.perf_counter()
        keys, weights, groups, owners, perms = [], [], [], [], []
        for g, s in enumerate(self.set_indices):
            st = self.sets[s]
            if st.sampler is not None:
                pass_index, idx, pm, w = st.sampler.next_pass_indices()
                # key space: pass 0 is plain sampling, SPT passes are 1, 2, ...
                k = photon_keys(self.config.seed, s, pass_index + 1, idx)
            else:
                n = self.frame_share(s, total)
                idx = np.arange(st.next_index, st.next_index + n, dtype=np.int64)
                pm = self._perms(s)
                k = photon_keys(self.config.seed, s, 0, idx)
                w = None
                st.next_index += n
            perms.append(pm)
            keys.append(k)
            weights.append(np.ones(len(idx)) if w is None else w)
            groups.append(np.full(len(idx), g, np.int64))
            owners.append(idx)
        group = np.concatenate(groups)
        # every set's Halton points in one parallel pass (one thread launch per frame)
        points = halton_points_grouped(np.concatenate(owners), group, np.stack(perms))
        cells = self._guide_points(points, weights, owners)
        t1 = time.perf_counter()
        # the records in photon order (a stable sort by photon index, each chunk's on the
        # tracer's threads): a set's photons are one index range, so its records are one
        # slice, in the order (photon, bounce) that keeps maps identical across batching.
        # What every store needs (on the wall?, h, v) is computed once per frame, not
        # once per set.
        res = self.tracer.trace_points(points, np.concatenate(keys), np.concatenate(weights),
                                       group=group, n_groups=len(self.set_indices),
                                       by_source=True)
        t2 = time.perf_counter()
        rec = res.records
        if self._elements is not None and rec.path is not None:
            el = self._elements
            self._rows = signature_rows(el, rec.path, rec.events, emitter_index(
                self.tracer.emitters, points[rec.source], el.emitter_triangles))
            if self._match is not None:
                self._matched = self._match(self._rows)
        offsets = np.cumsum([0] + [len(o) for o in owners])
        bounds = np.searchsorted(rec.source, offsets)
        frame_level = self._insert_frame(rec, bounds, offsets)
        wall = None if frame_level and self.per_source is None else _WallHits(self, rec)
        if self.per_source is not None:  # the group from the emitted photon's sample point
            self.per_source.add(self.per_source.groups.of_points(points)[rec.source[wall.index]],
                                wall.h, wall.v, luminous(rec.power[wall.index]))
            for g, s in enumerate(self.set_indices):  # the binning estimator's own sums
                sl, idx = wall.span(int(bounds[g]), int(bounds[g + 1]))
                self._add_to_pixels(self.per_source.set_sums(s, self.channels), wall.h[sl],
                                    wall.v[sl], rec.power[idx].astype(np.float64))
        if cells is not None:
            self._guide_learn(rec, bounds, offsets, cells,
                              wall if wall is not None else _WallHits(self, rec))
        for g, s in enumerate(self.set_indices):
            st = self.sets[s]
            lo, hi = offsets[g], offsets[g + 1]
            if not frame_level:
                self._insert_slice(st, rec, wall, int(bounds[g]), int(bounds[g + 1]), lo)
            st.emitted += hi - lo
            st.frames += 1
            st.ledger += res.ledger[g]
            st.emitted_power += res.emitted[g]
            caustic = res.caustic_source[lo:hi]
            st.caustic += int(caustic.sum())
            st.records += int(bounds[g + 1] - bounds[g])
            if st.sampler is not None:
                trigger = caustic if self.plan.spt else np.zeros(hi - lo, np.bool_)
                if st.aperture_hits is not None:  # SPT aimed at test points
                    trigger = trigger.copy()
                    trigger[st.aperture_hits] = True
                st.sampler.update(owners[g], trigger)
        return ShootResult(len(points), len(rec), int(res.rays), time.perf_counter() - t0,
                           t1 - t0, t2 - t1)

    def _guide_points(self, points: np.ndarray, weights: list[np.ndarray],
                      owners: list[np.ndarray]) -> np.ndarray | None:
        """Carry each guided set's points through its guide (in place) and multiply its
        weights by 1/p; the photons' guide cells (None: no set is guided). A set's guide
        holds only what its own earlier frames taught it (:mod:`lightsim.engine.guiding`)."""
        if not self._guide_rows:
            return None
        cells = np.zeros(len(points), np.int64)
        lo = 0
        for g, s in enumerate(self.set_indices):
            st = self.sets[s]
            hi = lo + len(owners[g])
            live = targets_at(self._guide_rows, st.frames)
            st.guide.set_targets(live)
            pts, w, c = st.guide.warp(points[lo:hi])
            if self._guide_remap is not None and len(live):  # a ray file's direction order
                pts[:, 0] = self._guide_remap(pts[:, 0])
            points[lo:hi] = pts
            weights[g] = weights[g] * w
            cells[lo:hi] = c
            lo = hi
        return cells

    def _guide_learn(self, rec: PhotonRecords, bounds: np.ndarray, offsets: np.ndarray,
                     cells: np.ndarray, wall: _WallHits) -> None:
        """Teach each set's guide where its wall photons of this frame landed."""
        for g, s in enumerate(self.set_indices):
            sl, idx = wall.span(int(bounds[g]), int(bounds[g + 1]))
            lum = luminous(rec.power[idx].astype(np.float64))
            self.sets[s].guide.learn(cells[rec.source[idx]], wall.h[sl], wall.v[sl], lum)

    def _perms(self, s: int) -> np.ndarray:
        if s not in self._perm_cache:
            self._perm_cache[s] = digit_permutations(self.config.seed, s, None)
        return self._perm_cache[s]

    # -- insertion -----------------------------------------------------------------------
    def insert(self, st: SetState, rec: PhotonRecords) -> None:
        """Add one frame's records of set ``st`` to every store it keeps (``rec.source``:
        the set's photon indices of the frame, from 0)."""
        self._insert_slice(st, rec, _WallHits(self, rec), 0, len(rec), 0)

    def _insert_frame(self, rec: PhotonRecords, bounds: np.ndarray,
                      offsets: np.ndarray) -> bool:
        """Insert a whole frame (every owned set's records, set after set) at once where
        the stores allow it (kNN/ICI stores, no binning): the wall coordinates, the probe
        windows and the ICI lattice of all sets in one compiled pass
        (:func:`~lightsim.engine.frame_insert.insert_wall`) — the same sums per cell,
        photons in the same order, so the stores are bit-identical to
        :meth:`_insert_slice`'s. Returns False (nothing done) where :meth:`_insert_slice`
        must do it."""
        sets = [self.sets[s] for s in self.set_indices]
        if any(st.bins is not None or st.photonmap is None for st in sets):
            return False
        if self._lattice_ready is not None:  # its zeros are written before any sum
            self._lattice_ready.result()
            self._lattice_ready = None
        fr, C = self.frame, self.channels
        # point stores (every set's at the same points): the frame's photons near them
        # found once, each set's share passed on
        near = (sets[0].photonmap.near(rec.position)
                if isinstance(sets[0].photonmap, PointStore) else None)
        near_bounds = None if near is None else np.searchsorted(near, bounds)
        none = np.zeros(len(sets), np.bool_)
        (h0, h1), (v0, v1) = fr.h_range_m, fr.v_range_m
        nh, nv = self._grid_shape
        pitch_h, pitch_v = (h1 - h0) / nh, (v1 - v0) / nv
        dh, dv = fr.pixel_size_m
        (i0, i1), (j0, j1) = window_offsets(0.5 * dh / pitch_h), window_offsets(0.5 * dv / pitch_v)
        W, H = fr.resolution
        if self.config.uses_ici:  # the lattice, and no probe windows (the table above)
            reach = (0, -1, 0, -1, nh, nv)  # empty: no photon reaches a window
            windows = np.zeros((len(sets), 0, C))
            lattice = self._stacked(sets, "lattice", (4 * H * W, C), none)
        else:
            reach = (i0, i1, j0, j1, nh, nv)
            windows = self._stacked(sets, "windows", (nh * nv, C), ~none)
            lattice = np.zeros((0, 0, C))
        n_slots = (reach[1] - reach[0] + 1) * (reach[3] - reach[2] + 1)
        need_hv = any(st.apertures is not None for st in sets)
        axes = np.array([fr.centre, fr.h_axis, fr.v_axis], np.float64)
        win_geometry = (float(h0), float(v0), float(pitch_h), float(pitch_v), 0.5 * dh,
                        0.5 * dv)
        lat_geometry = (float(h0), float(v1), float(dh), float(dv))

        def insert(g0: int, g1: int, name: str) -> tuple:
            """Sets g0..g1-1 into their stores (the rows of those sets only, with work
            arrays of their own): their photon maps or point stores, :func:`insert_wall`'s
            outputs, then the apertures."""
            for g in range(g0, g1):
                a, b = int(bounds[g]), int(bounds[g + 1])
                if b > a and near is None:
                    sets[g].photonmap.add(rec.position[a:b], rec.normal[a:b],
                                          rec.power[a:b])
                elif b > a:
                    sets[g].photonmap.add(rec.position[a:b], rec.normal[a:b], rec.power[a:b],
                                          near[near_bounds[g]:near_bounds[g + 1]] - a)
            win_work = self._blocks.get(f"windows work {name}")
            if win_work is None or win_work.shape != (n_slots, windows.shape[1], C):
                win_work = self._blocks[f"windows work {name}"] = np.zeros(
                    (n_slots, windows.shape[1], C))
            work = np.zeros(0, np.int32)
            if self.config.uses_ici:
                work = self._blocks.get(f"lattice work {name}")
                if work is None or work.shape[0] != lattice.shape[1]:  # kept at −1
                    work = self._blocks[f"lattice work {name}"] = np.full(
                        lattice.shape[1], -1, np.int32)
            out = insert_wall(
                rec.part, self._wall_part_ids, rec.position, rec.power, bounds[g0:g1 + 1],
                axes, windows[g0:g1], win_geometry, reach, win_work,
                lattice[g0:g1] if len(lattice) else lattice, lat_geometry, (int(W), int(H)),
                work, need_hv)
            if need_hv:  # detector apertures count every wall photon
                index, h, v = out[3:]
                wb = np.searchsorted(index, bounds[g0:g1 + 1])
                for g in range(g0, g1):
                    st = sets[g]
                    if st.apertures is not None:
                        sl = slice(int(wb[g - g0]), int(wb[g - g0 + 1]))
                        idx = index[sl]
                        hit = st.apertures.add(h[sl], v[sl], rec.power[idx])
                        st.aperture_hits = rec.source[idx][hit] - offsets[g]
                        if st.paths is not None:
                            st.paths.add(self._rows[idx], st.apertures.locate(h[sl], v[sl]),
                                         rec.power[idx])
                            st.paths.add_cells(self._rows[idx],
                                               self._raster.cell(h[sl], v[sl]), rec.power[idx])
                            self._add_to_path_map(st, h[sl], v[sl], idx, rec.power)
            return out[:3]

        # the sets in two halves of about equal records, one half on a second thread:
        # the kernels and the apertures' passes run without the GIL, and each set's stores
        # get the same sums either way. Not the first frame: it touches the stores' memory
        # for the first time (page faults that two threads would only queue for) and
        # loads the kernels
        split = len(sets)
        if len(sets) > 1 and len(rec) >= SPLIT_RECORDS and self._frames_inserted and (
                self.config.threads or os.cpu_count() or 1) > 1:
            split = int(np.clip(np.searchsorted(bounds, 0.5 * bounds[-1]), 1, len(sets) - 1))
        pending = (second_thread().submit(insert, split, len(sets), "b")
                   if split < len(sets) else None)
        try:
            halves = [insert(0, split, "a")]
        finally:
            if pending is not None:
                halves.append(pending.result())
        counts = np.concatenate([c for c, _, _ in halves])
        ok = np.concatenate([o for _, o, _ in halves])
        pb = halves[0][2]  # each set's share of ok: the second half's bounds follow on
        if len(halves) == 2:
            pb = np.concatenate([pb, halves[1][2][1:] + pb[-1]])
        self._frames_inserted += 1
        if self.config.uses_ici:
            # a set's lattice is created by its first wall photon; ΣΦ, ΣΦ², count of the
            # photons on it (their standard errors), summed by NumPy as before
            p_ok = rec.power[ok].astype(np.float64)
            for g, st in enumerate(sets):
                if counts[g] == 0:
                    continue
                if st.lattice is None:
                    st.lattice = lattice[g]
                lum = luminous(p_ok[pb[g]:pb[g + 1]])
                st.wall_moments += (float(lum.sum()), float((lum * lum).sum()),
                                    float(pb[g + 1] - pb[g]))
        return True

    def _stacked(self, sets: list[SetState], name: str, shape: tuple[int, ...],
                 want: np.ndarray) -> np.ndarray:
        """An (S, *shape) float64 array whose row g is set g's store ``name`` (each set's
        store a view of it, so a compiled pass fills every set's); a set without the
        store gets its (zero) row where ``want[g]``, and keeps None otherwise (its row
        stays zero until it is given one)."""
        block = self._blocks.get(name)
        if block is None or block.shape != (len(sets), *shape):
            block = self._blocks[name] = np.zeros((len(sets), *shape))
        for g, st in enumerate(sets):
            cur = getattr(st, name)
            if cur is None:
                if want[g]:
                    setattr(st, name, block[g])
            elif cur.base is not block:
                block[g] = cur
                setattr(st, name, block[g])
        return block

    def _insert_slice(self, st: SetState, rec: PhotonRecords, wall: _WallHits, a: int,
                      b: int, first: int) -> None:
        """Add records ``a:b`` of the frame (set ``st``'s, photon indices from ``first``)
        to every store the set keeps; ``wall`` holds the frame's wall coordinates."""
        sl, idx = wall.span(a, b)
        h, v = wall.h[sl], wall.v[sl]
        if st.apertures is not None:  # detector apertures count every wall photon directly
            hit = st.apertures.add(h, v, rec.power[idx])
            st.aperture_hits = rec.source[idx][hit] - first
            if st.paths is not None and len(self._rows):
                st.paths.add(self._rows[idx], st.apertures.locate(h, v), rec.power[idx])
                st.paths.add_cells(self._rows[idx], self._raster.cell(h, v), rec.power[idx])
                self._add_to_path_map(st, h, v, idx, rec.power)
        if st.bins is not None:
            self._add_to_bins(st, h, v, rec.power[idx].astype(np.float64))
            return
        if b > a:
            st.photonmap.add(rec.position[a:b], rec.normal[a:b], rec.power[a:b])
            if len(idx):
                power = rec.power[idx].astype(np.float64)
                if st.windows is not None:
                    self._add_to_windows(st, h, v, power)
                self._add_to_lattice(st, h, v, power)

    def _add_to_path_map(self, st: SetState, h: np.ndarray, v: np.ndarray, idx: np.ndarray,
                         power: np.ndarray) -> None:
        """Add the wall photons ``idx`` (at h, v in m) of the mapped path class to the
        set's path map (``--provenance-map``: lm per wall pixel, unnormalised)."""
        if self._match is None or len(idx) == 0:
            return
        on = self._matched[idx]
        if st.path_map is None:
            W, H = self.frame.resolution
            st.path_map = np.zeros((H * W, self.channels))
        if on.any():
            W, H = self.frame.resolution
            row, col = self.frame.pixel_index(h[on], v[on])
            ok = (col >= 0) & (col < W) & (row >= 0) & (row < H)
            add_to_cells(st.path_map, row[ok] * W + col[ok],
                         power[idx[on]][ok].astype(np.float64))

    def _add_to_bins(self, st: SetState, h: np.ndarray, v: np.ndarray,
                     power: np.ndarray) -> None:
        """Add wall photons (h, v in m; power (n, C) lm) to their pixels (the binning
        estimator)."""
        self._add_to_pixels(st.bins, h, v, power)

    def _add_to_pixels(self, store: np.ndarray, h: np.ndarray, v: np.ndarray,
                       power: np.ndarray) -> None:
        """Add wall photons (h, v in m; power (n, C) lm) to the (H, W, C) pixel sums
        ``store``: the binning estimator's additions, also kept by ``--per-source`` runs."""
        W, H = self.frame.resolution
        row, col = self.frame.pixel_index(h, v)
        ok = (col >= 0) & (col < W) & (row >= 0) & (row < H)
        add_to_cells(store.reshape(W * H, self.channels), row[ok] * W + col[ok], power[ok])

    def _add_to_lattice(self, st: SetState, h: np.ndarray, v: np.ndarray,
                        power: np.ndarray) -> None:
        """Add wall photons (h, v in m; power (n, C) lm) to the set's half-pixel lattice
        (the ICI windows) and to ΣΦ, ΣΦ² (their standard errors)."""
        if not self.config.uses_ici:
            return
        flat, ok = ici.lattice_index(h, v, self.frame)
        power = power[ok]
        W, H = self.frame.resolution
        if st.lattice is None:
            st.lattice = np.zeros((4 * H * W, self.channels))
        add_to_cells(st.lattice, flat[ok], power)
        lum = luminous(power)
        st.wall_moments += (float(lum.sum()), float((lum * lum).sum()), float(ok.sum()))

    def _add_to_windows(self, st: SetState, h: np.ndarray, v: np.ndarray,
                        power: np.ndarray) -> None:
        """Add wall photons (h, v in m; power (n, C) lm) to the pixel-sized windows
        centred on the grid probes.

        The probe grid (:func:`~lightsim.render.frame.probe_grid`) has cell pitch Δ; a
        window is one pixel (dh × dv, half-open) around a cell centre. Windows overlap only
        when pixels are coarser than the grid, hence the loop over neighbouring cells.
        """
        (h0, h1), (v0, v1) = self.frame.h_range_m, self.frame.v_range_m
        nh, nv = self._grid_shape
        pitch_h, pitch_v = (h1 - h0) / nh, (v1 - v0) / nv
        dh, dv = self.frame.pixel_size_m
        uh, uv = (h - h0) / pitch_h - 0.5, (v - v0) / pitch_v - 0.5  # in cell-centre units
        (i0, i1), (j0, j1) = window_offsets(0.5 * dh / pitch_h), window_offsets(0.5 * dv / pitch_v)
        rh, rv = np.round(uh).astype(np.int64), np.round(uv).astype(np.int64)
        for i in range(i0, i1 + 1):
            ci = rh + i
            oh = (uh - ci) * pitch_h  # offset from the window centre (m), half-open
            in_h = (ci >= 0) & (ci < nh) & (oh >= -0.5 * dh) & (oh < 0.5 * dh)
            for j in range(j0, j1 + 1):
                cj = rv + j
                ov = (uv - cj) * pitch_v
                ok = in_h & (cj >= 0) & (cj < nv) & (ov >= -0.5 * dv) & (ov < 0.5 * dv)
                if ok.any():
                    flat = cj[ok] * nh + ci[ok]
                    for c in range(self.channels):
                        st.windows[:, c] += np.bincount(flat, weights=power[ok, c],
                                                        minlength=nh * nv)

    # -- statistics, checkpoints ---------------------------------------------------------
    def stats(self) -> dict[int, dict[str, Any]]:
        """Per-set counters and bookkeeping (unnormalised ledger)."""
        return {s: {"emitted": st.emitted, "frames": st.frames, "caustic": st.caustic,
                    "records": st.records, "kept": kept_records(st),
                    "ledger": st.ledger.copy(),
                    "emitted_power": st.emitted_power.copy()}
                for s, st in self.sets.items()}

    def apertures(self) -> dict[int, np.ndarray | None]:
        """Per-set detector-aperture counts (:mod:`lightsim.engine.apertures`), or None."""
        return {s: None if st.apertures is None else st.apertures.counts.copy()
                for s, st in self.sets.items()}

    def paths(self) -> dict[int, dict | None]:
        """Per-set aperture flux per path signature (:meth:`lightsim.provenance.
        PathCounter.export`), or None (a run without ``--provenance``)."""
        return {s: None if st.paths is None else
                {**st.paths.export(), "map": None if st.path_map is None
                 else st.path_map.copy()}
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
