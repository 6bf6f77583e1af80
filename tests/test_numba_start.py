"""numba's first kernel load without scipy.linalg (lightsim.engine.numba_start)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest


def _run(code: str) -> str:
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


def test_a_kernel_loads_without_scipy_linalg_and_blas_still_works():
    pytest.importorskip("scipy")
    out = _run("""
        import sys
        import numpy as np
        from numba import njit
        from lightsim.engine.numba_start import defer_blas_probe
        assert defer_blas_probe()
        assert not defer_blas_probe()  # once: arraymath is imported now

        @njit
        def add(a):
            return a + 1.0

        assert add(1.0) == 2.0  # the CPU target is set up: every lowering module loaded
        print("linalg" if "scipy.linalg" in sys.modules else "no-linalg")
        from numba.np import arraymath, linalg
        assert arraymath._HAVE_BLAS and arraymath.ensure_blas is linalg.ensure_blas

        @njit
        def dot(a, b):
            return np.dot(a, b)

        a = np.arange(12.0).reshape(3, 4)
        assert np.array_equal(dot(a, a.T), a @ a.T)  # BLAS: numba imports scipy itself
        print("linalg" if "scipy.linalg" in sys.modules else "no-linalg")
    """)
    assert out.split() == ["no-linalg", "linalg"]


def test_a_simulate_process_does_not_import_scipy_linalg(tmp_path):
    """A whole run on a glTF scene loads its kernels without scipy.linalg (the scene is
    written by another process: the analytic builders import trimesh, hence scipy)."""
    glb = tmp_path / "point.glb"
    _run(f"""
        from pathlib import Path
        from lightsim.validation.bench.peer import write_scene_glb
        from lightsim.validation.scenes.analytic import isotropic_case
        write_scene_glb(isotropic_case(resolution=(8, 8)), Path({str(glb)!r}))
    """)
    out = _run(f"""
        import sys
        from lightsim.engine.config import RunConfig
        from lightsim.engine.server import Session
        from lightsim.scene import load_scene

        scene = load_scene({str(glb)!r}, resolution=(8, 8))
        with Session(scene, RunConfig(frame_photons=2_000, interleave=2)) as s:
            est = s.run(photons=4_000)
        assert est.photons == 4_000 and "numba.np.arraymath" in sys.modules
        print("linalg" if "scipy.linalg" in sys.modules else "no-linalg")
    """)
    assert out.split() == ["no-linalg"]
