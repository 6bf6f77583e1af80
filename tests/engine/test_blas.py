"""The command's BLAS policy: one thread, the user's setting respected."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

import lightsim  # noqa: F401

_CHILD = """
import json, sys
import numpy as np
from threadpoolctl import threadpool_info
from lightsim.engine.blas import single_blas_thread
before = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
from lightsim.render.ici import halves, held_out_blur
rng = np.random.default_rng(3)
rungs = {s: rng.random((4, 20011, 1)).astype(np.float32) for s in range(16)}
emitted = {s: 1000 + s for s in range(16)}
areas = np.array([1.0, 4.0, 9.0, 16.0]) * 1e-6
ref = held_out_blur(rungs, emitted, 0.3, areas, 2.0, halves(16))
on = single_blas_thread()
after = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
same = bool(np.array_equal(held_out_blur(rungs, emitted, 0.3, areas, 2.0, halves(16)), ref))
print(json.dumps({"on": on, "before": before, "after": after, "same": same}))
"""


def _child(env_extra: dict[str, str]) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True,
                         env=env, timeout=120, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_one_blas_thread_and_the_same_held_out_blur():
    got = _child({})
    assert got["on"] is True
    assert got["after"] and all(n == 1 for n in got["after"])
    assert got["same"]  # the written map's figure does not depend on BLAS's threads


def test_a_thread_count_the_user_set_is_left_alone():
    got = _child({"OPENBLAS_NUM_THREADS": "2"})
    assert got["on"] is False
    assert got["after"] and all(n == 2 for n in got["after"])


def test_library_import_keeps_blas_threads():
    # importing lightsim sets no policy: only the command and the Ray clients do
    assert os.environ.get("OPENBLAS_NUM_THREADS") in (None, os.environ.get(
        "OPENBLAS_NUM_THREADS"))
    assert np.tensordot(np.ones(3), np.ones((3, 2)), 1).tolist() == [3.0, 3.0]
