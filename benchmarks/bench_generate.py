"""Dataset generation throughput: the default set (50 major + 15 minor training/validation and
50 + 50 test trajectories, 22 cars) for each scenario, with 1 and 2 worker processes.

Usage: python benchmarks/bench_generate.py [--repeats 3]
Reports trajectories/s and simulated agent-steps/s (every 0.1 s simulation step of every car,
collision and off-road checks included), median of --repeats runs, HDF5 writing included.
Prints a line per configuration and, last, one JSON line {"benchmark": "generate", ...}.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

import generate  # noqa: E402  (tools/generate.py; also puts the repository root on sys.path)

from scenarios import SCENARIOS  # noqa: E402


def time_generation(scenario: str, workers: int) -> float:
    """Seconds to generate and write the default set of `scenario`."""
    with tempfile.TemporaryDirectory() as folder, contextlib.redirect_stderr(io.StringIO()):
        out = Path(folder) / "set.h5"
        argv = ["--scenario", scenario, "--workers", str(workers), "--out", str(out)]
        start = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            generate.main(argv)
        return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs per configuration (default 3)")
    args = parser.parse_args()
    record: dict = {"benchmark": "generate"}
    for name in sorted(SCENARIOS):
        config = SCENARIOS[name]().config
        trajectories = len(
            generate.plan(generate.config_from_args(generate.parse_args(["--scenario", name])))
        )
        sim_steps = config.num_steps * config.record_every
        for workers in (1, 2):
            seconds = statistics.median(time_generation(name, workers) for _ in range(args.repeats))
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
