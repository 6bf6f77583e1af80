"""Matrix LED high beam: N individually driven segments behind one shared lens → GLB.

A row of N LED dies (the segments) lies in the focal plane of an aspheric plano-convex
lens (:mod:`lightsim.luminaires.asphere`). The lens images each die to infinity: die k,
centred at x_k beside the lens axis, lights the vertical stripe of the screen around
H_k ≈ atan(x_k / f) (world +X beside the axis becomes H > 0, the driver's right, because
the image is inverted), and a die from y_lo to y_hi lights V from about −atan(y_hi / f)
to −atan(y_lo / f). The die edges are placed with the lens's traced mapping
(:func:`~lightsim.luminaires.asphere.offset_for_angle_m`), which off the axis bends a
little more than atan(x / f). The stripes are equally wide and tile ``span_deg`` without gaps; the
dies are ``fill`` of their pitch wide. A black housing (board and tube) takes the light
that misses the lens, as a real lamp's does.

Segment dies are separate emitter parts named ``led_00`` … ``led_NN`` from the left
(H < 0) to the right, each with ``extras.lightsim.group = "led_NN"`` and
``extras.lightsim.segment = k``: a run can switch one on alone (``--part-material
led_03=ignore`` switches one off), and a per-segment map can group by these names.

Axes and units follow ``docs/reference/conventions.md``: metres, +Y up, the lamp shines
along +Z; the lens axis is the Z axis, the dies lie in the plane z = 0 facing +Z.

Parameters of :class:`MatrixParams`

======================  =====  ========  ===================================================
name                    unit   default   meaning
======================  =====  ========  ===================================================
segments                –      16        number of segments (N ≥ 1)
span_deg                °      24        total width of the stripes, centred on H = 0
v_low_deg, v_high_deg   °      −1.5, 2   vertical extent of every stripe (V down, up)
fill                    –      1.0       die width / pitch (1: the segments of one
                                         monolithic die touch, as on pixel LED arrays)
flux_lm                 lm     260       mean flux of a segment; each gets its share by
                                         die area (equal luminance, ≈ 45 lm/mm²)
lens_diameter_m         m      0.080     lens clear diameter
lens_distance_m         m      0.050     dies to the lens's flat back face
lens_ior                –      1.52      lens glass (crown glass)
only_segment            –      none      build only this segment's die (the others are
                                         left out); ``None``: all
======================  =====  ========  ===================================================
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes

from .asphere import lens_design, lens_glass, lens_mesh, offset_for_angle_m, revolve
from .gltf_writer import GltfMaterial, GltfPart, glb_bytes

__all__ = ["MatrixParams", "build_matrix", "segment_name", "stripe_edges_deg",
           "write_matrix"]

MM = 1e-3

#: LED die: emissive white (the flux is in the node extras).
SEGMENT_MATERIAL = GltfMaterial(name="LED segment (emitter)", base_color=(1.0, 1.0, 1.0),
                                roughness=1.0, emissive=(1.0, 1.0, 1.0))
#: Board and housing: blackened.
HOUSING_BLACK = GltfMaterial(name="black housing", base_color=(0.05, 0.05, 0.05),
                             roughness=0.9, double_sided=True)


@dataclass(frozen=True)
class MatrixParams:
    """Parameters of :func:`build_matrix` (SI units; see the module table)."""

    segments: int = 16
    span_deg: float = 24.0
    v_low_deg: float = -1.5
    v_high_deg: float = 2.0
    fill: float = 1.0
    flux_lm: float = 260.0
    lens_diameter_m: float = 0.080
    lens_distance_m: float = 0.050
    lens_ior: float = 1.52
    only_segment: int | None = None

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in fields(cls)]


def segment_name(k: int) -> str:
    """Part name of segment k (0 = leftmost stripe on the screen)."""
    return f"led_{k:02d}"


def stripe_edges_deg(segments: int, span_deg: float) -> np.ndarray:
    """H edges (°) of the N stripes, left to right: N + 1 values from −span/2 to span/2."""
    return np.linspace(-0.5 * span_deg, 0.5 * span_deg, segments + 1)


def _check(p: MatrixParams) -> None:
    if not isinstance(p.segments, (int, np.integer)) or isinstance(p.segments, bool) \
            or not 1 <= p.segments <= 128:
        raise InputError(f"segments must be a whole number from 1 to 128, got {p.segments!r}")
    if not (math.isfinite(p.span_deg) and 0.5 <= p.span_deg <= 50.0):
        raise InputError(f"stripe span {p.span_deg!r}° is outside 0.5–50°")
    if not (math.isfinite(p.v_low_deg) and math.isfinite(p.v_high_deg)
            and -15.0 <= p.v_low_deg < p.v_high_deg <= 15.0):
        raise InputError(f"stripe height {p.v_low_deg!r}…{p.v_high_deg!r}° must rise "
                         "within −15…15°")
    if not (math.isfinite(p.fill) and 0.1 <= p.fill <= 1.0):
        raise InputError(f"die fill {p.fill!r} is outside 0.1–1")
    if not (math.isfinite(p.flux_lm) and p.flux_lm > 0):
        raise InputError(f"segment flux must be > 0 lm, got {p.flux_lm!r}")
    if p.only_segment is not None and not 0 <= p.only_segment < p.segments:
        raise InputError(f"segment {p.only_segment} does not exist (0…{p.segments - 1})")


def build_matrix(**kwargs: Any) -> tuple[list[GltfPart], dict[str, Any]]:
    """Build the matrix high beam as glTF parts.

    Parameters
    ----------
    **kwargs
        :class:`MatrixParams` fields.

    Returns
    -------
    parts : list of GltfPart
        ``led_00`` …, ``board``, ``housing``, ``lens``.
    facts : dict
        ``stripes_deg`` (the N + 1 H edges), lens focal length and thickness (m), die
        size (m) and luminance (cd/m²).

    Raises
    ------
    InputError
        Unknown option, fewer than one segment, sizes that make no lamp.
    """
    unknown = sorted(set(kwargs) - set(MatrixParams.names()))
    if unknown:
        raise InputError(f"unknown matrix option(s): {', '.join(unknown)}")
    p = MatrixParams(**kwargs)
    _check(p)
    lens = lens_design(p.lens_diameter_m, p.lens_distance_m, ior=p.lens_ior)
    f = lens.focal_length_m
    edges = stripe_edges_deg(p.segments, p.span_deg)
    radius = 0.5 * p.lens_diameter_m
    xe_paraxial = f * np.tan(np.radians(edges))
    if xe_paraxial[-1] - xe_paraxial[0] > 1.2 * radius:
        raise InputError(f"the dies span {(xe_paraxial[-1] - xe_paraxial[0]) / MM:.1f} mm, "
                         f"more than the lens can image (Ø{p.lens_diameter_m / MM:g} mm)")
    # die-plane X of the stripe edges by the lens's own mapping (its image is inverted:
    # H > 0 needs world +X; off the axis it spreads a little more than atan(x / f))
    xe = offset_for_angle_m(lens, -edges)
    y_lo, y_hi = offset_for_angle_m(lens, np.array([p.v_high_deg, p.v_low_deg]))
    parts: list[GltfPart] = []
    widths = p.fill * np.diff(xe)
    # equal luminance on every die (one pixel array, one current density): the flux of a
    # segment follows its die's area, flux_lm on average
    flux = p.flux_lm * p.segments * widths / widths.sum()
    for k in range(p.segments):
        if p.only_segment is not None and k != p.only_segment:
            continue
        centre = 0.5 * (xe[k] + xe[k + 1])
        half = 0.5 * widths[k]
        # square in the plane z = 0, counter-clockwise seen from +Z (faces the lens)
        v = np.array([[centre - half, y_lo, 0.0], [centre + half, y_lo, 0.0],
                      [centre + half, y_hi, 0.0], [centre - half, y_hi, 0.0]])
        name = segment_name(k)
        parts.append(GltfPart(name, v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64),
                              None, SEGMENT_MATERIAL, extras={"lightsim": {
                                  "flux_lm": float(flux[k]), "emission": "lambertian",
                                  "group": name, "segment": k,
                                  "stripe_h_deg": [float(edges[k]), float(edges[k + 1])],
                                  "stripe_v_deg": [p.v_low_deg, p.v_high_deg]}}))
    # black board just behind the dies, and a tube from it to the lens
    board_r = radius + 1 * MM
    vb, fb, _ = revolve(np.array([0.0, board_r]), np.array([-0.1 * MM, -0.1 * MM]),
                        np.array([0.0, 0.0]), np.array([1.0, 1.0]), 48)
    parts.append(GltfPart("board", vb, fb, None, HOUSING_BLACK))
    vt, ft, _ = revolve(np.array([board_r, board_r]),
                        np.array([-0.1 * MM, p.lens_distance_m - 0.5 * MM]),
                        np.array([1.0, 1.0]), np.array([0.0, 0.0]), 48)
    parts.append(GltfPart("housing", vt, ft, None, HOUSING_BLACK))
    vl, fl, nl = lens_mesh(lens, p.lens_distance_m)
    parts.append(GltfPart("lens", vl, fl, nl, lens_glass(p.lens_ior, lens.thickness_m),
                          extras={"lightsim": {"type": "aspheric plano-convex",
                                               "focal_length_m": f,
                                               "thickness_m": lens.thickness_m}}))
    die_area = float(widths.sum()) * (y_hi - y_lo)
    facts = {"params": asdict(p), "stripes_deg": [float(e) for e in edges],
             "lens_focal_length_m": f, "lens_thickness_m": lens.thickness_m,
             "die_widths_m": [float(w) for w in widths], "die_height_m": float(y_hi - y_lo),
             "luminance_cd_m2": p.flux_lm * p.segments / (math.pi * die_area),
             "segment_flux_lm": [float(x) for x in flux],
             "flux_lm": float(flux.sum() if p.only_segment is None
                              else flux[p.only_segment])}
    return parts, facts


def write_matrix(path: str | os.PathLike, **kwargs: Any) -> dict[str, Any]:
    """Build the matrix high beam and write it as a GLB file (atomically).

    Returns
    -------
    dict
        The build's facts plus ``path``, ``bytes`` and ``triangles`` ({part: count}).
    """
    parts, facts = build_matrix(**kwargs)
    extras = {"lightsim": {
        "generator": "lightsim.luminaires.matrix", "units": {"length": "m", "flux": "lm"},
        "axes": "+Y up, lamp shines along +Z, dies in the plane z = 0 on the lens axis",
        "parameters": facts["params"], "stripes_deg": facts["stripes_deg"]}}
    data = glb_bytes(parts, asset_extras=extras)
    write_bytes(path, data)
    return {**facts, "path": os.fspath(path), "bytes": len(data),
            "triangles": {part.name: part.triangle_count for part in parts}}
