"""validation/snapshot.compare: bit-identical maps, summaries without their timings."""

from __future__ import annotations

import json
import shutil

import numpy as np

from lightsim.io.exr import write_exr
from lightsim.validation.snapshot import compare


def _run_folder(path, lux, seconds, ies=b"IESNA:LM-63-2002\n"):
    path.mkdir(parents=True)
    write_exr(path / "wall_lux.exr", {"Y": lux.astype(np.float32)})
    np.savez(path / "probes.npz", values_lux=lux[2:5].astype(np.float64))
    (path / "summary.json").write_text(json.dumps({
        "seconds": seconds, "machine": {"cpus": 2}, "photons": 1000,
        "error_vs_time": [{"photons": 1000, "seconds": seconds}],
        "farfield": {"files": [str(path / "a.ies")]}}))
    (path / "a.ies").write_bytes(ies)


def test_identical_runs_differ_only_in_timings(tmp_path):
    lux = np.random.default_rng(1).random((8, 16))
    _run_folder(tmp_path / "a", lux, 1.5)
    _run_folder(tmp_path / "b", lux, 2.5)
    assert compare(tmp_path / "a", tmp_path / "b") == []


def test_one_changed_pixel_or_figure_is_reported(tmp_path):
    lux = np.random.default_rng(1).random((8, 16))
    _run_folder(tmp_path / "a", lux, 1.0)
    other = lux.copy()
    other[3, 4] = np.nextafter(np.float32(other[3, 4]), np.float32(2))
    _run_folder(tmp_path / "b", other, 1.0, ies=b"IESNA:LM-63-2002 \n")
    diffs = compare(tmp_path / "a", tmp_path / "b")
    assert "wall_lux.exr:Y: pixels differ" in diffs
    assert any(d.startswith("probes.npz:values_lux") for d in diffs)
    assert "a.ies: bytes differ" in diffs
    shutil.rmtree(tmp_path / "b")
    _run_folder(tmp_path / "b", lux, 1.0)
    doc = json.loads((tmp_path / "b" / "summary.json").read_text())
    doc["photons"] = 1001
    (tmp_path / "b" / "summary.json").write_text(json.dumps(doc))
    assert compare(tmp_path / "a", tmp_path / "b") == [
        "summary.json/photons: 1000 before, 1001 after"]
