"""``bench memory``: real child runs of both paths, their peak RSS, the plot and the JSON."""

from __future__ import annotations

import pytest

from lightsim.cli.main import main
from lightsim.validation.bench.memory import bench_memory, plot_memory, run_child
from lightsim.validation.bench.peer import CASES, write_scene_glb


def test_child_peak_rss_and_the_plot(tmp_path):
    """The fast variant: one child process's own peak RSS, and the plot of rows."""
    code, seconds, rss, cpu = run_child(["--help"])
    assert code == 0 and seconds > 0 and cpu > 0 and 10 * 2**20 < rss < 8 * 2**30
    rows = [{"path": p, "photons": n, "peak_rss_mb": m}
            for p, n, m in (("default", 10**6, 300), ("default", 4 * 10**6, 305),
                            ("keep-all", 10**6, 320), ("keep-all", 4 * 10**6, 400))]
    png = plot_memory(rows, tmp_path / "m.png", "test")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_bench_memory_measures_both_paths_and_plots(tmp_path):
    glb = write_scene_glb(CASES["paraboloid"](8), tmp_path / "p.glb")
    rows = bench_memory(str(glb), (40_000,), keep_all_max=40_000, resolution="16x16",
                        regulation=None)
    assert [r["path"] for r in rows] == ["default", "keep-all"]
    for r in rows:
        # a whole lightsim process: interpreter, numpy, numba, embree (> 50 MB), and
        # far below this machine's memory
        assert 50 < r["peak_rss_mb"] < 8000 and r["photons_per_s"] > 0
        assert r["photons"] == 40_000 and r["rss_vs_first"] == 1.0
    assert rows[0]["rss_vs_default"] == 1.0
    png = plot_memory(rows, tmp_path / "m.png", "test")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_memory_bad_photons_is_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "memory", "--photons", "lots", "--json", str(tmp_path / "m.json")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--photons" in err[0]
    assert not (tmp_path / "m.json").exists()
    with pytest.raises(SystemExit) as exc:
        main(["bench", "memory", "--photons", "0"])
    assert exc.value.code == 2


def test_a_failed_child_run_says_why(tmp_path):
    with pytest.raises(RuntimeError, match="failed"):
        bench_memory(str(tmp_path / "missing.glb"), (1000,), regulation=None)
