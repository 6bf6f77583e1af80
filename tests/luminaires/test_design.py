"""Ring-and-sector multi-facet reflector and its optimiser (``lightsim design``)."""

from __future__ import annotations

import itertools
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.luminaires.design import DesignSettings, design_lowbeam
from lightsim.luminaires.design_lamp import (
    SIGN_AIMS,
    Layout,
    cutoff_line,
    facet_images,
    facets_for,
    filament_points,
    hole_diameter,
    start_vector,
    unshaded,
    write_design,
)
from lightsim.luminaires.design_terms import rule_terms
from lightsim.luminaires.headlight import build_headlight
from lightsim.luminaires.reflector import Facet, aim_direction, faceted_reflector_mesh
from lightsim.materials import MIRROR
from lightsim.scene import load_scene

REPO = Path(__file__).resolve().parents[2]
F = 0.025
LAYOUT = Layout(rings=2, sectors=6)


def test_every_facet_is_a_paraboloid_of_the_common_focus_aimed_at_its_direction():
    facets = facets_for(start_vector(LAYOUT), LAYOUT, hole_diameter(LAYOUT))
    v, faces, n = faceted_reflector_mesh(F, 0.5 * hole_diameter(LAYOUT), 0.08, facets,
                                         rings=10, columns=6)
    focus = np.array([0.0, 0.0, F])
    per = len(v) // len(facets)
    assert len(facets) == 12 and len({fc.focal_m for fc in facets}) == 2
    for k, fc in enumerate(facets):
        d = aim_direction(fc.h_deg, fc.v_deg)
        p, nm = v[k * per:(k + 1) * per] - focus, n[k * per:(k + 1) * per]
        rho = np.linalg.norm(p, axis=1)
        # focus–directrix property of a paraboloid with axis d and the facet's focal length
        assert np.allclose(rho, p @ d + 2 * fc.focal_m, rtol=0, atol=1e-12)
        u = p / rho[:, None]
        r = u - 2 * np.sum(u * nm, axis=1, keepdims=True) * nm
        assert np.allclose(r, d, atol=1e-12)  # light from the focus leaves along d
        assert np.all(np.sum(-u * nm, axis=1) > 0)  # normals face the focus
        # the facet covers its ring: directions from the focus towards the base radii
        t = (u[:, 2] * 2 * F + np.sqrt((2 * F * u[:, 2]) ** 2 + 4 * F * F * (1 - u[:, 2] ** 2))
             ) / np.maximum(1 - u[:, 2] ** 2, 1e-30)
        r_base = np.hypot(u[:, 0], u[:, 1]) * t * 0 + np.hypot(*(u[:, :2] * (
            2 * F / (1 - u[:, 2]))[:, None]).T)
        assert r_base.min() >= fc.r0_m - 1e-9 and r_base.max() <= fc.r1_m + 1e-9
    assert aim_direction(2.0, 0.0)[0] < 0 and aim_direction(0.0, -1.0)[1] < 0
    assert len(faces) == len(facets) * 10 * 5 * 2


def test_traced_rays_from_the_focus_leave_along_their_facets_aim():
    """Independent check with trimesh's ray caster (embree when present) on flat facets."""
    trimesh = pytest.importorskip("trimesh")
    facets = [Facet(0.0, math.pi, 1.5, -1.0), Facet(math.pi, 2 * math.pi, -2.0, -0.5,
                                                      focal_m=0.03)]
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
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[tri], loc)
    nrm = np.einsum("ij,ijk->ik", bary, vn[faces[tri]])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    out = dirs[ray] - 2 * np.sum(dirs[ray] * nrm, axis=1, keepdims=True) * nrm
    k = (phi[ray] >= math.pi).astype(int)
    want = np.array([aim_direction(f.h_deg, f.v_deg) for f in facets])[k]
    err = np.degrees(np.arccos(np.clip(np.sum(out * want, axis=1), -1, 1)))
    assert np.percentile(err, 95) < 0.05  # O(h²) error of the interpolated normals


