"""A process pool for long jobs that stops cleanly: `run_parallel(function, items, jobs, desc)`.

Workers are spawned (never forked from a process that imported torch), run one torch thread and
ignore SIGINT and SIGTERM (a terminal's Ctrl-C reaches the whole process group); the parent, on
any exception (KeyboardInterrupt included), sets a shared stop event, and each job calls
`check_stop()` at its safe points, so no job is killed halfway through a write. The parent
takes Ctrl-C and SIGTERM between its polls of the running jobs (`DeferredSignals`), never inside
the library's waiting code, and further signals during the clean stop do not cut it short.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import TypeVar

from tqdm import tqdm

from pipeline.signals import DeferredSignals


class Stopped(KeyboardInterrupt):
    """Raised in a worker at a safe point once the parent asked the jobs to stop."""


_POLL_SECONDS = 0.2  # how often the parent looks for a recorded signal while jobs run
_STOP = None  # the pool's stop event, in a worker process (set by _init_worker)


def _init_worker(stop) -> None:
    """Worker start: one torch thread; signals are the parent's business, the event is ours."""
    import torch

    global _STOP
    _STOP = stop
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    torch.set_num_threads(1)


def check_stop(*_) -> None:
    """A safe point: raise Stopped if the parent set the stop event (any arguments ignored, so
    it serves as training's step callback)."""
    if _STOP is not None and _STOP.is_set():
        raise Stopped


@contextlib.contextmanager
def _signals_blocked() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back in this thread; processes started meanwhile inherit the
    block, so a Ctrl-C cannot reach a worker before it ignores the signal. A signal that
    arrives meanwhile is delivered on leaving."""
    held = {signal.SIGINT, signal.SIGTERM}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


Item = TypeVar("Item")
Result = TypeVar("Result")


def due_items(
    queue: Iterator[tuple[int, Item]], count: int, deadline: float | None
) -> list[tuple[int, Item]]:
    """The next at most `count` (index, item) pairs of `queue` to start, none once `deadline`
    (a `time.monotonic()` value; None: no deadline) has passed: the local pool's and the Ray
    backend's rule for handing out work."""
    due: list[tuple[int, Item]] = []
    while len(due) < count and (deadline is None or time.monotonic() < deadline):
        pair = next(queue, None)
        if pair is None:
            break
        due.append(pair)
    return due


def run_parallel(
    function: Callable[[Item], Result],
    items: Sequence[Item],
    jobs: int,
    desc: str,
    deadline: float | None = None,
) -> list[Result | None]:
    """function(item) for every item in `jobs` spawned processes; results in item order.

    Items are handed out as workers become free. With a `deadline` (a `time.monotonic()`
    value), no item starts after it: the running ones finish and the rest are left out, their
    results None. On any exception here (Ctrl-C included) the stop event is set: running jobs
    end at their next safe point, the rest never start, and the exception is re-raised once all
    stopped.
    """
    results: list = [None] * len(items)
    if not items:
        return results
    context = multiprocessing.get_context("spawn")  # never fork a process that imported torch
    stop = context.Event()
    workers = min(jobs, len(items))
    executor = ProcessPoolExecutor(
        workers, mp_context=context, initializer=_init_worker, initargs=(stop,)
    )
    with DeferredSignals() as signals:
        bar = tqdm(total=len(items), desc=desc, unit="job", file=sys.stderr, dynamic_ncols=True)
        queue = iter(enumerate(items))
        running: dict = {}
        try:
            while True:
                for k, item in due_items(queue, workers - len(running), deadline):
                    with _signals_blocked():  # a worker may start in submit
                        running[executor.submit(function, item)] = k
                if not running:
                    break
                signals.check()
                done, _ = wait(running, timeout=_POLL_SECONDS, return_when=FIRST_COMPLETED)
                for future in done:
                    results[running.pop(future)] = future.result()
                    bar.update()
        except BaseException:
            stop.set()
            raise
        finally:
            bar.close()
            executor.shutdown(wait=True, cancel_futures=True)
    return results
