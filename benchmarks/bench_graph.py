"""Training step time against crowd size: the complete graph against sparse neighbour graphs.

Usage: python benchmarks/bench_graph.py [--agents 8,32,64] [--repeats 5] [--threads 1]
[--k 8] [--radius 4.0]

Synthetic random-walk crowds shaped like ETH/UCY windows: batches of 8 scenes, T = 20 steps of
0.4 s (8 observed + 12 predicted), every pedestrian present throughout, walking at ~1.3 m/s with
a heading that wanders, started uniformly in a square sized for 0.1 pedestrians per m^2 (so the
neighbourhood of an agent does not grow with the crowd). For each crowd size and graph
(`all`: every other agent, N(N-1) edges; `knn` with k neighbours; `radius` within r metres) it
times `predictor.training.train_step` (forward with the sampled rollout, the paper's loss,
backward, Adam) of the default `ours` model (paper preset) and reports the median over repeats
(one warm-up step first) and the mean number of edges per agent.

The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from predictor.graph import neighbour_graph  # noqa: E402
from predictor.model import SmoothAttentionPredictor  # noqa: E402
from predictor.presets import make_configs  # noqa: E402
from predictor.run_state import make_optimizer  # noqa: E402
from predictor.training import train_step  # noqa: E402
from trajectory_data.torch_dataset import Batch  # noqa: E402

SCENES, STEPS, OBSERVED, DT = 8, 20, 8, 0.4  # ETH/UCY window shape, the paper's batch size
DENSITY = 0.1  # pedestrians per m^2
SPEED = 1.3  # [m/s] walking speed


def random_walk_crowd(scenes: int, agents: int, seed: int) -> Batch:
    """Pedestrians walking with wandering headings in a square of DENSITY; all present."""
    gen = torch.Generator().manual_seed(seed)
    side = math.sqrt(agents / DENSITY)  # [m]
    start = torch.rand(scenes, 1, agents, 2, generator=gen) * side  # (B, 1, N, 2)
    heading = 2 * math.pi * torch.rand(scenes, 1, agents, generator=gen)
    turns = 0.3 * torch.randn(scenes, STEPS - 1, agents, generator=gen)  # [rad] per step
    heading = heading + torch.cat([torch.zeros_like(heading), turns.cumsum(1)], 1)  # (B, T, N)
    speed = SPEED * (1 + 0.2 * torch.randn(scenes, 1, agents, generator=gen)).clamp(min=0.3)
    step = torch.stack([heading.cos(), heading.sin()], -1) * (speed * DT).unsqueeze(-1)
    positions = start + step.cumsum(1) - step[:, :1]  # (B, T, N, 2)
    return Batch(
        states=positions,
        valid=torch.ones(scenes, STEPS, agents, dtype=torch.bool),
        attention=torch.full((scenes, STEPS, agents), -1, dtype=torch.long),
        interaction=torch.zeros(scenes, STEPS, dtype=torch.bool),
        case=torch.zeros(scenes, dtype=torch.long),
        seed=torch.arange(scenes),
    )


def time_steps(graph: dict, batch: Batch, repeats: int) -> tuple[float, list[float]]:
    """(median, all) seconds of one training step of a fresh default model with `graph`."""
    model_cfg, train_cfg = make_configs("ours", graph)
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(model_cfg)
    optimizer = make_optimizer(model, train_cfg)
    train_step(model, optimizer, batch, OBSERVED, train_cfg)  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        train_step(model, optimizer, batch, OBSERVED, train_cfg)
        times.append(time.perf_counter() - start)
    return statistics.median(times), times


def edges_per_agent(graph: dict, batch: Batch) -> float:
    """Mean out-degree of the graph the model builds for `batch`."""
    built = neighbour_graph(
        batch.positions,
        batch.valid,
        OBSERVED,
        graph.get("neighbours", "all"),
        graph.get("neighbour_radius_m", 50.0),
        graph.get("neighbour_k", 16),
    )
    return built.num_edges / (batch.batch_size * batch.num_agents)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agents", default="8,32,64", help="comma-separated crowd sizes")
    parser.add_argument("--repeats", type=int, default=5, help="timed steps per setting")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--k", type=int, default=8, help="neighbours of the knn graph")
    parser.add_argument("--radius", type=float, default=4.0, help="[m] radius of the radius graph")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    graphs = {
        "all": {},
        f"knn{args.k}": {"neighbours": "knn", "neighbour_k": args.k},
        f"radius{args.radius:g}m": {"neighbours": "radius", "neighbour_radius_m": args.radius},
    }
    results = []
    for agents in (int(a) for a in args.agents.split(",")):
        batch = random_walk_crowd(SCENES, agents, seed=agents)
        row: dict = {"agents": agents}
        for name, graph in graphs.items():
            median, _ = time_steps(graph, batch, args.repeats)
            row[f"{name}_step_s"] = round(median, 4)
            row[f"{name}_edges_per_agent"] = round(edges_per_agent(graph, batch), 2)
        results.append(row)
        print(
            f"{agents} agents: "
            + ", ".join(
                f"{name} {row[f'{name}_step_s']} s/step "
                f"({row[f'{name}_edges_per_agent']} edges/agent)"
                for name in graphs
            ),
            file=sys.stderr,
        )
    print(
        json.dumps(
            {
                "benchmark": "graph",
                "threads": args.threads,
                "scenes": SCENES,
                "steps": STEPS,
                "observed": OBSERVED,
                "repeats": args.repeats,
                "results": results,
            }
        )
    )


if __name__ == "__main__":
    main()
