"""Environment throughput: the PettingZoo environment one scene at a time, the vector
environment B scenes at once, and the direct `rollout` the dataset generator uses.

Usage: python benchmarks/bench_env.py [--versions a,b] [--num-envs 64,256,1024] [--repeats 5]

Counted: agent-steps, one per live agent per env step (an env step holds the action for
`record_every` simulation steps), with the expert driving every car and resets included
(the vector environment's autoresets: the steps in which a scene restarts count no agent).
Timed: for the PettingZoo environment `step` alone and `expert_actions() + step`; for the
vector environment `expert_actions() + step` over two and a half episodes per scene; for
`rollout` ms per episode. Medians of `--repeats` runs.

Prints a line per version and, last, one JSON line {"benchmark": "env", ...} with per-version
figures and two headlines at the first `--num-envs` value: `vector_env_agent_steps_per_s`,
the slowest version's vector rate (a floor), and `vector_env_speedup`, the geometric mean over
the versions of vector / PettingZoo (`expert_actions() + step`), both measured in this run.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a plain checkout too

from scenarios import ENV_MODULES, VERSIONS, rollout  # noqa: E402

DEFAULT_VERSIONS = ("double_merge_v1", "halting_car_v3")


def time_env(name: str, episodes: int, seed: int) -> tuple[float, float]:
    """(agent-steps/s of step alone, agent-steps/s of expert_actions + step) over `episodes`."""
    env = ENV_MODULES[name].parallel_env()
    cases = VERSIONS[name].scenario_class.case_names
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


def time_vector_env(name: str, num_envs: int, seed: int) -> float:
    """Agent-steps/s of `expert_actions() + step` of the vector env, 2.5 episodes per scene."""
    cases = VERSIONS[name].scenario_class.case_names
    env = ENV_MODULES[name].vector_env(
        num_envs, case=[cases[b % len(cases)] for b in range(num_envs)]
    )
    env.reset(seed=seed)
    steps = int(2.5 * env.max_cycles)
    agent_steps = 0
    start = time.perf_counter()
    for _ in range(steps):
        *_, infos = env.step(env.expert_actions())
        agent_steps += sum(int((info["live"] & ~info["reset"]).sum()) for info in infos.values())
    return agent_steps / (time.perf_counter() - start)


def time_rollout(name: str, episodes: int, seed: int) -> float:
    """Milliseconds per `rollout` episode (cases alternate)."""
    scenario = VERSIONS[name].make()
    cases = scenario.case_names
    start = time.perf_counter()
    for episode in range(episodes):
        rollout(scenario, seed + episode, cases[episode % len(cases)])
    return 1000.0 * (time.perf_counter() - start) / episodes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--versions",
        default=",".join(DEFAULT_VERSIONS),
        help=f"comma-separated versions (default {','.join(DEFAULT_VERSIONS)})",
    )
    parser.add_argument(
        "--num-envs", default="256", help="comma-separated scene counts B (default 256)"
    )
    parser.add_argument("--episodes", type=int, default=20, help="episodes per run (default 20)")
    parser.add_argument(
        "--repeats", type=int, default=5, help="runs; the median is reported (default 5)"
    )
    args = parser.parse_args()
    names = [name for name in args.versions.split(",") if name]
    if not names or any(name not in VERSIONS for name in names):
        parser.error(f"--versions must name versions from {', '.join(VERSIONS)}")
    sizes = [int(size) for size in args.num_envs.split(",") if size]
    if args.episodes < 1 or args.repeats < 1 or not sizes or min(sizes) < 1:
        parser.error("--episodes, --repeats and every --num-envs value must be at least 1")
    result: dict = {"benchmark": "env", "num_envs": sizes[0]}
    vector_rates, speedups = [], []
    for name in names:
        env_runs = [time_env(name, args.episodes, 1000 * run) for run in range(args.repeats)]
        step_rate = statistics.median(run[0] for run in env_runs)
        with_expert = statistics.median(run[1] for run in env_runs)
        rollout_ms = statistics.median(
            time_rollout(name, args.episodes, 1000 * run) for run in range(args.repeats)
        )
        result[f"{name}_step_agent_steps_per_s"] = round(step_rate)
        result[f"{name}_expert_and_step_agent_steps_per_s"] = round(with_expert)
        result[f"{name}_rollout_ms_per_episode"] = round(rollout_ms, 2)
        vector = {}
        for size in sizes:
            runs = [time_vector_env(name, size, 1000 * run) for run in range(args.repeats)]
            vector[size] = statistics.median(runs)
            result[f"{name}_vector_env_{size}_agent_steps_per_s"] = round(vector[size])
        vector_rates.append(vector[sizes[0]])
        speedups.append(vector[sizes[0]] / with_expert)
        print(
            f"{name}: PettingZoo step {step_rate:,.0f} agent-steps/s, expert_actions + step "
            f"{with_expert:,.0f}; vector env "
            + ", ".join(f"B={size} {rate:,.0f}" for size, rate in vector.items())
            + f" agent-steps/s (expert + step); rollout {rollout_ms:.1f} ms/episode "
            f"(medians of {args.repeats})"
        )
    result["vector_env_agent_steps_per_s"] = round(min(vector_rates))
    result["vector_env_speedup"] = round(math.exp(statistics.fmean(map(math.log, speedups))), 1)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
