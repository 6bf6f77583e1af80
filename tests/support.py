"""Shared by the command-line tests (imported as ``from support import ...``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from lightsim.cli.main import main
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """Run ``lightsim argv``; return (exit code, stdout, stderr)."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def write_point_lamp(path: Path, *extra: GltfPart) -> Path:
    """A GLB with an isotropic 1000 lm point-like source (0.1 mm icosphere) at the origin,
    plus ``extra`` parts; the loader adds the wall."""
    ico = trimesh.creation.icosphere(1, radius=1e-4)
    write_glb(path, [GltfPart("filament", np.asarray(ico.vertices), np.asarray(ico.faces),
                              None, GltfMaterial("f", emissive=(1, 1, 1)),
                              extras={"lightsim": {"flux_lm": 1000.0}}), *extra])
    return path
