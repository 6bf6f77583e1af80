"""JSON summaries: numpy conversion, NaN/inf → null, strict JSON, errors, atomicity."""

from __future__ import annotations

import dataclasses
import enum
import json
from pathlib import Path

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.io.summary import read_json, to_jsonable, write_json


def _strict_load(text: str):
    def reject(token):
        raise ValueError(f"non-standard JSON token {token}")
    return json.loads(text, parse_constant=reject)


class Mode(enum.Enum):
    FAST = "fast"


@dataclasses.dataclass
class Point:
    name: str
    h_deg: float


def test_conversion_rules(tmp_path):
    obj = {
        "f32": np.float32(0.5), "f64": np.float64(1e-300), "i": np.int64(7),
        "b": np.bool_(True), "nan": float("nan"), "inf": np.inf, "ninf": -np.inf,
        "arr": np.array([[1.0, np.nan], [np.inf, 2.0]]), "iarr": np.arange(3, dtype=np.int16),
        "tuple": (1, 2), "set": {3, 1, 2}, "path": Path("/tmp/x.exr"), "mode": Mode.FAST,
        "point": Point("50R", 1.72), 5: "int key", "nested": {"deep": [np.float32(np.nan)]},
        "unicode": "1° Günther",
    }
    write_json(tmp_path / "s.json", obj)
    text = (tmp_path / "s.json").read_text(encoding="utf-8")
    got = _strict_load(text)                     # valid JSON: no NaN/Infinity tokens
    assert got["f32"] == 0.5 and got["f64"] == 1e-300 and got["i"] == 7 and got["b"] is True
    assert got["nan"] is None and got["inf"] is None and got["ninf"] is None
    assert got["arr"] == [[1.0, None], [None, 2.0]] and got["iarr"] == [0, 1, 2]
    assert got["tuple"] == [1, 2] and got["set"] == [1, 2, 3]
    assert got["path"] == "/tmp/x.exr" and got["mode"] == "fast"
    assert got["point"] == {"name": "50R", "h_deg": 1.72}
    assert got["5"] == "int key" and got["nested"] == {"deep": [None]}
    assert got["unicode"] == "1° Günther"
    assert read_json(tmp_path / "s.json") == got


def test_unserialisable_raises_and_keeps_old_file(tmp_path):
    path = tmp_path / "s.json"
    write_json(path, {"ok": 1})
    with pytest.raises(TypeError):
        write_json(path, {"bad": object()})
    with pytest.raises(TypeError):
        to_jsonable(np.array([1 + 2j]))
    assert read_json(path) == {"ok": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["s.json"]


def test_read_errors(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_json(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text('{"a": 1,,}')
    with pytest.raises(InputError, match="line 1") as info:
        read_json(tmp_path / "bad.json")
    assert "\n" not in str(info.value)
    (tmp_path / "trunc.json").write_text('{"a": [1, 2')
    with pytest.raises(InputError):
        read_json(tmp_path / "trunc.json")
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(InputError):
        read_json(tmp_path / "bin.json")
    with pytest.raises(InputError):
        read_json(tmp_path)


def test_one_line_option(tmp_path):
    write_json(tmp_path / "c.json", {"a": [1, 2]}, indent=None)
    assert (tmp_path / "c.json").read_text() == '{"a": [1, 2]}\n'
