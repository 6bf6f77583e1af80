"""``lightsim adb``'s files: the composed map, its isolux and road views with the road users
drawn, the levels over the frames, and adb.json (every frame's levels and verdicts).

All files are written as one set (staged, ``adb.json`` moved in last:
:class:`~lightsim.io.atomic.OutputSet`); nothing is written when any input is bad.

=======================  ===================================================================
file                     content
=======================  ===================================================================
``adb.json``             settings, limits (line, source, certainty), per frame: the levels,
                         the verdict at every glare position with its interval (cd), the
                         residual light in every road user's outline (cd, interval,
                         fraction of all-on)
``adb_composed.exr``     the shown frame's composed map (channel ``Y``, lx)
``adb_isolux.png``       its iso-lux lines (lx) on the screen, outlines and glare positions
                         in their verdict colours
``adb_road.png``         bird's-eye road view (lx on the road) with the road users drawn
``adb_levels.png``       every segment's level against the frame (sequences only)
=======================  ===================================================================
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import uniform_filter

from lightsim import __version__
from lightsim.io.atomic import OutputSet
from lightsim.io.caption import add_caption, png_metadata
from lightsim.io.exr import wall_metadata, write_exr
from lightsim.io.summary import write_json
from lightsim.render.road import road_illuminance
from lightsim.wall import WallFrame

from .adb import VEHICLE_SIZE_M, AdbComposer, AdbResult

FILES = ("adb.json", "adb_composed.exr", "adb_isolux.png", "adb_road.png", "adb_levels.png")
COLOURS = {"pass": "#1a9850", "fail": "#d73027", "undecided": "#fc8d59",
           "off screen": "#777777"}


def adb_json(result: AdbResult) -> dict[str, Any]:
    """The content of ``adb.json``."""
    tr = result.traffic
    return {
        "lightsim_version": __version__,
        "traffic_file": tr.path,
        "road": {"mount_height_m": tr.mount_height_m, "lane_width_m": tr.lane_width_m,
                 "lamp_offset_m": tr.lamp_offset_m, "side": tr.side},
        "settings": {"aperture_deg": result.settings.aperture_deg,
                     "confidence": result.settings.confidence,
                     "ruleset": result.settings.ruleset},
        "limits": [{"kind": ln.kind, "line": ln.line, "distance_m": ln.distance_m,
                    "max_cd": ln.max_cd, "certainty": ln.certainty, "source": ln.source}
                   for ln in result.limits.lines],
        "segments": list(result.names),
        "fixed_levels": dict(tr.fixed),
        "shown_frame": result.shown,
        "summary": result.summary(),
        "frames": [f.to_dict(result.names) for f in result.frames],
    }


def write_adb(out: Path, result: AdbResult, composer: AdbComposer,
              plots: bool = True, caption: str | None = None) -> list[Path]:
    """Write the set into ``out`` (created); returns the files written. ``caption``: the
    text under every plot and in its PNG metadata (the run's lamp, seed, photons, error
    figure, the ADB rule set and lightsim's version)."""
    out.mkdir(parents=True, exist_ok=True)
    shown = result.frames[result.shown]
    lux = composer.composed(shown.levels)
    with OutputSet(out, "adb.json", FILES) as staged:
        d = staged.dir
        write_exr(d / "adb_composed.exr", {"Y": lux},
                  wall_metadata(result.wall, units="lx", quantity="illuminance",
                                levels=[float(w) for w in shown.levels],
                                segments=list(result.names), frame=result.shown,
                                lightsim_version=__version__))
        if plots:
            users = result.traffic.frames[result.shown]
            isolux_with_users(d / "adb_isolux.png", lux, result.wall, shown, users, caption)
            road_with_users(d / "adb_road.png", lux, result.wall, users,
                            result.traffic.mount_height_m, caption)
            if len(result.frames) > 1:
                levels_plot(d / "adb_levels.png", result, caption)
        write_json(d / "adb.json", adb_json(result))
        names = sorted(p.name for p in d.iterdir() if p.is_file())
        staged.commit()
    return [out / n for n in names]


def isolux_with_users(path: Path, lux: np.ndarray, wall: dict[str, Any], frame: Any,
                      users: list[Any], caption: str | None = None) -> None:
    """Iso-lux lines of the composed map, each road user's outline and glare positions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    f = WallFrame.from_dict(wall)
    x0, x1, y0, y1 = f.extent_deg()
    fig, ax = plt.subplots(figsize=(9, 4), dpi=110)
    peak = float(np.nanmax(lux)) if lux.size else 0.0
    if peak > 0:
        # contours of the pixel means smoothed over 3 × 3 pixels (display only: the noise of
        # single pixels would draw rings around every photon)
        levels = [x for x in (0.3, 1, 3, 10, 30, 100, 300, 1000) if peak / 100 <= x < peak]
        h, v = f.h_deg(), f.v_deg()
        im = ax.imshow(np.log10(np.maximum(lux, peak * 1e-4)), extent=(x0, x1, y0, y1),
                       origin="upper", cmap="magma", aspect="auto")
        fig.colorbar(im, ax=ax, label="log10 illuminance at 25 m (lx)")
        if levels:
            cs = ax.contour(h, v, uniform_filter(lux.astype(np.float64), 3), levels=levels,
                            colors="white", linewidths=0.6)
            ax.clabel(cs, fontsize=6, fmt="%g")
    for r in frame.residual:
        h0, h1, v0, v1 = r["zone_deg"]
        ax.add_patch(Rectangle((h0, v0), h1 - h0, v1 - v0, fill=False, color="cyan",
                               linewidth=1.0))
        ax.text(h0, v1, f" {r['user']}: {r['mean_cd']:.0f} cd", color="cyan", fontsize=6,
                va="bottom")
    for p in frame.positions:
        ax.plot(p["h_deg"], p["v_deg"], "o", ms=4, color=COLOURS[p["verdict"]],
                markeredgecolor="white", markeredgewidth=0.5)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xlabel("H (deg)")
    ax.set_ylabel("V (deg)")
    ax.set_title("ADB composed map: road users' outlines, glare positions (green pass, "
                 "red fail, orange undecided)", fontsize=8)
    fig.tight_layout()
    _save(fig, path, caption)


def road_with_users(path: Path, lux: np.ndarray, wall: dict[str, Any], users: list[Any],
                    mount_height_m: float, caption: str | None = None) -> None:
    """Bird's-eye road view of the composed map (lx on the road) with the road users."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    far = max([60.0] + [1.2 * u.distance_m for u in users])
    side = max([8.0] + [abs(u.lateral_m) + 3.0 for u in users])
    road = road_illuminance(lux, wall, mount_height_m, (-side, side), (0.0, far),
                            max(far / 400.0, 0.1))
    fig, ax = plt.subplots(figsize=(5, 7), dpi=110)
    e = np.ma.masked_invalid(road.lux)
    levels = [1, 3, 5, 10, 20, 50]
    im = ax.pcolormesh(road.x_m, road.z_m, np.log10(np.maximum(e, 1e-2)), cmap="magma",
                       shading="auto", vmin=-1, vmax=2)
    fig.colorbar(im, ax=ax, label="log10 road illuminance (lx)")
    if np.nanmax(road.lux) > 1:
        ax.contour(road.x_m, road.z_m, e, levels=levels, colors="white", linewidths=0.6)
    w, length = VEHICLE_SIZE_M[0], 4.5
    for u in users:
        z0 = u.distance_m  # the near end of the vehicle
        ax.add_patch(Rectangle((u.lateral_m - 0.5 * w, z0), w, length, color="cyan",
                               alpha=0.8))
        ax.text(u.lateral_m + 0.6 * w, z0, f"{u.name} ({u.distance_m:.0f} m)", color="cyan",
                fontsize=6)
    ax.set_xlabel("lateral (m, + right)")
    ax.set_ylabel("distance ahead (m)")
    ax.set_title("ADB road view (lamp at 0, 0)", fontsize=8)
    fig.tight_layout()
    _save(fig, path, caption)


def levels_plot(path: Path, result: AdbResult, caption: str | None = None) -> None:
    """Each segment's level against the frame (and the first road user's distance)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    levels = np.array([f.levels for f in result.frames])
    fig, ax = plt.subplots(figsize=(8, 4), dpi=110)
    im = ax.imshow(levels.T, aspect="auto", origin="lower", cmap="viridis", vmin=0, vmax=1,
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, label="level (0 off, 1 full)")
    ax.set_yticks(range(len(result.names)), result.names, fontsize=6)
    ax.set_xlabel("frame")
    ax.set_title("ADB segment levels over the traffic sequence", fontsize=8)
    fig.tight_layout()
    _save(fig, path, caption)


def _save(fig: Any, path: Path, caption: str | None = None) -> None:
    import matplotlib.pyplot as plt

    add_caption(fig, caption)
    fig.savefig(path, metadata=png_metadata(caption))
    plt.close(fig)
