"""Atomic file output for the pipeline's jobs: a file is either written whole or not at all."""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success it replaces `path`, else it is removed.

    The temporary name keeps the target's suffix, so writers that infer the format from the file
    name (e.g. matplotlib's savefig) still work. The block must only write the temporary file.
    Any exception (an OSError from a read-only directory or a full disk, Ctrl-C) propagates
    after the temporary file is removed; command-line tools use `pipeline.cli.writing`, which
    turns an OSError into one error line.
    """
    target = Path(path)
    temp = target.with_name(f".{target.stem}.{secrets.token_hex(6)}.tmp{target.suffix}")
    try:
        yield temp
        os.replace(temp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            temp.unlink(missing_ok=True)
        raise
