"""A training run's directory: checking and claiming it, atomic writes, cleaning up a failed start.

Every failure is a one-line `RunError` naming the path (read-only directory, full disk, a
directory that is not empty...); nothing is half-written: files are written beside their
target and renamed into place.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import torch

RUN_FILES = ("config.json", "metrics.jsonl", "last.pt", "best.pt")


class RunError(ValueError):
    """A run directory or data file cannot be used as asked; the message is one line."""


class RunWriteError(RunError):
    """A file of the run could not be written (or moved, removed...); `errno` is the OSError's
    (None if it had none): a path refused for permission differs from a full disk."""

    def __init__(self, message: str, errno: int | None = None) -> None:
        super().__init__(message)
        self.errno = errno

    def __reduce__(self):  # picklable across process pools
        return (type(self), (str(self), self.errno))


@contextlib.contextmanager
def writing(path: Path, action: str = "write") -> Iterator[None]:
    """Turn an OSError of the block into a one-line RunWriteError naming `path`."""
    try:
        yield
    except OSError as err:
        raise RunWriteError(f"cannot {action} {path}: {err.strerror or err}", err.errno) from None


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
            if _replaced(out_dir / "last.pt").is_file():
                raise RunError(
                    f"nothing to resume in {out_dir}: an --overwrite there was interrupted before "
                    f"its first checkpoint and set the previous run aside as {REPLACED_PREFIX}*; "
                    "rename those files back to resume it, or start over with --overwrite"
                )
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


# an old run's file set aside by overwrite until the new run has written last.pt
REPLACED_PREFIX = ".replaced-"


@dataclass
class Claim:
    """What `claim_out_dir` changed in `out_dir`: the directories it created (outermost first)
    and the old run's files it set aside (with overwrite), so that a failed start can undo both."""

    out_dir: Path
    created: list[Path] = field(default_factory=list)
    set_aside: list[Path] = field(default_factory=list)  # the old files' own paths
    restored: bool = False  # `undo` put an old run's files back

    def undo(self) -> None:
        """A fresh run that never wrote last.pt failed: remove its files and the directories it
        created (only if empty), and put the old run's files back."""
        for name in RUN_FILES:
            with contextlib.suppress(OSError):
                (self.out_dir / name).unlink(missing_ok=True)
        for path in self.set_aside:
            with contextlib.suppress(OSError):
                os.replace(_replaced(path), path)
                self.restored = True
        for directory in reversed(self.created):
            with contextlib.suppress(OSError):
                directory.rmdir()

    def commit(self) -> None:
        """The new run has its first checkpoint: the old run's files go."""
        for path in self.set_aside:
            with contextlib.suppress(OSError):
                _replaced(path).unlink(missing_ok=True)
        self.set_aside = []


def _replaced(path: Path) -> Path:
    return path.with_name(REPLACED_PREFIX + path.name)


def claim_out_dir(out_dir: Path, overwrite: bool) -> Claim:
    """Create `out_dir` (and missing parents) and, with overwrite, set an old run's files aside
    (renamed with `REPLACED_PREFIX`): nothing of the old run is lost before the new one has
    written its first checkpoint (`Claim.commit`), and a failed start restores it
    (`Claim.undo`)."""
    claim = Claim(out_dir, [p for p in (out_dir, *out_dir.parents) if not p.exists()][::-1])
    with writing(out_dir, "create run directory"):
        out_dir.mkdir(parents=True, exist_ok=True)
    if overwrite:
        for name in RUN_FILES + ("eval.json",):
            path = out_dir / name
            if _replaced(path).exists():
                # an earlier overwrite was interrupted: what it set aside is the run to keep,
                # and `path` (if any) is the interrupted attempt's
                with writing(path, "remove"):
                    path.unlink(missing_ok=True)
                claim.set_aside.append(path)
            elif path.exists():
                with writing(path, "set aside"):
                    os.replace(path, _replaced(path))
                claim.set_aside.append(path)
    return claim
