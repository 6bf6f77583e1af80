"""OpenEXR lux maps: exact round trip, metadata, foreign files, errors, atomic writes."""

from __future__ import annotations

import math

import numpy as np
import OpenEXR
import pytest

import lightsim.io.exr as exr
from lightsim.errors import InputError, LightsimError
from lightsim.io.exr import read_exr, set_exr_threads, wall_metadata, write_exr

WALL = {"centre": [0.0, 0.0, 25.0], "h_axis": [-1.0, 0.0, 0.0], "v_axis": [0.0, 1.0, 0.0],
        "normal": [0.0, 0.0, -1.0], "h_range_m": [-12.5, 12.5], "v_range_m": [-5.0, 5.0],
        "distance_m": 25.0, "resolution": [16, 9]}


def _lux(seed=0, shape=(9, 16)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    E = (rng.random(shape) * 1e3).astype(np.float32)
    E.flat[:8] = [0.0, 1e-30, 1e9, 3.4e38, 1e-45, -0.0, 1.0, 65504.0]
    return E


def test_pixels_round_trip_exactly(tmp_path):
    E = _lux()
    sigma = np.sqrt(np.abs(E[::-1].astype(np.float64)))  # float64 → stored as float32
    channels = {"E": E, "sigma": sigma}
    write_exr(tmp_path / "a.exr", channels)
    assert channels["E"] is E and channels["sigma"] is sigma  # caller's dict untouched
    chans, _ = read_exr(tmp_path / "a.exr")
    assert set(chans) == {"E", "sigma"}
    assert chans["E"].dtype == np.float32 and chans["E"].shape == E.shape
    np.testing.assert_array_equal(chans["E"], E)            # exact float32 equality
    assert chans["E"].view(np.uint32)[0, 5] == np.float32(-0.0).view(np.uint32)
    np.testing.assert_array_equal(chans["sigma"], sigma.astype(np.float32))
    assert chans["E"].flat[1] == np.float32(1e-30) and chans["E"].flat[2] == np.float32(1e9)


def test_metadata_round_trip(tmp_path):
    meta = {
        "units": "lx", "scene": "Günther ring 1°", "frame": 12, "negative": -3,
        "big_int": 2**40, "distance_m": 25.0, "pi": math.pi, "tiny": 1e-300,
        "h_range_m": [-12.5, 12.5], "exact_pair": [0.1, 0.2], "triple": [0.1, 0.2, 0.3],
        "many_floats": [0.1, 0.2, 0.3, 0.4], "f32_floats": [1.5, 2.5, -3.0, 4.0, 2.0**-100],
        "resolution": [640, 480], "ints": [1, 2, 3, 4], "flag": True, "nothing": None,
        "empty": [], "names": ["50R", "B50L"], "wall": WALL,
        "nested": {"a": {"b": [1, 2.5, "x"]}, "c": None},
        "np_float": np.float64(0.125), "np_int": np.int64(7), "tuple": (1.0, 2.0),
    }
    write_exr(tmp_path / "m.exr", {"E": _lux()}, meta)
    _, got = read_exr(tmp_path / "m.exr")
    expect = dict(meta, np_float=0.125, np_int=7, tuple=[1.0, 2.0])
    assert got == expect
    for key in ("frame", "distance_m", "pi", "h_range_m", "resolution"):
        assert type(got[key]) is type(expect[key])
    # native attributes where OpenEXR has a matching type; JSON text otherwise
    header = OpenEXR.File(str(tmp_path / "m.exr"), header_only=True).header()
    assert header["units"] == "lx" and header["frame"] == 12
    assert isinstance(header["json:wall"], str) and "json:flag" in header
    assert header["f32_floats"] == [1.5, 2.5, -3.0, 4.0, 2.0**-100]


def test_special_float_metadata(tmp_path):
    meta = {"nan": float("nan"), "inf": float("inf"), "in_json": {"x": float("nan")}}
    write_exr(tmp_path / "n.exr", {"Y": np.zeros((2, 2), np.float32)}, meta)
    _, got = read_exr(tmp_path / "n.exr")
    assert math.isnan(got["nan"]) and got["inf"] == math.inf
    assert got["in_json"] == {"x": None}        # JSON has no NaN: documented → null


def test_wall_metadata_helper(tmp_path):
    meta = wall_metadata(WALL, units="lx")
    write_exr(tmp_path / "w.exr", {"E": _lux()}, meta)
    _, got = read_exr(tmp_path / "w.exr")
    assert got["wall"] == WALL and got["units"] == "lx"
    assert got["wall_distance_m"] == 25.0 and got["wall_resolution"] == [16, 9]


@pytest.mark.parametrize("dtype", [np.float16, np.float32])
@pytest.mark.parametrize("names", ["RGB", "RGBA", "Y"])
def test_reads_foreign_exr(tmp_path, dtype, names):
    rng = np.random.default_rng(1)
    chans = {c: rng.random((5, 7)).astype(dtype) for c in names}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "owner": "someone", "exposure": 1.5}  # a 32-bit float attribute
    OpenEXR.File(header, dict(chans)).write(str(tmp_path / "f.exr"))  # (it mutates the dict)
    got, meta = read_exr(tmp_path / "f.exr")
    assert set(got) == set(names)
    for c in names:
        assert got[c].dtype == np.float32
        np.testing.assert_array_equal(got[c], chans[c].astype(np.float32))
    assert meta["owner"] == "someone" and meta["exposure"] == 1.5
    assert "compression" not in meta and "channels" not in meta


