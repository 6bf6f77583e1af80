"""Multi-facet reflector geometry and the facet-aim optimiser (``lightsim design``)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.luminaires.design import design_lowbeam, facets_for, objective, write_design
from lightsim.luminaires.reflector import Facet, aim_direction, faceted_reflector_mesh
from lightsim.materials import MIRROR

REPO = Path(__file__).resolve().parents[1]
F = 0.025


def test_every_facet_is_a_paraboloid_of_the_common_focus_aimed_at_its_direction():
    facets = facets_for(np.array([-0.8, 1.2, 3.0, 0.6]), 8)
    v, faces, n = faceted_reflector_mesh(F, 0.0095, 0.08, facets, rings=10, columns=6)
    focus = np.array([0.0, 0.0, F])
    per = len(v) // len(facets)
    for k, fc in enumerate(facets):
        d = aim_direction(fc.h_deg, fc.v_deg)
        p, nm = v[k * per:(k + 1) * per] - focus, n[k * per:(k + 1) * per]
        rho = np.linalg.norm(p, axis=1)
        # focus–directrix property of a paraboloid with axis d and focal length f
        assert np.allclose(rho, p @ d + 2 * F, rtol=0, atol=1e-12)
        u = p / rho[:, None]
        r = u - 2 * np.sum(u * nm, axis=1, keepdims=True) * nm
        assert np.allclose(r, d, atol=1e-12)  # light from the focus leaves along d
        assert np.all(np.sum(-u * nm, axis=1) > 0)  # normals face the focus
    # the aim directions: H right is world −X, V up is +Y
    assert aim_direction(2.0, 0.0)[0] < 0 and aim_direction(0.0, -1.0)[1] < 0
    assert len(faces) == len(facets) * 10 * 5 * 2


def test_traced_rays_from_the_focus_leave_along_their_facets_aim():
    """Independent check with trimesh's ray caster (embree when present) on flat facets."""
    trimesh = pytest.importorskip("trimesh")
    facets = [Facet(0.0, math.pi, 1.5, -1.0), Facet(math.pi, 2 * math.pi, -2.0, -0.5)]
    v, faces, vn = faceted_reflector_mesh(F, 0.0095, 0.08, facets, rings=60, columns=80)
    mesh = trimesh.Trimesh(v, faces, process=False)
    rng = np.random.default_rng(7)
    phi = rng.uniform(0.05, 2 * math.pi - 0.05, 400)
    phi = phi[np.abs(np.sin(phi)) > 0.05]  # keep away from the facet seams
    r = rng.uniform(0.02, 0.075, len(phi))
    target = np.column_stack([r * np.cos(phi), r * np.sin(phi), r * r / (4 * F)])
    origin = np.tile([0.0, 0.0, F], (len(phi), 1))
    dirs = target - origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    loc, ray, tri = mesh.ray.intersects_location(origin, dirs, multiple_hits=False)
    assert len(ray) > 0.95 * len(phi)
    # shading normal as lightsim uses it: the vertex normals interpolated at the hit
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[tri], loc)
    nrm = np.einsum("ij,ijk->ik", bary, vn[faces[tri]])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    out = dirs[ray] - 2 * np.sum(dirs[ray] * nrm, axis=1, keepdims=True) * nrm
    k = (phi[ray] >= math.pi).astype(int)
    want = np.array([aim_direction(f.h_deg, f.v_deg) for f in facets])[k]
    err = np.degrees(np.arccos(np.clip(np.sum(out * want, axis=1), -1, 1)))
    assert np.percentile(err, 95) < 0.05  # O(h²) error of the interpolated normals


def test_bad_facets_are_input_errors():
    with pytest.raises(InputError):
        faceted_reflector_mesh(F, 0.01, 0.08, [])
    with pytest.raises(InputError):
        faceted_reflector_mesh(F, 0.01, 0.08, [Facet(0, 1, float("nan"), 0)])
    with pytest.raises(InputError):
        faceted_reflector_mesh(F, 0.09, 0.08, [Facet(0, 1, 0, 0)])


def test_objective_is_zero_with_margin_and_names_the_missed_limits():
    limits = {"75R": {"min": 10100.0}, "B50L": {"max": 350.0}, "7": {"min": 65, "max": 625}}
    assert objective({"75R": 12000, "B50L": 200, "7": 300}, limits)[0] == 0.0
    j, failing = objective({"75R": 5000, "B50L": 200, "7": 0.0}, limits)
    assert failing == ["75R", "7"]
    assert j == pytest.approx(math.log(5000 / 11110) ** 2 + math.log(1 / 71.5) ** 2)
    j2, failing2 = objective({"75R": 10500, "B50L": 200, "7": 300}, limits)
    assert failing2 == [] and 0 < j2 < 1e-2  # inside the limit but inside the safety margin


def test_written_design_loads_with_all_parts(tmp_path):
    from lightsim.scene import load_scene

    path = tmp_path / "lamp.glb"
    write_design(path, [-0.7, 1.0, 2.0, 0.3], n=6)
    scene = load_scene(path)
    names = {p.name for p in scene.parts}
    assert {"filament", "bulb", "shield", "reflector", "lens"} <= names
    refl = next(p for p in scene.parts if p.name == "reflector")
    assert refl.material.kind == MIRROR
    assert len(refl.extras["lightsim"]["facets"]) == 6


def test_design_is_deterministic_for_a_seed():
    kw = dict(facets=4, photons=20_000, resolution=(80, 32), evaluations=2, seed=2)
    a = design_lowbeam("r112-b-passing", **kw)
    b = design_lowbeam("r112-b-passing", **kw)
    assert len(a.history) == 2
    assert [h["objective"] for h in a.history] == [h["objective"] for h in b.history]
    assert a.x == b.x and np.isfinite(a.objective)


@pytest.mark.parametrize("args, needle", [
    (["o.glb", "--regulation", "r999"], "r999"),
    (["o.glb", "--regulation", "r112-b-passing", "--facets", "1"], "--facets"),
    (["o.txt", "--regulation", "r112-b-passing"], ".glb"),
    (["o.glb", "--regulation", "r112-b-passing", "--bulb", "H99"], "H99"),
])
def test_design_bad_input_is_one_line_and_exit_2(args, needle, tmp_path):
    r = subprocess.run([sys.executable, "-m", "lightsim.cli.main", "design", *args],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], r.stderr
    assert not (tmp_path / "o.glb").exists()
