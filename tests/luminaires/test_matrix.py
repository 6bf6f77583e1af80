"""The matrix LED high beam (``lightsim luminaire matrix``): segments and their stripes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import lightsim.luminaires
from lightsim.errors import InputError
from lightsim.luminaires.matrix import build_matrix, segment_name, stripe_edges_deg
from lightsim.scene import SceneSettings, load_scene
from lightsim.simulate import SimulateOptions, run_simulation

from support import run_cli

EXAMPLES = Path(lightsim.luminaires.__file__).parent / "examples"
EXAMPLE_COMMAND = "lightsim luminaire matrix luminaires/examples/matrix.glb"
RES = (240, 48)  # 30 × 12 m wall at 25 m: 0.14° per column


def _h_deg(res: tuple[int, int]) -> np.ndarray:
    w = res[0]
    return np.degrees(np.arctan(((np.arange(w) + 0.5) / w * 30.0 - 15.0) / 25.0))


def _one_segment_lux(glb: Path, out: Path, k: int, segments: int, photons: int
                     ) -> tuple[np.ndarray, dict]:
    """Simulate with only segment k lit: the others are left out with the existing
    ``--part-material NAME=ignore`` (emitters neither occlude nor reflect)."""
    off = {segment_name(j): "ignore" for j in range(segments) if j != k}
    opts = SimulateOptions(scene_path=str(glb), photons=photons, resolution=RES,
                           out_dir=str(out), outputs=("json",), part_materials=off)
    result = run_simulation(opts)
    return result.lux, result.summary


def test_parts_and_named_emitters(tmp_path, capsys):
    path = tmp_path / "m.glb"
    code, text, _ = run_cli(["luminaire", "matrix", str(path), "--segments", "5"], capsys)
    assert code == 0 and "5 segments" in text
    scene = load_scene(path, SceneSettings(resolution=RES))
    names = sorted(e.name for e in scene.emitters)
    assert names == [f"led_{k:02d}" for k in range(5)]
    assert all(e.emission == "lambertian" for e in scene.emitters)
    assert {"lens", "housing", "board"} <= set(scene.part_names)
    assert not [w for w in scene.warnings if "dielectric" in w]
    parts, facts = build_matrix(segments=5)
    groups = [p.extras["lightsim"]["group"] for p in parts if p.name.startswith("led_")]
    assert groups == [f"led_{k:02d}" for k in range(5)]
    assert facts["flux_lm"] == pytest.approx(sum(e.flux_lm for e in scene.emitters))
    # die k sits where the lens images it into stripe k: world +X ↔ H > 0, left to right
    xs = [p.vertices[:, 0].mean() for p in parts if p.name.startswith("led_")]
    assert np.all(np.diff(xs) > 0)


def test_stripe_edges():
    e = stripe_edges_deg(16, 24.0)
    assert len(e) == 17 and e[0] == -12 and e[-1] == 12
    assert np.allclose(np.diff(e), 1.5)


def test_each_segment_lights_its_own_stripe_left_to_right(tmp_path):
    segments = 6
    path = tmp_path / "m.glb"
    assert run_cli_ok(["luminaire", "matrix", str(path), "--segments", str(segments),
                       "--span", "24"])
    edges = stripe_edges_deg(segments, 24.0)
    _, facts = build_matrix(segments=segments, span_deg=24.0)
    assert sum(facts["segment_flux_lm"]) == pytest.approx(260.0 * segments)
    h = _h_deg(RES)
    centroids = []
    for k in range(segments):
        lux, summary = _one_segment_lux(path, tmp_path / f"o{k}", k, segments, 60_000)
        e = summary["energy_lm"]
        assert e["emitted"] == pytest.approx(facts["segment_flux_lm"][k])
        parts = sum(e[n] for n in ("wall", "absorbed_diffuse", "absorbed_mirror",
                                   "absorbed_volume", "escaped", "roulette", "max_depth"))
        assert parts == pytest.approx(e["emitted"], rel=1e-6)
        column = lux.sum(axis=0)
        c = float((column * h).sum() / column.sum())
        centroids.append(c)
        assert edges[k] < c < edges[k + 1], (k, c, edges[k:k + 2])
        # most of the segment's light on the wall lies in its own stripe (± 0.5°: the
        # lens blurs the die's image off the axis)
        inside = (h > edges[k] - 0.5) & (h < edges[k + 1] + 0.5)
        assert column[inside].sum() > 0.7 * column.sum(), k
    assert np.all(np.diff(centroids) > 0)


def run_cli_ok(argv: list[str]) -> bool:
    from lightsim.cli.main import main
    with pytest.raises(SystemExit) as exc:
        main(argv)
    return not exc.value.code


@pytest.mark.parametrize("args, message", [
    (["--segments", "0"], "segments must be"),
    (["--segments", "-3"], "segments must be"),
    (["--flux", "nan"], "segment flux"),
    (["--span", "80"], "stripe span"),
    (["--segments", "4", "--only-segment", "4"], "does not exist"),
])
def test_cli_bad_input_is_one_line(args, message, tmp_path, capsys):
    out = tmp_path / "m.glb"
    code, _, err = run_cli(["luminaire", "matrix", str(out), *args], capsys)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_bad_parameters():
    with pytest.raises(InputError, match="unknown matrix option"):
        build_matrix(colour=3)
    with pytest.raises(InputError, match="stripe height"):
        build_matrix(v_low_deg=2.0, v_high_deg=1.0)
    with pytest.raises(InputError, match="more than the lens"):
        build_matrix(span_deg=50.0, lens_diameter_m=0.03, lens_distance_m=0.04)


def test_only_segment_builds_one_die(tmp_path, capsys):
    path = tmp_path / "m.glb"
    code, _, _ = run_cli(["luminaire", "matrix", str(path), "--only-segment", "3"], capsys)
    assert code == 0
    scene = load_scene(path, SceneSettings(resolution=RES))
    assert [e.name for e in scene.emitters] == ["led_03"]


def test_shipped_example_regenerates(tmp_path, capsys):
    shipped = EXAMPLES / "matrix.glb"
    assert EXAMPLE_COMMAND in (EXAMPLES / "README.md").read_text(encoding="utf-8")
    fresh = tmp_path / "matrix.glb"
    code, _, _ = run_cli(["luminaire", "matrix", str(fresh)], capsys)
    assert code == 0
    assert fresh.read_bytes() == shipped.read_bytes()
    assert shipped.stat().st_size < 1_000_000


@pytest.mark.slow
def test_shipped_example_stripes(tmp_path):
    """All 16 segments of the shipped example, one at a time."""
    glb = EXAMPLES / "matrix.glb"
    edges = stripe_edges_deg(16, 24.0)
    h = _h_deg(RES)
    centroids = []
    for k in range(16):
        lux, _ = _one_segment_lux(glb, tmp_path / f"o{k}", k, 16, 100_000)
        column = lux.sum(axis=0)
        centroids.append(float((column * h).sum() / column.sum()))
        assert edges[k] < centroids[-1] < edges[k + 1]
    assert np.all(np.diff(centroids) > 0)


@pytest.mark.slow
def test_all_on_passes_r149_class_b_driving(tmp_path, capsys):
    out = tmp_path / "o"
    code, _, _ = run_cli(["simulate", str(EXAMPLES / "matrix.glb"), "--photons", "16000000",
                          "--resolution", "320x128", "--regulation", "r149-b-driving",
                          "--out", str(out), "--outputs", "json"], capsys)
    assert code == 0
    results = json.loads((out / "summary.json").read_text())["regulation"]["results"]
    verdicts = {r["name"]: r["verdict"] for r in results if r["kind"] != "measure"}
    assert set(verdicts.values()) == {"pass"}, verdicts
