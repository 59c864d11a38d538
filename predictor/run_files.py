"""A training run's directory: checking and claiming it, atomic writes, cleaning up a failed start.

Every failure is a one-line `RunError` naming the path (read-only directory, full disk, a
directory that is not empty...); nothing is half-written: files are written beside their
target and renamed into place.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

import torch

RUN_FILES = ("config.json", "metrics.jsonl", "last.pt", "best.pt")


class RunError(ValueError):
    """A run directory or data file cannot be used as asked; the message is one line."""


@contextlib.contextmanager
def writing(path: Path, action: str = "write") -> Iterator[None]:
    """Turn an OSError of the block into a one-line RunError naming `path`."""
    try:
        yield
    except OSError as err:
        raise RunError(f"cannot {action} {path}: {err.strerror or err}") from None


def atomic_save(obj: object, path: Path) -> None:
    """torch.save to a temporary file beside `path`, then rename (RunError if that fails)."""
    temp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with writing(path):
            torch.save(obj, temp)
            os.replace(temp, path)
    finally:
        with contextlib.suppress(OSError):
            temp.unlink(missing_ok=True)


def atomic_write_text(text: str, path: Path) -> None:
    """Write text to a temporary file beside `path`, then rename (RunError if that fails)."""
    temp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with writing(path):
            temp.write_text(text)
            os.replace(temp, path)
    finally:
        with contextlib.suppress(OSError):
            temp.unlink(missing_ok=True)


def check_out_dir(out_dir: Path, resume: bool, overwrite: bool) -> None:
    """Check, without changing anything, that `out_dir` can hold the run as asked: a fresh run
    needs it absent or empty (or overwrite), a resumed one needs its last.pt."""
    if resume and overwrite:
        raise RunError("--resume and --overwrite exclude each other")
    if out_dir.exists() and not out_dir.is_dir():
        raise RunError(f"{out_dir} exists and is not a directory")
    if resume:
        if not out_dir.exists():
            raise RunError(f"nothing to resume: {out_dir} does not exist")
        if not (out_dir / "last.pt").is_file():
            raise RunError(
                f"nothing to resume in {out_dir}: it has no last.pt (the run never finished an "
                "epoch); start the run again without --resume (with --overwrite if the directory "
                "is not empty)"
            )
        return
    if out_dir.is_dir() and any(out_dir.iterdir()) and not overwrite:
        raise RunError(
            f"{out_dir} is not empty; pass --resume to continue the run there "
            "or --overwrite to start over"
        )


def claim_out_dir(out_dir: Path, overwrite: bool) -> list[Path]:
    """Create `out_dir` (and missing parents) and, with overwrite, remove an old run's files.

    Returns the directories created, outermost first, for `remove_failed_start`.
    """
    created = [p for p in (out_dir, *out_dir.parents) if not p.exists()][::-1]
    with writing(out_dir, "create run directory"):
        out_dir.mkdir(parents=True, exist_ok=True)
    if overwrite:
        for name in RUN_FILES + ("eval.json",):
            with writing(out_dir / name, "remove"):
                (out_dir / name).unlink(missing_ok=True)
    return created


def remove_failed_start(out_dir: Path, created: list[Path]) -> None:
    """Remove what a fresh run that never wrote last.pt left: its files, then the directories
    it created (only if empty)."""
    for name in RUN_FILES:
        with contextlib.suppress(OSError):
            (out_dir / name).unlink(missing_ok=True)
    for directory in reversed(created):
        with contextlib.suppress(OSError):
            directory.rmdir()
