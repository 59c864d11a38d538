"""Ray's own costs (pipeline.ray_backend): starting a local instance and the overhead per task.

Usage: python benchmarks/bench_ray.py [--repeats 5] [--tasks 200] [--starts 3]
Measures, on a local Ray instance with 2 CPUs:
- start-up: seconds of `ray_session(num_cpus=2)` until connected (median of --starts; each
  instance is shut down before the next);
- per task: --tasks trivial tasks (an int in, an int out) through `map_in_order` (what
  generation uses per chunk: all submitted at once) and through `map_settled` (what sweeps use
  per job: at most one task per CPU out), total wall seconds / --tasks, median of --repeats,
  against a direct call of the same function;
- a 1 MB result (a float64 array, about a 32-trajectory chunk's episodes): seconds per task.
One warm-up round runs first so worker start-up is not counted. Prints a line per figure and,
last, one JSON line {"benchmark": "ray", ...}; without Ray installed, {"benchmark": "ray",
"skipped": ...}.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from pipeline.ray_backend import RayUnavailableError, map_in_order, map_settled, ray_session

CPUS = 2  # like the development machine and the Ray tests
MEGABYTE_FLOATS = 131_072  # float64 values in 1 MiB


def identity(value: int) -> int:
    return value


def megabyte(value: int) -> np.ndarray:
    return np.full(MEGABYTE_FLOATS, float(value))


def seconds_per_item(run, items: list, repeats: int) -> float:
    """Median over `repeats` of the wall seconds of run(items), divided by len(items)."""
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run(items)
        times.append((time.perf_counter() - started) / len(items))
    return statistics.median(times)


def start_up_seconds(starts: int) -> float:
    times = []
    for _ in range(starts):
        started = time.perf_counter()
        with ray_session(num_cpus=CPUS):
            times.append(time.perf_counter() - started)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="rounds per figure (default 5)")
    parser.add_argument("--tasks", type=int, default=200, help="tasks per round (default 200)")
    parser.add_argument("--starts", type=int, default=3, help="Ray start-ups timed (default 3)")
    args = parser.parse_args()
    try:
        start_s = start_up_seconds(args.starts)
    except RayUnavailableError as error:
        print(f"ray: skipped ({error})")
        print(json.dumps({"benchmark": "ray", "skipped": str(error)}))
        return
    items = list(range(args.tasks))
    with ray_session(num_cpus=CPUS):
        map_in_order(identity, items)  # warm-up: the workers start and import numpy
        figures = {
            "direct_call_s": seconds_per_item(lambda xs: [identity(x) for x in xs], items, 3),
            "map_in_order_s_per_task": seconds_per_item(
                lambda xs: map_in_order(identity, xs), items, args.repeats
            ),
            "map_settled_s_per_task": seconds_per_item(
                lambda xs: map_settled(identity, xs), items, args.repeats
            ),
            "map_in_order_1mb_result_s_per_task": seconds_per_item(
                lambda xs: map_in_order(megabyte, xs),
                items[:50],
                args.repeats,
            ),
        }
    print(f"ray: start-up of a local instance with {CPUS} CPUs: {start_s:.2f} s")
    for name, value in figures.items():
        print(f"ray: {name} = {value * 1e6:.2f} us")
    record = {"benchmark": "ray", "cpus": CPUS, "start_up_s": round(start_s, 2)}
    record.update({name: float(f"{value:.3g}") for name, value in figures.items()})
    print(json.dumps(record))


if __name__ == "__main__":
    main()
