"""Base scene + :class:`~lightsim.view.controls.Controls` → the edited scene.

=====================  ======  ==================================================================
quantity               unit    how it is applied
=====================  ======  ==================================================================
filament offset        mm      translation of every emitter (world axes)
filament tilt          deg     rotation of every emitter about world X through the filament
                               centre; + lifts the filament's front (+Z) end
bulb                   –       every emitter replaced by the preset's filament, centred at the
                               focus + the preset's offset (the focus is the file's filament
                               centre − its own preset's offset); glass and shield stay
flux                   lm      total emitter flux (shares between emitters kept)
aim H / V              deg     every non-wall part rotated about the origin (the lamp's
                               reference point): yaw first (+H = towards the driver's right,
                               world −X), then pitch (+V = up)
wall distance          m       the wall and its frame scaled about the origin: same angular
                               field, pixels and H/V degrees at the new distance
=====================  ======  ==================================================================

Every edit is computed from the *base* scene (not from the previous edit), so a sequence of
edits never accumulates rounding and the edit log replays to the same scene.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from lightsim.errors import InputError
from lightsim.raycast import WALL_MAX_TRIANGLES
from lightsim.scene import EMITTER, WALL, Part, Scene
from lightsim.view.controls import Controls


@dataclass(frozen=True)
class BulbPreset:
    """What the editor needs of a bulb preset (built by ``lightsim.luminaires.live``).

    Attributes
    ----------
    name : str
    flux_lm : float
        The preset's luminous flux (lm).
    offset_m : (3,) tuple
        Filament centre relative to the reflector focus (m).
    axis : (3,) tuple
        Unit filament axis.
    build : callable (centre_m, axis) → Part
        The preset's emitter part at ``centre_m`` (m) along ``axis``.
    """

    name: str
    flux_lm: float
    offset_m: tuple[float, float, float]
    axis: tuple[float, float, float]
    build: Callable[[np.ndarray, np.ndarray], Part]


def rotation_x(deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=np.float64)


def rotation_y(deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=np.float64)


def affine(lin: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = lin
    if t is not None:
        m[:3, 3] = t
    return m


def aim_matrix(h_deg: float, v_deg: float) -> np.ndarray:
    """4×4 rotation that turns the lamp's +Z towards (h_deg right, v_deg up).

    The wall's H axis is world −X, so +H is a rotation about +Y by −h; +V about +X by −v.
    """
    return affine(rotation_y(-h_deg) @ rotation_x(-v_deg))


class SceneEditor:
    """Applies controls to a base scene (see the module docstring).

    Parameters
    ----------
    base : Scene
        The loaded scene (with its wall).
    bulbs : dict of str → BulbPreset
        Presets for the bulb control (may be empty: the control then only keeps the file's).
    """

    def __init__(self, base: Scene, bulbs: dict[str, BulbPreset] | None = None) -> None:
        if base.wall is None:
            raise InputError("the scene has no measurement wall")
        if not base.emitters:
            raise InputError("the scene has no emitter")
        self.base = base
        self.bulbs = dict(bulbs or {})
        em = base.emitters
        pts = np.concatenate([p.vertices for p in em])
        self.filament_centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
        ls = (em[0].extras or {}).get("lightsim", {}) if isinstance(em[0].extras, dict) else {}
        self.base_bulb = str(ls.get("bulb", "")) if isinstance(ls, dict) else ""
        fil = ls.get("filament", {}) if isinstance(ls, dict) else {}
        axis = np.asarray(fil.get("axis", (0.0, 0.0, 1.0)) if isinstance(fil, dict)
                          else (0.0, 0.0, 1.0), float)
        self.base_axis = axis / max(np.linalg.norm(axis), 1e-300)
        preset = self.bulbs.get(self.base_bulb)
        offset = np.asarray(preset.offset_m if preset else (0.0, 0.0, 0.0), float)
        self.focus = self.filament_centre - offset
        self.base_flux = base.total_flux

    def defaults(self) -> Controls:
        """The controls that reproduce the base scene exactly."""
        return Controls(bulb=self.base_bulb, flux_lm=float(self.base_flux),
                        wall_distance_m=float(self.base.wall.distance_m))

    def bulb_names(self) -> tuple[str, ...]:
        names = list(self.bulbs)
        if self.base_bulb and self.base_bulb not in names:
            names.insert(0, self.base_bulb)
        return tuple(names) if names else (self.base_bulb,)

    # -- the edit ------------------------------------------------------------------------
    def emitters(self, c: Controls) -> list[Part]:
        """The emitter parts for the bulb, pose and flux of ``c`` (before aiming)."""
        if c.bulb and c.bulb != self.base_bulb and c.bulb in self.bulbs:
            preset = self.bulbs[c.bulb]
            centre = self.focus + np.asarray(preset.offset_m, float)
            em = [preset.build(centre, np.asarray(preset.axis, float))]
        else:
            centre = self.filament_centre
            em = list(self.base.emitters)
        total = sum(p.flux_lm for p in em)
        shares = [p.flux_lm / total if total > 0 else 1.0 / len(em) for p in em]
        pose = self.pose_matrix(c, centre)
        return [replace(p.transformed(pose), flux_lm=c.flux_lm * w) for p, w in zip(em, shares)]

    def pose_matrix(self, c: Controls, centre: np.ndarray | None = None) -> np.ndarray:
        """4×4 T(centre + d) · R(tilt) · T(−centre): offset d (mm) and tilt about the
        filament's own centre."""
        if centre is None:
            centre = self._centre(c)
        d = 1e-3 * np.array([c.filament_x_mm, c.filament_y_mm, c.filament_z_mm])
        lin = rotation_x(-c.filament_tilt_deg)
        return affine(lin, centre + d - lin @ centre)

    def emitter_matrix(self, c: Controls) -> np.ndarray:
        """4×4 from the unposed emitters of ``c``'s bulb to where they are drawn (pose,
        then aim): the engine's ``light_transform`` is the ratio of two of these."""
        return aim_matrix(c.aim_h_deg, c.aim_v_deg) @ self.pose_matrix(c)

    def _centre(self, c: Controls) -> np.ndarray:
        if c.bulb and c.bulb != self.base_bulb and c.bulb in self.bulbs:
            return self.focus + np.asarray(self.bulbs[c.bulb].offset_m, float)
        return self.filament_centre

    def wall_aimable(self) -> bool:
        """Whether the engine can aim by moving the wall (its wall is intersected outside
        embree, :meth:`~lightsim.scene.Scene.with_wall_transform`); a wall of more
        triangles stays in the embree scene, so aiming rebuilds it."""
        n = int(np.count_nonzero(self.base.tri_is_wall))
        return 0 < n <= WALL_MAX_TRIANGLES

    def session_scene(self, c: Controls) -> Scene:
        """The scene the live session traces: the lamp *unaimed* and the wall (with its
        pixel frame) turned the opposite way, R⁻¹ — the same lux map in wall
        coordinates as :meth:`build`'s aimed lamp, but an aim change is then only a wall
        transform (``Session.update(wall_transform=…)``, the embree scene stays).
        Without :meth:`wall_aimable`: :meth:`build`."""
        if not self.wall_aimable():
            return self.build(c)
        lamp = self.build(replace(c, aim_h_deg=0.0, aim_v_deg=0.0))
        if c.aim_h_deg == 0 and c.aim_v_deg == 0:
            return lamp
        return lamp.with_wall_transform(self.wall_matrix(c))

    def wall_matrix(self, c: Controls) -> np.ndarray:
        """4×4 that places the wall for :meth:`session_scene`: the inverse of the aim."""
        return aim_matrix(c.aim_h_deg, c.aim_v_deg).T  # a rotation: R⁻¹ = Rᵀ

    def build(self, c: Controls) -> Scene:
        """The edited scene (a new :class:`Scene`; the base is never modified)."""
        aim = aim_matrix(c.aim_h_deg, c.aim_v_deg)
        moved = not (c.aim_h_deg == 0 and c.aim_v_deg == 0)
        parts: list[Part] = []
        emitters = self.emitters(c)
        scale = c.wall_distance_m / self.base.wall.distance_m
        placed = False
        for p in self.base.parts:
            if p.role == EMITTER:  # the new emitters take the place of the first old one
                if not placed:
                    parts.extend(e.transformed(aim) if moved else e for e in emitters)
                    placed = True
                continue
            if p.role == WALL:
                parts.append(p if scale == 1.0 else p.transformed(affine(np.eye(3) * scale)))
            else:
                parts.append(p.transformed(aim) if moved else p)
        w = self.base.wall
        wall = w if scale == 1.0 else replace(
            w, centre=w.centre * scale, distance_m=w.distance_m * scale,
            h_range_m=(w.h_range_m[0] * scale, w.h_range_m[1] * scale),
            v_range_m=(w.v_range_m[0] * scale, w.v_range_m[1] * scale))
        return Scene(parts, wall, self.base.source, list(self.base.warnings),
                     self.base.channels)
