"""User-facing errors.

Every problem caused by the user's input (a missing file, a mesh with NaN vertices, a
negative flux, a nonsense option) is raised as :class:`LightsimError` with one line that
names the problem. The command line prints that line and exits with code 2; it never
shows a traceback for these.
"""


class LightsimError(Exception):
    """A problem with the user's input or environment, reported in one line (exit 2)."""

    exit_code = 2


class InputError(LightsimError):
    """Bad input data: a file that is missing, corrupt or physically meaningless."""


class ClusterError(LightsimError):
    """A Ray cluster that cannot be reached or lost all its workers."""
