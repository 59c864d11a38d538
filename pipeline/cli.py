"""Shared helpers for the command-line tools in tools/ (`from pipeline.cli import ...`).

- `ArgumentParser`: argparse whose usage errors are one line on stderr with exit status 2.
- `fail(msg, code=2)`: print one error line to stderr and exit.
- `require_file(path)`: exit 2 unless `path` is an existing file.
- `check_output(path, overwrite)`: exit 2 if the output exists (without overwrite) or its
  directory can be neither written nor created.
- `writing(path)`: context manager creating missing folders above `path` and yielding a
  temporary path beside it, renamed onto
  `path` on success and removed on any failure (Ctrl-C included; `pipeline.files.atomic_output`);
  a write that fails with an OSError (read-only directory, full disk) exits 2 with
  `error: cannot write PATH: REASON`.
- `run_main(main, argv)`: run a tool's main; a reader that closed the pipe (`tool | head`) ends
  it quietly with status 1 instead of a BrokenPipeError traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NoReturn

from pipeline.files import atomic_output


def run_main(main: Callable[[list[str] | None], None], argv: list[str] | None = None) -> None:
    """Call main(argv); if stdout's reader went away, exit 1 without a traceback.

    Python ignores SIGPIPE, so the write raises BrokenPipeError; stdout is pointed at devnull
    so the interpreter's final flush does not raise a second time.
    """
    try:
        main(argv)
        sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise SystemExit(1) from None


def fail(msg: str, code: int = 2) -> NoReturn:
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


def check_output(path: str | os.PathLike, overwrite: bool = False) -> Path:
    """The path as a Path; exits 2 if it exists (unless overwrite), or if its directory can
    neither be written nor created in the nearest existing folder above it (missing folders are
    created by `writing`, as the generator and trainer create theirs)."""
    path = Path(path)
    if path.exists() and not overwrite:
        fail(f"output {path} already exists; pass --overwrite to replace it")
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
    program with one line `error: cannot write PATH: REASON`, exit 2."""
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
            fail(f"cannot write {path}: {err.strerror or err}")
        raise
