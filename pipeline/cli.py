"""Shared helpers for the command-line tools in tools/ (`from pipeline.cli import ...`).

Every tool follows one exit-status rule (docs/CLI.md): 0 done; `USAGE` (2) the command cannot be
carried out as given (a bad option, a missing or malformed input, an output that exists, a place
that cannot be written); `FAILED` (1) the work was started and failed (a training diverged, a
job failed, the disk filled up); `INTERRUPTED` (130) Ctrl-C or SIGTERM. Errors are one line on
stderr, `error: ...`, never a traceback.

- `ArgumentParser`: argparse whose usage errors are one line on stderr with exit status 2.
- `fail(msg, code=2)`: print one error line to stderr and exit.
- `status(message)`: a status line on stderr, for a phase without a progress bar.
- `require_file(path)`: exit 2 unless `path` is an existing file.
- `check_output(path, overwrite)`: exit 2 if the output exists (without overwrite) or its
  directory can be neither written nor created.
- `write_failure_code(errno)`: the status of a failed write: 2 if the path is refused
  (permission, read-only, not a folder), 1 if the write itself failed (full disk, I/O error).
- `writing(path)`: context manager creating missing folders above `path` and yielding a
  temporary path beside it, renamed onto
  `path` on success and removed on any failure (Ctrl-C included; `pipeline.files.atomic_output`);
  a write that fails with an OSError exits with `error: cannot write PATH: REASON` and
  `write_failure_code`'s status.
- `run_main(main, argv)`: run a tool's main; a reader that closed the pipe (`tool | head`) ends
  it quietly with status 1 instead of a BrokenPipeError traceback; Ctrl-C (and SIGTERM) that
  the tool does not handle itself ends it with `error: interrupted` and status 130.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import os
import signal
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NoReturn

from pipeline.files import atomic_output

USAGE, FAILED, INTERRUPTED = 2, 1, 130  # exit statuses besides 0 (docs/CLI.md)
# errnos of a write refused because of the path (the user picks another): USAGE; any other
# (no space left, I/O error, quota) is the work failing: FAILED
REFUSED_PATH_ERRNOS = frozenset(
    {
        errno.EACCES,
        errno.EPERM,
        errno.EROFS,
        errno.ENOTDIR,
        errno.EISDIR,
        errno.ENOENT,
        errno.EEXIST,
        errno.ENAMETOOLONG,
    }
)


def write_failure_code(error_number: int | None) -> int:
    """Exit status of a write that failed with `error_number` (an OSError's errno): USAGE when
    the path was refused (permission, read-only, not a folder...), FAILED otherwise (full disk,
    I/O error)."""
    return USAGE if error_number in REFUSED_PATH_ERRNOS else FAILED


def _terminate(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM stops a tool as Ctrl-C does: cleanly, status 130


def run_main(main: Callable[[list[str] | None], None], argv: list[str] | None = None) -> None:
    """Call main(argv) under the exit-status rule of the tools.

    If stdout's reader went away, exit 1 without a traceback: Python ignores SIGPIPE, so the
    write raises BrokenPipeError; stdout is pointed at devnull so the interpreter's final
    flush does not raise a second time. A KeyboardInterrupt the tool lets through (Ctrl-C, or
    SIGTERM, which raises one here unless a handler is installed already) ends it with one
    line and status 130.
    """
    if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _terminate)
    try:
        main(argv)
        sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise SystemExit(FAILED) from None
    except KeyboardInterrupt:
        fail("interrupted", code=INTERRUPTED)


def status(message: str) -> None:
    """A status line on stderr (flushed), for a phase that shows no progress bar."""
    print(message, file=sys.stderr, flush=True)


def fail(msg: str, code: int = USAGE) -> NoReturn:
    """Print `error: msg` as one line on stderr and exit with `code` (2: usage/input error)."""
    print(f"error: {' '.join(str(msg).split())}", file=sys.stderr)
    raise SystemExit(code)


class ArgumentParser(argparse.ArgumentParser):
    """argparse.ArgumentParser whose errors are a single stderr line and exit status 2."""

    def error(self, message: str) -> NoReturn:
        fail(f"{self.prog}: {message} (see --help)")


def require_file(path: str | os.PathLike, what: str = "input file") -> Path:
    """The path as a Path; exits 2 with one line if it is not an existing file."""
    path = Path(path)
    if not path.is_file():
        problem = "is not a file" if path.exists() else "does not exist"
        fail(f"{what} {path} {problem}")
    return path


def check_output(
    path: str | os.PathLike, overwrite: bool = False, elsewhere: str | None = None
) -> Path:
    """The path as a Path; exits 2 if it exists (unless overwrite), or if its directory can
    neither be written nor created in the nearest existing folder above it (missing folders are
    created by `writing`, as the generator and trainer create theirs). `elsewhere` names the
    option that writes to another path (e.g. "--out FILE"), for the message."""
    path = Path(path)
    if path.exists() and not overwrite:
        other = f", or {elsewhere} to write elsewhere" if elsewhere else ""
        fail(f"output {path} already exists; pass --overwrite to replace it{other}")
    if path.is_dir():
        fail(f"output {path} is a directory")
    existing = next(p for p in (path.parent, *path.parent.parents) if p.exists() or p == Path())
    if not existing.is_dir():
        fail(f"output directory {path.parent} cannot be created: {existing} is not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):  # found now, not after the work
        fail(f"cannot write in output directory {existing}")
    return path


@contextlib.contextmanager
def writing(path: str | os.PathLike) -> Iterator[Path]:
    """`pipeline.files.atomic_output` for a tool, creating missing folders above `path` (removed
    again if the write fails): an OSError raised in the block, or by the final rename, ends the
    program with one line `error: cannot write PATH: REASON` and `write_failure_code`'s status
    (2 for a refused path, 1 for a full disk)."""
    parent = Path(path).parent
    created = [p for p in (parent, *parent.parents) if not p.exists()][::-1]
    try:
        parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path) as temp:
            yield temp
    except BaseException as err:
        for folder in reversed(created):
            with contextlib.suppress(OSError):
                folder.rmdir()  # only if empty
        if isinstance(err, OSError):
            fail(f"cannot write {path}: {err.strerror or err}", write_failure_code(err.errno))
        raise