def test_shield_shading_of_the_image_model_matches_a_ray_cast_on_the_shield_mesh():
    """The image model's cup test against trimesh rays on the shield the lamp really has."""
    trimesh = pytest.importorskip("trimesh")
    shield = next(p for p in build_headlight(bulb="H4-low", lens="clear",
                                             reflector_rings=4, reflector_sectors=16)
                  if p.name == "shield")
    mesh = trimesh.Trimesh(shield.vertices, shield.faces, process=False)
    rng = np.random.default_rng(3)
    s = filament_points(Layout(), 300)
    phi = rng.uniform(0, 2 * math.pi, len(s))
    r = rng.uniform(0.012, 0.08, len(s))
    p = np.column_stack([r * np.cos(phi), r * np.sin(phi), r * r / (4 * F)])
    d = p - s
    hit = mesh.ray.intersects_any(s, d / np.linalg.norm(d, axis=1, keepdims=True))
    model = unshaded(s, p, Layout())
    assert 0.3 < model.mean() < 0.8  # both lit and shaded rays are tested
    assert np.mean(model == ~hit) > 0.97  # seam and coarse-arc rays may differ


def test_images_of_every_lit_facet_stay_under_the_cutoff_line():
    lay = Layout()
    hole = hole_diameter(lay)
    x = start_vector(lay)
    x[1] = 0.0  # no lift of the vertex ring
    facets = facets_for(x, lay, hole)
    images = facet_images(facets, lay, hole)
    v0 = -0.57
    lit = [img for img in images if img.dh.size]
    assert 12 <= len(lit) < len(facets)  # the cup shades part of the lower half
    for fc, img in zip(facets, images):
        if img.dh.size:
            over = img.dv + fc.v_deg - cutoff_line(img.dh + fc.h_deg, v0)
            # 98 % of each image below c(h), the drop of its ring on top
            assert np.mean(over <= 1e-9) >= 0.97
    # upper facets are fully lit, the one straight under the cup not at all
    assert images[2].lit_fraction > 0.9 and images[6].lit_fraction < 0.1


def test_sign_slivers_put_their_images_on_their_aims_and_keep_the_tiling():
    plain = Layout()
    lay = Layout(sign_share=0.03)
    hole = hole_diameter(lay)
    x = start_vector(lay)
    base = facets_for(x, plain, hole)
    facets = facets_for(x, lay, hole)
    n = lay.rings * lay.sectors
    assert len(facets) == n + len(SIGN_AIMS)
    slivers = facets[n:]
    # the slivers are cut from vertex-ring facets: ring 0's azimuths still tile 2π once,
    # the other rings are untouched
    ring0 = sorted((f.phi0_rad, f.phi1_rad) for f in facets[:lay.sectors] + slivers)
    assert ring0[0][0] == pytest.approx(0.0) and ring0[-1][1] == pytest.approx(2 * math.pi)
    assert all(a[1] == pytest.approx(b[0]) for a, b in itertools.pairwise(ring0))
    assert facets[lay.sectors:n] == base[lay.sectors:n]
    share = sum(f.phi1_rad - f.phi0_rad for f in slivers) / (2 * math.pi / lay.sectors)
    assert share == pytest.approx(0.03 * sum(a[2] for a in SIGN_AIMS))
    # each sliver's traced image is centred on its overhead-sign aim
    for fc, img, (h, v, _w) in zip(slivers, facet_images(slivers, lay, hole), SIGN_AIMS):
        assert img.lit_fraction > 0.5
        assert abs(np.median(img.dh + fc.h_deg) - h) < 0.2
        assert abs(np.median(img.dv + fc.v_deg) - v) < 0.2
    with pytest.raises(InputError):
        Layout(sign_share=2.0).check()


