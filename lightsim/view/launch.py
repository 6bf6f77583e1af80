"""A live session from a loaded scene, its settings and the product's hooks.

:func:`open_live` joins the engine's pieces: the scene editor (with the bulb presets of
the hooks), the first controls (the scene's, photons per frame from the settings, a
restored ``state.json`` on top), the camera of the second tab, and the engine
:class:`~lightsim.engine.server.Session` factory (in-process or Ray, as the settings
say). The hooks — bulb presets, regulation table, run writer — come from
:mod:`lightsim.luminaires.live` (the engine imports no ``luminaires``).

======================  =====  ===========  ==============================================
camera of the 2nd tab   unit   value        meaning
======================  =====  ===========  ==============================================
position                m      (0, 1, −1)   above and behind the lamp
look at                 m      (0, 0, d)    H-V on the wall at distance d
field of view           deg    32           horizontal
======================  =====  ===========  ==============================================
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.io.summary import read_json
from lightsim.render.camera import PinholeCamera
from lightsim.scene import Scene
from lightsim.view.controls import Controls
from lightsim.view.editor import SceneEditor
from lightsim.view.live import LiveSession, Publish, ViewHooks
from lightsim.view.settings import ViewSettings


def default_camera(distance: float, resolution: tuple[int, int] = (400, 200)
                   ) -> PinholeCamera:
    """The second tab's camera: above and behind the lamp, looking at H-V on the wall
    ``distance`` metres away; ``resolution`` in pixels (W, H)."""
    return PinholeCamera(position=(0.0, 1.0, -1.0), look_at=(0.0, 0.0, float(distance)),
                         fov_deg=32.0, resolution=tuple(resolution))


def read_state(path: str | Path) -> dict[str, Any]:
    """A session folder's ``state.json`` (``lightsim view --state``), checked to hold
    controls; :class:`InputError` (one line) otherwise."""
    if not Path(path).is_file():
        raise InputError(f"{path}: no such file")
    state = read_json(path)
    if not isinstance(state, dict) or not isinstance(state.get("controls"), dict):
        raise InputError(f"{path}: not a lightsim view state.json")
    return state


def open_live(scene: Scene, settings: ViewSettings, hooks: ViewHooks, *,
              folder: Path | None = None, state: dict[str, Any] | None = None,
              publish: Publish | None = None) -> LiveSession:
    """The live session of ``scene`` (not started: :meth:`LiveSession.start`).

    Parameters
    ----------
    scene : Scene
        The loaded scene (its wall at ``settings.resolution``).
    settings : ViewSettings
    hooks : ViewHooks
        Bulb presets, regulation table and run writer.
    folder : Path, optional
        Session folder (edit log, state, saved runs); None: nothing is written.
    state : dict, optional
        A ``state.json`` (:func:`read_state`): its controls replace the scene's.
    publish : callable (kind, payload), optional
        Where frames, status and messages go (the web app's hub); None: nowhere.
    """
    editor = SceneEditor(scene, hooks.bulbs)
    controls = editor.defaults().with_changes({"frame_photons": settings.frame_photons})
    if state is not None:
        controls = Controls.from_dict({**controls.to_dict(), **state.get("controls", {})},
                                      editor.bulb_names())
    cam = default_camera(scene.wall.distance_m, settings.camera_resolution) \
        if settings.camera else None

    def make_session(sc: Scene, config: RunConfig, camera: bool = False) -> Session:
        # the camera pass (every diffuse hit stored, not only the wall's: ~10 % more work
        # per photon) only when the live session asks for it: while a tab shows the camera
        return Session(sc, config, workers=settings.workers, address=settings.address,
                       camera=camera and cam is not None, regulation=settings.regulation)

    return LiveSession(editor, make_session, RunConfig(), publish or (lambda k, p: None),
                       settings, hooks, controls=controls, folder=folder, camera=cam)
