"""Environment throughput: `ParallelEnv.step` with expert actions for all 22 cars, and the
direct `rollout` the dataset generator uses.

Usage: python benchmarks/bench_env.py [--episodes 20] [--repeats 5]
Timed: `step` alone (observations, rewards, infos included; the expert's actions are computed
outside the timed call), and `expert_actions() + step` together; `rollout` per episode.
Prints a table line per scenario and, last, one JSON line {"benchmark": "env", ...}.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a plain checkout too

from scenarios import SCENARIOS, env_module, rollout  # noqa: E402


def time_env(scenario_name: str, episodes: int, seed: int) -> tuple[float, float]:
    """(agent-steps/s of step alone, agent-steps/s of expert_actions + step) over `episodes`."""
    module = env_module(scenario_name)
    env = module.parallel_env()
    cases = SCENARIOS[scenario_name].case_names
    step_time = total_time = 0.0
    agent_steps = 0
    for episode in range(episodes):
        env.reset(seed=seed + episode, options={"case": cases[episode % len(cases)]})
        while env.agents:
            start = time.perf_counter()
            actions = env.unwrapped.expert_actions()
            middle = time.perf_counter()
            env.step(actions)
            end = time.perf_counter()
            agent_steps += len(actions)
            step_time += end - middle
            total_time += end - start
    return agent_steps / step_time, agent_steps / total_time


def time_rollout(scenario_name: str, episodes: int, seed: int) -> float:
    """Milliseconds per `rollout` episode (cases alternate)."""
    scenario = SCENARIOS[scenario_name]()
    cases = scenario.case_names
    start = time.perf_counter()
    for episode in range(episodes):
        rollout(scenario, seed + episode, cases[episode % len(cases)])
    return 1000.0 * (time.perf_counter() - start) / episodes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20, help="episodes per run (default 20)")
    parser.add_argument(
        "--repeats", type=int, default=5, help="runs; the median is reported (default 5)"
    )
    args = parser.parse_args()
    if args.episodes < 1 or args.repeats < 1:
        parser.error("--episodes and --repeats must be at least 1")
    result: dict = {"benchmark": "env"}
    for name in SCENARIOS:
        env_runs = [time_env(name, args.episodes, 1000 * run) for run in range(args.repeats)]
        rollout_runs = [
            time_rollout(name, args.episodes, 1000 * run) for run in range(args.repeats)
        ]
        step_rate = statistics.median(run[0] for run in env_runs)
        with_expert = statistics.median(run[1] for run in env_runs)
        rollout_ms = statistics.median(rollout_runs)
        print(
            f"{name}: step {step_rate:,.0f} agent-steps/s, expert_actions + step "
            f"{with_expert:,.0f} agent-steps/s, rollout {rollout_ms:.1f} ms/episode "
            f"(median of {args.repeats} x {args.episodes} episodes, 22 cars)"
        )
        result[f"{name}_step_agent_steps_per_s"] = round(step_rate)
        result[f"{name}_expert_and_step_agent_steps_per_s"] = round(with_expert)
        result[f"{name}_rollout_ms_per_episode"] = round(rollout_ms, 2)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
