"""Dataset generation throughput: the default set (50 major + 15 minor training/validation and
50 + 50 test trajectories, 22 cars) for each scenario, one by one and as batched worlds, with 1
and 2 local worker processes, and through Ray (2 CPUs) where Ray is installed.

Usage: python benchmarks/bench_generate.py [--repeats 3] [--scenarios a,b] [--no-ray]
Reports simulated agent-steps/s (every 0.1 s simulation step of every car, collision and
off-road checks included), median of --repeats runs, HDF5 writing included, side by side:
one by one (`batch_scenes=1`) and batched (`DEFAULT_BATCH_SCENES`) with 1 and 2 workers, and
batched on a local Ray instance of 2 CPUs (started once, its start-up not counted). Prints a
table and, last, one JSON line {"benchmark": "generate", ...} with `batched_speedup` (geometric
mean over scenarios and worker counts of batched / one-by-one throughput).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import math
import statistics
import tempfile
import time
from pathlib import Path

from pipeline.episode_runner import DEFAULT_BATCH_SCENES
from pipeline.generation import GenerateConfig, generate_dataset, plan
from scenarios import VERSIONS

# (label, batch_scenes, workers, backend) of each column
RUNS = (
    ("one_by_one_workers1", 1, 1, "local"),
    ("one_by_one_workers2", 1, 2, "local"),
    ("batched_workers1", DEFAULT_BATCH_SCENES, 1, "local"),
    ("batched_workers2", DEFAULT_BATCH_SCENES, 2, "local"),
    ("batched_ray_cpus2", DEFAULT_BATCH_SCENES, 2, "ray"),
)


def time_generation(config: GenerateConfig, workers: int, batch_scenes: int, backend: str) -> float:
    """Seconds to generate and write the dataset of `config`."""
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        generate_dataset(
            config,
            Path(folder) / "set.h5",
            workers=workers,
            progress=False,
            backend=backend,
            batch_scenes=batch_scenes,
        )
        return time.perf_counter() - start


def agent_steps(name: str) -> int:
    """Simulated agent-steps of the default set of scenario `name`."""
    config = VERSIONS[name].config()
    trajectories = len(plan(GenerateConfig.for_scenario(name)))
    return trajectories * config.num_steps * config.record_every * config.num_cars


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs per configuration (default 3)")
    parser.add_argument("--scenarios", default="", help="comma-separated names (default all)")
    parser.add_argument("--no-ray", action="store_true", help="skip the Ray column")
    args = parser.parse_args()
    names = [name for name in args.scenarios.split(",") if name] or list(VERSIONS)
    use_ray = not args.no_ray and importlib.util.find_spec("ray") is not None
    record: dict = {"benchmark": "generate", "batch_scenes": DEFAULT_BATCH_SCENES}
    if not use_ray:
        record["ray"] = "skipped (not installed)" if not args.no_ray else "skipped (--no-ray)"
    runs = [run for run in RUNS if use_ray or run[3] != "ray"]
    rates: dict[tuple[str, str], float] = {}
    with contextlib.ExitStack() as stack:
        if use_ray:
            from pipeline.ray_backend import ray_session

            start = time.perf_counter()
            stack.enter_context(ray_session(num_cpus=2))
            record["ray_start_s"] = round(time.perf_counter() - start, 2)
        for name in names:
            config = GenerateConfig.for_scenario(name)
            for label, batch_scenes, workers, backend in runs:
                if backend == "ray":  # warm-up: the Ray workers import the package once
                    time_generation(config, workers, batch_scenes, backend)
                seconds = statistics.median(
                    time_generation(config, workers, batch_scenes, backend)
                    for _ in range(args.repeats)
                )
                rates[name, label] = agent_steps(name) / seconds
                record[f"{name}_{label}_agent_steps_per_s"] = round(rates[name, label])
            for workers in (1, 2):
                speedup = (
                    rates[name, f"batched_workers{workers}"]
                    / rates[name, f"one_by_one_workers{workers}"]
                )
                record[f"{name}_batched_speedup_workers{workers}"] = round(speedup, 2)
    speedups = [value for key, value in record.items() if "_batched_speedup_" in key]
    record["batched_speedup"] = round(math.exp(statistics.mean(map(math.log, speedups))), 2)
    print_table(names, [run[0] for run in runs], rates)
    print(json.dumps(record))


def print_table(names: list[str], labels: list[str], rates: dict) -> None:
    """Agent-steps/s, one row per scenario, one column per run."""
    print(f"generate: simulated agent-steps/s, default set (batch_scenes {DEFAULT_BATCH_SCENES})")
    print(f"{'scenario':<16}" + "".join(f"{label:>22}" for label in labels))
    for name in names:
        print(f"{name:<16}" + "".join(f"{rates[name, label]:>22,.0f}" for label in labels))


if __name__ == "__main__":
    main()
