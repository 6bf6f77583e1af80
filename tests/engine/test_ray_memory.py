"""A Ray run's memory per node: the actors of the default run (no photon kept) hold
constant memory as frames pass, while the keep-all path grows with every frame (real Ray,
isolated on loopback)."""

from __future__ import annotations

import json
import sys

import pytest

from netns import SCENE_SCRIPT, run_in_netns

pytestmark = [pytest.mark.ray, pytest.mark.slow]  # two Ray runtimes, 14 M photons: ~100 s

SCRIPT = SCENE_SCRIPT + """
import json, os
from lightsim.engine import pointstore
from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session

def rss_mb(pid):
    with open(f"/proc/{pid}/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6

rng = np.random.default_rng(3)
hv = np.column_stack([rng.uniform(-1.5, 1.5, 400), rng.uniform(-1.5, 1.5, 400)])
out = {}
for keep in (False, True):
    cfg = RunConfig(frame_photons=200_000, keep_photons=keep)
    with Session(scene(), cfg, workers=2, extra_probes=hv) as s:
        s.run(photons=1_000_000, probes=False)
        pids = s.backend.pids()
        before = [rss_mb(p) for p in pids] + [rss_mb(os.getpid())]
        s.run(photons=7_000_000, probes=False)
        after = [rss_mb(p) for p in pids] + [rss_mb(os.getpid())]
        kept = s.kept_photons()
        values = s.probe(hv).values
        bound = cfg.n_sets * (pointstore.POOL_MIN + pointstore.POOL_SLACK * cfg.k * len(hv))
    out[str(keep)] = {"before": before, "after": after, "kept": kept, "bound": bound,
                      "lit": float(values.max())}
print("RESULT " + json.dumps(out))
"""


def test_actors_hold_constant_memory_without_kept_photons(tmp_path):
    script = tmp_path / "ray_memory.py"
    script.write_text(SCRIPT)
    res = run_in_netns(f"{sys.executable} {script}", timeout=400)
    assert res.returncode == 0, res.stderr[-3000:]
    line = next(ln for ln in res.stdout.splitlines() if ln.startswith("RESULT "))
    out = json.loads(line[len("RESULT "):])
    drop, keep = out["False"], out["True"]
    assert drop["lit"] > 0 and keep["lit"] > 0
    assert keep["kept"] > 5_000_000 and drop["kept"] <= drop["bound"]  # the pools
    grow_drop = [a - b for a, b in zip(drop["after"], drop["before"], strict=True)]
    grow_keep = [a - b for a, b in zip(keep["after"], keep["before"], strict=True)]
    # 6 M more photons: the keep-all actors grow by their photons (~50 B each), the
    # default run's actors and driver stay within allocator noise
    assert sum(grow_keep[:-1]) > 150, grow_keep
    assert max(grow_drop) < 20, grow_drop
