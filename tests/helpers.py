"""Helpers shared by the CLI tests (imported as ``from helpers import ...``)."""

from __future__ import annotations

import pytest

from lightsim.cli.main import main


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """Run ``lightsim argv``; return (exit code, stdout, stderr)."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err
