"""The console script skips the cyclic collector's final walk (cli.main), an in-process
caller does not: its garbage must stay collectable."""

from __future__ import annotations

import gc
import subprocess
import sys

import pytest

from lightsim.cli.main import main


def test_in_process_main_leaves_the_collector_alone():
    before = gc.get_freeze_count()
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert gc.get_freeze_count() == before


def test_console_script_freezes_before_exit_and_still_reports_errors(tmp_path):
    probe = ("import gc, sys\n"
             "from lightsim.cli import main as m\n"
             "sys.argv = ['lightsim', 'simulate', sys.argv[1]]\n"
             "try:\n"
             "    m.main()\n"
             "except SystemExit as e:\n"
             "    print('frozen', gc.get_freeze_count() > 0, 'code', e.code)\n")
    out = subprocess.run([sys.executable, "-c", probe, str(tmp_path / "missing.glb")],
                         capture_output=True, text=True, timeout=120)
    assert "frozen True code 2" in out.stdout
    assert out.stderr.strip().count("\n") == 0 and "no such file" in out.stderr
