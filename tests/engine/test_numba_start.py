"""numba's cached kernels loaded without its whole CPU target set-up
(lightsim.engine.numba_start)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest


def _run(code: str, cwd=None) -> str:
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=300, check=False, cwd=cwd)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


KERNELS = '''
import numpy as np
from numba import njit, prange


@njit(cache=True)
def scaled(a, s):
    out = np.empty_like(a)  # an NRT allocation: the runtime must be up
    for i in range(a.shape[0]):
        out[i] = a[i] * s
    return out


@njit(cache=True, parallel=True)
def total(a):
    s = 0.0
    for i in prange(a.shape[0]):
        s += a[i]
    return s
'''


def test_cached_kernels_load_without_the_compiler_set_up_and_compiling_still_works(tmp_path):
    """A kernel loaded from numba's cache runs (NRT allocation, a parallel loop) without
    the lowering modules imported; a kernel compiled afterwards (BLAS) still compiles
    with the full target."""
    (tmp_path / "nbkernels.py").write_text(KERNELS)
    use = """
        import sys
        import numpy as np
        from lightsim.engine.numba_start import lazy_target_setup
        print(lazy_target_setup(), lazy_target_setup())  # acts once
        import nbkernels
        a = np.arange(10.0)
        assert np.array_equal(nbkernels.scaled(a, 2.0), 2 * a)
        assert nbkernels.total(a) == 45.0
        hits = sum(nbkernels.scaled.stats.cache_hits.values())
        print(hits, "numba.np.arraymath" in sys.modules, "scipy.linalg" in sys.modules)
    """
    _run(use, cwd=tmp_path)  # compiles and caches (the compiler sets the target up)
    out = _run(use + """
        from numba import njit

        @njit
        def dot(a, b):
            return np.dot(a, b)

        m = np.arange(12.0).reshape(3, 4)
        assert np.array_equal(dot(m, m.T), m @ m.T)  # compiled: the full target
        print("numba.np.arraymath" in sys.modules)
    """, cwd=tmp_path)
    assert out.split() == ["True", "False", "1", "False", "False", "True"]


def test_a_simulate_process_does_not_set_numba_s_compiler_up(tmp_path):
    """A whole run on a glTF scene loads its kernels without numba's lowering modules
    (nor scipy.linalg, which one of them imports); the scene is written by another
    process: the analytic builders import trimesh, hence scipy."""
    pytest.importorskip("scipy")
    glb = tmp_path / "point.glb"
    _run(f"""
        from pathlib import Path
        from lightsim.validation.bench.peer import write_scene_glb
        from lightsim.validation.scenes.analytic import isotropic_case
        write_scene_glb(isotropic_case(resolution=(8, 8)), Path({str(glb)!r}))
    """)
    code = f"""
        import sys
        from lightsim.engine.config import RunConfig
        from lightsim.engine.server import Session
        from lightsim.scene import SceneSettings, load_scene

        scene = load_scene({str(glb)!r}, SceneSettings(resolution=(8, 8)))
        with Session(scene, RunConfig(frame_photons=2_000, interleave=2)) as s:
            est = s.run(photons=4_000)
        assert est.photons == 4_000
        print(sum(est.lux.ravel() > 0) > 0, "numba.np.arraymath" in sys.modules,
              "scipy.linalg" in sys.modules)
    """
    _run(code)  # the kernels may compile here (a fresh tree): then the target is set up
    assert _run(code).split() == ["True", "False", "False"]
