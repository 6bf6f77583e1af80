"""A TM-25 header whose counts the file cannot hold (extra columns, spectral tables, text)
is refused in one line before any loop runs over them: found by ``lightsim fuzz`` (seed 2,
kind tm25, ``extra items = 2147483647``), which ran out of its time limit reading 2³¹
column names."""

from __future__ import annotations

import struct

import pytest

from lightsim.errors import InputError
from lightsim.io.rayfile import read_tm25, write_tm25
from lightsim.luminaires.rayfiles import lambertian_square

from support import run_cli


@pytest.fixture
def tm25(tmp_path):
    pos, dirs, flux = lambertian_square(1e-3, 50, 1000.0)
    return write_tm25(tmp_path / "ok.tm25ray", pos, dirs, flux)


@pytest.mark.parametrize(("offset", "value", "what"), [
    (80, 2**31 - 1, "extra items 2147483647"),
    (76, 2**31 - 1, "tables 2147483647"),
    (84, 2**31 - 32, "text 2147483616 bytes"),
])
def test_counts_beyond_the_file_are_one_line(tm25, tmp_path, capsys, offset, value, what):
    raw = bytearray(tm25.read_bytes())
    struct.pack_into("<i", raw, offset, value)
    bad = tmp_path / "bad.tm25ray"
    bad.write_bytes(bytes(raw))
    with pytest.raises(InputError, match=what):
        read_tm25(bad)
    out = tmp_path / "out"
    code, _, err = run_cli(["simulate", str(bad), "--photons", "1000", "--resolution", "16x8",
                            "-q", "--out", str(out)], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_a_file_ending_in_its_spectral_tables_is_one_line(tm25, tmp_path):
    raw = bytearray(tm25.read_bytes())
    struct.pack_into("<i", raw, 76, 3)  # three tables, none in the file
    bad = tmp_path / "short.tm25ray"
    bad.write_bytes(bytes(raw[:1500]))
    with pytest.raises(InputError):
        read_tm25(bad)


def test_the_unmutated_file_still_reads(tm25):
    rf = read_tm25(tm25)
    assert rf.n_rays > 0 and rf.items[:3] == ["x", "y", "z"]
