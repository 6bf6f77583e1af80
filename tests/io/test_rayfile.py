"""Ray-file sources: TM-25 and Zemax binary readers/writers, the flux-weighted sampler,
and an exact Lambertian square LED against Lambert's contour integral."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from lightsim.emitters.rayfile import RaySource, rotation_z_to
from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.io.rayfile import read_rayfile, write_tm25, write_zemax
from lightsim.luminaires.rayfiles import lambertian_square, lambertian_square_luminance
from lightsim.render.frame import luminous
from lightsim.scene import SceneSettings, load_scene
from lightsim.validation.scenes.analytic import lambert_polygon_lux, pixel_average

from support import run_cli

# the shipped example, found from the repository rather than the working directory
HEADLIGHT = str(Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "headlight.glb")


def _rays(n=50, seed=3):
    rng = np.random.default_rng(seed)
    pos = rng.normal(scale=1e-3, size=(n, 3))
    k = rng.normal(size=(n, 3))
    k[:, 2] = np.abs(k[:, 2]) + 0.1
    return pos, k / np.linalg.norm(k, axis=1, keepdims=True), rng.uniform(0.5, 2.0, n)


def test_tm25_round_trip_layout_and_memmap(tmp_path):
    pos, k, flux = _rays()
    lam = np.linspace(450, 650, len(pos))
    path = write_tm25(tmp_path / "a.tm25ray", pos, k, flux, lam, name="test LED")
    rf = read_rayfile(path)
    # TM-25-13: 256-byte file header + 32 flag bytes + 9 × 4000-byte texts, then rays
    assert rf.offset == 256 + 32 + 9 * 4000
    assert path.stat().st_size == rf.offset + len(pos) * 8 * 4
    assert rf.items == ["x", "y", "z", "kx", "ky", "kz", "lambda", "Tri_Y"]
    assert rf.unit_m == 1e-3 and rf.meta["name"] == "test LED"
    rays = rf.rays()
    assert isinstance(rays, np.memmap)  # streamed, not loaded
    np.testing.assert_allclose(rays[:, :3] * rf.unit_m, pos, rtol=1e-6)
    np.testing.assert_allclose(rays[:, rf.column("lambda")], lam, rtol=1e-6)
    assert rf.luminous_flux() == pytest.approx(flux.sum(), rel=1e-6)
    assert rf.header_flux_lm == pytest.approx(flux.sum(), rel=1e-6)


@pytest.mark.parametrize("units,scale", [("mm", 1e-3), ("cm", 1e-2), ("m", 1.0)])
def test_zemax_round_trip(tmp_path, units, scale):
    pos, k, flux = _rays()
    path = write_zemax(tmp_path / "a.dat", pos, k, flux, units=units)
    assert path.stat().st_size == 208 + len(pos) * 7 * 4  # 208-byte header, 7 floats/ray
    rf = read_rayfile(path)
    assert rf.format == "zemax" and rf.unit_m == scale and rf.flux_is_luminous
    np.testing.assert_allclose(rf.rays()[:, :3] * rf.unit_m, pos, rtol=1e-5, atol=1e-12)
    assert rf.luminous_flux() == pytest.approx(flux.sum(), rel=1e-6)
    o, d = RaySource(path).sample_rays(np.array([[0.0], [0.999999]]))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-6)
    assert np.all(np.isfinite(o))


def test_radiant_only_file_needs_flux(tmp_path):
    """A Zemax file in watts gives relative weights only: the lumens must be given."""
    pos, k, flux = _rays()
    path = write_zemax(tmp_path / "w.dat", pos, k, flux)
    data = bytearray(path.read_bytes())
    data[196:200] = (0).to_bytes(4, "little")  # flux type 0: watts
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="give --flux"):
        RaySource(path)
    assert RaySource(path, flux_lm=250.0).flux_lm == 250.0


def test_corrupt_files_give_one_line(tmp_path):
    pos, k, flux = _rays()
    good = write_tm25(tmp_path / "a.tm25ray", pos, k, flux).read_bytes()
    cases = {"short.tm25ray": good[:-5], "long.tm25ray": good + b"\0" * 4,
             "magic.dat": b"XXXX" + good[4:300], "empty.tm25ray": b""}
    for name, data in cases.items():
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(InputError) as err:
            read_rayfile(p)
        assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="no such"):
        read_rayfile(tmp_path / "missing.tm25ray")


def test_sampler_weights_by_flux_with_replacement(tmp_path):
    """Two rays with flux 1 and 3: drawn 1 : 3; 8× more photons than rays reuse them."""
    pos = np.array([[0.0, 0.0, 0.0], [1e-3, 0.0, 0.0]])
    k = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    path = write_tm25(tmp_path / "two.tm25ray", pos, k, [1.0, 3.0])
    src = RaySource(path, position=(0.0, 0.0, 0.1))
    assert src.flux_lm == pytest.approx(4.0) and not src.equal_flux
    u = (np.arange(16) + 0.5) / 16
    o, d = src.sample_rays(u[:, None])
    first = np.all(d == [0, 0, 1], axis=1)
    assert first.sum() == 4 and (~first).sum() == 12
    np.testing.assert_allclose(o[~first], [[1e-3, 0.0, 0.1]] * 12, atol=1e-9)


def test_rotation_takes_z_to_axis():
    for axis in ((0, 1, 0), (1, 1, 0), (0, 0, -1), (0, 0, 1)):
        a = np.asarray(axis, float) / np.linalg.norm(axis)
        rot = rotation_z_to(a)
        np.testing.assert_allclose(rot @ [0, 0, 1], a, atol=1e-12)
        np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)


def test_lambertian_square_led_is_exact(tmp_path):
    """A 4 cm Lambertian square, 40 000 rays, 160 000 photons (each ray ~4 times) on a
    wall 10 cm away: E from Lambert's contour integral with L = Φ/(πA)."""
    side, flux, d = 0.04, 100.0, 0.1
    pos, k, fl = lambertian_square(side, 40_000, flux, seed=2)
    path = write_tm25(tmp_path / "led.tm25ray", pos, k, fl)
    scene = load_scene(path, SceneSettings(wall_distance=d, wall_size=(0.3, 0.3),
                                           resolution=(30, 30)))
    with Session(scene, RunConfig(frame_photons=160_000, interleave=2,
                                  estimator="bin")) as s:
        lux = luminous(s.run(photons=160_000).lux)
        energy = s.energy()
    assert energy["emitted"] == pytest.approx(flux, rel=1e-6)  # float32 ray fluxes
    lum = lambertian_square_luminance(side, flux)
    h = side / 2
    square = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    frame = scene.wall
    exact = pixel_average(lambda hh, vv: lambert_polygon_lux(
        lum, square, frame.to_world(hh, vv), -frame.normal), frame)
    centre = exact > 0.5 * exact.max()
    ratio = lux[centre].sum() / exact[centre].sum()
    assert ratio == pytest.approx(1.0, abs=0.01)
    # per pixel: binomial noise of ~180 photons per central pixel (7.5 %), 5 sigma
    assert np.max(np.abs(lux[centre] / exact[centre] - 1)) < 0.4
    tail = (exact > 0.05 * exact.max()) & ~centre
    assert lux[tail].sum() / exact[tail].sum() == pytest.approx(1.0, abs=0.03)


