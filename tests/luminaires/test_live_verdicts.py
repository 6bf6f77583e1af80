"""``lightsim view``'s regulation table: verdicts decided on the ``--until decided``
schedule while the photons come in, each row marked decided or open."""

from __future__ import annotations

import numpy as np
import pytest

from lightsim.engine.config import RunConfig
from lightsim.engine.server import Session
from lightsim.luminaires.live import regulation_hook
from lightsim.luminaires.regulations.check import aperture_config
from lightsim.scene import SceneSettings, load_scene

from support import write_point_lamp

RULES = "r112-b-passing"
FRAME = 100_000


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    scene = load_scene(str(write_point_lamp(tmp_path_factory.mktemp("l") / "lamp.glb")),
                       SceneSettings(resolution=(80, 32)))
    cfg = aperture_config(RunConfig(seed=3, estimator="bin", frame_photons=FRAME),
                          RULES, "right", scene.wall, 1.5)
    s = Session(scene, cfg)
    yield s
    s.close()


def test_table_fills_in_as_verdicts_decide(session):
    """Looks at 1, 2, 4, 8, 16 frames: the count of decided rows never falls, a decided
    row keeps its verdict, a call between looks shows the last look's table, and the
    isotropic source's 79.6 cd lies in the running intervals at the nominal rate."""
    hook = regulation_hook(RULES, "right", cap_photons=64 * FRAME)
    truth = 1000.0 / (4 * np.pi)
    kept: dict[str, str] = {}
    counts, titles = [], []
    for frame in range(1, 17):
        session.shoot()
        table = hook(session)
        assert all(isinstance(r["decided"], bool) for r in table.rows)
        if frame in (1, 2, 4, 8, 16):
            assert f"at {frame * FRAME:,} photons" in table.title
            counts.append(sum(r["decided"] for r in table.rows))
        else:
            assert table is hook(session)  # between looks: the last look's table
        titles.append(table.title)
        for r in table.rows:
            if r["decided"]:
                assert r["verdict"] in ("pass", "fail")
                assert kept.setdefault(r["name"], r["verdict"]) == r["verdict"], r
            else:
                assert r["verdict"] not in ("pass", "fail"), r
    assert counts == sorted(counts) and counts[-1] > counts[0]
    assert "look 5 of" in titles[-1]
    # each running interval misses the truth with probability ≤ 5 %: of 17 points, more
    # than 4 missing would happen less than once in 100 runs
    misses = [r["name"] for r in hook(session).rows if r["kind"] == "point"
              and not r["interval"][0] <= truth <= r["interval"][1]]
    assert len(misses) <= 4, misses
