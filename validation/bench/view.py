"""``lightsim bench view``: the interactive session measured through a real browser.

Headless Chromium (Debian's ``/usr/bin/chromium``, driven by Playwright) opens the page of
``lightsim view`` on the shipped headlight and

1. **latency**: changes a control (aim H) and times, in the page, from sending the change
   to the first image drawn that carries it (``performance.now()`` both ends);
2. **interaction frames/s**: drags a control continuously (a change every 50 ms, as a
   slider drag) and counts the images drawn per second — every one has new photons;
3. **convergence**: after the last change, the time until the page shows the written
   map's own error figure (a pooled map's, not the grid probes') ≤ 5 % and ≤ 2 %;
4. **model for 16/64 Ray workers** from the measured per-frame costs, with the scaling
   bench's model (``docs/explanation/benchmarks.md``):
   T(N) = (t_shoot + t_render)·cores / N + t_rpc + B / bandwidth + t_server + N·t_result.

The baseline, measured in the same run without browser or web server, is the engine
alone: ``Session.update`` + ``Session.frame()`` in this process at the same settings and
edits, measured before and after the browser part (best of the two: the machine is
shared, and its load average is printed with the table).

=====================  ======  ========  ==================================================
parameter              unit    default   meaning
=====================  ======  ========  ==================================================
``resolution``         px      640×256   wall pixels
``frame_photons``      –       20 000    photons per frame
``changes``            –       5         latency samples
``drag_seconds``       s       6         length of the continuous drag
``converge_timeout``   s       40        give up waiting for 2 % after this
``t_rpc``              s       1.5 ms    Ray actor round trip (measured on Ray 2.60)
``t_result``           s       0.2 ms    driver receives one actor's reply (measured)
``bandwidth``          B/s     1.17·10⁸  server link (1 Gbit/s)
=====================  ======  ========  ==================================================
"""

from __future__ import annotations

import os
import shutil
import statistics
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numba
import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.errors import LightsimError
from lightsim.luminaires.live import build_live, start_view
from lightsim.scene import SceneSettings, load_scene
from lightsim.view.editor import SceneEditor
from lightsim.view.settings import ViewSettings

T_RPC = 1.5e-3
T_RESULT = 0.2e-3
BANDWIDTH = 117e6
CHROMIUM = "/usr/bin/chromium"


def load_average() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def engine_baseline(scene_path: str, resolution: tuple[int, int], frame_photons: int,
                    frames: int = 3) -> dict[str, float]:
    """:func:`engine_alone` in a worker thread, as the view's session runs (so the
    two differ only in the browser, server and page)."""
    with ThreadPoolExecutor(1) as pool:
        return pool.submit(engine_alone, scene_path, resolution, frame_photons,
                           frames).result()


def engine_alone(scene_path: str, resolution: tuple[int, int], frame_photons: int,
                     frames: int = 3) -> dict[str, float]:
    """The engine alone, the same edits as the page makes: seconds of an aim change
    (scene rebuilt) + frame, frames/s of filament moves (light transform) + frame, and
    photons/s of accumulation (``Session.accumulate``)."""
    scene = load_scene(scene_path, SceneSettings(resolution=resolution))
    editor = SceneEditor(scene)
    c = editor.defaults()
    with Session(scene, RunConfig(frame_photons=frame_photons)) as s:
        s.frame()  # warm-up
        aim, drag, shoot, render = [], [], [], []
        for i in range(frames):
            t0 = time.perf_counter()
            s.update(scene=editor.build(c.with_changes({"aim_h_deg": 0.1 * (i + 1)})))
            s.frame()
            aim.append(time.perf_counter() - t0)
        for i in range(frames):
            a, b = (c.with_changes({"filament_x_mm": 0.005 * j}) for j in (i, i + 1))
            t0 = time.perf_counter()
            s.update(light_transform=editor.emitter_matrix(b)
                     @ np.linalg.inv(editor.emitter_matrix(a)))
            est = s.frame()
            drag.append(time.perf_counter() - t0)
            shoot.append(est.timings["shoot"])
            render.append(est.timings["render"] + est.timings["assemble"])
        n0, t0 = sum(s.emitted_per_set().values()), time.perf_counter()
        s.accumulate(4)
        rate = (sum(s.emitted_per_set().values()) - n0) / (time.perf_counter() - t0)
    # the engine's own rate: frames of simulate's default size (200 000 photons)
    with Session(scene, RunConfig()) as s:
        s.accumulate(1)
        t0 = time.perf_counter()
        s.accumulate(2)
        sim_rate = 2 * s.config.frame_photons / (time.perf_counter() - t0)
    return {"simulate_photons_per_s": sim_rate, "aim_update_frame_s": statistics.median(aim),
            "drag_fps": 1.0 / statistics.median(drag), "shoot_s": statistics.median(shoot),
            "render_s": statistics.median(render), "accumulate_photons_per_s": rate}


