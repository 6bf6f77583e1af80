"""The ``lightsim`` command: a click group whose sub-commands live one per module.

Sub-commands are imported lazily so that ``lightsim --help`` and quick commands do not pay
for numba, embree or Ray start-up. Errors caused by the user's input
(:class:`lightsim.errors.LightsimError`) and bad options or arguments (click's
``UsageError``) print one line ``lightsim: error: …`` and exit with code 2. The console
script's process is tuned for a run by the engine
(:func:`lightsim.engine.process.command_process`).
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import sys
from contextlib import nullcontext

import click

from lightsim import __version__
from lightsim.engine.process import command_process
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
    "road": "road:road",
    "check": "check:check",
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

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The command list of ``--help`` from each command's docstring, read from its
        source without importing it (importing every command would load the engine)."""
        rows = []
        width = formatter.width - 6 - max((len(n) for n in self.lazy_commands), default=0)
        for name in self.list_commands(ctx):
            text = command_docstring(self.lazy_commands[name])
            if text is not None:
                rows.append((name, click.utils.make_default_short_help(text, width)))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


def command_docstring(target: str) -> str | None:
    """The docstring of the function ``"module:attribute"`` (module relative to
    ``lightsim.cli``) as the source has it, or None where there is no such module."""
    module_name, attr = target.split(":")
    spec = importlib.util.find_spec(f"lightsim.cli.{module_name}")
    if spec is None or spec.origin is None:
        return None
    with open(spec.origin, encoding="utf-8") as f:
        tree = ast.parse(f.read(), filename=spec.origin)
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.name == attr:
            return ast.get_docstring(node) or ""
    return ""


@click.group(cls=LazyGroup, lazy_commands=COMMANDS,
             context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="lightsim")
def cli() -> None:
    """Simulate and check automotive headlight beam patterns with photon mapping."""
    # wire the application: photometric readers and bulbs register with the core's
    # emitters (a plug-in registry, loaded when a command runs, not for --help)
    importlib.import_module("lightsim.luminaires")


def _one_line(text: str) -> str:
    return " ".join(text.split())


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script (``argv`` None: this process is the command's,
    tuned for the run) or of an in-process caller (``argv`` given, its process as it is);
    maps input errors to one line and exit code 2."""
    with command_process(sys.argv[1:]) if argv is None else nullcontext():
        _run(argv)


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
