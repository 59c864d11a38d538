"""The Ray backend: run the pipeline's chunks of work as Ray tasks, on a local or remote cluster.

Ray is an optional extra (`pip install -e '.[ray]'`). `ray_session(address, num_cpus)` connects
to the cluster at `address` (else the `RAY_ADDRESS` environment variable) or starts a local
instance with `num_cpus` CPUs, and shuts down only what it started; inside a session,
`map_in_order(function, items, ...)` runs `function(item)` as one task per item (retried
`max_retries` times if its worker dies) and returns the results in item order;
`map_settled(...)` does the same for long jobs (sweeps): tasks are handed out as the cluster's
CPUs free up, none after a deadline, and a task that raised or whose worker died more often than
it may be retried comes back as a `TaskFailed` value instead of stopping the others. The
workers must be able to import this package (installed, or started from a checkout with it on
the path).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from pipeline.pool import due_items

DEFAULT_POLL_SECONDS = 0.1  # how often the caller's `check` runs while tasks are out
# Ray starts its workers at niceness 15 (raylet `worker_niceness`), so beside any busy process
# a local instance's tasks got a few per cent of a core (benchmarks/README.md: 7-10x slower);
# a local instance runs the caller's own work, as the local backend's processes do: same niceness
LOCAL_WORKER_NICENESS = 0


class RayUnavailableError(RuntimeError):
    """Ray is not installed; the message says how to install it."""


def require_ray():
    """The `ray` module; RayUnavailableError, saying how to install it, if it is missing."""
    try:
        import ray
    except ImportError:
        raise RayUnavailableError(
            "the ray backend needs Ray: pip install -e '.[ray]' (or pip install ray)"
        ) from None
    return ray


@contextlib.contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None) -> Iterator[Any]:
    """Yield the `ray` module, connected: to a running session, to `address` (or RAY_ADDRESS),
    or to a new local instance with `num_cpus` CPUs whose workers run at the caller's priority
    (`LOCAL_WORKER_NICENESS`), shut down on leaving."""
    ray = require_ray()
    if ray.is_initialized():
        yield ray
        return
    address = address or os.environ.get("RAY_ADDRESS") or None
    options = {"logging_level": logging.WARNING, "log_to_driver": False}
    if address is None:  # a local instance: ours to configure
        options.update(
            num_cpus=num_cpus,
            include_dashboard=False,
            _system_config={"worker_niceness": LOCAL_WORKER_NICENESS},
        )
    handlers = _signal_handlers()
    ray.init(address=address, **options)
    _restore(handlers)  # in case Ray installed its own: Ctrl-C stays the caller's business
    try:
        yield ray
    finally:
        ray.shutdown()


def _signal_handlers() -> dict:
    """The current SIGINT and SIGTERM handlers (only in the main thread, where they can be set)."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}


def _restore(handlers: dict) -> None:
    for signum, handler in handlers.items():
        if handler is not None:
            signal.signal(signum, handler)


def map_in_order(
    function: Callable[[Any], Any],
    items: Sequence[Any],
    *,
    num_cpus: float = 1,
    max_retries: int = 2,
    on_result: Callable[[Any], None] = lambda result: None,
    check: Callable[[], None] = lambda: None,
    poll_seconds: float = DEFAULT_POLL_SECONDS,
) -> list[Any]:
    """function(item) for every item as Ray tasks (inside `ray_session`); results in item order.

    `on_result(result)` is called as each task finishes (for progress), `check()` between
    polls (it may raise, e.g. a deferred KeyboardInterrupt); on any exception the tasks still
    out are cancelled and the exception re-raised.
    """
    import ray

    remote = ray.remote(num_cpus=num_cpus, max_retries=max_retries)(function)
    refs = [remote.remote(item) for item in items]
    position = {ref: k for k, ref in enumerate(refs)}
    results: list[Any] = [None] * len(refs)
    pending = list(refs)
    try:
        while pending:
            check()
            done, pending = ray.wait(pending, num_returns=1, timeout=poll_seconds)
            for ref in done:
                result = ray.get(ref)
                results[position[ref]] = result
                on_result(result)
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    return results


@dataclass(frozen=True)
class TaskFailed:
    """The result of a task that raised, or whose worker died on every attempt."""

    error: str  # one line: the exception's type and message, or how the worker died


def _failure(error: BaseException, attempts: int) -> TaskFailed:
    """One line saying why a task failed (Ray's own error text carries a remote traceback)."""
    import ray.exceptions

    if isinstance(error, ray.exceptions.RayTaskError):
        cause = getattr(error, "cause", None) or error
        text = str(cause).strip().splitlines()
        return TaskFailed(f"{type(cause).__name__}: {text[0] if text else ''}".rstrip(": "))
    return TaskFailed(f"worker died on each of {attempts} attempts ({type(error).__name__})")


def cluster_slots(num_cpus: float) -> int:
    """How many tasks of `num_cpus` CPUs the connected cluster runs at once (at least 1)."""
    import ray

    return max(1, int(ray.cluster_resources().get("CPU", 1) // num_cpus))


def map_settled(
    function: Callable[[Any], Any],
    items: Sequence[Any],
    *,
    num_cpus: float = 1,
    max_retries: int = 1,
    deadline: float | None = None,
    on_result: Callable[[Any], None] = lambda result: None,
    check: Callable[[], None] = lambda: None,
    poll_seconds: float = DEFAULT_POLL_SECONDS,
) -> list[Any]:
    """function(item) for every item as Ray tasks (inside `ray_session`); results in item order.

    At most `cluster_slots(num_cpus)` tasks are out at once; none is handed out after
    `deadline` (a `time.monotonic()` value), and the items left have None as their result.
    A task that raises (not retried: the error would repeat) or whose worker dies more than
    `max_retries` times has a `TaskFailed` result; the others go on. `on_result(result)` is
    called as each task finishes, `check()` between polls; on an exception here (Ctrl-C
    included) the tasks still out are cancelled (their workers killed) and it is re-raised.
    """
    import ray

    remote = ray.remote(num_cpus=num_cpus, max_retries=max_retries)(function)
    results: list[Any] = [None] * len(items)
    queue = iter(enumerate(items))
    slots = cluster_slots(num_cpus)
    out: dict = {}  # ObjectRef -> item index
    try:
        while True:
            for k, item in due_items(queue, slots - len(out), deadline):
                out[remote.remote(item)] = k
            if not out:
                return results
            check()
            done, _ = ray.wait(list(out), num_returns=1, timeout=poll_seconds)
            for ref in done:
                k = out.pop(ref)
                try:
                    results[k] = ray.get(ref)
                except ray.exceptions.RayError as error:  # raised, or its worker died
                    results[k] = _failure(error, max_retries + 1)
                on_result(results[k])
    except BaseException:
        for ref in out:
            ray.cancel(ref, force=True)
        raise
