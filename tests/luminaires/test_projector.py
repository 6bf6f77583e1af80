"""The LED projector module (``lightsim luminaire projector``) and its aspheric lens."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import lightsim.luminaires
from lightsim.errors import InputError
from lightsim.io.closed_mesh import closed_mesh
from lightsim.luminaires.asphere import (
    image_angle_deg,
    lens_design,
    lens_mesh,
    offset_for_angle_m,
)
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb
from lightsim.luminaires.projector import ProjectorParams, build_projector, shield_edge
from lightsim.scene import SceneSettings, load_scene
from lightsim.simulate import SimulateOptions, run_simulation

from support import run_cli

EXAMPLES = Path(lightsim.luminaires.__file__).parent / "examples"
#: the shipped example's command (also in luminaires/examples/README.md)
EXAMPLE_COMMAND = "lightsim luminaire projector luminaires/examples/projector.glb"
RES = (160, 64)  # 30 × 12 m wall at 25 m: about 0.21° per pixel


def _angles(res: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre H and V (°) of the default wall (30 × 12 m at 25 m), row 0 on top."""
    w, h = res
    hm = (np.arange(w) + 0.5) / w * 30.0 - 15.0
    vm = 6.0 - (np.arange(h) + 0.5) / h * 12.0
    return np.degrees(np.arctan(hm / 25.0)), np.degrees(np.arctan(vm / 25.0))


def _simulate(glb: Path, out: Path, photons: int, **extra) -> tuple[np.ndarray, dict]:
    opts = SimulateOptions(scene_path=str(glb), photons=photons, resolution=RES,
                           out_dir=str(out), outputs=("json",), **extra)
    result = run_simulation(opts)
    return result.lux, result.summary


def _energy_closes(summary: dict) -> None:
    e = summary["energy_lm"]
    parts = sum(e[k] for k in ("wall", "absorbed_diffuse", "absorbed_mirror",
                               "absorbed_volume", "escaped", "roulette", "max_depth"))
    assert parts == pytest.approx(e["emitted"], rel=1e-6)
    assert e["wall"] > 0.2 * e["emitted"]


@pytest.fixture(scope="module")
def lowbeam(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("projector") / "p.glb"
    assert _cli(["luminaire", "projector", str(path)]) == 0
    return path


def _cli(argv: list[str]) -> int:
    from lightsim.cli.main import main
    with pytest.raises(SystemExit) as exc:
        main(argv)
    return exc.value.code or 0


# ---------------------------------------------------------------------------------------
# the lens
# ---------------------------------------------------------------------------------------


def test_lens_is_closed_and_its_thickness_leaves_the_edge():
    d = lens_design(0.06, 0.04, edge_m=0.002, ior=1.52)
    assert d.profile_z_m[-1] == pytest.approx(0.002, abs=1e-9)
    assert d.profile_r_m[-1] == pytest.approx(0.03)
    # paraxial focal length of a plano-convex lens, f = R / (n − 1), R from the vertex
    # curvature of the designed profile
    r, z = d.profile_r_m[:6], d.profile_z_m[:6]
    curvature = np.polyfit(r ** 2, z, 1)[0] * 2  # z ≈ t − r² / (2R)
    assert 1 / abs(curvature) / (1.52 - 1) == pytest.approx(d.focal_length_m, rel=0.01)
    v, f, n = lens_mesh(d, 0.1)
    mesh = closed_mesh(v, f)
    assert mesh.watertight and mesh.volume > 0
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)


def test_lens_mapping_is_paraxial_near_the_axis_and_inverts():
    d = lens_design(0.08, 0.05)
    small = 0.2e-3
    assert image_angle_deg(d, 0.0) == pytest.approx(0.0, abs=1e-9)
    # the fan's mean over the whole aperture: within 10 % of atan(x / f) (the asphere is
    # corrected on the axis only, its marginal rays bend off-axis light further)
    assert image_angle_deg(d, small) == pytest.approx(
        -math.degrees(math.atan(small / d.focal_length_m)), rel=0.1)
    offsets = np.linspace(-0.012, 0.012, 7)
    angles = np.array([image_angle_deg(d, x) for x in offsets])
    assert np.all(np.diff(angles) < 0)  # inverted image, monotonic
    assert np.allclose(offset_for_angle_m(d, angles), offsets, atol=2e-5)
    with pytest.raises(InputError, match="further off the axis"):
        offset_for_angle_m(d, np.array([60.0]))


