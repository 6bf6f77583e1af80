"""``python -m lightsim.cli ARGS``: the ``lightsim`` command (as the console script runs it)."""

from lightsim.cli.main import main

main()
