"""STEP/IGES import (OpenCASCADE via cascadio): names, units, exact-surface normals,
material maps, tessellation tolerances and the beam error of an exact paraboloid.

The STEP/IGES files are made at test time with OpenCASCADE's own writer (cadquery-ocp);
without it (or without cascadio) the tests are skipped with the reason.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from support import run_cli

pytest.importorskip("cascadio", reason="STEP/IGES import needs cascadio (the 'cad' extra)")
pytest.importorskip("OCP", reason="making STEP files needs cadquery-ocp (the 'cad' extra)")

from lightsim.errors import InputError
from lightsim.io import cad
from lightsim.io.cad import Tessellation, read_cad
from lightsim.luminaires.cad_example import (
    example_material_map,
    headlamp_shapes,
    write_cad,
)
from lightsim.materials import DIELECTRIC, MIRROR
from lightsim.scene import EMITTER, SceneSettings, load_scene
from lightsim.validation.cad_beam import beam_error, write_paraboloid_step

COARSE = Tessellation(0.1, 10.0)  # fast meshes for the tests that do not measure optics


@pytest.fixture(scope="module")
def lamp(tmp_path_factory):
    d = tmp_path_factory.mktemp("cad")
    step = write_cad(d / "lamp.step", headlamp_shapes())
    (d / "lamp.toml").write_text(example_material_map(1000.0))
    return step, d / "lamp.toml"


def test_step_parts_keep_names_units_and_exact_normals(lamp):
    step, _ = lamp
    parts = {p.name: p for p in read_cad(step, COARSE)}
    assert set(parts) == {"reflector", "filament", "bulb", "lens"}
    refl = parts["reflector"]
    v = np.asarray(refl.vertices)
    r = np.hypot(v[:, 0], v[:, 1])
    # metres (the STEP file is in mm): the rim at 80 mm, z = r²/(4f) with f = 25 mm
    assert r.max() == pytest.approx(0.080, abs=1e-6) and r.min() == pytest.approx(0.010,
                                                                                   abs=1e-6)
    np.testing.assert_allclose(v[:, 2], r * r / 0.1, atol=1e-7)
    # vertex normals from the exact surface: ∝ (−x/2f, −y/2f, 1) up to the sign
    n = np.asarray(refl.normals)
    exact = np.column_stack([-v[:, 0] / 0.05, -v[:, 1] / 0.05, np.ones(len(v))])
    exact /= np.linalg.norm(exact, axis=1, keepdims=True)
    assert np.abs(np.einsum("ij,ij->i", n, exact)).min() > 1 - 1e-9


def test_material_map_assigns_optics(lamp):
    step, mmap = lamp
    scene = load_scene(step, SceneSettings(materials=mmap, tessellation=COARSE))
    by = {p.name: p for p in scene.parts}
    assert by["reflector"].material.kind == MIRROR
    np.testing.assert_allclose(by["reflector"].material.rgb, 0.88)
    assert by["lens"].material.kind == DIELECTRIC
    assert by["lens"].material.ior == pytest.approx(1.59)
    assert by["bulb"].material.ior == pytest.approx(1.46)
    assert by["filament"].role == EMITTER and by["filament"].flux_lm == pytest.approx(1000)


def test_material_map_errors_and_unmatched_parts(lamp, tmp_path):
    step, _ = lamp
    partial = tmp_path / "partial.toml"
    partial.write_text('[[rule]]\nmatch = "filament"\nkind = "emitter"\nflux_lm = 10\n'
                       '[[rule]]\nmatch = "lens"\nkind = "ignore"\n')
    scene = load_scene(step, SceneSettings(materials=partial, tessellation=COARSE))
    assert "lens" not in scene.part_names
    assert any("no rule for" in w and "reflector" in w for w in scene.warnings)
    for body, frag in (('[[rule]]\nmatch = "x"\nkind = "chrome"\n', "kind"),
                       ('[[rule]]\nmatch = "x"\nkind = "glass"\nior = -1\n', "ior"),
                       ("[[rule]\n", "TOML"), ('title = "empty"\n', "has no")):
        bad = tmp_path / "bad.toml"
        bad.write_text(body)
        with pytest.raises(InputError, match=frag) as err:
            load_scene(step, SceneSettings(materials=bad, tessellation=COARSE))
        assert "\n" not in str(err.value)


def test_iges_import_keeps_names_and_units(tmp_path):
    igs = write_cad(tmp_path / "lamp.igs", headlamp_shapes(lens=False))
    parts = read_cad(igs, COARSE)
    verts = np.concatenate([np.asarray(p.vertices) for p in parts])
    assert np.abs(verts).max() == pytest.approx(0.080, abs=1e-4)  # metres, not mm
    assert {p.name for p in parts} == {"reflector", "filament"}


def test_iges_unit_flag_without_ocp(tmp_path, monkeypatch):
    """With cascadio alone the IGES unit comes from the global section."""
    igs = write_cad(tmp_path / "lamp.igs", headlamp_shapes(lens=False))
    assert cad.iges_unit_m(igs.read_bytes()) == 1e-3
    monkeypatch.setattr(cad, "iges_as_step", lambda path: None)
    monkeypatch.setattr(cad, "_has_ocp", lambda: False)
    parts = cad.read_cad(igs, COARSE)
    verts = np.concatenate([np.asarray(p.vertices) for p in parts])
    assert np.abs(verts).max() == pytest.approx(0.080, abs=1e-4)
    assert all(p.name.startswith("iges-") for p in parts)


def test_bad_cad_input_is_one_line(tmp_path, capsys):
    bad = tmp_path / "junk.step"
    bad.write_text("not a step file")
    with pytest.raises(InputError, match="not a STEP file"):
        load_scene(bad)
    broken = tmp_path / "broken.step"
    broken.write_text("ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\n#1=GARBAGE(;\nENDSEC;\n"
                      "END-ISO-10303-21;\n")
    code, _, err = run_cli(["simulate", str(broken), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and err.count("\n") == 1 and "broken.step" in err
    with pytest.raises(InputError, match="tolerance"):
        Tessellation(-1.0, 2.0)
    with pytest.raises(InputError, match="tolerance"):
        Tessellation(0.01, 95.0)


@pytest.mark.parametrize("tol_mm", [0.5, 0.1, 0.03])
def test_linear_tolerance_is_in_mm_and_met(tmp_path, tol_mm):
    """OpenCASCADE's facets stay within the linear tolerance (mm) of the exact surface."""
    step = write_paraboloid_step(tmp_path / "p.step", 25.0, 80.0, 10.0)
    refl = read_cad(step, Tessellation(tol_mm, 30.0))[0]
    tri = np.asarray(refl.vertices)[refl.faces]
    pts = np.concatenate([tri.mean(axis=1), 0.5 * (tri[:, 0] + tri[:, 1]),
                          0.5 * (tri[:, 1] + tri[:, 2]), 0.5 * (tri[:, 2] + tri[:, 0])])
    r2 = pts[:, 0] ** 2 + pts[:, 1] ** 2
    f = 0.025
    dist = np.abs(r2 / (4 * f) - pts[:, 2]) / np.sqrt(1 + r2 / (4 * f * f))  # ⊥ to surface
    assert dist.max() <= tol_mm * 1e-3
    assert dist.max() > 0.3 * tol_mm * 1e-3  # and the mesher uses the room it is given


