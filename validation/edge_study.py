"""The written map at edges: true error in the edge band and the interior, centred vs fused.

One accumulating :class:`~lightsim.engine.server.Session` per scene; at each photon budget
its final image's per-set ICI rungs are kept and both written maps are made from the
*same* rungs: the centred ICI map (``directional=False``) and the fused directional one
(:mod:`lightsim.render.directional`). Each is scored against the truth

* analytic scenes: the exact pixel means (:mod:`lightsim.validation.scenes.analytic`);
* scene files: a ``bin`` reference run of ``reference_factor`` × the largest budget.

Regions (over the lit pixels, truth ≥ ``lit_fraction`` × its maximum):

* **edge band**: lit pixels within ``band`` pixels (Chebyshev) of a pixel whose truth
  differs from theirs by more than a factor 2 (the beam's rim, a cut-off);
* **interior**: the other lit pixels;
* **inner** (paraboloid cases): pixel centres within 0.8 × the rim radius (the peer
  bench's score).

==================  =====  =========  ====================================================
parameter           unit   default    meaning
==================  =====  =========  ====================================================
``budgets``         –      –          photons (all sets) at which both maps are scored
``band``            px     2          half-width of the edge band
``lit_fraction``    –      0.1        lit threshold (the figure's own)
``reference_factor``–      6          reference photons / largest budget (scene files)
``frame_photons``   –      250 000    photons per frame
==================  =====  =========  ====================================================
"""

from __future__ import annotations

import json
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.io.exr import read_exr
from lightsim.render import written_map
from lightsim.render.frame import luminous
from lightsim.render.written_map import MapInputs
from lightsim.scene import SceneSettings, load_scene
from lightsim.simulate import SimulateOptions, run_simulation
from lightsim.validation import converge as cv
from lightsim.validation.bench.peer import CASES, LIGHTSIM_OUTPUTS, truth_of, write_scene_glb

REFERENCE_FACTOR = 6  # reference photons / largest budget (scene files)


def edge_band(truth: np.ndarray, lit: np.ndarray, band: int = 2) -> np.ndarray:
    """Lit pixels within ``band`` pixels of a factor-2 step of ``truth`` (H, W)."""
    H, W = truth.shape
    t = np.maximum(truth, 1e-300)
    step = np.zeros((H, W), bool)
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = t[max(dy, 0):H, max(dx, 0):W + min(dx, 0)]
        b = t[:H - dy, max(-dx, 0):W - max(dx, 0)]
        s = (np.maximum(a, b) > 2.0 * np.minimum(a, b))
        step[max(dy, 0):H, max(dx, 0):W + min(dx, 0)] |= s
        step[:H - dy, max(-dx, 0):W - max(dx, 0)] |= s
    near = np.zeros_like(step)
    for dy in range(-band, band + 1):
        for dx in range(-band, band + 1):
            near[max(dy, 0):H + min(dy, 0), max(dx, 0):W + min(dx, 0)] |= \
                step[max(-dy, 0):H + min(-dy, 0), max(-dx, 0):W + min(-dx, 0)]
    return near & lit


def rel_rmse(lux: np.ndarray, truth: np.ndarray, mask: np.ndarray, mean_lit: float,
             truth_var: np.ndarray | None = None) -> float:
    """rms error over ``mask`` relative to the mean truth over all lit pixels; a
    reference's own noise variance ``truth_var`` (lx²) is subtracted from the mean square."""
    if not mask.any():
        return math.nan
    d = lux[mask] - truth[mask]
    mse = float(np.mean(d * d))
    if truth_var is not None:
        mse = max(mse - float(np.mean(truth_var[mask])), 0.0)
    return math.sqrt(mse) / mean_lit


@dataclass
class MapScore:
    """One written map at one budget."""

    estimator: str          # "centred" or "fused"
    photons: int
    figure: float | None    # the map's own error figure (relative)
    alpha: float            # weight of the pixel counts in the written map
    all_lit: float          # true relative rms error, all lit pixels
    interior: float
    edge: float
    inner: float | None     # paraboloid cases: inner 80 % of the beam
    map_seconds: float      # time of written_map on this process
    edge_rungs: dict[int, float] = field(default_factory=dict)  # rung → share in the band

    def row(self) -> str:
        fig = "–" if self.figure is None else f"{self.figure:.4f}"
        inner = "–" if self.inner is None else f"{self.inner:.4f}"
        rungs = " ".join(f"{k}:{v:.2f}" for k, v in sorted(self.edge_rungs.items()))
        return (f"{self.estimator:8s} {self.photons:>11,} {fig:>7s} {self.all_lit:.4f} "
                f"{inner:>7s} {self.interior:.4f} {self.edge:.4f} {self.alpha:5.3f} "
                f"{self.map_seconds:6.2f}  {rungs}")


