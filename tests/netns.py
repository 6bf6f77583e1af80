"""Run a command in a private network namespace that has only loopback.

Ray here would otherwise bind to the machine's other address even when told to use
127.0.0.1; inside the namespace only ``lo`` exists, so every test talks over loopback.
Root uses ``unshare --net`` (with a private PID namespace where allowed, so that
``ray stop`` in a test cannot touch other Ray processes); other users try an
unprivileged user namespace (``unshare -rn``). Without either, the Ray tests are skipped
with the reason.
"""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest

RAY_ENV = {"RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0",
           "PYTHONUNBUFFERED": "1"}

#: the start of a Ray test's script: ``scene()``, a point source at a paraboloid's focus
#: lighting a 64 × 64 wall 2 m away
SCENE_SCRIPT = """
import numpy as np
from lightsim.scene import Scene, make_wall
from lightsim.validation.scenes import primitives as prim

def scene():
    wall, frame = make_wall(2.0, (4.0, 4.0), resolution=(64, 64))
    mirror = prim.paraboloid(0.5, 0.6, 0.9, radial=24, azimuthal=96)
    src = prim.point_source(1000.0, radius=1e-3, centre=(0, 0, 0.5))
    return Scene([src, mirror, wall], frame)
"""


def _unshare_prefix() -> list[str]:
    if shutil.which("unshare") is None:
        pytest.skip("unshare(1) not available: cannot isolate Ray on loopback")
    # A PID namespace too (when allowed): `ray stop` inside then sees only this test's
    # processes, never another Ray session running on the same machine.
    pid = ["--pid", "--fork", "--mount-proc"]
    for prefix in (["unshare", "--net", *pid], ["unshare", "-rn", *pid],
                   ["unshare", "--net"], ["unshare", "-rn"]):
        probe = subprocess.run([*prefix, "true"], capture_output=True, timeout=20)
        if probe.returncode == 0:
            return prefix
    pytest.skip("no permission for a network namespace (unshare --net / -rn)")
    raise AssertionError  # unreachable


def run_in_netns(script: str, timeout: float = 300, env: dict[str, str | None] | None = None
                 ) -> subprocess.CompletedProcess:
    """Run a bash ``script`` inside a loopback-only network namespace.

    ``env`` adds variables to :data:`RAY_ENV` (Ray's token authentication off); a value of
    None removes one (``{"RAY_AUTH_MODE": None}``: Ray's own default, token authentication
    where a token exists)."""
    full_env = {**os.environ, **RAY_ENV}
    for k, v in (env or {}).items():
        if v is None:
            full_env.pop(k, None)
        else:
            full_env[k] = v
    for k in ("RAY_ADDRESS", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH"):
        if k not in (env or {}):
            full_env.pop(k, None)
    cmd = [*_unshare_prefix(), "bash", "-c", "ip link set lo up && " + script]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=full_env)
