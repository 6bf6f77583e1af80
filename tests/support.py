"""Shared by the command-line tests (imported as ``from support import ...``)."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from contextlib import contextmanager
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


#: Debian's Chromium, which the browser tests drive (Playwright's own download is not
#: reachable)
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


@contextmanager
def browser_page(url: str, viewport: tuple[int, int] = (1300, 800)) -> Iterator[tuple]:
    """A Chromium page (Playwright) opened at ``url``: yields (page, errors), ``errors``
    collecting the page's script errors; the browser is closed afterwards. Skips with
    the reason where Playwright or Chromium is missing."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright (Python) is not installed")
    if not Path(CHROMIUM).exists():
        pytest.skip("Debian's chromium is not installed")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(url)
            yield page, errors
        finally:
            browser.close()