def error_law(scene_path: str, resolution: tuple[int, int] = (640, 256),
              marks: tuple[float, ...] = (1e6, 2e6, 4e6, 8e6, 16e6),
              batch: int = 400_000) -> list[dict[str, Any]]:
    """The written map's error figure against photons, as the view accumulates it: one
    session at the view's configuration (M = 4, k = 64, batches of ``batch`` photons, one
    numba thread) and a pooled map with its figure at each of ``marks`` photons. Shows
    which part falls: noise ∝ 1/√N, the blur (ICI bandwidth bias) does not, so the
    photons a level needs follow from √(noise² + blur²)."""
    live = build_live(scene_path, ViewSettings(resolution=tuple(resolution), regulation=None,
                                               camera=False))
    live.open_session(live.editor.session_scene(live.controls), live.controls)
    s = live.session
    rows: list[dict[str, Any]] = []
    try:
        numba.set_num_threads(1)
        s.shoot(50_000)  # compile, then start afresh
        s.frame(image=True, shoot=False, mode="pooled", probes="ici")
        s.update(light_transform=np.eye(4))
        traced = 0.0
        for mark in sorted(marks):
            while live.photons_now() < mark:
                t0 = time.perf_counter()
                s.shoot(batch)
                traced += time.perf_counter() - t0
            t0 = time.perf_counter()
            est = s.frame(image=True, shoot=False, mode="pooled", probes=False)
            cost = time.perf_counter() - t0
            e, n = est.error, int(est.photons)
            rows.append({"photons": n, "written map error": est.rel_error,
                         "noise": None if e is None else e.noise,
                         "blur": None if e is None else e.bias,
                         "e·√N": est.rel_error * n ** 0.5 if est.rel_error else None,
                         "pooled map s": cost, "tracing photons/s": n / traced,
                         "load average": load_average()})
    finally:
        s.close()
    return rows


def frame_model(t_clients: float, t_server: float, nbytes: float, workers: int
                ) -> dict[str, float]:
    """The scaling bench's per-frame model (docs/explanation/benchmarks.md) for ``workers``
    one-core workers.

    ``t_clients``: one core's shoot + render seconds of a frame; ``t_server``: the
    server's seconds (assemble, encode for the page); ``nbytes``: bytes from the actors.
    """
    t = (t_clients / workers + T_RPC + nbytes / BANDWIDTH + t_server
         + workers * T_RESULT)
    server = T_RPC + nbytes / BANDWIDTH + t_server + workers * T_RESULT
    return {"frame_s": t, "fps": 1.0 / t, "server_share": server / t}


def still_log(log: list[dict[str, Any]]) -> dict[str, Any]:
    """What the still scene's seconds went to: tracing (batches) and every other step
    (pooled maps, grid figure, table, interleaved images), seconds and counts, and the
    steps other than batches in order (t: seconds since the last change)."""
    acc = [e for e in log if e.get("mode") == "accumulation"]
    spent: dict[str, list[float]] = {}
    for e in acc:
        q = e.get("quality", "?")
        spent.setdefault(q, []).append(e.get("batch_s", e.get("frame_s", 0.0)))
    return {"seconds": {k: float(sum(v)) for k, v in spent.items()},
            "counts": {k: len(v) for k, v in spent.items()},
            "traced_photons": int(sum(e.get("batch_photons", 0) for e in acc)),
            "steps": [[round(e.get("t", 0.0), 3), e.get("quality"), e.get("photons"),
                       round(e.get("frame_s", 0.0), 3)] for e in acc
                      if e.get("quality") != "batch"]}