def test_lens_collimates_a_point_at_its_focus(tmp_path):
    """Traced by the engine (its dielectric: refraction, Fresnel, TIR): light from a
    small source at the focus leaves the lens within a fraction of a degree of the axis."""
    d = lens_design(0.06, 0.04, ior=1.52)
    v, f, n = lens_mesh(d, 0.04)
    s = 0.05e-3  # a 0.1 mm die facing the lens
    die = GltfPart("led", np.array([[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0]]),
                   np.array([[0, 1, 2], [0, 2, 3]]), None,
                   GltfMaterial("e", emissive=(1, 1, 1)),
                   extras={"lightsim": {"flux_lm": 100.0, "emission": "lambertian"}})
    glass = GltfMaterial("glass", base_color=(1, 1, 1), transmission=1.0, ior=1.52)
    path = tmp_path / "lens.glb"
    write_glb(path, [die, GltfPart("lens", v, f, n, glass)])
    lux, summary = _simulate(path, tmp_path / "o", 200_000)
    h, vv = _angles(RES)
    near = (np.abs(h)[None, :] < 0.5) & (np.abs(vv)[:, None] < 0.5)
    assert lux[near].sum() > 0.9 * lux.sum()
    # what the lens collects: Lambertian share of its cone, less two Fresnel losses
    share = math.sin(math.radians(d.collect_half_angle_deg)) ** 2
    wall = summary["energy_lm"]["wall"]
    assert 0.8 * share * 100 < wall < share * 100


# ---------------------------------------------------------------------------------------
# the module
# ---------------------------------------------------------------------------------------


def test_parts_emitters_and_load(lowbeam):
    scene = load_scene(lowbeam, SceneSettings(resolution=RES))
    assert not [w for w in scene.warnings if "dielectric" in w]
    emitters = scene.emitters
    _, facts = build_projector()
    assert sorted(e.name for e in emitters) == [f"led_{k:02d}" for k in range(len(emitters))]
    assert all(e.emission == "lambertian" for e in emitters)
    assert sum(e.flux_lm for e in emitters) == pytest.approx(facts["flux_lm"], rel=1e-9)
    # every die faces up (the reflector's side)
    for e in emitters:
        n = np.cross(e.vertices[e.faces[:, 1]] - e.vertices[e.faces[:, 0]],
                     e.vertices[e.faces[:, 2]] - e.vertices[e.faces[:, 0]])
        assert np.all(n[:, 1] > 0)
    names = set(scene.part_names)
    assert {"reflector", "shield", "baffle", "lens", "board"} <= names


def test_shield_edge_steps_on_the_traffic_side():
    f = 0.05
    x, y = shield_edge(ProjectorParams(step_deg=15.0, step_rise_deg=1.0), f, 0.02)
    assert np.all(y <= 0) and y[0] == 0.0  # flat at F2 on world −X (non-step side)
    drop = f * math.tan(math.radians(1.0))
    assert y[-1] == pytest.approx(-drop)
    assert (x[2] - x[1]) == pytest.approx(drop / math.tan(math.radians(15.0)))
    xl, yl = shield_edge(ProjectorParams(step_deg=15.0, step_rise_deg=1.0, traffic="left"),
                         f, 0.02)
    assert np.allclose(xl, -x[::-1]) and np.allclose(yl, y[::-1])


def _top_edge(lux: np.ndarray, cols: np.ndarray, vv: np.ndarray) -> float:
    """Highest V (°) where the column band still has 5 % of its peak."""
    profile = lux[:, cols].mean(axis=1)
    lit = np.nonzero(profile > 0.05 * profile.max())[0]
    return float(vv[lit.min()])


