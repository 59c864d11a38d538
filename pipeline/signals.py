"""`DeferredSignals`: Ctrl-C (SIGINT) and SIGTERM handled at safe points of the main thread, not
wherever the interpreter happens to be (inside a C callback or a library's lock handling)."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType


class DeferredSignals:
    """Context manager: SIGINT and SIGTERM are recorded and delivered only at `check()`.

    Python runs a signal handler wherever the main thread happens to be, including inside a
    pymunk (cffi) callback: a shape query of the collision check, or the destructor of an
    episode's pymunk space, which the cyclic garbage collector runs at any moment. cffi prints
    a KeyboardInterrupt raised there ("From cffi callback ...") and swallows it, and generation
    goes on (or Chipmunk aborts the process, its space left locked); inside
    `concurrent.futures.wait` it can leave a lock released twice ("release unlocked lock", seen
    when a reproduction was interrupted). Here the handler only records the signal, and
    `check()`, called at the caller's safe points (between episodes, between a pool's polls),
    passes it to the handler that was installed before (normally raising KeyboardInterrupt)
    from ordinary Python code. Only signals with a Python handler are deferred (a default
    SIGTERM still ends the process at once); outside the main thread nothing is deferred. On
    leaving, the previous handlers are restored and a signal still pending is delivered.
    """

    def __init__(self) -> None:
        self._previous: dict[int, Callable] = {}
        self._pending: list[tuple[int, FrameType | None]] = []

    def __enter__(self) -> DeferredSignals:
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                handler = signal.getsignal(signum)
                if callable(handler):
                    self._previous[signum] = handler
                    signal.signal(signum, self._record)
        return self

    def _record(self, signum: int, frame: FrameType | None) -> None:
        self._pending.append((signum, frame))

    def check(self) -> None:
        """Deliver recorded signals to their previous handlers (which may raise)."""
        while self._pending:
            signum, frame = self._pending.pop(0)
            self._previous[signum](signum, frame)

    def __exit__(self, exc_type, exc, traceback) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        if exc_type is None:
            self.check()
        self._pending.clear()