def test_beam_error_falls_as_the_tolerance_tightens(tmp_path):
    """Rays from the focus leave an exact paraboloid parallel to the axis; the imported
    mesh's error falls with the tolerance and is tiny at the default."""
    step = write_paraboloid_step(tmp_path / "p.step", 25.0, 80.0, 10.0)
    coarse, default = (beam_error(step, 25.0, 80.0, 10.0, lin, ang, rays=20_000)
                       for lin, ang in ((0.1, 10.0), (0.01, 2.0)))
    assert coarse.triangles < default.triangles
    assert default.rms_mrad < 0.1 * coarse.rms_mrad
    assert coarse.rms_mrad > 0.3         # a coarse mesh visibly widens the beam
    assert default.rms_mrad < 0.05       # < 1.25 mm at 25 m
    assert default.normal_err_mrad < 1e-2


def test_cli_cad_to_regulation_table(tmp_path, capsys):
    step = tmp_path / "lamp.step"
    code, out, err = run_cli(["luminaire", "cad-example", str(step)], capsys)
    assert code in (0, None), err
    code, out, err = run_cli(["simulate", str(step), "--materials", str(step.with_suffix(
        ".toml")), "--cad-linear-tol", "0.1", "--cad-angular-tol", "10", "--photons",
        "20000", "--resolution", "64x32", "--regulation", "r149-b-driving", "--out",
        str(tmp_path / "o")], capsys)
    assert code in (0, None), err
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["regulation"]["ruleset"] == "r149-b-driving"
    names = {r["name"]: r["verdict"] for r in s["regulation"]["results"]}
    assert "Imax" in names and "Imax" in out
    assert s["energy_lm"]["emitted"] == pytest.approx(1000.0)