def test_rule_terms_use_the_interval_bounds_and_the_zone_maximum():
    rows = [{"name": "75R", "kind": "point", "value_cd": 12000, "interval_cd": [9000, 15000],
             "limit": {"min": 10100}, "verdict": "uncertain"},
            {"name": "B50L", "kind": "point", "value_cd": 100, "interval_cd": [50, 200],
             "limit": {"max": 350}, "verdict": "pass"},
            {"name": "III", "kind": "zone", "value_cd": 300, "interval_cd": [200, 400],
             "max_interval_cd": [200, 900], "limit": {"max": 625}, "verdict": "uncertain"},
            {"name": "HV", "kind": "measure", "value_cd": 1, "interval_cd": [0, 2],
             "limit": {}, "verdict": "info"}]
    t = {x.name: x for x in rule_terms(rows, 0.1)}
    assert set(t) == {"75R", "B50L", "III"}
    assert t["75R"].margin == pytest.approx(math.log(9000 / 11110))  # the lower bound
    assert t["75R"].penalty == pytest.approx(math.log(9000 / 11110) ** 2)
    assert t["B50L"].margin == pytest.approx(math.log(315 / 200)) and t["B50L"].penalty == 0
    assert t["III"].margin == pytest.approx(math.log(562.5 / 900))  # the brightest probe


def test_written_design_loads_with_all_parts(tmp_path):
    path = tmp_path / "lamp.glb"
    write_design(path, start_vector(LAYOUT), LAYOUT)
    scene = load_scene(path)
    names = {p.name for p in scene.parts}
    assert {"filament", "bulb", "shield", "reflector", "lens"} <= names
    refl = next(p for p in scene.parts if p.name == "reflector")
    assert refl.material.kind == MIRROR
    assert len(refl.extras["lightsim"]["facets"]) == 12
    with pytest.raises(InputError):
        write_design(path, [0.0, 1.0], LAYOUT)  # wrong length


def test_bad_facets_are_input_errors():
    with pytest.raises(InputError):
        faceted_reflector_mesh(F, 0.01, 0.08, [])
    with pytest.raises(InputError):
        faceted_reflector_mesh(F, 0.01, 0.08, [Facet(0, 1, float("nan"), 0)])
    with pytest.raises(InputError):
        faceted_reflector_mesh(F, 0.09, 0.08, [Facet(0, 1, 0, 0)])
    with pytest.raises(InputError):
        faceted_reflector_mesh(F, 0.01, 0.08, [Facet(0, 1, 0, 0, focal_m=1.0)])
    with pytest.raises(InputError):
        faceted_reflector_mesh(F, 0.01, 0.08, [Facet(0, 1, 0, 0, r0_m=0.0, r1_m=0.05)])


def test_design_is_deterministic_for_a_seed():
    settings = DesignSettings(regulation="r112-b-passing", rings=1, sectors=4,
                              photons=20_000, resolution=(80, 32), evaluations=2, rounds=1,
                              seed=2, validate_factor=0, optimiser="simulator",
                              sign_share=0.0, foreground=0.0)
    a = design_lowbeam(settings)
    b = design_lowbeam(settings)
    assert len(a.history) >= 2
    assert [h["objective"] for h in a.history] == [h["objective"] for h in b.history]
    assert a.x == b.x and np.isfinite(a.objective)
    names = {t.name for t in a.terms}
    # every rule, then the cut-off's terms (or the "no cut-off" penalty of a tiny lamp)
    assert names >= {"75R", "III", "1+2+3"}
    assert {"smoothness", "reach 1 lx", "sharpness G"} <= names or "cut-off" in names


@pytest.mark.parametrize("args, needle", [
    (["o.glb", "--regulation", "r999"], "r999"),
    (["o.glb", "--regulation", "r112-b-passing", "--sectors", "1"], "--sectors"),
    (["o.glb", "--regulation", "r112-b-passing", "--resolution", "big"], "--resolution"),
    (["o.txt", "--regulation", "r112-b-passing"], ".glb"),
    (["o.glb", "--regulation", "r112-b-passing", "--bulb", "H99"], "H99"),
    (["o.glb", "--regulation", "r112-b-passing", "--sign-share", "nan"], "--sign-share"),
])
def test_design_bad_input_is_one_line_and_exit_2(args, needle, tmp_path):
    r = subprocess.run([sys.executable, "-m", "lightsim.cli.main", "design", *args],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], r.stderr
    assert not (tmp_path / "o.glb").exists()
