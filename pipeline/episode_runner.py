"""Rolling out planned episodes, in this process, in a process pool or as Ray tasks, with
Ctrl-C handled between episodes (`DeferredSignals`); pipeline.generation plans the episodes
and writes the dataset.

Episodes are rolled out `batch_scenes` at a time as one batched world
(`scenarios.rollout_batch`; 1: one by one); a scene's episode does not depend on the batch it
runs in, bit for bit. The result is the episodes in
slot order, whatever the number of workers, the backend or the batch size.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.pool
import signal
import sys
from dataclasses import dataclass

from tqdm import tqdm

from pipeline.signals import DeferredSignals
from scenarios import VERSIONS, Scenario
from scenarios.rollout import Episode, rollout_batch


@dataclass(frozen=True)
class Slot:
    """One trajectory to generate: where it goes and with which seed."""

    split: str
    case: str
    seed: int


_POLL_SECONDS = 0.1  # how often the parent looks for a recorded signal while workers run
_MAX_CHUNK = 32  # most episodes per pool task, one by one (fewer tasks, but a moving bar)
# Episodes stepped together as one batched world when none is asked for: measured on the 2-core
# development machine (benchmarks/README.md), a batch costs ~18 ms plus ~0.7-0.9 ms per scene,
# so 64 scenes run at ~1 ms each while a chunk of a default set still goes to each worker.
DEFAULT_BATCH_SCENES = 64


_SCENARIO: Scenario | None = None  # the scenario object episodes are rolled out with
_STOP = None  # in a pool worker, the pool's stop event (set by _init_worker); else None


def _load_scenario(scenario_name: str) -> None:
    global _SCENARIO
    _SCENARIO = VERSIONS[scenario_name].make()


def _init_worker(scenario_name: str, stop) -> None:
    """Workers leave Ctrl-C to the parent (which stops the pool through `stop`) and die quietly
    on SIGTERM."""
    global _STOP
    _STOP = stop
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _load_scenario(scenario_name)


def _run_batch(slots: list[Slot]) -> list[Episode]:
    """Roll out `slots` with the loaded scenario as one batched world."""
    return rollout_batch(_SCENARIO, [slot.seed for slot in slots], [slot.case for slot in slots])


def _batches(slots: list[Slot], batch_scenes: int) -> list[list[Slot]]:
    """Consecutive batches of at most `batch_scenes` slots."""
    return [slots[i : i + batch_scenes] for i in range(0, len(slots), batch_scenes)]


def _run_chunk(task: tuple[list[Slot], int]) -> list[Episode]:
    """A pool or Ray task: roll out a chunk of slots in batches of `batch_scenes`; in a pool
    that is stopping, nothing (the parent uses no result then), at once or after this batch."""
    slots, batch_scenes = task
    episodes: list[Episode] = []
    for batch in _batches(slots, batch_scenes):
        if _STOP is not None and _STOP.is_set():
            return []
        episodes.extend(_run_batch(batch))
    return episodes


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


def _ray_chunk(task: tuple[str, list[Slot], int]) -> list[Episode]:
    """A Ray task: roll out a chunk of slots of a scenario in batches of `batch_scenes`."""
    scenario_name, slots, batch_scenes = task
    if _SCENARIO is None or _SCENARIO.name != scenario_name:
        _load_scenario(scenario_name)
    return _run_chunk((slots, batch_scenes))


def _chunks(slots: list[Slot], workers: int, batch_scenes: int = 1) -> list[list[Slot]]:
    """Consecutive chunks for the workers: one by one, at most _MAX_CHUNK slots, about 8 per
    worker; batched, one batch each, at most `batch_scenes` and about 2 per worker (so a
    worker slowed down by other load leaves the other one a chunk to take)."""
    if batch_scenes == 1:
        size = max(1, min(_MAX_CHUNK, len(slots) // (8 * workers)))
    else:
        size = max(1, min(batch_scenes, -(-len(slots) // (2 * workers))))
    return [slots[i : i + size] for i in range(0, len(slots), size)]


def run_slots(
    slots: list[Slot],
    scenario_name: str,
    workers: int,
    progress: tqdm,
    signals: DeferredSignals,
    backend: str = "local",
    batch_scenes: int = DEFAULT_BATCH_SCENES,
) -> list[Episode]:
    """Roll out every slot, in order; the result depends on none of `workers`, `backend` and
    `batch_scenes` (episodes stepped together as one batched world; 1: one by one).

    With workers > 1 the slots go to a pool in chunks; on any exception (KeyboardInterrupt
    included) the pool's stop event is set, so the workers end their chunks after the current
    batch and skip the rest, and the pool is closed and joined; with backend "ray", the chunks
    are Ray tasks in the running Ray session (see `generate_episodes`). In this process,
    recorded signals are delivered between batches.
    """
    if batch_scenes < 1:
        raise ValueError(f"batch_scenes must be at least 1, got {batch_scenes}")
    episodes = []
    chunks = _chunks(slots, workers, batch_scenes)
    if backend == "ray":
        from pipeline.ray_backend import map_in_order

        results = map_in_order(
            _ray_chunk,
            [(scenario_name, chunk, batch_scenes) for chunk in chunks],
            on_result=lambda chunk: progress.update(len(chunk)),
            check=signals.check,
        )
        return [episode for chunk in results for episode in chunk]
    if workers == 1:
        _load_scenario(scenario_name)
        for batch in _batches(slots, batch_scenes):
            episodes.extend(_run_batch(batch))
            progress.update(len(batch))
            signals.check()
        return episodes
    context = multiprocessing.get_context("spawn" if sys.platform == "darwin" else "fork")
    stop = context.Event()
    pool = context.Pool(workers, initializer=_init_worker, initargs=(scenario_name, stop))
    try:
        tasks = [(chunk, batch_scenes) for chunk in chunks]
        results = pool.imap(_run_chunk, tasks)  # chunksize 1: an iterator with next(timeout)
        for _ in chunks:
            chunk = _next_result(results, signals)
            episodes.extend(chunk)
            progress.update(len(chunk))
    except BaseException:
        stop.set()
        raise
    finally:
        # never Pool.terminate(): a worker it kills while sending a result keeps the result
        # queue's lock, and the pool's threads wait for that lock forever (an interrupted
        # sharded run hung so, about once in a hundred)
        pool.close()
        pool.join()
    return episodes
