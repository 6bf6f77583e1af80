"""``lightsim view``: the interactive session in the browser (see ``lightsim.view``).

This module is the only place that joins the engine's view package with ``luminaires``:
it injects the bulb presets (filament meshes), the regulation evaluation, the run-folder
writer and the GLB writer into :class:`lightsim.view.live.LiveSession`.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import click
import numpy as np

from lightsim.engine.config import RunConfig
from lightsim.errors import InputError
from lightsim.options import click_option, lookup
from lightsim.simulate import SimulateOptions


def bulb_presets() -> dict[str, Any]:
    """Every bulb preset as a :class:`~lightsim.view.editor.BulbPreset`."""
    from lightsim.luminaires import bulbs, filament
    from lightsim.materials import DIFFUSE, Material
    from lightsim.scene import EMITTER, Part
    from lightsim.view.editor import BulbPreset

    out = {}
    for name in bulbs.bulb_names():
        spec = bulbs.get_bulb(name)

        def build(centre: np.ndarray, axis: np.ndarray, spec=spec) -> Part:
            verts, faces = filament.filament_mesh(spec.filament_length_m,
                                                  spec.filament_diameter_m, centre, axis)
            extras = {"lightsim": {"flux_lm": spec.flux_lm, "emission": "isotropic",
                                   "bulb": spec.name,
                                   "filament": {"length_m": spec.filament_length_m,
                                                "diameter_m": spec.filament_diameter_m,
                                                "centre_m": [float(x) for x in centre],
                                                "axis": [float(x) for x in axis]}}}
            return Part("filament", EMITTER, np.asarray(verts, float),
                        np.asarray(faces, np.int64), None, Material("filament", DIFFUSE),
                        flux_lm=spec.flux_lm, extras=extras)

        out[name] = BulbPreset(name, spec.flux_lm, tuple(spec.filament_offset_m),
                               tuple(spec.filament_axis), build)
    return out


def regulation_hook(ruleset: str, traffic: str):
    """Regulation table of a live session: every set estimates the rule set's probes."""
    from lightsim.luminaires.regulations import load_ruleset, probe_points
    from lightsim.luminaires.regulations.check import evaluate_probe_values
    from lightsim.render.frame import luminous
    from lightsim.view.live import RegulationTable

    rs = load_ruleset(ruleset)
    cache: dict[float, tuple[Any, np.ndarray]] = {}

    def evaluate(session) -> RegulationTable:
        frame = session.scene.wall
        d = float(frame.distance_m)
        if d not in cache:
            probes = probe_points(rs, traffic, frame=frame.to_dict())
            hv = np.stack([d * np.tan(np.radians(probes.h_deg)),
                           d * np.tan(np.radians(probes.v_deg))], axis=1)
            cache.clear()
            cache[d] = (probes, hv)
        probes, hv = cache[d]
        values = luminous(session.probe(hv).values) if len(hv) else np.zeros((1, 0))
        results, unevaluated, _ = evaluate_probe_values(rs, probes, hv, values, d, traffic)
        rows, points = [], []
        for r in results:
            lim = r.get("limit") or {}
            text = " ".join(f"{'≥' if k == 'min' else '≤'} {v:,.0f}" for k, v in lim.items()
                            if k in ("min", "max"))
            rows.append({"name": r["name"], "kind": r.get("kind"), "limit": text or "–",
                         "value": _num(r.get("value_cd")),
                         "interval": [_num(x) for x in r["interval_cd"]]
                         if r.get("interval_cd") else None,
                         "verdict": r.get("verdict")})
            if r.get("kind") == "point" and r.get("h_deg") is not None:
                points.append({"name": r["name"], "h_deg": float(r["h_deg"]),
                               "v_deg": float(r["v_deg"]), "verdict": r.get("verdict")})
        return RegulationTable(f"{rs.id} ({traffic}-hand traffic)", rows, points,
                               len(unevaluated))

    return evaluate


