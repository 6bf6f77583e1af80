"""Reflector design to a regulation target: aim the facets of a multi-facet reflector.

The lamp is the parametric headlight (:mod:`lightsim.luminaires.headlight`: bulb, shield
cup, clear cover lens) with its paraboloid replaced by a multi-facet reflector
(:mod:`lightsim.luminaires.reflector`) of ``facets`` azimuthal sectors. Facet k, centred at
azimuth φ_k, is aimed at the wall direction

    h_k = h0 + spread · cos φ_k,      v_k = v0 − drop · max(0, sin φ_k)      (degrees)

so the design has four parameters x = (v0, h0, spread, drop): the vertical aim of the
pattern, its horizontal shift towards the traffic side, the horizontal spread of the side
facets and an extra downward aim of the upper facets (which form the hot spot).

Objective (minimised), over the rule set's test points and zones with limits:

    J(x) = Σ_rules  max(0, −m_rule)²,
    m = ln(I / (I_min·(1 + s)))  for a minimum,   m = ln(I_max·(1 − s) / I)  for a maximum,

with I the simulated intensity (cd, floored at 1 cd), s = ``safety`` (default 0.10) the
margin asked beyond the limit so that the final run's 95 % intervals have room. Every
evaluation writes the lamp as a GLB, loads it as a user would and simulates it with the
same seed and photon count (common random numbers: the objective's noise does not change
between evaluations, so the optimiser sees geometry). Test points are read with the kNN
estimate at the points (``aperture 0``), which varies smoothly with the geometry.

Optimiser: :func:`scipy.optimize.minimize` with ``method="Nelder-Mead"`` from a fixed
start and initial simplex, at most ``evaluations`` function evaluations — deterministic
for a seed.

Parameters of :func:`design_lowbeam`

================  =====  ===========  =====================================================
name              unit   default      meaning
================  =====  ===========  =====================================================
bulb              –      ``H4-low``   bulb preset (the H4 passing filament and its cup)
regulation        –      –            rule set id (``r112-b-passing``)
facets            –      8            azimuthal sectors
focal_length_m    m      0.025        common focal length
aperture_m        m      0.160        lamp opening (rim diameter of the base paraboloid)
photons           –      100 000      photons per evaluation
resolution        px     160×64       wall pixels per evaluation
evaluations       –      30           Nelder–Mead function-evaluation budget
seed              –      1            photon seed of every evaluation
safety            –      0.10         relative margin asked beyond every limit
aim               –      False        aim every candidate's cut-off at 0.57° D before
                                      evaluating (as ``simulate --aim``): v0 then only
                                      moves the pattern relative to its own cut-off
================  =====  ===========  =====================================================
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.errors import InputError
from lightsim.io.atomic import write_bytes

from .gltf_writer import GltfMaterial, GltfPart, glb_bytes
from .headlight import HeadlightParams, build_headlight, headlight_asset_extras
from .reflector import Facet, faceted_reflector_mesh

__all__ = ["DesignResult", "design_lowbeam", "facets_for", "objective", "write_design"]

X0 = (-0.6, 1.0, 2.0, 0.3)  # start: cut-off at −0.6°, 1° right, ±2° spread, 0.3° drop
STEP = (0.4, 0.5, 2.0, 0.5)  # initial simplex edge per parameter (degrees)
LENS_GAP_M = 0.015  # room for facets aimed off-axis, whose rims stand further forward


@dataclass
class DesignResult:
    """Outcome of :func:`design_lowbeam`.

    Attributes
    ----------
    x : list of float
        Best parameters (v0, h0, spread, drop), in degrees.
    objective : float
        J at ``x`` (dimensionless).
    history : list of dict
        Per evaluation: ``x``, ``objective``, ``failing`` (rule names), ``seconds``.
    values_cd : dict
        Rule name → intensity at ``x`` (cd) in the optimisation's run.
    seconds : float
        Wall-clock time of the optimisation, s.
    """

    x: list[float]
    objective: float
    history: list[dict[str, Any]] = field(default_factory=list)
    values_cd: dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0


def facets_for(x: np.ndarray, n: int) -> list[Facet]:
    """The ``n`` facets of parameters ``x = (v0, h0, spread, drop)`` (degrees)."""
    v0, h0, spread, drop = (float(t) for t in x)
    edges = 2 * math.pi * np.arange(n + 1) / n
    out = []
    for k in range(n):
        phi = 0.5 * (edges[k] + edges[k + 1])
        out.append(Facet(float(edges[k]), float(edges[k + 1]),
                         h0 + spread * math.cos(phi), v0 - drop * max(0.0, math.sin(phi))))
    return out


def _parts(x: np.ndarray, n: int, bulb: str, f: float, aperture_m: float,
           traffic: str) -> tuple[list[GltfPart], HeadlightParams]:
    params = HeadlightParams(bulb=bulb, focal_length_m=f, aperture_m=aperture_m,
                             lens="clear", traffic=traffic, lens_gap_m=LENS_GAP_M,
                             reflector_rings=8, reflector_sectors=32)
    parts = build_headlight(**{k: v for k, v in asdict(params).items()})
    i = next(k for k, p in enumerate(parts) if p.name == "reflector")
    old = parts[i]
    hole = float(old.extras["lightsim"]["hole_diameter_m"])
    v, fc, nm = faceted_reflector_mesh(f, 0.5 * hole, 0.5 * aperture_m, facets_for(x, n))
    lens = next((p for p in parts if p.name == "lens"), None)
    if lens is not None and float(v[:, 2].max()) >= float(lens.vertices[:, 2].min()):
        raise InputError("the facets' rim reaches the cover lens: aim them less steeply")
    mat = GltfMaterial(**asdict(old.material))
    extras = {"lightsim": {"surface": "multi-facet paraboloids", "focal_length_m": f,
                           "aperture_m": aperture_m, "hole_diameter_m": hole,
                           "facets": [asdict(t) for t in facets_for(x, n)]}}
    parts[i] = GltfPart("reflector", v, fc, nm, mat, extras=extras)
    return parts, params


def write_design(path: str | os.PathLike, x: np.ndarray, n: int = 8, bulb: str = "H4-low",
                 focal_length_m: float = 0.025, aperture_m: float = 0.160,
                 traffic: str = "right") -> int:
    """Write the designed lamp as a GLB (atomically); returns its size in bytes."""
    parts, params = _parts(np.asarray(x, float), n, bulb, focal_length_m, aperture_m,
                           traffic)
    extras = headlight_asset_extras(params)
    extras["lightsim"]["generator"] = "lightsim.luminaires.design"
    extras["lightsim"]["design"] = {"x_deg": [float(t) for t in x], "facets": n,
                                    "parameters": "v0, h0, spread, drop (deg)"}
    data = glb_bytes(parts, asset_extras=extras)
    write_bytes(path, data)
    return len(data)


def objective(values: dict[str, float], limits: dict[str, dict[str, float]],
              safety: float = 0.10) -> tuple[float, list[str]]:
    """J (see the module docstring) and the names of the rules whose limit is missed."""
    j, failing = 0.0, []
    for name, lim in limits.items():
        value = max(float(values.get(name, 0.0)), 1.0)
        m = math.inf
        if lim.get("min") is not None and lim["min"] > 0:
            m = min(m, math.log(value / (lim["min"] * (1 + safety))))
            if value < lim["min"]:
                failing.append(name)
        if lim.get("max") is not None and lim["max"] > 0:
            m = min(m, math.log(lim["max"] * (1 - safety) / value))
            if value > lim["max"] and name not in failing:
                failing.append(name)
        if m < 0:
            j += m * m
    return j, failing


def design_lowbeam(regulation: str, *, bulb: str = "H4-low", facets: int = 8,
                   focal_length_m: float = 0.025, aperture_m: float = 0.160,
                   photons: int = 100_000, resolution: tuple[int, int] = (160, 64),
                   evaluations: int = 30, seed: int = 1, safety: float = 0.10,
                   traffic: str = "right", aim: bool = False,
                   progress: Callable[[int, dict[str, Any]], None] | None = None
                   ) -> DesignResult:
    """Optimise the facet aims against ``regulation`` (see the module docstring)."""
    from scipy.optimize import minimize

    from lightsim.luminaires.regulations import load_ruleset
    from lightsim.simulate import SimulateOptions
    from lightsim.validation.tolerance import run_sample

    load_ruleset(regulation)
    if facets < 2 or facets > 64:
        raise InputError(f"--facets must be 2–64, got {facets}")
    if evaluations < 1 or photons < 1:
        raise InputError("--evaluations and --photons must be ≥ 1")
    if not (0 <= safety < 1):
        raise InputError(f"safety margin must lie in [0, 1), got {safety}")
    t0 = time.perf_counter()
    history: list[dict[str, Any]] = []
    best: dict[str, Any] = {"j": math.inf}
    with tempfile.TemporaryDirectory(prefix="lightsim-design-") as tmp:
        glb = Path(tmp) / "candidate.glb"

        def evaluate(x: np.ndarray) -> float:
            t1 = time.perf_counter()
            try:
                write_design(glb, x, facets, bulb, focal_length_m, aperture_m, traffic)
            except InputError:
                return 1e6  # an infeasible lamp (facets through the lens)
            opts = SimulateOptions(str(glb), out_dir=tmp, photons=photons,
                                   resolution=resolution, regulation=regulation,
                                   traffic=traffic, aperture=0.0, config={"seed": seed},
                                   aim=aim)
            s = run_sample(opts, np.zeros(5))
            values = dict(zip(s.names, s.value_cd))
            j, failing = objective(values, dict(zip(s.names, s.limits)), safety)
            if s.verdicts and s.verdicts[0].startswith("not aimable"):
                j, failing = j + 100.0, ["no cut-off to aim"]  # worse than any aimable lamp
            entry = {"x": [float(t) for t in x], "objective": j, "failing": failing,
                     "seconds": time.perf_counter() - t1}
            history.append(entry)
            if j < best["j"]:
                best.update(j=j, x=entry["x"], values=values)
            if progress is not None:
                progress(len(history), entry)
            return j

        x0 = np.array(X0)
        simplex = np.vstack([x0] + [x0 + np.eye(4)[k] * STEP[k] for k in range(4)])
        minimize(evaluate, x0, method="Nelder-Mead",
                 options={"maxfev": int(evaluations), "initial_simplex": simplex,
                          "xatol": 0.02, "fatol": 1e-4})
    return DesignResult(x=best["x"], objective=best["j"], history=history,
                        values_cd=best.get("values", {}),
                        seconds=time.perf_counter() - t0)
