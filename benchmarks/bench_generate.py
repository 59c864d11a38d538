"""Dataset generation throughput: the default set (50 major + 15 minor training/validation and
50 + 50 test trajectories, 22 cars) for each scenario, with 1 and 2 worker processes.

Usage: python benchmarks/bench_generate.py [--repeats 3]
Reports trajectories/s and simulated agent-steps/s (every 0.1 s simulation step of every car,
collision and off-road checks included), median of --repeats runs, HDF5 writing included.
Prints a line per configuration and, last, one JSON line {"benchmark": "generate", ...}.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from pipeline.generation import GenerateConfig, generate_dataset, plan
from scenarios import SCENARIOS


def time_generation(config: GenerateConfig, workers: int) -> float:
    """Seconds to generate and write the dataset of `config`."""
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        generate_dataset(config, Path(folder) / "set.h5", workers=workers, progress=False)
        return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs per configuration (default 3)")
    args = parser.parse_args()
    record: dict = {"benchmark": "generate"}
    for name in sorted(SCENARIOS):
        config = SCENARIOS[name]().config
        generate_config = GenerateConfig.for_scenario(name)
        trajectories = len(plan(generate_config))
        sim_steps = config.num_steps * config.record_every
        for workers in (1, 2):
            seconds = statistics.median(
                time_generation(generate_config, workers) for _ in range(args.repeats)
            )
            rate = trajectories / seconds
            agent_steps = rate * sim_steps * config.num_cars
            print(
                f"generate {name} workers={workers}: {trajectories} trajectories in "
                f"{seconds:.2f} s = {rate:.1f} traj/s, {agent_steps:,.0f} agent-steps/s"
            )
            record[f"{name}_workers{workers}_seconds"] = round(seconds, 2)
            record[f"{name}_workers{workers}_traj_per_s"] = round(rate, 1)
            record[f"{name}_workers{workers}_agent_steps_per_s"] = round(agent_steps)
    print(json.dumps(record))


if __name__ == "__main__":
    main()