def _one_line_input_error(path) -> str:
    with pytest.raises(InputError) as info:
        read_exr(path)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_read_errors_are_one_line_input_errors(tmp_path):
    assert "not found" in _one_line_input_error(tmp_path / "missing.exr")
    (tmp_path / "text.exr").write_text("hello, not an image")
    assert "not an OpenEXR" in _one_line_input_error(tmp_path / "text.exr")
    (tmp_path / "empty.exr").write_bytes(b"")
    _one_line_input_error(tmp_path / "empty.exr")
    (tmp_path / "dir.exr").mkdir()
    _one_line_input_error(tmp_path / "dir.exr")


@pytest.mark.parametrize("keep", [0.999, 0.6, 0.1, 0.01])
def test_truncated_file_is_an_input_error(tmp_path, keep):
    rng = np.random.default_rng(2)
    write_exr(tmp_path / "full.exr", {"E": rng.random((96, 128)).astype(np.float32)},
              {"wall": WALL})
    data = (tmp_path / "full.exr").read_bytes()
    (tmp_path / "cut.exr").write_bytes(data[:int(len(data) * keep)])
    _one_line_input_error(tmp_path / "cut.exr")


class SimulatedCrash(Exception):
    pass


def test_failed_write_keeps_old_file_and_leaves_no_temp(tmp_path, monkeypatch):
    target = tmp_path / "lux.exr"
    old = _lux(1)
    write_exr(target, {"E": old}, {"run": "old"})
    assert [p.name for p in tmp_path.iterdir()] == ["lux.exr"]

    def crash_midway(exr_file, tmp):
        exr_file.write(str(tmp))                      # a complete file under the temp name…
        with open(tmp, "r+b") as fh:                  # …cut short, then the writer dies
            fh.truncate(100)
        raise SimulatedCrash("disk unplugged")

    monkeypatch.setattr(exr, "_encode", crash_midway)
    with pytest.raises(SimulatedCrash):
        write_exr(target, {"E": _lux(2)}, {"run": "new"})
    assert [p.name for p in tmp_path.iterdir()] == ["lux.exr"]
    chans, meta = read_exr(target)
    np.testing.assert_array_equal(chans["E"], old)
    assert meta == {"run": "old"}


def test_write_over_existing_file(tmp_path):
    target = tmp_path / "lux.exr"
    write_exr(target, {"E": _lux(1)}, {"run": "old"})
    write_exr(target, {"E": _lux(2)}, {"run": "new"})
    chans, meta = read_exr(target)
    np.testing.assert_array_equal(chans["E"], _lux(2))
    assert meta == {"run": "new"}
    assert [p.name for p in tmp_path.iterdir()] == ["lux.exr"]


def test_write_argument_errors(tmp_path):
    E = _lux()
    with pytest.raises(ValueError):
        write_exr(tmp_path / "x.exr", {})
    with pytest.raises(ValueError):
        write_exr(tmp_path / "x.exr", {"E": E, "F": E[:, :3]})
    with pytest.raises(ValueError):
        write_exr(tmp_path / "x.exr", {"E": E[0]})
    with pytest.raises(ValueError, match="float32 range"):
        write_exr(tmp_path / "x.exr", {"E": np.full((2, 2), 1e300)})
    for key in ("compression", "json:x", ""):
        with pytest.raises(ValueError):
            write_exr(tmp_path / "x.exr", {"E": E}, {key: 1})
    with pytest.raises(TypeError):
        write_exr(tmp_path / "x.exr", {"E": E}, {"obj": object()})
    with pytest.raises(LightsimError):
        write_exr(tmp_path / "no" / "such" / "dir.exr", {"E": E})
    assert not list(tmp_path.iterdir())


def test_thread_count():
    assert set_exr_threads(2) == 2
    assert OpenEXR.global_thread_count() == 2
    assert set_exr_threads(0) == 0
    assert set_exr_threads() >= 1