def _num(x: Any) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def scene_gltf_parts(scene) -> list[Any]:
    """The scene's parts as glTF parts (materials mapped back to the loader's rules)."""
    from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart
    from lightsim.materials import DIELECTRIC, MIRROR
    from lightsim.scene import EMITTER, WALL

    out = []
    for p in scene.parts:
        m = p.material
        rgb = tuple(float(x) for x in np.clip(m.rgb, 0, 1))
        extras: dict[str, Any] = {}
        if p.role == EMITTER:
            mat = GltfMaterial(m.name or "emitter", emissive=(1.0, 1.0, 1.0))
            ls = dict((p.extras or {}).get("lightsim", {}))
            ls.update(flux_lm=float(p.flux_lm), emission=p.emission)
            extras = {"lightsim": ls}
        elif p.role == WALL:
            mat = GltfMaterial("wall", base_color=rgb)
            extras = {"lightsim": {"role": "wall"}}
        elif m.kind == MIRROR:
            mat = GltfMaterial(m.name or p.name, base_color=rgb, metallic=1.0, roughness=0.0)
        elif m.kind == DIELECTRIC:
            d = 0.01  # m: attenuation colour after 1 cm, σ = −ln(c)/d on reading
            att = tuple(float(max(np.exp(-s * d), 1e-12)) for s in m.sigma)
            absorbing = bool(np.any(np.asarray(m.sigma) > 0))
            mat = GltfMaterial(m.name or p.name, transmission=1.0, ior=float(m.ior),
                               attenuation_distance=d if absorbing else None,
                               attenuation_color=att if absorbing else None)
        else:
            mat = GltfMaterial(m.name or p.name, base_color=rgb)
        out.append(GltfPart(p.name if p.role != WALL else "wall", p.vertices, p.faces,
                            p.normals if p.role not in (EMITTER, WALL) else None, mat,
                            extras=extras or None))
    return out


def save_hook(scene_path: str, ruleset: str | None, traffic: str, workers: int,
              address: str | None):
    """Writes a normal run folder (as ``simulate``) plus ``scene.glb`` and ``controls.json``."""
    from lightsim.io.summary import write_json
    from lightsim.luminaires.analyses import for_options
    from lightsim.luminaires.gltf_writer import write_glb
    from lightsim.simulate import SimulateOptions, write_outputs

    def save(folder: Path, session, est, controls, scene) -> list[str]:
        w = scene.wall
        opts = SimulateOptions(
            scene_path=str(scene_path), out_dir=str(folder), flux=controls.flux_lm,
            wall_distance=float(w.distance_m),
            wall_size=(w.h_range_m[1] - w.h_range_m[0], w.v_range_m[1] - w.v_range_m[0]),
            resolution=tuple(w.resolution), workers=workers, address=address,
            regulation=ruleset, traffic=traffic,
            config={"k": controls.k, "interleave": controls.interleave,
                    "frame_photons": controls.frame_photons})
        write_outputs(folder, opts, session, est, for_options(opts))
        write_glb(folder / "scene.glb", scene_gltf_parts(scene),
                  asset_extras={"lightsim": {"edited_by": "lightsim view",
                                             "controls": controls.to_dict()}})
        write_json(folder / "controls.json", {"scene": str(scene_path),
                                              "controls": controls.to_dict()})
        return sorted(p.name for p in folder.iterdir())

    return save


def default_camera(distance: float, resolution: tuple[int, int] = (400, 200)):
    """The second tab's camera: above and behind the lamp, looking at H-V on the wall."""
    from lightsim.render.camera import PinholeCamera

    return PinholeCamera(position=(0.0, 1.0, -1.0), look_at=(0.0, 0.0, float(distance)),
                         fov_deg=32.0, resolution=tuple(resolution))


def build_live(scene_path: str, *, resolution=(640, 256), workers: int = 0,
               address: str | None = None, regulation: str | None = "r112-b-passing",
               traffic: str = "right", folder: Path | None = None,
               state: dict[str, Any] | None = None, frame_photons: int = 20_000,
               camera: bool = True, camera_resolution: tuple[int, int] = (400, 200),
               publish=None, **live_kw: Any):
    """The live session of ``lightsim view`` (also used by the benchmark and the tests)."""
    from lightsim.engine.config import RunConfig
    from lightsim.engine.server import Session
    from lightsim.luminaires.regulations import load_ruleset
    from lightsim.scene import load_scene
    from lightsim.view.controls import Controls
    from lightsim.view.editor import SceneEditor
    from lightsim.view.live import LiveSession

    if regulation is not None:
        load_ruleset(regulation)  # an unknown rule set fails before any work
    if traffic not in ("right", "left"):
        raise InputError(f"traffic must be 'right' or 'left', got '{traffic}'")
    scene = load_scene(scene_path, resolution=tuple(resolution))
    editor = SceneEditor(scene, bulb_presets())
    controls = editor.defaults().with_changes({"frame_photons": frame_photons})
    if state is not None:
        controls = Controls.from_dict({**controls.to_dict(), **state.get("controls", {})},
                                      editor.bulb_names())
    cam = default_camera(scene.wall.distance_m, camera_resolution) if camera else None

    def make_session(sc, config: RunConfig, camera: bool = False):
        # the camera pass (every diffuse hit stored, not only the wall's: ~10 % more work
        # per photon) only when the live session asks for it: while a tab shows the camera
        return Session(sc, config, workers=workers, address=address,
                       camera=camera and cam is not None, regulation=regulation)

    return LiveSession(editor, make_session, RunConfig(), publish or (lambda k, p: None),
                       controls=controls,
                       regulation=regulation_hook(regulation, traffic) if regulation else None,
                       save_run=save_hook(scene_path, regulation, traffic, workers, address),
                       folder=folder, camera=cam, **live_kw)


