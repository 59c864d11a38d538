"""One training step of two code trees in one process, alternating (issue 13: a change of the
model's code against the code before it).

Usage: python benchmarks/experiments/step_trees.py --trees OLD,NEW [--repeats 15]
[--presets paper,agent] [--scenes 8]

Loads each tree's `predictor` package (and its benchmarks/bench_training.py) under its own
module objects, then builds, per tree and preset, the same Ours model (same seed) on the same
synthetic batch (`bench_training.synthetic_batch`: 22 agents, T = 60, 15 observed, 45 fed back;
`--scenes` of them) and times `train_step`, one step of each tree in turn (who goes first
alternating) after two warm-ups, one torch thread. Alternating in one process is what made
small differences measurable with other work on the machine (separate processes see different
load). Prints per preset the median seconds per step of each tree, old / new (of the medians,
and the median of the per-step ratios), and both trees' first-step losses (equal to float
rounding where the change keeps the mathematics). The last line of stdout is one JSON object.
A git worktree of the earlier commit serves as OLD (`git worktree add DIR COMMIT`).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import os
import statistics
import sys
import time
from types import SimpleNamespace

import torch

SCENES, STEPS, AGENTS, OBSERVED = 8, 60, 22, 15  # the paper's batch and window


def load_tree(tree: str) -> SimpleNamespace:
    """The functions a step needs, imported from `tree` (its modules then leave sys.modules,
    so the next tree imports its own; the objects keep their modules' globals)."""
    for name in [n for n in sys.modules if n.split(".")[0] in ("predictor", "bench_training")]:
        del sys.modules[name]
    sys.path[:0] = [tree, os.path.join(tree, "benchmarks")]
    try:
        bench = importlib.import_module("bench_training")
        config = importlib.import_module("predictor.config")
        model = importlib.import_module("predictor.model")
        presets = importlib.import_module("predictor.presets")
        run_state = importlib.import_module("predictor.run_state")
        training = importlib.import_module("predictor.training")
        # the modules a pass imports lazily (type hints only) are loaded now
        importlib.import_module("predictor.pass_inputs")
    finally:
        del sys.path[:2]
    if not model.__file__.startswith(tree):
        raise SystemExit(f"step_trees: {tree} did not provide predictor ({model.__file__})")
    return SimpleNamespace(
        bench=bench,
        resolve_roles=config.resolve_roles,
        Model=model.SmoothAttentionPredictor,
        make_configs=presets.make_configs,
        make_optimizer=run_state.make_optimizer,
        train_step=training.train_step,
    )


def build(code: SimpleNamespace, preset: str, scenes: int):
    """Model, optimiser, batch and training config of one tree."""
    batch = code.bench.synthetic_batch(scenes, STEPS, AGENTS, seed=1)
    focal = torch.zeros(scenes, AGENTS, dtype=torch.bool)
    focal[:, :2] = True  # the scenarios' two scored main cars
    batch = dataclasses.replace(batch, focal=focal)
    model_cfg, train_cfg = code.make_configs("ours", preset=preset)
    model_cfg = code.resolve_roles(model_cfg, code.bench.ROLE_NAMES)
    torch.manual_seed(0)
    model = code.Model(model_cfg)
    if model_cfg.frame == "agent":
        model.fit_normalisation(batch.positions, batch.valid, OBSERVED, batch.roles)
    return model, code.make_optimizer(model, train_cfg), batch, train_cfg


def time_preset(codes: list[SimpleNamespace], preset: str, repeats: int, scenes: int) -> dict:
    runs = [build(code, preset, scenes) for code in codes]
    times: list[list[float]] = [[] for _ in codes]
    losses: list[list[float]] = [[] for _ in codes]
    for step in range(repeats + 2):
        for index in (0, 1) if step % 2 == 0 else (1, 0):  # who goes first alternates too
            code, (model, optimizer, batch, cfg) = codes[index], runs[index]
            torch.manual_seed(step)  # the same rollout samples for both trees
            start = time.perf_counter()
            terms = code.train_step(model, optimizer, batch, OBSERVED, cfg)
            if step >= 2:  # two warm-up steps
                times[index].append(time.perf_counter() - start)
            losses[index].append(terms["loss"])
    old, new = (statistics.median(t) for t in times)
    paired = statistics.median(a / b for a, b in zip(*times, strict=True))
    return {
        "preset": preset,
        "old_s": round(old, 4),
        "new_s": round(new, 4),
        "speedup": round(old / new, 3),
        "paired_speedup": round(paired, 3),  # median of the per-step ratios old / new
        "first_loss": [losses[0][0], losses[1][0]],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", required=True, help="OLD,NEW: two checkouts of the project")
    parser.add_argument("--repeats", type=int, default=15, help="timed steps per tree (15)")
    parser.add_argument("--presets", default="paper,agent", help="comma-separated (paper,agent)")
    parser.add_argument("--scenes", type=int, default=SCENES, help="scenes per batch (8)")
    args = parser.parse_args()
    trees = [os.path.abspath(tree) for tree in args.trees.split(",")]
    if len(trees) != 2 or not all(os.path.isdir(tree) for tree in trees):
        parser.error("--trees takes two existing folders, OLD,NEW")
    torch.set_num_threads(1)
    codes = [load_tree(tree) for tree in trees]
    results = []
    for preset in args.presets.split(","):
        result = time_preset(codes, preset, args.repeats, args.scenes)
        results.append(result)
        print(
            f"{preset}: old {result['old_s']:.3f} s, new {result['new_s']:.3f} s per step "
            f"({result['speedup']:.3f}x, paired {result['paired_speedup']:.3f}x); "
            f"first losses {result['first_loss']}",
            file=sys.stderr,
        )
    print(json.dumps({"benchmark": "step_trees", "trees": trees, "results": results}))


if __name__ == "__main__":
    main()
