"""The material map's key table: one declaration for the reader, the refusal of keys that
do not apply to a rule's kind, and the manual's reference table."""

from __future__ import annotations

from pathlib import Path

import pytest

from lightsim import materialmap
from lightsim.errors import InputError
from lightsim.materialmap import RULE_KEYS, key_table_markdown, read_material_map

from support import run_cli

DOC = Path(__file__).resolve().parents[2] / "docs" / "reference" / "material-maps.md"


def _write(tmp_path, body: str) -> Path:
    m = tmp_path / "map.toml"
    m.write_text('schema = "lightsim-materials-1"\n[[rule]]\nmatch = "x"\n' + body)
    return m


def test_manual_table_is_the_code_table():
    assert key_table_markdown() in DOC.read_text(encoding="utf-8")


def test_module_table_names_every_key_and_its_kinds():
    doc = materialmap.__doc__
    for k in RULE_KEYS:
        row = next(line for line in doc.splitlines() if line.startswith(f"``{k.key}``"))
        assert all(kind in row for kind in k.kinds), row


@pytest.mark.parametrize("kind, key, value", [
    ("diffuse", "reflectance", "0.9"), ("mirror", "ior", "1.5"), ("mirror", "albedo", "0.2"),
    ("glass", "flux_lm", "10"), ("ignore", "albedo", "0.5"), ("emitter", "attenuation", "1"),
    ("wall", "emission", '"lambertian"')])
def test_a_key_of_another_kind_is_refused(tmp_path, kind, key, value):
    m = _write(tmp_path, f'kind = "{kind}"\n{key} = {value}\n')
    with pytest.raises(InputError) as exc:
        read_material_map(m)
    msg = str(exc.value)
    assert "\n" not in msg and "rule 1" in msg and f"'{key}'" in msg and kind in msg


@pytest.mark.parametrize("kind, key, value", [
    ("mirror", "reflectance", "0.9"), ("glass", "ior", "1.59"), ("glass", "attenuation", "2"),
    ("diffuse", "albedo", "0.3"), ("wall", "albedo", "0.8"), ("emitter", "flux_lm", "5"),
    ("emitter", "emission", '"lambertian"')])
def test_a_key_of_its_own_kind_is_read(tmp_path, kind, key, value):
    rule = read_material_map(_write(tmp_path, f'kind = "{kind}"\n{key} = {value}\n')).rules[0]
    expected = value.strip('"') if value.startswith('"') else float(value)
    assert rule.kind == kind and getattr(rule, key) == expected


def test_cli_refuses_a_misplaced_key_in_one_line(tmp_path, capsys):
    m = _write(tmp_path, 'kind = "diffuse"\nreflectance = 0.9\n')
    lamp = tmp_path / "lamp.obj"
    lamp.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    code, _, err = run_cli(["simulate", str(lamp), "--materials", str(m), "--photons", "10",
                            "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "Traceback" not in err
    assert "'reflectance' does not apply to kind 'diffuse'" in err
    assert not (tmp_path / "o").exists()
