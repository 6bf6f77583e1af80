"""Light sources: IES/LDT files as goniometric point sources; collimated emitters."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.luminaires.photometric import read_photometric, sample_directions, write_ldt
from lightsim.scene import load_scene

IES = Path(__file__).parents[1] / "luminaires" / "photometric" / "interlight-ovni-60w-5300lm.ies"


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
    scene = load_scene(path, wall_distance=d, wall_size=(w, h), resolution=(32, 32))
    assert scene.total_flux == pytest.approx(grid.total_flux(), rel=1e-5)
    with Session(scene, RunConfig(estimator="bin", frame_photons=100_000, interleave=2)) as s:
        s.run(photons=300_000)
        e = s.energy()
    frac = _wall_fraction(grid, d, w, h)
    sigma = np.sqrt(frac * (1 - frac) / 300_000) + np.sqrt(frac * (1 - frac) / 400_000)
    assert e["wall"] / e["emitted"] == pytest.approx(frac, abs=4 * sigma)
    assert e["wall"] + e["escaped"] == pytest.approx(e["emitted"], rel=1e-9)


def test_photometric_source_flux_override():
    scene = load_scene(IES, flux=1000.0)
    assert scene.total_flux == pytest.approx(1000.0)
    grid = read_photometric(IES)
    src = scene.emitters[0].distribution
    np.testing.assert_allclose(src.candela, grid.candela * 1000.0 / grid.total_flux(),
                               rtol=1e-12)