HEADER = (f"{'map':8s} {'photons':>11s} {'figure':>7s} {'all-lit':7s} {'inner':>7s} "
          f"{'interior':8s} {'edge':6s} {'alpha':5s} {'map s':>6s}  edge-band rungs (share)")


def capture_run(session: Session, photons: int) -> MapInputs:
    """Run ``session`` to ``photons`` and keep what its written map was made from."""
    estimator = session.map_estimator
    estimator.keep_inputs = True
    try:
        session.run(photons=photons, probes=False)
    finally:
        estimator.keep_inputs = False
    return estimator.last_inputs


def score(cap: MapInputs, truth: np.ndarray, lit: np.ndarray, band: np.ndarray,
          inner: np.ndarray | None, photons: int, truth_var: np.ndarray | None = None
          ) -> list[MapScore]:
    """Both written maps of one capture against the truth (``truth_var``: a reference's
    noise variance, lx²)."""
    out = []
    mean_lit = float(truth[lit].mean())
    for name, directional in (("centred", False), ("fused", True), ("written", None)):
        t0 = time.perf_counter()
        wm = cap.make(directional)
        dt = time.perf_counter() - t0
        lux = luminous(wm.lux).reshape(cap.shape)
        rung = wm.choice.rung.reshape(cap.shape)[band]
        share = {int(k): float(np.mean(rung == k)) for k in np.unique(rung)}
        out.append(MapScore(
            name, photons, None if wm.error is None else wm.error.total, wm.alpha,
            *(rel_rmse(lux, truth, m, mean_lit, truth_var) for m in (lit, lit & ~band, band)),
            None if inner is None else rel_rmse(lux, truth, inner & lit, mean_lit, truth_var),
            dt,
            share))
    return out


def study(scene, truth: np.ndarray, budgets: list[int], inner: np.ndarray | None = None,
          truth_var: np.ndarray | None = None, seed: int = 1, frame_photons: int = 250_000,
          band: int = 2, lit_fraction: float = 0.1, progress=print, **settings: Any
          ) -> list[MapScore]:
    """Score both maps at every budget in one accumulating session (``settings``: more
    :class:`RunConfig` fields); rows carry the photons actually emitted (a Selective
    Photon Tracing pass is whole, so a budget may be overshot)."""
    lit = truth >= lit_fraction * truth.max()
    bnd = edge_band(truth, lit, band)
    progress(f"{int(lit.sum())} lit pixels, {int(bnd.sum())} in the edge band")
    progress(HEADER)
    cfg = RunConfig(seed=seed, frame_photons=frame_photons, **settings)
    rows = []
    with Session(scene, cfg) as s:
        for b in sorted(budgets):
            cap = capture_run(s, int(b))
            for r in score(cap, truth, lit, bnd, inner, int(sum(cap.emitted.values())),
                           truth_var):
                progress(r.row())
                rows.append(r)
    return rows


def time_maps(cap: MapInputs, repeats: int = 3) -> dict[str, float]:
    """Median seconds of :func:`lightsim.render.written_map.written_map` on one capture: the
    centred map and the fused one (after a first call that loads numba's kernels)."""
    out = {}
    for name, directional in (("centred", False), ("fused", True), ("written", None)):
        cap.make(directional)
        ts = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            cap.make(directional)
            ts.append(time.perf_counter() - t0)
        out[name] = float(np.median(ts))
    return out


def timing(path: str, resolution: tuple[int, int], photons: int, repeats: int = 3
           ) -> dict[str, float]:
    """:func:`time_maps` on a run of ``photons`` of the scene file at ``resolution``."""
    scene = load_scene(path, SceneSettings(resolution=resolution))
    with Session(scene, RunConfig(seed=1, frame_photons=500_000)) as s:
        cap = capture_run(s, photons)
    return time_maps(cap, repeats)


@dataclass
class StopRun:
    """One ``lightsim simulate --target-error`` run of a peer-bench case."""

    estimator: str
    photons: int
    figure: float | None
    all_lit: float
    inner: float
    seconds: float


