"""The ``lightsim`` command: a click group whose sub-commands live one per module.

Sub-commands are imported lazily so that ``lightsim --help`` and quick commands do not pay
for numba, embree or Ray start-up. Errors caused by the user's input
(:class:`lightsim.errors.LightsimError`) and bad options or arguments (click's
``UsageError``) print one line ``lightsim: error: …`` and exit with code 2.
"""

from __future__ import annotations

import importlib
import sys

import click

from lightsim import __version__
from lightsim.errors import LightsimError

# command name -> "module:attribute" (modules relative to lightsim.cli)
COMMANDS: dict[str, str] = {
    "simulate": "simulate:simulate",
    "luminaire": "luminaire:luminaire",
    "bench": "bench:bench",
    "compare": "compare:compare",
    "validate": "validate:validate",
    "converge": "validate:converge",
    "report": "report:report",
    "photo": "photo:photo",
    "view": "view:view",
    "screen-target": "screen_target:screen_target",
    "fuzz": "fuzz:fuzz",
    "tolerance": "tolerance:tolerance",
    "design": "design:design",
}


class LazyGroup(click.Group):
    """A group that imports a sub-command's module only when it is used.

    ``lazy_commands`` maps a command name to ``"module:attribute"`` (modules relative to
    ``lightsim.cli``); a module that does not exist yet hides its command.
    """

    def __init__(self, *args: object, lazy_commands: dict[str, str] | None = None,
                 **kwargs: object) -> None:
        super().__init__(*args, **kwargs)
        self.lazy_commands = dict(lazy_commands or {})

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(self.lazy_commands)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        target = self.lazy_commands.get(cmd_name)
        if target is None:
            return None
        module_name, attr = target.split(":")
        try:
            module = importlib.import_module(f"lightsim.cli.{module_name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"lightsim.cli.{module_name}":
                return None  # command not built yet
            raise
        return getattr(module, attr)


@click.group(cls=LazyGroup, lazy_commands=COMMANDS,
             context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="lightsim")
def cli() -> None:
    """Simulate and check automotive headlight beam patterns with photon mapping."""
    # wire the application: photometric readers and bulbs register with the core's emitters
    import lightsim.luminaires  # noqa: F401


def _one_line(text: str) -> str:
    return " ".join(text.split())


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script; maps input errors to one line and exit code 2."""
    if argv is None:  # the console script's process: freed arrays are reused, not faulted
        from lightsim.io import plot_worker

        # the plots' helper starts first: it imports matplotlib while this process
        # imports the engine (lightsim/io/plot_worker.py)
        plot_worker.prestart(sys.argv[1:])
        from lightsim.engine.blas import single_blas_thread
        from lightsim.engine.memory import keep_freed_memory, small_pages

        keep_freed_memory()
        small_pages()  # fresh huge pages are slow faults on the VMs (engine/memory.py)
        single_blas_thread()  # the cores are the run's threads', not BLAS's spinning ones
    try:
        _run(argv)
    finally:
        if argv is None:  # the process ends here: see _skip_final_collection
            _skip_final_collection()


def _skip_final_collection() -> None:
    """Move every live object out of the cyclic collector's reach before the interpreter
    exits: its final collections walk every object numba and llvmlite created (measured
    0.27-0.31 s after any cached kernel ran, against 0.02-0.03 s frozen), on every
    command. Reference counting still frees them and atexit handlers still run; only the
    console script does it (an in-process caller's garbage stays collectable)."""
    import gc

    gc.freeze()


def _run(argv: list[str] | None) -> None:
    try:
        cli.main(args=argv, prog_name="lightsim", standalone_mode=False)
    except LightsimError as exc:
        click.echo(f"lightsim: error: {exc}", err=True)
        sys.exit(exc.exit_code)
    except click.exceptions.Abort:
        click.echo("lightsim: aborted", err=True)
        sys.exit(130)
    except click.exceptions.NoArgsIsHelpError as exc:  # bare `lightsim`: the help, as asked
        exc.show()
        sys.exit(exc.exit_code)
    except click.ClickException as exc:
        if type(exc).show is not click.ClickException.show and not isinstance(
                exc, click.UsageError):
            exc.show()  # a command's own one-line report (e.g. compare's failed limits)
        else:  # a bad option or argument: one line, not click's usage block
            click.echo(f"lightsim: error: {_one_line(exc.format_message())}", err=True)
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        click.echo("lightsim: interrupted", err=True)
        sys.exit(130)
    except BrokenPipeError:
        sys.exit(0)
    sys.exit(0)


if __name__ == "__main__":  # pragma: no cover
    main()
