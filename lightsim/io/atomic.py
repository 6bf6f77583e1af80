"""Atomic file output: write to a temporary name in the same folder, then rename.

A crash or Ctrl-C while writing never leaves a half-written file under the final name,
and an older file of that name stays intact until the new one is complete.

A folder of outputs is written as a set (:class:`OutputSet`): into a staging folder inside
it, then moved in with the marker file (``summary.json``) last, so the marker's presence
means the run finished; :func:`clean_stale` removes what killed writers left behind.

==================  =====  =====================  ========================================
parameter           unit   default                meaning
==================  =====  =====================  ========================================
``suffix``          –      the path's suffix      suffix of a temporary file
``marker``          –      ``summary.json``       file moved last; present = set complete
``previous``        –      ()                     names of an earlier set to drop
==================  =====  =====================  ========================================
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    Parameters
    ----------
    path : path-like
        Final destination.
    suffix : str, optional
        Suffix of the temporary file (some writers pick the format from it); defaults to
        the suffix of ``path``.
    """
    path = Path(path)
    suffix = path.suffix if suffix is None else suffix
    # The temporary file keeps the final suffix: some writers choose the format from it.
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{suffix}", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    # mkstemp makes the file private (0600); outputs get the usual mode (0666 & ~umask)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    write_bytes(path, text.encode("utf-8"))


# --------------------------------------------------------------------------------------
# a folder of outputs as one set
# --------------------------------------------------------------------------------------

STAGING_PREFIX = ".lightsim-staging-"
"""Name prefix of staging folders inside an output folder (followed by the writer's pid)."""

TEMP_RE = re.compile(r"^\..+\.tmp\.[A-Za-z0-9]+$|^\..+\.tmp$")
"""Names of :func:`atomic_path`'s temporary files (``.<name>.<random>.tmp<suffix>``)."""


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def _staging_pid(name: str) -> int:
    head = name[len(STAGING_PREFIX):].split("-", 1)[0]
    return int(head) if head.isdigit() else -1


def clean_stale(out: str | os.PathLike, marker: str = "summary.json") -> list[str]:
    """Remove what killed writers left in ``out``; one message per thing removed or found.

    Removed: staging folders (``.lightsim-staging-<pid>-…``) whose process is gone, and
    temporary files of :func:`atomic_path` (``.<name>.<random>.tmp<suffix>``) older than a
    minute. Reported, not removed: output files without ``marker`` (an unfinished set; the
    next completed run replaces it).

    Parameters
    ----------
    out : path-like
        The output folder (need not exist).
    marker : str
        The file whose presence means a finished set.

    Returns
    -------
    list of str
        Messages for the user (already phrased as warnings).
    """
    out = Path(out)
    notes: list[str] = []
    if not out.is_dir():
        return notes
    now = time.time()
    for p in sorted(out.iterdir()):
        try:
            if p.is_dir() and p.name.startswith(STAGING_PREFIX):
                pid = _staging_pid(p.name)
                if pid != os.getpid() and not _pid_alive(pid):
                    shutil.rmtree(p, ignore_errors=True)
                    notes.append(f"{out}: removed the staging folder {p.name} of a run that "
                                 "was killed while writing its outputs")
            elif p.is_file() and TEMP_RE.match(p.name) and now - p.stat().st_mtime > 60:
                p.unlink()
                notes.append(f"{out}: removed the temporary file {p.name} of an interrupted "
                             "write")
        except OSError:
            continue
    return notes


def unfinished_set(out: str | os.PathLike, names: Iterable[str],
                   marker: str = "summary.json") -> list[str]:
    """Output files among ``names`` present in ``out`` without ``marker`` (sorted)."""
    out = Path(out)
    if (out / marker).exists():
        return []
    return sorted(n for n in names if (out / n).is_file())


class OutputSet:
    """Write a folder's outputs into a staging folder, then publish them together.

    Use as a context manager: write every file into :attr:`dir` (each may itself use
    :func:`atomic_path`), then :meth:`commit`. Committing removes the previous set's
    ``marker`` first (so the folder never shows a finished run while files change), moves
    every staged file into the folder, removes files of the previous set that the new one
    does not have (``previous``), and moves ``marker`` in last: its presence means the set
    is complete. Leaving the block without committing — an exception, Ctrl-C — removes
    the staging folder; after a SIGKILL the next :func:`clean_stale` does.

    Parameters
    ----------
    out : path-like
        The output folder (must exist).
    marker : str
        The file that is moved last.
    previous : iterable of str
        Names an earlier set may have left that must not survive next to the new one.
    """

    def __init__(self, out: str | os.PathLike, marker: str = "summary.json",
                 previous: Iterable[str] = ()) -> None:
        self.out = Path(out)
        self.marker = marker
        self.previous = set(previous)
        self.dir = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}-",
                                         dir=self.out))
        self.committed = False

    def __enter__(self) -> OutputSet:
        return self

    def __exit__(self, *exc: object) -> None:
        if not self.committed:
            self.discard()

    def discard(self) -> None:
        """Remove the staging folder and everything in it."""
        shutil.rmtree(self.dir, ignore_errors=True)

    def commit(self) -> list[str]:
        """Publish the staged files (``marker`` last); returns their names."""
        staged = sorted(p.name for p in self.dir.iterdir() if p.is_file()
                        and not TEMP_RE.match(p.name))
        with contextlib.suppress(FileNotFoundError):
            (self.out / self.marker).unlink()
        for name in staged:
            if name != self.marker:
                os.replace(self.dir / name, self.out / name)
        for name in sorted(self.previous - set(staged) - {self.marker}):
            with contextlib.suppress(FileNotFoundError, IsADirectoryError):
                (self.out / name).unlink()
        if self.marker in staged:
            _fsync_dir(self.out)  # the set's files are in place before the marker appears
            os.replace(self.dir / self.marker, self.out / self.marker)
        _fsync_dir(self.out)
        self.committed = True
        self.discard()
        return staged


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