def latency_parts(samples: list[tuple[int, dict[str, float]]], log: list[dict[str, Any]]
                  ) -> dict[str, float]:
    """Where the change → image time went (ms, medians over the samples): the server's
    wait for a batch or frame in progress, update, shoot, render (+ assemble), encode (from
    the live session's log entry of the frame that carried the change), the page's draw
    (inflate, decode, paint) and the rest: browser → server → browser transport."""
    rows = []
    for n, page in samples:
        e = next((x for x in log if x.get("token_n") == n and x.get("mode") == "interaction"),
                 None)
        if e is None:
            continue
        server = {"wait": e.get("wait_s", 0.0), "update": e.get("update_s", 0.0),
                  "shoot": e.get("shoot_s", 0.0),
                  "render": e.get("render_s", 0.0) + e.get("assemble_s", 0.0),
                  "encode": e.get("encode_s", 0.0)}
        row = {k: 1e3 * v for k, v in server.items()}
        row["page draw"] = page.get("draw", 0.0)
        row["transport"] = page.get("arrived", 0.0) - sum(row[k] for k in server)
        row["total"] = page["ms"]
        rows.append(row)
    return {k: float(np.median([r[k] for r in rows])) for k in rows[0]} if rows else {}


_DRAG_JS = """async (seconds) => {
  const V = window.lightsimView;
  const t0 = performance.now(), n0 = V.wallFrames;
  let x = 0, last = t0;
  while (performance.now() - t0 < seconds * 1000) {
    if (performance.now() - last >= 50) {   // a slider drag: a change every 50 ms
      x = (x + 1) % 20; V.setControl('filament_x_mm', 0.005 * x); last = performance.now();
    }
    await new Promise((r) => setTimeout(r, 5));
  }
  return [(V.wallFrames - n0) / ((performance.now() - t0) / 1000), V.wallFrames - n0];
}"""

_CONVERGE_JS = """async ([timeout, marks]) => {
  const V = window.lightsimView;
  const t0 = performance.now(), out = {}, series = [];
  let best = null, last = null;
  while (performance.now() - t0 < timeout * 1000) {
    const s = V.status;
    // only the written map's own figure (a pooled map) counts, not the grid probes'
    if (s && s.edit >= marks.edit && s.rel_error !== null && s.error_source === "written map") {
      best = best === null ? s.rel_error : Math.min(best, s.rel_error);
      if (s.error_photons !== last) {
        last = s.error_photons;
        series.push([(performance.now() - t0) / 1000, s.rel_error, s.error_photons]);
      }
      for (const m of marks.levels)
        if (!(m in out) && s.rel_error <= m) out[m] = (performance.now() - t0) / 1000;
      if (Object.keys(out).length === marks.levels.length) break;
    }
    await new Promise((r) => setTimeout(r, 20));
  }
  return {reached: out, best, series, photons: V.status ? V.status.photons : 0,
          seconds: (performance.now() - t0) / 1000};
}"""


