"""Per-source maps (lightsim.persource, simulate --per-source): the emitter group of every
photon, superposition bit for bit, the all-on map equal to a plain binning run's, memory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lightsim import persource
from lightsim.emitters import EmitterMix
from lightsim.errors import InputError
from lightsim.io.exr import read_exr
from lightsim.persource import (
    ALL_ON,
    EmitterGroups,
    PerSourceSums,
    compose,
    read_per_source,
    split_exactly,
)
from lightsim.sampling import digit_permutations, halton_points
from lightsim.scene import SceneSettings, load_scene
from lightsim.simulate import SimulateOptions, read_checkpoint, run_simulation

MATRIX = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "matrix.glb"


@pytest.fixture(scope="module")
def matrix_scene():
    return load_scene(str(MATRIX), SceneSettings(resolution=(64, 32)))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The shipped matrix lamp, once with --per-source (kNN map) and once binned, same
    photons and seed, in several frames."""
    base = tmp_path_factory.mktemp("persource")
    out = {}
    for name, per_source, config in (("per_source", True, {"frame_photons": 20_000}),
                                     ("binned", False, {"estimator": "bin",
                                                        "frame_photons": 20_000})):
        opts = SimulateOptions(scene_path=str(MATRIX), photons=60_000, out_dir=str(base / name),
                               resolution=(64, 32), per_source=per_source,
                               outputs=("exr", "json"), config=config)
        out[name] = run_simulation(opts)
    return out


def test_groups_follow_the_emitted_photons(matrix_scene):
    """The group of a sample point is the part its photon is emitted from: every origin
    lies on its group's die (the dies sit side by side in x)."""
    mix = EmitterMix.from_scene(matrix_scene)
    groups = EmitterGroups.of(matrix_scene, mix)
    assert len(groups) == 16 and sorted(groups.names) == [f"led_{k:02d}" for k in range(16)]
    u = halton_points(np.arange(20_000, dtype=np.int64), digit_permutations(3, 0, None))
    origin, _ = mix.sample(u)
    g = groups.of_points(u)
    parts = {p.name: p for p in matrix_scene.emitters}
    for k, name in enumerate(groups.names):
        tri = parts[name].triangles.reshape(-1, 3)
        x = origin[g == k, 0]
        assert len(x) > 0
        assert x.min() >= tri[:, 0].min() - 1e-12 and x.max() <= tri[:, 0].max() + 1e-12


def test_empty_and_edge_points(matrix_scene):
    groups = EmitterGroups.of(matrix_scene, EmitterMix.from_scene(matrix_scene))
    assert groups.of_points(np.zeros((0, 5))).shape == (0,)
    u = np.zeros((2, 5))
    u[1, 2] = np.nextafter(1.0, 0.0)
    g = groups.of_points(u)
    assert g[0] != g[1] and 0 <= g.min() and g.max() < 16


def test_superposition_is_bit_for_bit(runs):
    """The all-on channel is the sum of the group channels as written, bit for bit."""
    out = runs["per_source"].out_dir
    ch, meta = read_exr(out / "per_source.exr")
    names = meta["groups"]
    total = np.zeros_like(ch[ALL_ON])
    for n in names:  # a reader's own float32 sum, in group order
        total += ch[n]
    assert np.array_equal(total, ch[ALL_ON])
    maps = read_per_source(out)
    assert np.array_equal(maps.all_on(), ch[ALL_ON])
    assert np.array_equal(compose(maps.lux, np.ones(len(names))), ch[ALL_ON])


def test_all_on_equals_a_plain_binned_run_bit_for_bit(runs):
    """The same photons counted per pixel by the plain binning estimator: its map, bit for
    bit, is the all-on channel and the float32 sum of the group channels as read back."""
    ch, meta = read_exr(runs["per_source"].out_dir / "per_source.exr")
    binned, _ = read_exr(runs["binned"].out_dir / "wall_lux.exr")
    y = binned["Y"]
    assert y.max() > 10 and runs["binned"].summary["frames"] > 1
    assert runs["per_source"].summary["photons"] == runs["binned"].summary["photons"]
    assert np.array_equal(ch[ALL_ON], y)
    for order in (meta["groups"], meta["groups"][::-1]):  # any order adds up exactly
        total = np.zeros_like(y)
        for n in order:
            total += ch[n]
        assert np.array_equal(total, y)


def test_split_exactly_in_blocks_of_rows(monkeypatch):
    """Split a block of rows at a time: the same shares as in one block."""
    rng = np.random.default_rng(5)
    parts = rng.uniform(0, 1, (16, 12, 9)) ** 3 * 50.0
    total = parts.sum(axis=0).astype(np.float32)
    whole = split_exactly(parts, total)
    monkeypatch.setattr(persource, "SPLIT_CELLS", 100)  # a row per block
    assert np.array_equal(split_exactly(parts, total), whole)