def stop_study(name: str = "paraboloid", target: float = 0.02, seed: int = 1,
               resolution: int = 64, folder=None) -> list[StopRun]:
    """``lightsim simulate CASE.glb --target-error T`` in this process
    (:func:`lightsim.simulate.run_simulation`), with the centred and with the fused
    written map (:data:`lightsim.render.written_map.DIRECTIONAL`), each map scored against
    the exact answer over all lit pixels and the inner 80 % of the beam."""
    case = CASES[name](resolution)
    tr = truth_of(case)
    lit = tr.exact_px >= 0.1 * tr.exact_px.max()
    mean_lit = float(tr.exact_px[lit].mean())
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(folder or tmp)
        glb = write_scene_glb(case, base / "scene.glb")
        before = written_map.DIRECTIONAL
        try:
            for label, directional in (("centred", False), ("written", True)):
                written_map.DIRECTIONAL = directional
                out = base / f"out-{label}"
                opts = SimulateOptions(scene_path=str(glb), target_error=target,
                                       resolution=(resolution, resolution), out_dir=str(out),
                                       outputs=tuple(LIGHTSIM_OUTPUTS.split(",")),
                                       config={"seed": seed})
                t0 = time.perf_counter()
                run_simulation(opts)
                dt = time.perf_counter() - t0
                summary = json.loads((out / "summary.json").read_text())
                lux = read_exr(out / "wall_lux.exr")[0]["Y"].astype(np.float64)
                runs.append(StopRun(label, int(summary["photons"]), summary.get("rel_error"),
                                    rel_rmse(lux, tr.exact_px, lit, mean_lit),
                                    tr.error(lux), dt))
        finally:
            written_map.DIRECTIONAL = before
    return runs


def main(argv: list[str] | None = None) -> None:
    """``python -m lightsim.validation.edge_study paraboloid|FILE.glb [WxH] budgets…
    [--reference=FILE.npz]`` (the scene file's reference kept there for the next run) or
    ``… --time FILE.glb WxH photons``."""
    args = list(sys.argv[1:] if argv is None else argv)
    name = args.pop(0)
    if name == "--stop":  # --stop CASE [target]
        for r in stop_study(args[0], float(args[1]) if len(args) > 1 else 0.02):
            fig = "–" if r.figure is None else f"{r.figure:.4f}"
            print(f"{r.estimator:8s} stopped at {r.photons:>11,} photons, figure {fig}, "
                  f"true all-lit {r.all_lit:.4f}, inner {r.inner:.4f} ({r.seconds:.1f} s)")
        return
    if name == "--figure":  # --figure FILE WxH budgets…: the figures of both maps
        W, H = (int(v) for v in args[1].split("x"))
        scene = load_scene(args[0], SceneSettings(resolution=(W, H)))
        with Session(scene, RunConfig(seed=1, frame_photons=500_000)) as s:
            for b in sorted(int(float(x)) for x in args[2:]):
                cap = capture_run(s, b)
                figs = []
                for directional in (False, None):
                    t0 = time.perf_counter()
                    wm = cap.make(directional)
                    figs.append((wm.error.total, time.perf_counter() - t0, wm.fused))
                print(f"{b:>11,} photons: centred figure {figs[0][0]:.4f} "
                      f"({figs[0][1]:.2f} s), written {figs[1][0]:.4f} "
                      f"({'fused' if figs[1][2] else 'centred'}, {figs[1][1]:.2f} s)")
        return
    if name == "--time":  # --time FILE WxH photons
        W, H = (int(v) for v in args[1].split("x"))
        t = timing(args[0], (W, H), int(float(args[2])))
        print(f"written map at {W} x {H}: centred {t['centred']:.3f} s, fused "
              f"{t['fused']:.3f} s, written (both, the better) {t['written']:.3f} s "
              f"(ratio {t['written'] / t['centred']:.2f})")
        return
    args = [x for x in args if not x.startswith("--reference=")]
    budgets = [int(float(x)) for x in args if "x" not in x]
    res = [tuple(int(v) for v in x.split("x")) for x in args if "x" in x]
    if name in CASES:
        case = CASES[name](64)
        tr = truth_of(case)
        study(case.scene, tr.exact_px, budgets, tr.inner)
        return
    target = cv.scene_target(name, res[0] if res else (320, 128))
    saved = [x.split("=", 1)[1] for x in sys.argv if x.startswith("--reference=")]
    if saved and Path(saved[0]).exists():  # a reference kept from an earlier run
        with np.load(saved[0]) as z:
            target.ref_px, target.ref_se = z["px"], z["se"]
    else:
        t0 = time.perf_counter()
        cv.reference_run(target, None, 1, 1_000_000, photons=REFERENCE_FACTOR * max(budgets))
        print(f"reference: {REFERENCE_FACTOR * max(budgets):,} bin photons in "
              f"{time.perf_counter() - t0:.0f} s")
        if saved:
            np.savez(saved[0], px=target.ref_px, se=target.ref_se)
    study(target.scene, target.ref_px, budgets, truth_var=target.ref_se**2)


if __name__ == "__main__":
    main()
