"""The console script skips the cyclic collector's final walk (cli.main), an in-process
caller does not: its garbage must stay collectable."""

from __future__ import annotations

import gc
import subprocess
import sys

import click
import pytest

from lightsim.cli.main import COMMANDS, cli, main


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



def test_command_list_comes_from_the_sources_without_importing_them():
    """``lightsim --help`` lists each command with the short help click would give it, read
    from the command's source: no command module (and so no engine) is imported for it."""
    code = ("import sys\n"
            "from click.testing import CliRunner\n"
            "from lightsim.cli.main import cli\n"
            "out = CliRunner().invoke(cli, ['--help'], terminal_width=80).output\n"
            "loaded = sorted(m for m in sys.modules if m.startswith('lightsim.cli.')\n"
            "                and m != 'lightsim.cli.main')\n"
            "print(repr(loaded)); print(out)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    loaded, _, listing = res.stdout.partition("\n")
    assert loaded == "[]", loaded
    ctx = click.Context(cli)
    limit = 80 - 6 - max(len(n) for n in COMMANDS)
    lines = [ln.strip() for ln in listing.splitlines()]
    for name in COMMANDS:
        short = cli.get_command(ctx, name).get_short_help_str(limit)
        assert any(ln.split(None, 1) == [name, short] for ln in lines), (name, short)