def test_split_exactly_edges():
    """Shares add up to the total in float32 whatever the order: zero totals, a zero part,
    parts that miss the total by rounding, tiny and huge scales, no part at a lit pixel."""
    rng = np.random.default_rng(3)
    for scale in (1e-30, 1e-3, 1.0, 97.0, 1e30):
        parts = rng.uniform(0, 1, (16, 8, 9)) ** 4 * scale
        parts[3] = 0.0
        parts[:, 0, 0] = 0.0
        total = parts.sum(axis=0).astype(np.float32)
        total[1, 1] = np.nextafter(total[1, 1], np.float32(np.inf))  # one ulp above
        total[0, 1] = np.float32(scale)  # lit, with no part at all
        parts[:, 0, 1] = 0.0
        shares = split_exactly(parts, total)
        assert shares.dtype == np.float32 and np.all(shares >= 0)
        for order in (range(16), range(15, -1, -1), rng.permutation(16)):
            acc = np.zeros_like(total)
            for g in order:
                acc += shares[g]
            assert np.array_equal(acc, total)
        lit = total > 0
        err = np.abs(shares.astype(np.float64) - parts)[:, lit] / total[lit].astype(np.float64)
        assert err[:, 2:].max() < 1e-6
    assert split_exactly(np.zeros((0, 2, 2)), np.zeros((2, 2), np.float32)).shape == (0, 2, 2)


def test_segments_light_their_stripes_left_to_right(runs):
    maps = read_per_source(runs["per_source"].out_dir)
    centroid = []
    for k in range(16):
        m = maps.lux[maps.index(f"led_{k:02d}")].astype(np.float64)
        centroid.append((m.sum(axis=0) * np.arange(m.shape[1])).sum() / m.sum())
    assert np.all(np.diff(centroid) > 0)


def test_summary_records_each_groups_error(runs):
    ps = runs["per_source"].summary["per_source"]
    assert ps["file"] == "per_source.exr" and len(ps["groups"]) == 16
    for g in ps["groups"]:
        assert 0 < g["rel_error"] < 1 and g["max_lx"] > 0 and g["flux_on_wall_lm"] > 0
    maps = read_per_source(runs["per_source"].out_dir)
    assert np.all(maps.variance >= 0) and maps.photons == runs["per_source"].summary["photons"]


def test_plain_run_writes_no_per_source_maps(runs):
    out = runs["binned"].out_dir
    assert not (out / "per_source.exr").exists()
    assert "per_source" not in runs["binned"].summary
    with pytest.raises(InputError, match="no per-source maps"):
        read_per_source(out)


def test_memory_grows_with_groups_times_pixels(matrix_scene):
    groups = EmitterGroups.of(matrix_scene, EmitterMix.from_scene(matrix_scene))
    sums = PerSourceSums(groups, matrix_scene.wall)
    W, H = matrix_scene.wall.resolution
    before = sums.nbytes
    rng = np.random.default_rng(1)
    n = 50_000
    sums.add(rng.integers(0, 16, n), rng.uniform(-5, 5, n), rng.uniform(-2, 2, n),
             np.full(n, 1e-3))
    assert sums.nbytes == before == 16 * W * H * 16  # ΣΦ and ΣΦ², float64
    assert sums.power.sum() == pytest.approx(1e-3 * n, rel=1e-9)


def test_resumed_run_has_the_same_per_source_maps(tmp_path):
    """A run stopped after two frames and resumed from its checkpoint replays its photons:
    the per-source maps equal an uninterrupted run's, bit for bit."""
    def opts(out: Path) -> SimulateOptions:
        return SimulateOptions(scene_path=str(MATRIX), photons=100_000, out_dir=str(out),
                               resolution=(48, 24), per_source=True, outputs=("exr", "json"),
                               config={"frame_photons": 20_000})

    whole = run_simulation(opts(tmp_path / "whole"))
    polls = {"n": 0}

    def stop() -> bool:
        polls["n"] += 1
        return polls["n"] >= 2

    cut = run_simulation(opts(tmp_path / "cut"), should_stop=stop)
    assert cut.interrupted and (tmp_path / "cut" / "checkpoint.json").exists()
    resumed_opts, resume = read_checkpoint(tmp_path / "cut")
    resumed = run_simulation(resumed_opts, resume=resume)
    assert resumed.summary["photons"] == whole.summary["photons"]
    a, _ = read_exr(tmp_path / "cut" / "per_source.exr")
    b, _ = read_exr(tmp_path / "whole" / "per_source.exr")
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
