"""One training step on the paper's batch, the complete graph's dense path against the packed
path it replaced (issue 13).

Usage: python benchmarks/bench_training_step.py [--repeats 15] [--presets paper,agent]

`train_step` (forward with the sampled rollout, the loss, backward, Adam) on 8 synthetic scenes
of 22 agents (T = 60, 15 observed, 45 fed back; `bench_training.synthetic_batch`), one torch
thread, for each preset: the same model and batch with the graph's per-edge operations on
their dense path (`predictor.graph.Graph.complete`, the default for a complete graph) and on
the packed path (index_select / index_add, the implementation before; the flag off), one step
of each in turn so both see the same load, after two warm-up steps each. Prints, per preset,
the median seconds per step of each path and their ratio `training_speedup` (packed / dense),
and the two paths' first-step losses (equal to float rounding). The last line of stdout is
one JSON object.

Both paths run the same code otherwise, so the ratio is what the dense path gives; what the
rest of that change gave (the rollout's presence terms and role-pair bias computed once a
pass) is in benchmarks/README.md, measured against the previous commit.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_training import ROLE_NAMES, synthetic_batch  # noqa: E402

import predictor.model.pass_inputs  # noqa: E402
from predictor.config import resolve_roles  # noqa: E402
from predictor.graph import neighbour_graph  # noqa: E402
from predictor.model import SmoothAttentionPredictor  # noqa: E402
from predictor.presets import make_configs  # noqa: E402
from predictor.run_state import make_optimizer  # noqa: E402
from predictor.training import train_step  # noqa: E402

SCENES, STEPS, AGENTS, OBSERVED = 8, 60, 22, 15  # the paper's batch and window


def packed_graph(*args, **kwargs):
    """`neighbour_graph` with the dense path switched off (the packed operations)."""
    return dataclasses.replace(neighbour_graph(*args, **kwargs), complete=False)


def time_preset(preset: str, repeats: int) -> dict:
    """Median step seconds of the dense and the packed path, alternating."""
    batch = synthetic_batch(SCENES, STEPS, AGENTS, seed=1)
    focal = torch.zeros(SCENES, AGENTS, dtype=torch.bool)
    focal[:, :2] = True  # the scenarios' two scored main cars
    batch = dataclasses.replace(batch, focal=focal)
    model_cfg, train_cfg = make_configs("ours", preset=preset)
    model_cfg = resolve_roles(model_cfg, ROLE_NAMES)
    paths = {"dense": neighbour_graph, "packed": packed_graph}
    runs = {}
    for name in paths:
        torch.manual_seed(0)
        model = SmoothAttentionPredictor(model_cfg)
        if model_cfg.frame == "agent":
            model.fit_normalisation(batch.positions, batch.valid, OBSERVED, batch.roles)
        runs[name] = (model, make_optimizer(model, train_cfg), [], [])
    for step in range(repeats + 2):
        for name, (model, optimizer, times, losses) in runs.items():
            predictor.model.pass_inputs.neighbour_graph = paths[name]
            torch.manual_seed(step)  # the same rollout samples for both paths
            start = time.perf_counter()
            terms = train_step(model, optimizer, batch, OBSERVED, train_cfg)
            if step >= 2:  # two warm-up steps
                times.append(time.perf_counter() - start)
            losses.append(terms["loss"])
    predictor.model.pass_inputs.neighbour_graph = neighbour_graph
    dense, packed = (statistics.median(runs[name][2]) for name in ("dense", "packed"))
    return {
        "preset": preset,
        "dense_step_s": round(dense, 4),
        "packed_step_s": round(packed, 4),
        "training_speedup": round(packed / dense, 3),
        "first_loss_dense": runs["dense"][3][0],
        "first_loss_packed": runs["packed"][3][0],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="timed steps per path")
    parser.add_argument("--presets", default="paper,agent", help="comma-separated presets")
    args = parser.parse_args()
    torch.set_num_threads(1)
    results = []
    for preset in args.presets.split(","):
        result = time_preset(preset, args.repeats)
        results.append(result)
        print(
            f"preset={preset}: dense {result['dense_step_s']} s, packed "
            f"{result['packed_step_s']} s per step, speedup {result['training_speedup']}x",
            file=sys.stderr,
        )
    speedups = [r["training_speedup"] for r in results]
    summary = {
        "benchmark": "training_step",
        "threads": 1,
        "scenes": SCENES,
        "steps": STEPS,
        "agents": AGENTS,
        "observed": OBSERVED,
        "results": results,
        "training_speedup": round(statistics.geometric_mean(speedups), 3),
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
