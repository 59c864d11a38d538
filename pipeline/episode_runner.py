"""Rolling out planned episodes, in this process, in a process pool or as Ray tasks, with
Ctrl-C handled between episodes (`DeferredSignals`); pipeline.generation plans the episodes
and writes the dataset.

The result is the episodes in slot order, whatever the number of workers or the backend.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.pool
import signal
import sys
import threading
from collections.abc import Callable
from types import FrameType
from typing import TYPE_CHECKING

from tqdm import tqdm

from scenarios import SCENARIOS, Scenario
from scenarios.rollout import Episode, rollout

if TYPE_CHECKING:
    from pipeline.generation import Slot

_POLL_SECONDS = 0.1  # how often the parent looks for a recorded signal while workers run
_MAX_CHUNK = 32  # most episodes per pool task (fewer tasks, but a progress bar that moves)


class DeferredSignals:
    """Context manager: SIGINT and SIGTERM are recorded and delivered only at `check()`.

    Python runs a signal handler wherever the main thread happens to be, including inside a
    pymunk (cffi) callback: a shape query of the collision check, or the destructor of an
    episode's pymunk space, which the cyclic garbage collector runs at any moment. cffi prints
    a KeyboardInterrupt raised there ("From cffi callback ...") and swallows it, and generation
    goes on (or Chipmunk aborts the process, its space left locked). Here the handler
    only records the signal, and `check()`, called between episodes, passes it to the handler
    that was installed before (normally raising KeyboardInterrupt) from ordinary Python code.
    Only signals with a Python handler are deferred (a default SIGTERM still ends the process at
    once); outside the main thread nothing is deferred. On leaving, the previous handlers are
    restored and a signal still pending is delivered.
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


_SCENARIO: Scenario | None = None  # the scenario object episodes are rolled out with


def _load_scenario(scenario_name: str) -> None:
    global _SCENARIO
    _SCENARIO = SCENARIOS[scenario_name]()


def _init_worker(scenario_name: str) -> None:
    """Workers leave Ctrl-C to the parent (which stops the pool) and die quietly on SIGTERM."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _load_scenario(scenario_name)


def _run_slot(slot: Slot) -> Episode:
    return rollout(_SCENARIO, slot.seed, slot.case)


def _run_chunk(slots: list[Slot]) -> list[Episode]:
    return [_run_slot(slot) for slot in slots]


def _next_result(
    results: multiprocessing.pool.IMapIterator, signals: DeferredSignals
) -> list[Episode]:
    """The pool's next chunk of episodes; signals recorded meanwhile are delivered while waiting."""
    while True:
        signals.check()
        try:
            return results.next(timeout=_POLL_SECONDS)
        except multiprocessing.TimeoutError:
            pass


def _ray_chunk(task: tuple[str, list[Slot]]) -> list[Episode]:
    """A Ray task: roll out a chunk of slots of a scenario."""
    scenario_name, slots = task
    if _SCENARIO is None or _SCENARIO.name != scenario_name:
        _load_scenario(scenario_name)
    return _run_chunk(slots)


def _chunks(slots: list[Slot], workers: int) -> list[list[Slot]]:
    """Consecutive chunks of at most _MAX_CHUNK slots, about 8 per worker."""
    size = max(1, min(_MAX_CHUNK, len(slots) // (8 * workers)))
    return [slots[i : i + size] for i in range(0, len(slots), size)]


def run_slots(
    slots: list[Slot],
    scenario_name: str,
    workers: int,
    progress: tqdm,
    signals: DeferredSignals,
    backend: str = "local",
) -> list[Episode]:
    """Roll out every slot, in order; the result depends neither on `workers` nor `backend`.

    With workers > 1 the slots go to a pool in chunks, terminated on any exception
    (KeyboardInterrupt included); with backend "ray", the chunks are Ray tasks in the running
    Ray session (see `generate_episodes`).
    """
    episodes = []
    if backend == "ray":
        from pipeline.ray_backend import map_in_order

        chunks = map_in_order(
            _ray_chunk,
            [(scenario_name, chunk) for chunk in _chunks(slots, workers)],
            on_result=lambda chunk: progress.update(len(chunk)),
            check=signals.check,
        )
        return [episode for chunk in chunks for episode in chunk]
    if workers == 1:
        _load_scenario(scenario_name)
        for slot in slots:
            episodes.append(_run_slot(slot))
            progress.update()
            signals.check()
        return episodes
    chunks = _chunks(slots, workers)
    context = multiprocessing.get_context("spawn" if sys.platform == "darwin" else "fork")
    with context.Pool(workers, initializer=_init_worker, initargs=(scenario_name,)) as pool:
        results = pool.imap(_run_chunk, chunks)  # chunksize 1: an iterator with next(timeout)
        for _ in chunks:
            chunk = _next_result(results, signals)
            episodes.extend(chunk)
            progress.update(len(chunk))
    return episodes
