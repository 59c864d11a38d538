"""Simulator throughput: a 22-car world stepped with collision and off-road checks every step.

Usage: python benchmarks/bench_simulator.py [--steps 2000] [--repeats 7]
Prints a table line and, last, one JSON line {"benchmark": "simulator", ...}.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from carlo_lite import StraightRoad, World

NUM_CARS = 22


def make_world(seed: int = 0) -> World:
    """22 cars spread over a 4-lane road, in lane centres, at 8-14 m/s."""
    rng = np.random.default_rng(seed)
    road = StraightRoad(num_lanes=4, length_m=100_000.0)
    lanes = np.arange(NUM_CARS) % 4
    x = np.arange(NUM_CARS) // 4 * 25.0 + rng.uniform(0, 5, NUM_CARS)
    y = np.array([road.lane_center_y(int(lane)) for lane in lanes])
    return World(road, np.column_stack([x, y]), np.zeros(NUM_CARS), rng.uniform(8, 14, NUM_CARS))


def run_once(num_steps: int) -> float:
    """Agent-steps per second for one run of `num_steps` world steps with all checks."""
    world = make_world()
    rng = np.random.default_rng(1)
    controls = np.column_stack(
        [rng.uniform(-0.01, 0.01, NUM_CARS), rng.uniform(-0.5, 0.5, NUM_CARS)]
    )
    start = time.perf_counter()
    for _ in range(num_steps):
        world.step(controls)
        world.incidents()  # collisions and off-road, every step
    return num_steps * NUM_CARS / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--steps", type=int, default=2000, help="world steps per run (default 2000)"
    )
    parser.add_argument(
        "--repeats", type=int, default=7, help="runs; the median is reported (default 7)"
    )
    args = parser.parse_args()
    rates = [run_once(args.steps) for _ in range(args.repeats)]
    median = statistics.median(rates)
    print(
        f"simulator: {median:,.0f} agent-steps/s (median of {args.repeats}, {NUM_CARS} cars, "
        f"collision + off-road checks every step)"
    )
    print(
        json.dumps(
            {
                "benchmark": "simulator",
                "agent_steps_per_s": round(median),
                "runs": [round(r) for r in rates],
                "num_cars": NUM_CARS,
            }
        )
    )


if __name__ == "__main__":
    main()
