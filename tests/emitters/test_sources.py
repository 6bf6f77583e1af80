"""Light sources: IES/LDT files as goniometric point sources; collimated emitters."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.luminaires.photometric import (
    HVGrid,
    read_photometric,
    sample_directions,
    write_ies,
    write_ldt,
)
from lightsim.scene import SceneSettings, load_scene

IES = Path(__file__).parents[2] / "luminaires" / "photometric" / "interlight-ovni-60w-5300lm.ies"


def _wall_fraction(grid, d: float, w: float, h: float, n: int = 400_000) -> float:
    """Fraction of the distribution's flux heading into the wall rectangle at z = d."""
    rng = np.random.default_rng(4)
    dirs, _ = sample_directions(grid, rng.random(n), rng.random(n))
    fwd = dirs[:, 2] > 0
    x = np.where(fwd, dirs[:, 0] / np.where(fwd, dirs[:, 2], 1) * d, np.inf)
    y = np.where(fwd, dirs[:, 1] / np.where(fwd, dirs[:, 2], 1) * d, np.inf)
    return float(np.mean(fwd & (np.abs(x) < w / 2) & (np.abs(y) < h / 2)))


@pytest.mark.parametrize("fmt", ["ies", "ldt"])
def test_photometric_file_as_point_source(tmp_path, fmt):
    path = IES
    grid = read_photometric(IES)
    if fmt == "ldt":
        path = tmp_path / "lamp.ldt"
        write_ldt(path, grid)
    d, w, h = 2.0, 8.0, 8.0
    scene = load_scene(path, SceneSettings(wall_distance=d, wall_size=(w, h), resolution=(32, 32)))
    assert scene.total_flux == pytest.approx(grid.total_flux(), rel=1e-5)
    with Session(scene, RunConfig(estimator="bin", frame_photons=100_000, interleave=2)) as s:
        s.run(photons=300_000)
        e = s.energy()
    frac = _wall_fraction(grid, d, w, h)
    sigma = np.sqrt(frac * (1 - frac) / 300_000) + np.sqrt(frac * (1 - frac) / 400_000)
    assert e["wall"] / e["emitted"] == pytest.approx(frac, abs=4 * sigma)
    assert e["wall"] + e["escaped"] == pytest.approx(e["emitted"], rel=1e-9)


def test_photometric_source_flux_override():
    scene = load_scene(IES, SceneSettings(flux=1000.0))
    assert scene.total_flux == pytest.approx(1000.0)
    grid = read_photometric(IES)
    src = scene.emitters[0].distribution
    np.testing.assert_allclose(src.candela, grid.candela * 1000.0 / grid.total_flux(),
                               rtol=1e-12)


def test_type_a_source_wall_lux_is_the_files_intensity(tmp_path):
    """The wall a run produces from a Type A file is the file's interpolated intensity:
    E = I(direction)·D/r³ (grid.wall_lux), pixel by pixel within the photon noise."""
    h = np.linspace(-30, 30, 25)
    v = np.linspace(-15, 15, 13)
    H, V = np.meshgrid(h, v, indexing="ij")
    cd = 20000 * np.exp(-((H - 6) / 9) ** 2 - ((V + 3) / 5) ** 2) + 100
    grid = HVGrid(h, v, cd, "A")
    path = write_ies(tmp_path / "beam.ies", grid)
    scene = load_scene(path, SceneSettings(wall_distance=25.0, wall_size=(16.0, 8.0),
                                           resolution=(16, 8)))
    n = 400_000
    with Session(scene, RunConfig(estimator="bin", frame_photons=100_000, interleave=2)) as s:
        est = s.run(photons=n)
    lux = est.lux[..., 0]
    # expected pixel mean: the file's wall illuminance averaged over 8 × 8 points per pixel
    fine = grid.wall_lux({"distance_m": 25.0, "h_range_m": [-8.0, 8.0],
                          "v_range_m": [-4.0, 4.0], "resolution": [128, 64]})
    want = fine.reshape(8, 8, 16, 8).mean(axis=(1, 3))
    sigma = np.sqrt(want * scene.total_flux / n / 1.0)      # Poisson, 1 m² pixels
    z = (lux - want) / np.maximum(sigma, 1e-12)
    bright = want > 0.2 * want.max()
    rel = np.abs(lux[bright] / want[bright] - 1)
    print(f"\nType A source on the wall: max |z| = {np.abs(z).max():.2f} (Poisson σ; Halton "
          f"points do better), bright pixels within {100 * rel.max():.2f} % "
          f"(mean {100 * rel.mean():.2f} %) of the file")
    assert np.abs(z).max() < 5 and rel.max() < 0.02


def test_core_finds_readers_through_the_entry_point():
    """A script that imports only the core still loads an IES file and a bulb: the
    registry loads the ``lightsim.sources`` entry point on first need."""
    code = ("import sys\n"
            "from lightsim.emitters import registry\n"
            "from lightsim.scene import SceneSettings, load_scene\n"
            "assert not any(m.startswith('lightsim.luminaires') for m in sys.modules)\n"
            f"s = load_scene({str(IES)!r}, SceneSettings(wall_distance=2.0, resolution=(8, 8)))\n"
            "print(round(s.total_flux), callable(registry.filament_factory()))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=False)
    assert res.returncode == 0, res.stderr
    flux = read_photometric(IES).total_flux()
    assert res.stdout.split() == [str(round(flux)), "True"]
