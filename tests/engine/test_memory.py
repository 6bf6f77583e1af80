"""Memory pre-flight: bytes per stored photon against real trees, and the refusal."""

from __future__ import annotations

import ctypes
import itertools
import json
import mmap
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lightsim.cli.main import main
from lightsim.engine import memory
from lightsim.engine.config import RunConfig
from lightsim.engine.memory import write_pages
from lightsim.engine.server import Session
from lightsim.errors import InputError
from lightsim.photonmap import KdTree
from lightsim.simulate import SimulateOptions, load
from lightsim.validation.bench.peer import CASES, write_scene_glb


def _photons(n: int, seed: int = 3):
    rng = np.random.default_rng(seed)
    pos = rng.normal(size=(n, 3)).astype(np.float32)
    pos[: n // 4] = pos[0]  # a coincident clump: zero-extent leaves
    nrm = np.tile(np.array([0, 0, 1], np.float32), (n, 1))
    return pos, nrm, rng.random((n, 3)).astype(np.float32)


@pytest.mark.parametrize("batches", [1, 20])
def test_model_bounds_the_bytes_real_trees_hold(batches):
    pos, nrm, pw = _photons(60_000)
    tree = KdTree(channels=3)
    for a, b in itertools.pairwise(np.linspace(0, len(pos), batches + 1).astype(int)):
        tree.add(pos[a:b], nrm[a:b], pw[a:b])
    measured = memory.index_bytes(tree) / len(tree)
    model = memory.bytes_per_photon(3)
    assert measured <= model <= 1.6 * measured
    assert memory.bytes_per_photon(3, peak=True) > model


def test_estimate_grows_with_photons_and_pixels_and_bin_stores_no_photons():
    a = memory.estimate_run(1_000_000, (64, 64))
    assert memory.estimate_run(2_000_000, (64, 64)).total > a.total
    assert memory.estimate_run(1_000_000, (640, 256)).total > a.total
    assert memory.estimate_run(1_000_000, (64, 64), photon_map=False).photon_bytes == 0


def test_check_fits_refuses_in_one_line_and_passes_when_there_is_room():
    cfg = RunConfig()
    with pytest.raises(InputError) as exc:
        memory.check_fits(10**9, (640, 256), cfg, 3, available=2 * 10**9)
    msg = str(exc.value)
    assert "\n" not in msg and "would not fit" in msg and "1,000,000,000 photons" in msg
    est = memory.check_fits(10**6, (640, 256), cfg, 3, available=10**12)
    assert est is not None and est.total < 10**12
    # no photon count (a time budget): one frame is checked
    assert memory.check_fits(None, (64, 64), cfg, 1, available=10**12).photons == \
        cfg.frame_photons


def test_memory_limit_env_caps_available(monkeypatch):
    monkeypatch.setenv("LIGHTSIM_MEMORY_LIMIT", "1e8")
    with pytest.raises(InputError, match="would not fit"):
        memory.check_fits(10**6, (64, 64), RunConfig(), 1, available=10**12)
    monkeypatch.setenv("LIGHTSIM_MEMORY_LIMIT", "lots")
    with pytest.raises(InputError, match="LIGHTSIM_MEMORY_LIMIT"):
        memory.check_fits(10, (8, 8), RunConfig(), 1, available=10**12)


def test_available_bytes_reads_meminfo():
    avail = memory.available_bytes()
    assert avail is None or avail > 0


@pytest.mark.parametrize("keeper", [["--keep-photons"], ["--bandwidth", "knn"]])
def test_simulate_refuses_before_it_starts(tmp_path, monkeypatch, capsys, keeper):
    glb = write_scene_glb(CASES["paraboloid"](8), tmp_path / "p.glb")
    out = tmp_path / "out"
    monkeypatch.setenv("LIGHTSIM_MEMORY_LIMIT", str(10**9))
    with pytest.raises(SystemExit) as exc:
        main(["simulate", str(glb), "--photons", "100000000", "--resolution", "8x8",
              *keeper, "--out", str(out), "--quiet"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "would not fit in memory" in err[0]
    assert " ".join(keeper) in err[0] and "keeps every photon" in err[0]
    assert not out.exists()


def test_two_billion_photons_refused_only_where_photons_are_kept(tmp_path, capsys):
    """The keep-all path with 2·10⁹ photons is refused in one line naming its option;
    the default run keeps no photon, so its estimate does not grow with them."""
    cfg = RunConfig(keep_photons=False)
    small = memory.check_fits(4 * 10**6, (320, 128), cfg, 3, available=int(24.6e9),
                              point_bytes=1e8)
    big = memory.check_fits(2 * 10**9, (320, 128), cfg, 3, available=int(24.6e9),
                            point_bytes=1e8)
    assert big.grows == () and big.photon_bytes == small.photon_bytes == 1e8
    assert big.total - small.total < 0.05e9  # one frame's wavefront at most
    assert any("nothing" in line for line in big.explain())
    keep = RunConfig()
    with pytest.raises(InputError) as exc:
        memory.check_fits(2 * 10**9, (320, 128), keep, 3, available=int(24.6e9),
                          keeper="--keep-photons")
    assert "--keep-photons keeps every photon" in str(exc.value)
    assert "\n" not in str(exc.value)
    est = memory.check_fits(10**6, (64, 64), keep, 1, available=10**12)
    assert est.grows == ("photon maps",) and "--keep-photons" in est.explain()[0]
    # the command: one line, exit 2, before any output
    glb = write_scene_glb(CASES["paraboloid"](8), tmp_path / "p.glb")
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as stop:
        main(["simulate", str(glb), "--photons", "2000000000", "--keep-photons",
              "--out", str(out), "--quiet"])
    assert stop.value.code == 2 and not out.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--keep-photons" in err[0]


def test_keep_freed_memory_reuses_freed_blocks_in_a_process_of_its_own():
    """The heap policy of the command (glibc): four 12 MB arrays made, written and freed
    again and again (as a frame's records or a map's merged layout are) fault their pages
    anew every time by default — the freed heap top beyond glibc's trim threshold goes
    back to the system — and not at all once the policy keeps it. The policy is set in a
    child process, not in the test process."""
    code = """
import resource, sys
import numpy as np
from lightsim.engine.memory import keep_freed_memory
if sys.argv[1] == "on" and not keep_freed_memory():
    print("unsupported"); raise SystemExit
faults = []
for _ in range(4):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    arrays = [np.empty(1_500_000) for _ in range(4)]  # 4 × 12 MB
    for a in arrays:
        a[:] = 1.0
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    del arrays, a
print(min(faults[1:]))
"""
    out = {m: subprocess.run([sys.executable, "-c", code, m], capture_output=True,
                             text=True, check=True).stdout.strip() for m in ("off", "on")}
    if out["on"] == "unsupported":
        pytest.skip("the C library is not glibc: no mallopt")
    assert int(out["off"]) > 500  # 48 MB refaulted: ~12 000 4 KiB pages (fewer if huge)
    assert int(out["on"]) < 50


def test_small_pages_turns_numpy_huge_pages_off_in_a_process_of_its_own():
    """The page policy of the command: after :func:`small_pages` NumPy's switch reads
    off and a fresh 64 MB array is faulted in normal 4 KiB pages (one fault per page: no
    2 MiB page; unless the kernel gives huge pages to every process, THP ``always``); a
    ``NUMPY_MADVISE_HUGEPAGE`` set by the user is kept. Run in child processes."""
    thp = Path("/sys/kernel/mm/transparent_hugepage/enabled")
    always = thp.exists() and "[always]" in thp.read_text()

    code = """
import resource
import numpy as np
from lightsim.engine.memory import small_pages
try:
    from numpy._core.multiarray import _set_madvise_hugepage as switch
except ImportError:
    from numpy.core.multiarray import _set_madvise_hugepage as switch
on = small_pages()
state = switch(False); switch(state)  # the switch returns its previous state
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
a = np.empty(8_000_000)  # 64 MB, fresh
a[:] = 1.0
print(on, state, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    on, state, faults = subprocess.run([sys.executable, "-c", code], capture_output=True,
                                       text=True, check=True, env=env).stdout.split()
    assert (on, state) == ("True", "False")
    if not always:
        assert int(faults) >= 0.9 * 64_000_000 / 4096  # every 4 KiB page faulted once
    env["NUMPY_MADVISE_HUGEPAGE"] = "1"  # the user's choice stays
    on, state, _ = subprocess.run([sys.executable, "-c", code], capture_output=True,
                                  text=True, check=True, env=env).stdout.split()
    assert (on, state) == ("False", "True")


# -- open-ended runs: stop before the photon maps outgrow the memory -------------------

def _limit_for(budget_bytes: float, resolution, cfg: RunConfig, channels: int) -> int:
    """The LIGHTSIM_MEMORY_LIMIT whose photon budget is ``budget_bytes``."""
    fixed = memory.photon_budget(resolution, cfg, channels, available=10**15)
    fixed = 10**15 / memory.HEADROOM - fixed  # images, one frame, the process
    return int(memory.HEADROOM * (budget_bytes + fixed)) + 1


def test_a_run_stops_before_its_kept_photons_pass_the_memory(monkeypatch):
    scene = CASES["paraboloid"](16).scene
    cfg = RunConfig(frame_photons=20_000, spt=False)
    with Session(scene, cfg) as s:  # the records one frame keeps, and the default memory
        s.run(photons=cfg.frame_photons)
        per_frame = s.kept_photons()
        assert s.memory_stop is None  # this machine's memory holds a frame easily
    C = scene.channels or 1
    per = memory.kept_photon_bytes(C, cfg.n_sets)
    assert per == pytest.approx(memory.KEPT_PEAK_FACTOR * memory.estimate_run(
        1000, (8, 8), C, cfg.n_sets).photon_bytes / 1000)
    budget = 3.5 * per_frame * per
    monkeypatch.setenv("LIGHTSIM_MEMORY_LIMIT",
                       str(_limit_for(budget, scene.wall.resolution, cfg, C)))
    with Session(scene, cfg) as s:
        assert s.photon_budget() == pytest.approx(budget, rel=1e-6)
        est = s.run(photons=50 * cfg.frame_photons)  # bounded even if nothing stopped it
        stop = s.memory_stop
        assert stop is not None and est.photons == stop.photons < 50 * cfg.frame_photons
        assert stop.kept == s.kept_photons() and stop.kept_bytes <= budget
        assert (stop.kept + s.frame_records) * per > budget  # another frame would pass it
        assert s.frames == 3 and est.lux is not None and est.lux.max() > 0
        assert "before its budget" in stop.message() and "\n" not in stop.message()
    # the bin estimator keeps no photons: nothing to check
    with Session(scene, RunConfig(frame_photons=20_000, estimator="bin", spt=False)) as s:
        assert s.photon_budget() is None
        s.run(photons=5 * cfg.frame_photons)
        assert s.memory_stop is None and s.frames == 5


def test_simulate_with_a_time_budget_stops_for_memory_and_says_so(tmp_path, monkeypatch,
                                                                    capsys):
    """`--time` cannot be checked before the run: it stops short of the memory with
    one warning, writes its outputs, and summary.json records the stop."""
    glb = write_scene_glb(CASES["paraboloid"](16), tmp_path / "p.glb")
    argv = ["--resolution", "16x16", "--frame-photons", "20000", "--keep-photons"]
    opts = SimulateOptions(scene_path=str(glb), resolution=(16, 16), keep_all_photons=True,
                           config={"frame_photons": 20_000, "keep_photons": True})
    cfg, scene = opts.run_config(), load(opts)
    C = scene.channels or 3
    # a budget for about 2.5 frames of every photon kept at the peak (the pre-flight
    # allows a frame at the model's cost)
    budget = 2.5 * cfg.frame_photons * memory.kept_photon_bytes(C, cfg.n_sets)
    monkeypatch.setenv("LIGHTSIM_MEMORY_LIMIT",
                       str(_limit_for(budget, scene.wall.resolution, cfg, C)))
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        main(["simulate", str(glb), *argv, "--time", "120", "--out", str(out)])
    assert exc.value.code in (0, None)
    err = [ln for ln in capsys.readouterr().err.splitlines() if "warning" in ln]
    assert len(err) == 1 and "stopped at" in err[0] and "memory" in err[0], err
    summary = json.loads((out / "summary.json").read_text())
    stop = summary["memory_stop"]
    assert stop["kept_bytes"] <= budget and summary["photons"] == stop["photons"]
    assert summary["seconds"] < 120 and (out / "wall_lux.exr").exists()


def _resident_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


@pytest.mark.parametrize("madvise", [True, False])
def test_write_pages_faults_the_pages_in_and_keeps_the_values(madvise, monkeypatch):
    """The lattice's pages written ahead (:func:`write_pages`): every page of an untouched
    array resident afterwards, by ``madvise(MADV_POPULATE_WRITE)`` or, without it, by
    writing one element a page; the values as they were (zeros, and a filled array)."""
    if not madvise:
        def no_libc(*a, **k):
            raise OSError("no libc here")
        monkeypatch.setattr(ctypes, "CDLL", no_libc)
    # 64 MB of a mapping of its own (untouched pages whatever the heap holds), 16 bytes
    # in, as NumPy's large arrays start: a partial page at either end
    size = 64 * 2**20
    buf = mmap.mmap(-1, size)
    big = np.frombuffer(buf, dtype=np.float64, count=(size - 16) // 8, offset=16)
    before = _resident_bytes()
    write_pages(big)
    assert _resident_bytes() - before > 0.9 * size
    assert not big.any()
    del big
    buf.close()
    filled = np.arange(3 * 5_000 * 7, dtype=np.float64).reshape(3, 5_000, 7)
    want = filled.copy()
    write_pages(filled)
    np.testing.assert_array_equal(filled, want)
    for small in (np.zeros(0), np.ones(1), np.arange(1_000, dtype=np.int32)):
        copy = small.copy()
        write_pages(small)
        np.testing.assert_array_equal(small, copy)
    strided = np.arange(100.0)[::3]  # not contiguous: left alone
    write_pages(strided)
    np.testing.assert_array_equal(strided, np.arange(100.0)[::3])
