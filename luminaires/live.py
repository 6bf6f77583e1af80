"""``lightsim view``'s product wiring: the engine's live session with the luminaires.

The engine's view package (:mod:`lightsim.view`) imports no ``luminaires``; this module
gives it, as :class:`~lightsim.view.live.ViewHooks`, what the product adds:

====================  =========================================================================
piece                 what
====================  =========================================================================
bulb presets          every bulb of :mod:`~lightsim.luminaires.bulbs` as a filament mesh
                      builder (:func:`bulb_presets`)
regulation table      the rule set's probes estimated from every set, with intervals and
                      verdicts decided as ``simulate --until decided`` decides them, each
                      row decided or open (:func:`regulation_hook`)
save run              a normal ``simulate`` run folder plus ``scene.glb`` (the edited scene)
                      and ``controls.json`` (:func:`save_hook`)
====================  =========================================================================

:func:`build_live` and :func:`start_view` are what ``lightsim view``, its benchmark and
its tests run: the scene loaded, the hooks built, the live session (and web server)
opened from one :class:`~lightsim.view.settings.ViewSettings`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from lightsim.io.summary import write_json
from lightsim.luminaires import bulbs, filament
from lightsim.luminaires.analyses import for_options
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb
from lightsim.luminaires.regulations import load_ruleset, unevaluated_rules
from lightsim.luminaires.regulations.sequential import VerdictRule
from lightsim.materials import DIELECTRIC, DIFFUSE, MIRROR, Material
from lightsim.scene import EMITTER, WALL, Part, Scene, SceneSettings, load_scene
from lightsim.simulate import SimulateOptions, write_outputs
from lightsim.view.app import Hub, ViewServer, serve
from lightsim.view.editor import BulbPreset
from lightsim.view.launch import open_live
from lightsim.view.live import (
    LiveSession,
    Publish,
    RegulationHook,
    RegulationTable,
    SaveHook,
    ViewHooks,
)
from lightsim.view.schedule import finite_or_none
from lightsim.view.settings import ViewSettings

ATTENUATION_DISTANCE = 0.01  # m: a glass's attenuation colour is given after 1 cm


def bulb_presets() -> dict[str, BulbPreset]:
    """Every bulb preset as a :class:`~lightsim.view.editor.BulbPreset`."""
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


def regulation_hook(ruleset: str, traffic: str, cap_photons: int | None = None
                    ) -> RegulationHook:
    """Regulation table of a live session: every set estimates the rule set's probes
    (intensities in cd at the rule set's points for ``traffic``-hand traffic), and the
    verdicts are decided as ``simulate --until decided`` decides them.

    The table looks at the verdicts on the rule's schedule
    (:class:`~lightsim.luminaires.regulations.sequential.VerdictRule`): first at the
    photons of its first call, then at every doubling, the error budget split over the
    looks up to ``cap_photons`` (where accumulation stops; default the view's
    ``max_photons``). A row is ``decided`` once its
    running interval clears or misses its limit, and stays so; a call between looks
    shows the last look's table. An edit (or a new session) starts the looks again."""
    cap = int(ViewSettings().max_photons if cap_photons is None else cap_photons)
    state: dict[str, Any] = {"key": None, "rule": None, "table": None}
    load_ruleset(ruleset)  # an unknown rule set fails here, before any look

    def evaluate(session) -> RegulationTable:
        photons = int(session.photons_emitted())
        # the photons the looks have seen are gone after an edit or with a new session
        key = (id(session), sum(1 for e in session.log if e.get("event") == "update"))
        rule = state["rule"]
        if rule is None or state["key"] != key or photons < rule.last_photons:
            rule = VerdictRule()
            rule.add(ruleset, traffic)
            rule.bind(session, max(cap, 2 * max(photons, 1)),
                      first_photons=max(photons, 1), from_photons=0)
            state.update(key=key, rule=rule, table=None)
        if rule.due(photons) or state["table"] is None:
            if rule.due(photons):
                rule.look(photons)
            state["table"] = live_table(rule, traffic, photons)
        return state["table"]

    return evaluate


def live_table(rule: VerdictRule, traffic: str, photons: int) -> RegulationTable:
    """The page's table of the rule's first rule set after its last look: every row with
    ``decided`` (True: pass or fail for good; False: still open)."""
    rows, points = [], []
    results = rule.rows(0)
    for r in results:
        lim = r.get("limit") or {}
        text = " ".join(f"{'≥' if k == 'min' else '≤'} {v:,.0f}" for k, v in lim.items()
                        if k in ("min", "max"))
        rows.append({"name": r["name"], "kind": r.get("kind"), "limit": text or "–",
                     "value": number_or_none(r.get("value_cd")),
                     "interval": [number_or_none(x) for x in r["interval_cd"]]
                     if r.get("interval_cd") else None,
                     "verdict": r.get("verdict"), "decided": bool(r.get("decided"))})
        if r.get("kind") == "point" and r.get("h_deg") is not None:
            points.append({"name": r["name"], "h_deg": float(r["h_deg"]),
                           "v_deg": float(r["v_deg"]), "verdict": r.get("verdict")})
    chk = rule.checks[0]
    done = sum(r["decided"] for r in rows)
    looked = rule.looks[-1]["photons"] if rule.looks else photons
    title = (f"{chk.rules.id} ({traffic}-hand traffic): {done} of {len(rows)} decided at "
             f"{looked:,} photons (look {len(rule.looks)} of {rule.schedule.looks})")
    unevaluated = len(unevaluated_rules(chk.rules, chk.probes))
    return RegulationTable(title, rows, points, unevaluated)


def number_or_none(x: Any) -> float | None:
    """``x`` as a finite float for the page's JSON, or None (missing, text, NaN, ±inf)."""
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return finite_or_none(v)


def scene_gltf_parts(scene: Scene) -> list[GltfPart]:
    """The scene's parts as glTF parts (materials mapped back to the loader's rules)."""
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
            d = ATTENUATION_DISTANCE  # σ = −ln(c)/d on reading
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


def save_hook(scene_path: str, settings: ViewSettings) -> SaveHook:
    """Writes a normal run folder (as ``simulate``) plus ``scene.glb`` and ``controls.json``."""

    def save(folder: Path, session, est, controls, scene) -> list[str]:
        w = scene.wall
        opts = SimulateOptions(
            scene_path=str(scene_path), out_dir=str(folder), flux=controls.flux_lm,
            wall_distance=float(w.distance_m),
            wall_size=(w.h_range_m[1] - w.h_range_m[0], w.v_range_m[1] - w.v_range_m[0]),
            resolution=tuple(w.resolution), workers=settings.workers,
            address=settings.address, regulation=settings.regulation,
            traffic=settings.traffic,
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


def view_hooks(scene_path: str, settings: ViewSettings) -> ViewHooks:
    """The bulb presets, the regulation table (none without ``settings.regulation``) and
    the run writer of a live session of ``scene_path``."""
    regulation = regulation_hook(settings.regulation, settings.traffic,
                                 settings.max_photons) if settings.regulation else None
    return ViewHooks(bulb_presets(), regulation, save_hook(scene_path, settings))


def build_live(scene_path: str, settings: ViewSettings | None = None, *,
               folder: Path | None = None, state: dict[str, Any] | None = None,
               publish: Publish | None = None) -> LiveSession:
    """The live session of ``lightsim view`` (not started), also run by the benchmark and
    the tests: ``scene_path`` loaded at ``settings.resolution``; ``folder``, ``state`` and
    ``publish`` as :func:`lightsim.view.launch.open_live` takes them."""
    settings = settings if settings is not None else ViewSettings()
    if settings.regulation is not None:
        load_ruleset(settings.regulation)  # an unknown rule set fails before any work
    scene = load_scene(scene_path, SceneSettings(resolution=tuple(settings.resolution)))
    return open_live(scene, settings, view_hooks(scene_path, settings), folder=folder,
                     state=state, publish=publish)


def start_view(scene_path: str, settings: ViewSettings | None = None, *,
               folder: Path | None = None, state: dict[str, Any] | None = None
               ) -> tuple[LiveSession, ViewServer]:
    """Start the live session and the web server on ``settings.host``:``settings.port``
    behind a new access token (``server.url`` carries it); returns (live, server)."""
    settings = settings if settings is not None else ViewSettings()
    hub = Hub()
    live = build_live(scene_path, settings, folder=folder, state=state, publish=hub.publish)
    res = tuple(settings.resolution)
    server = serve(live, hub, lambda path: load_scene(path, SceneSettings(resolution=res)),
                   settings)
    return live, server