def test_cli_rayfile_replaces_the_filament(tmp_path, capsys):
    led = tmp_path / "led.tm25ray"
    code, _, err = run_cli(["luminaire", "rayfile", str(led), "--rays", "10000",
                              "--flux", "500"], capsys)
    assert code in (0, None), err
    code, _, err = run_cli(["simulate", HEADLIGHT, "--rayfile",
                              str(led), "--rayfile-at", "0,0.0007,0.0285", "--rayfile-axis",
                              "0,1,0", "--photons", "20000", "--resolution", "64x32",
                              "--out", str(tmp_path / "o")], capsys)
    assert code in (0, None), err
    assert "emitter 'filament' replaced by the ray file led.tm25ray" in err
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["energy_lm"]["emitted"] == pytest.approx(500.0, rel=1e-6)
    assert any(p.startswith("rayfile-led: 1 triangles") or "rayfile-led" in p
               for p in s["scene"]["parts"])
    assert not any(p.startswith("filament") for p in s["scene"]["parts"])
    assert s["energy_lm"]["wall"] > 50.0
    code, _, err = run_cli(["simulate", HEADLIGHT, "--rayfile",
                            str(tmp_path / "nope.tm25ray"), "--out", str(tmp_path / "x")],
                           capsys)
    assert code == 2 and "no such ray file" in err and err.count("\n") == 1
    assert math.isfinite(s["lux"]["max_lx"])
