"""Filament emitter meshes and bulb presets."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from lightsim.errors import InputError
from lightsim.luminaires.bulbs import BULBS, get_bulb
from lightsim.luminaires.filament import filament_mesh, filament_part, orthonormal_basis


@pytest.mark.parametrize("axis", [(0, 0, 1), (1, 0, 0), (0, 1, 1), (-0.3, 0.2, -0.9)])
def test_cylinder_closed_outward_with_requested_size(axis):
    length, diameter, centre = 0.005, 0.0014, (0.01, -0.02, 0.025)
    v, f = filament_mesh(length, diameter, centre, axis, segments=16)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    # inscribed 16-gon prism: volume (n/2) r² sin(2π/n) · L, positive = outward normals
    r = diameter / 2
    assert mesh.volume == pytest.approx(8 * r * r * math.sin(2 * math.pi / 16) * length)
    np.testing.assert_allclose(mesh.vertices.mean(axis=0), centre, atol=1e-12)
    w = np.asarray(axis, float) / np.linalg.norm(axis)
    along = (v - centre) @ w
    radial = np.linalg.norm((v - centre) - np.outer(along, w), axis=1)
    assert along.min() == pytest.approx(-length / 2) and along.max() == pytest.approx(length / 2)
    assert radial.max() == pytest.approx(r)


def test_box_shape():
    v, f = filament_mesh(0.004, 0.001, (0, 0, 0), (0, 0, 1), shape="box")
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.volume == pytest.approx(0.004 * 0.001 * 0.001)
    np.testing.assert_allclose(mesh.extents, [0.001, 0.001, 0.004])


def test_basis_is_right_handed():
    for axis in [(0, 0, 1), (0, 1, 0), (1, 2, 3)]:
        u, v, w = orthonormal_basis(axis)
        np.testing.assert_allclose(np.cross(u, v), w, atol=1e-12)
        np.testing.assert_allclose([u @ u, v @ v, u @ v], [1, 1, 0], atol=1e-12)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((0.0, 0.001, (0, 0, 0), (0, 0, 1)), "length"),
        ((0.005, -1.0, (0, 0, 0), (0, 0, 1)), "diameter"),
        ((0.005, 0.001, (0, 0, 0), (0, 0, 0)), "non-zero"),
        ((0.005, 0.001, (0, np.nan, 0), (0, 0, 1)), "finite"),
        ((5.0, 1.4, (0, 0, 0), (0, 0, 1)), "implausibly"),
    ],
)
def test_bad_filament_sizes(args, message):
    with pytest.raises(InputError, match=message):
        filament_mesh(*args)


def test_filament_part_extras_and_emissive():
    spec = get_bulb("H7")
    part = filament_part(spec, (0, 0, 0.025), (0, 0, 1), 1500.0, emission="lambertian")
    assert part.name == "filament"
    assert max(part.material.emissive) > 0
    extras = part.extras["lightsim"]
    assert extras["flux_lm"] == 1500.0
    assert extras["emission"] == "lambertian"
    assert extras["bulb"] == "H7"
    assert extras["filament"]["length_m"] == spec.filament_length_m
    with pytest.raises(InputError, match="flux"):
        filament_part(spec, (0, 0, 0), (0, 0, 1), 0.0)
    with pytest.raises(InputError, match="flux"):
        filament_part(spec, (0, 0, 0), (0, 0, 1), float("nan"))
    with pytest.raises(InputError, match="emission"):
        filament_part(spec, (0, 0, 0), (0, 0, 1), 1.0, emission="laser")


def test_bulb_presets():
    assert set(BULBS) >= {"H1", "H4-high", "H4-low", "H7"}
    assert get_bulb("h4-LOW") is BULBS["H4-low"]
    assert BULBS["H1"].flux_lm == 1550.0 and "13.2 V" in BULBS["H1"].flux_source
    assert BULBS["H7"].flux_lm == 1500.0 and "1 350" in BULBS["H7"].flux_source
    assert BULBS["H4-low"].flux_lm == 1000.0 and "not verified" in BULBS["H4-low"].flux_source
    for spec in BULBS.values():
        assert spec.flux_source and 0 < spec.filament_diameter_m < spec.filament_length_m
        assert abs(np.linalg.norm(spec.filament_axis) - 1) < 1e-12
    for name in ("H1", "H7"):
        assert BULBS[name].filament_offset_m == (0.0, 0.0, 0.0)
        assert BULBS[name].filament_axis == (0.0, 0.0, 1.0) and not BULBS[name].shield_cup
    low, high = BULBS["H4-low"], BULBS["H4-high"]
    # passing filament entirely ahead of the focus (+Z) and above the axis, with a cup
    assert low.filament_offset_m[2] - low.filament_length_m / 2 > 0
    assert low.filament_offset_m[1] > 0 and low.shield_cup
    # driving filament on the axis with the focus on it; the two coils do not overlap
    z_high = high.filament_offset_m[2]
    assert high.filament_offset_m[:2] == (0.0, 0.0)
    assert z_high - high.filament_length_m / 2 < 0 < z_high + high.filament_length_m / 2
    low_rear = low.filament_offset_m[2] - low.filament_length_m / 2
    assert z_high + high.filament_length_m / 2 < low_rear


def test_flux_override_and_unknown_bulb():
    spec = get_bulb("H1").with_flux(1400)
    assert spec.flux_lm == 1400.0 and "--flux" in spec.flux_source
    for bad in (0, -5, float("inf"), "x"):
        with pytest.raises(InputError, match="flux"):
            get_bulb("H1").with_flux(bad)
    with pytest.raises(InputError, match="unknown bulb 'H9'"):
        get_bulb("H9")