@pytest.mark.parametrize("traffic", ["right", "left"])
def test_cutoff_rises_on_the_traffic_side_and_energy_closes(traffic, tmp_path):
    path = tmp_path / "p.glb"
    assert _cli(["luminaire", "projector", str(path), "--traffic", traffic]) == 0
    lux, summary = _simulate(path, tmp_path / "o", 600_000)
    _energy_closes(summary)
    h, vv = _angles(RES)
    left = _top_edge(lux, np.nonzero((h > -5) & (h < -3))[0], vv)
    right = _top_edge(lux, np.nonzero((h > 3) & (h < 5))[0], vv)
    assert -1.5 < min(left, right) < 0.0  # a cut-off below H–H on the non-step side
    if traffic == "right":
        assert right > left + 0.3
    else:
        assert left > right + 0.3


def test_high_beam_lets_the_shielded_light_through(tmp_path):
    """With the shield flipped down more light reaches the screen, and more of it above
    the low beam's cut-off (the part the shield held back is imaged upwards)."""
    light, wall = {}, {}
    for beam in ("low", "high"):
        path = tmp_path / f"{beam}.glb"
        assert _cli(["luminaire", "projector", str(path), "--beam", beam]) == 0
        lux, summary = _simulate(path, tmp_path / beam, 300_000)
        _energy_closes(summary)
        _, vv = _angles(RES)
        light[beam] = lux[vv > 0.0].sum() / lux.sum()
        wall[beam] = summary["energy_lm"]["wall"]
    assert wall["high"] > 1.1 * wall["low"]
    assert light["low"] < 0.05 and light["high"] > 2 * light["low"]


@pytest.mark.parametrize("kwargs, message", [
    ({"semi_major_m": 0.01}, "semi-major axis"),
    ({"focal_distance_m": float("nan")}, "focal distance"),
    ({"beam": "fog"}, "unknown beam"),
    ({"led": "XYZ"}, "unknown LED"),
    ({"flux_lm": -5.0}, "flux"),
    ({"sign_prisms": ((1.0, 0.5),)}, "sign prism"),
    ({"colour": 1}, "unknown projector option"),
])
def test_bad_parameters(kwargs, message):
    with pytest.raises(InputError, match=message):
        build_projector(**kwargs)


@pytest.mark.parametrize("args, message", [
    (["--lens-diameter", "0"], "lens diameter"),
    (["--semi-major", "5"], "semi-major"),
    (["--step", "90"], "step angle"),
])
def test_cli_bad_input_is_one_line(args, message, tmp_path, capsys):
    out = tmp_path / "p.glb"
    code, _, err = run_cli(["luminaire", "projector", str(out), *args], capsys)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_shipped_example_regenerates(tmp_path, capsys):
    shipped = EXAMPLES / "projector.glb"
    assert EXAMPLE_COMMAND in (EXAMPLES / "README.md").read_text(encoding="utf-8")
    fresh = tmp_path / "projector.glb"
    code, text, _ = run_cli(["luminaire", "projector", str(fresh)], capsys)
    assert code == 0 and "led_00" in text
    assert fresh.read_bytes() == shipped.read_bytes()
    assert shipped.stat().st_size < 1_500_000


@pytest.mark.slow
def test_low_beam_passes_r149_class_b(tmp_path, capsys):
    """The README-like run: every rule of r149-b-passing decided, and passed."""
    out = tmp_path / "o"
    code, _, _ = run_cli(["simulate", str(EXAMPLES / "projector.glb"), "--photons",
                          "48000000", "--resolution", "320x128", "--regulation",
                          "r149-b-passing", "--out", str(out), "--outputs", "json"], capsys)
    assert code == 0
    results = json.loads((out / "summary.json").read_text())["regulation"]["results"]
    verdicts = {r["name"]: r["verdict"] for r in results if r["kind"] != "measure"}
    assert set(verdicts.values()) == {"pass"}, verdicts
