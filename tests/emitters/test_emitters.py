"""Core emitters (lightsim.emitters) and the chunked tracer: the protocol, the registry,
the goniometric sampler against the photometric file's own interpolant, and results that
do not depend on how a batch is split over threads."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lightsim.emitters import Emitter, EmitterMix, GoniometricEmitter, MeshEmitter, registry
from lightsim.emitters.rayfile import RaySource
from lightsim.errors import InputError
from lightsim.luminaires.photometric import read_photometric
from lightsim.sampling import digit_permutations, halton_points, photon_keys
from lightsim.scene import load_scene
from lightsim.tracer import PhotonTracer

IES = Path(__file__).parents[2] / "luminaires" / "photometric" / "interlight-ovni-60w-5300lm.ies"


def points(n: int, seed: int = 5) -> np.ndarray:
    return halton_points(np.arange(n, dtype=np.int64), digit_permutations(seed, 0, None))


def test_scene_emitters_follow_the_protocol():
    scene = load_scene(IES)
    src = scene.emitters[0].emitter
    assert isinstance(src, GoniometricEmitter) and isinstance(src, Emitter)
    assert src.flux_lm == pytest.approx(scene.total_flux)
    o, d = src.sample(points(1000))
    np.testing.assert_array_equal(o, np.zeros((1000, 3)))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)


def test_goniometric_directions_follow_the_files_intensity():
    """Photons binned by direction reproduce the grid's interpolated intensity I = Φ dN/(N dΩ)
    in cones around a few directions (the reader and its interpolant are the reference)."""
    grid = read_photometric(IES)
    src = GoniometricEmitter(np.zeros(3), grid.table, float(grid.total_flux()))
    n = 400_000
    _, d = src.sample(points(n))
    for axis in (np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0]),
                 np.array([0.6, -0.8, 0.0])):
        axis = axis / np.linalg.norm(axis)
        half = math.radians(8.0)
        inside = d @ axis > math.cos(half)
        omega = 2 * math.pi * (1 - math.cos(half))
        k = int(inside.sum())
        if k < 200:
            continue
        measured = src.flux_lm * k / n / omega
        expected = float(np.mean(grid.intensity_towards(d[inside])))  # mean over the cone
        assert measured == pytest.approx(expected, rel=5 / math.sqrt(k))


def test_mixture_shares_photons_by_flux():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float)
    mesh = MeshEmitter.build([(tri, "lambertian", 30.0)])
    grid = read_photometric(IES)
    point = GoniometricEmitter(np.array([5.0, 5.0, 5.0]), grid.table, 70.0)
    mix = EmitterMix(mesh, 100.0, 0.3, [point])
    n = 20_000
    o, d = mix.sample(points(n))
    from_point = np.all(o == 5.0, axis=1)
    assert from_point.mean() == pytest.approx(0.7, abs=2e-3)  # stratified: no √n noise
    on_tri = o[~from_point]
    assert np.all(on_tri[:, 2] == 0) and np.all(on_tri[:, 0] + on_tri[:, 1] <= 1 + 1e-12)
    assert np.all(d[~from_point][:, 2] >= 0)  # Lambertian about +Z


def test_registry_says_what_is_missing(monkeypatch):
    monkeypatch.setattr(registry, "_READERS", {})
    monkeypatch.setattr(registry, "_FILAMENTS", [])
    # no package under the entry point: the one-line errors
    monkeypatch.setattr(registry, "ENTRY_POINT_GROUP", "lightsim.no-such-group")
    monkeypatch.setattr(registry, "_PLUGINS_LOADED", False)
    with pytest.raises(InputError, match=r"no photometric reader for '\.ies'"):
        load_scene(IES)
    with pytest.raises(InputError, match="no bulb catalogue"):
        registry.filament_factory()


def test_registry_loads_the_entry_point_on_first_need(monkeypatch):
    monkeypatch.setattr(registry, "_READERS", {})
    monkeypatch.setattr(registry, "_FILAMENTS", [])
    monkeypatch.setattr(registry, "_PLUGINS_LOADED", False)
    assert callable(registry.photometric_reader(".ies"))
    assert callable(registry.filament_factory())


def test_rayfile_source_is_an_emitter():
    assert hasattr(RaySource, "sample") and hasattr(RaySource, "describe")


def test_tracing_does_not_depend_on_threads_or_chunks():
    """Photon i is a function of its sample point and key only: one thread or two, small
    chunks or one, the records and the ledger are bit-identical (records in bounce-major,
    photon order within a batch); smaller batches reorder the records, nothing else."""
    scene = load_scene(Path(__file__).parents[2] / "luminaires" / "examples" / "headlight.glb")
    n = 6000
    pts = points(n, 9)
    keys = photon_keys(9, 0, 0, np.arange(n, dtype=np.int64))
    group = np.arange(n) % 3
    runs = []
    for threads, chunk, batch in ((1, 100_000, 262144), (2, 512, 262144), (2, 300, 2500)):
        tr = PhotonTracer(scene, threads=threads, min_chunk=chunk, batch=batch, record="all")
        r = tr.trace_points(pts, keys, group=group, n_groups=3, record_escaped=True)
        tr.close()
        runs.append(r)
    a = runs[0]
    assert len(a.records) > 1000
    c = runs[2]  # batches of 2500: the same records, batch-major
    order_a = np.lexsort((a.records.position[:, 0], a.records.source))
    order_c = np.lexsort((c.records.position[:, 0], c.records.source))
    for f in ("position", "normal", "power", "part", "flags", "source"):
        np.testing.assert_array_equal(getattr(a.records, f)[order_a],
                                      getattr(c.records, f)[order_c])
    np.testing.assert_allclose(a.ledger, c.ledger, rtol=1e-12)  # summed in another order
    for b in runs[1:2]:
        for f in ("position", "normal", "power", "part", "flags", "source"):
            np.testing.assert_array_equal(getattr(a.records, f), getattr(b.records, f))
        np.testing.assert_array_equal(a.ledger, b.ledger)
        np.testing.assert_array_equal(a.escaped_dir, b.escaped_dir)
        np.testing.assert_array_equal(a.caustic_source, b.caustic_source)
        assert a.rays == b.rays