def start_view(scene_path: str, port: int = 0, **kw: Any):
    """Start the live session and the web server; returns (live, server)."""
    from lightsim.scene import load_scene
    from lightsim.view.app import Hub, ViewServer, create_app

    hub = Hub()
    live = build_live(scene_path, publish=hub.publish, **kw)
    res = tuple(kw.get("resolution", (640, 256)))
    app = create_app(live, hub, lambda path: load_scene(path, resolution=res))
    server = ViewServer(app, port)
    server.start()
    live.start()
    return live, server


@click.command("view")
@click.argument("scene", type=click.Path(dir_okay=False))
@click_option(lookup(SimulateOptions, "workers"))
@click.option("--address", help="Ray cluster address HOST:PORT (instead of --workers).")
@click.option("--port", type=int, default=8765, show_default=True,
              help="Port on 127.0.0.1 (0 = any free port).")
@click.option("--regulation", default="r112-b-passing", show_default=True,
              help="Rule set drawn on the pattern ('none' for no table).")
@click_option(lookup(SimulateOptions, "traffic"))
@click_option(lookup(SimulateOptions, "resolution"))
@click_option(lookup(RunConfig, "frame_photons"), default=20_000)  # a control on the page
@click.option("--out", "out_dir", default="lightsim-view", show_default=True,
              type=click.Path(file_okay=False),
              help="Session folder: edits.jsonl, state.json, saved runs.")
@click.option("--state", "state_file", type=click.Path(dir_okay=False),
              help="Restore the controls of a state.json (e.g. after a crash).")
@click.option("--no-camera", is_flag=True, help="Leave out the camera tab.")
def view(scene: str, workers: int, address: str | None, port: int, regulation: str,
         traffic: str, resolution: tuple[int, int], frame_photons: int, out_dir: str,
         state_file: str | None, no_camera: bool) -> None:
    """Interactive session in the browser: live lux, controls, regulation, save run."""
    from lightsim.io.summary import read_json
    from lightsim.simulate import check_out_dir

    if workers and address:
        raise InputError("give --workers or --address, not both")
    if not 0 <= port <= 65535:
        raise InputError(f"--port must be 0–65535, got {port}")
    res = resolution
    state = None
    if state_file is not None:
        if not Path(state_file).is_file():
            raise InputError(f"{state_file}: no such file")
        state = read_json(state_file)
        if not isinstance(state, dict) or not isinstance(state.get("controls"), dict):
            raise InputError(f"{state_file}: not a lightsim view state.json")
    folder = check_out_dir(out_dir)
    live, server = start_view(scene, port, resolution=res, workers=workers, address=address,
                              regulation=None if regulation == "none" else regulation,
                              traffic=traffic, folder=folder, state=state,
                              frame_photons=frame_photons, camera=not no_camera)
    # the numba kernels compile now (the session's warm-up), not at the first edit
    click.echo("lightsim view: warming up (compiling kernels, first frames)…", err=True)
    while not live.ready.wait(0.5) and server.thread.is_alive():
        pass
    if live.error:
        server.stop()
        live.stop()
        raise InputError(live.error)
    click.echo(f"lightsim view: {server.url}  (session folder {folder}; Ctrl-C to stop)")
    try:
        while server.thread.is_alive():
            time.sleep(0.5)
    finally:
        server.stop()
        live.stop()