def bench_view(scene_path: str, resolution: tuple[int, int] = (640, 256),
               frame_photons: int = 20_000, changes: int = 5, drag_seconds: float = 6.0,
               converge_timeout: float = 40.0, chromium: str = CHROMIUM,
               screenshots: Path | None = None) -> dict[str, Any]:
    """Run the benchmark (see the module docstring); returns rows and the raw figures."""
    from playwright.sync_api import sync_playwright

    if not Path(chromium).exists():
        raise LightsimError(f"{chromium}: no Chromium (apt-get install chromium)")
    load0 = load_average()
    base = engine_baseline(scene_path, resolution, frame_photons)
    folder = Path(tempfile.mkdtemp(prefix="lightsim-bench-view-"))
    live, server = start_view(scene_path, ViewSettings(port=0, resolution=tuple(resolution),
                                                       frame_photons=frame_photons),
                              folder=folder)
    out: dict[str, Any] = {"engine": base, "load_average_start": load0}
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1300, "height": 900})
            page.goto(server.url)
            page.wait_for_function("window.lightsimView.wallFrames >= 2 && "
                                   "window.lightsimView.regulation !== null", timeout=120_000)
            # 1. latency of single changes
            lat, parts = [], []
            for i in range(changes):
                n = page.evaluate(f"window.lightsimView.setControl('aim_h_deg', {0.1 * (i + 1)})")
                page.wait_for_function(
                    f"window.lightsimView.latencies.some((l) => l.token === {n})",
                    timeout=60_000)
                got = page.evaluate(
                    f"window.lightsimView.latencies.find((l) => l.token === {n})")
                lat.append(got["ms"])
                parts.append((n, got))
                page.wait_for_timeout(300)
            out["latency_ms"] = lat
            out["latency_parts"] = latency_parts(parts, list(live.stats.log))
            # 2. interaction frames/s during a drag
            frames0 = len(live.stats.log)
            fps, drawn = page.evaluate(_DRAG_JS, drag_seconds)
            log = list(live.stats.log)[frames0:]
            inter = [e for e in log if e["mode"] == "interaction" and e["image"]]
            draw_ms = page.evaluate("window.lightsimView.drawMs")
            out["page_draw_ms"] = float(np.median(draw_ms)) if draw_ms else None
            out["drag"] = {"fps_drawn": fps, "frames_drawn": drawn,
                           "server_interaction_frames": len(inter),
                           "coalesced_edits": live.stats.edits_coalesced}
            if screenshots is not None:
                screenshots.mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(screenshots / "view-interaction.png"))
            # 3. convergence after the last change
            edit = page.evaluate("window.lightsimView.status.edit")
            n_log = len(live.stats.log)
            conv = page.evaluate(_CONVERGE_JS, [converge_timeout,
                                                {"edit": edit, "levels": [0.05, 0.02]}])
            out["converge"] = conv
            out["still_log"] = still_log(list(live.stats.log)[n_log:])
            batches = [e for e in list(live.stats.log) if e.get("quality") == "batch"]
            traced = sum(e["batch_s"] for e in batches)
            out["tracing_photons_per_s"] = (sum(e["batch_photons"] for e in batches)
                                            / traced if traced > 0 else 0.0)
            out["view_threads"] = {"used": live.last_status.get("numba_threads"),
                                   "warm_up_frame_s": dict(live.threads.frame_times),
                                   "warm_up_batch_s": dict(live.threads.batch_times),
                                   "accumulate": live.threads.accumulate,
                                   "still_batch_rates": dict(live.threads.rates)}
            if screenshots is not None:
                page.wait_for_timeout(1500)  # let a pooled map arrive if one is due
                page.screenshot(path=str(screenshots / "view-converged.png"))
            browser.close()
    finally:
        server.stop()
        live.stop()
        shutil.rmtree(folder, ignore_errors=True)
    out["load_average_end"] = load_average()
    # the machine is shared: the baseline again after the browser part, best of the two
    again = engine_baseline(scene_path, resolution, frame_photons)
    out["engine_before"], out["engine_after"] = base, again
    base = {"aim_update_frame_s": min(base["aim_update_frame_s"], again["aim_update_frame_s"]),
            "drag_fps": max(base["drag_fps"], again["drag_fps"]),
            "accumulate_photons_per_s": max(base["accumulate_photons_per_s"],
                                            again["accumulate_photons_per_s"]),
            "simulate_photons_per_s": max(base["simulate_photons_per_s"],
                                          again["simulate_photons_per_s"]),
            "shoot_s": min(base["shoot_s"], again["shoot_s"]),
            "render_s": min(base["render_s"], again["render_s"])}
    out["engine"] = base

    # 4. per-frame costs → model
    t_shoot = float(np.median([e["shoot_s"] for e in inter])) if inter else base["shoot_s"]
    t_render = float(np.median([e["render_s"] + e.get("assemble_s", 0.0) for e in inter])) \
        if inter else base["render_s"]
    t_encode = float(np.median([e["encode_s"] for e in inter if "encode_s" in e])) \
        if inter else 0.0
    frame_bytes = float(np.median([e["bytes"] for e in inter if "bytes" in e])) if inter else 0
    t_update = float(np.median([e["update_s"] for e in inter])) if inter else 0.0
    cores = os.cpu_count() or 1
    W, H = resolution
    rows: list[dict[str, Any]] = []
    lat_med = statistics.median(lat)
    rows.append({"figure": "change → first updated image drawn", "measured": lat_med,
                 "unit": "ms (median)", "target": "≤ 200", "met": lat_med <= 200,
                 "baseline (engine alone)": 1000 * base["aim_update_frame_s"],
                 "ratio vs baseline": lat_med / (1000 * base["aim_update_frame_s"])})
    rows.append({"figure": "interaction frames/s (drag, drawn)", "measured": fps,
                 "unit": "1/s", "target": "≥ 5", "met": fps >= 5,
                 "baseline (engine alone)": base["drag_fps"],
                 "ratio vs baseline": fps / base["drag_fps"]})
    acc_rate = conv["photons"] / max(conv["seconds"], 1e-9)
    rows.append({"figure": "accumulation photons/s (still scene)", "measured": acc_rate,
                 "unit": "1/s", "target": "–", "met": "–",
                 "baseline (engine alone)": base["accumulate_photons_per_s"],
                 "ratio vs baseline": acc_rate / base["accumulate_photons_per_s"]})
    trace_rate = out.get("tracing_photons_per_s", 0.0)
    rows.append({"figure": "accumulation batches: tracing photons/s", "measured": trace_rate,
                 "unit": "1/s", "target": "engine's rate", "met": "–",
                 "baseline (engine alone)": base["simulate_photons_per_s"],
                 "ratio vs baseline": trace_rate / base["simulate_photons_per_s"]})
    for level, target in ((0.05, 5.0), (0.02, 30.0)):
        t = conv["reached"].get(str(level), conv["reached"].get(level))
        rows.append({"figure": f"still → error ≤ {100 * level:.0f} %",
                     "measured": t if t is not None else f"not in {converge_timeout:.0f} s "
                     f"(best {100 * (conv['best'] or float('nan')):.1f} %)",
                     "unit": "s", "target": f"≤ {target:.0f}",
                     "met": t is not None and t <= target})
    inter_photons = float(np.median([e["photons"] for e in inter])) if inter else 0.0
    out["costs"] = {"update_s": t_update, "shoot_s": t_shoot, "render_s": t_render,
                    "encode_s": t_encode, "page_draw_s": (out.get("page_draw_ms") or 0) / 1e3,
                    "interaction_photons": inter_photons,
                    "frame_bytes_to_page": frame_bytes, "cores": cores,
                    "numba_threads": out.get("view_threads", {}).get("used") or cores}
    models = []
    for n, m in ((16, 4), (64, 8)):
        # one core's cost (the view's frames use its numba threads); sub-images W·H float32,
        # probes and pixel windows 2 × S × 2048 float32 (docs/explanation/benchmarks.md)
        nbytes = W * H * 4 + 2 * m * m * 2048 * 4
        t_clients = (t_shoot + t_render) * min(cores, out["costs"]["numba_threads"])
        mod = frame_model(t_clients, t_encode, nbytes, n)
        models.append({"workers": n, "M": m, "one-core client s/frame": t_clients,
                       "server s/frame": t_encode + T_RPC + nbytes / BANDWIDTH + n * T_RESULT,
                       "model fps": mod["fps"], "server share": mod["server_share"]})
    out["rows"], out["model"] = rows, models
    return out
