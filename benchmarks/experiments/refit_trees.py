"""The attended highway's per-epoch refit (`refit_attended`) on a dataset's training split, timed
for two code trees in turn (issue 13: a change of the refit against the code before it).

Usage: python benchmarks/experiments/refit_trees.py --data FILE.h5 --trees OLD,NEW
[--rounds 3] [--repeats 3] [--preset agent]

Each round runs one subprocess per tree (so each imports its own `predictor`), one torch thread
and one BLAS thread: it builds the preset's Ours model on the training split as a run does
(`predictor.run_state.build_state`), refits once to warm up and then `--repeats` times, and
prints the median seconds. The trees alternate, so both see the same load. The last line of
stdout is one JSON object: per tree the median over rounds of the per-round medians, and
old / new. A git worktree of the earlier commit serves as OLD (`git worktree add DIR COMMIT`).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

CHILD = """
import json, statistics, sys, time
sys.path.insert(0, {tree!r})
import torch
torch.set_num_threads(1)
import predictor
assert predictor.__file__.startswith({tree!r}), predictor.__file__
from predictor.config import resolve_roles
from predictor.data import TrajectoryDataset
from predictor.presets import make_configs
from predictor.run_state import build_state
train_set = TrajectoryDataset({data!r}, "train")
model_cfg, train_cfg = make_configs("ours", preset={preset!r})
model_cfg = resolve_roles(model_cfg, train_set.meta.role_names)
state = build_state(model_cfg, train_cfg, train_set)
scenes = state.refit_scenes
times = []
for _ in range({repeats} + 1):
    start = time.perf_counter()
    state.model.refit_attended(scenes.positions, scenes.valid, {observed}, scenes.attention,
                               scenes.roles)
    times.append(time.perf_counter() - start)
print(json.dumps(statistics.median(times[1:])))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="dataset file (HDF5)")
    parser.add_argument("--trees", required=True, help="OLD,NEW: two checkouts of the project")
    parser.add_argument("--rounds", type=int, default=3, help="alternations (default 3)")
    parser.add_argument("--repeats", type=int, default=3, help="timed refits per run (default 3)")
    parser.add_argument("--preset", default="agent", help="preset with a refit (default agent)")
    parser.add_argument("--observed", type=int, default=15, help="observed steps (default 15)")
    args = parser.parse_args()
    trees = [os.path.abspath(tree) for tree in args.trees.split(",")]
    if len(trees) != 2 or not all(os.path.isdir(tree) for tree in trees):
        parser.error("--trees takes two existing folders, OLD,NEW")
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    medians: dict[str, list[float]] = {tree: [] for tree in trees}
    for round_index in range(args.rounds):
        for tree in trees:
            code = CHILD.format(
                tree=tree,
                data=os.path.abspath(args.data),
                preset=args.preset,
                repeats=args.repeats,
                observed=args.observed,
            )
            done = subprocess.run(
                [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False
            )
            if done.returncode != 0:
                sys.exit(f"refit_trees: {tree} failed: {done.stderr.strip().splitlines()[-1]}")
            seconds = json.loads(done.stdout.strip().splitlines()[-1])
            medians[tree].append(seconds)
            print(f"round {round_index + 1} {tree}: {seconds:.3f} s per refit", file=sys.stderr)
    old, new = (statistics.median(medians[tree]) for tree in trees)
    print(
        json.dumps(
            {
                "benchmark": "refit_trees",
                "old_s": round(old, 3),
                "new_s": round(new, 3),
                "speedup": round(old / new, 3),
                "rounds": {tree: [round(v, 3) for v in medians[tree]] for tree in trees},
            }
        )
    )


if __name__ == "__main__":
    main()
