"""Experiment (issue 10): each main car's attention on the other at the last observed step, per
case, for trained runs: whether the attention reads the other car or switches by case.

Usage: python benchmarks/experiments/attention_by_case.py FILE.h5 RUN_DIR [RUN_DIR ...]

The highway reads the attention at the last observed step (docs/PREDICTOR.md); on Halting Car
v1 the agent preset's follower put ~0.00 on the leader in one case and ~1.00 in the other (a
switch between maps fitted per case), which the attention metric, counting only the labelled
interaction period, does not show. For each run (its `best.pt`), prints the mean weight of main
role 0 on main role 1 and of role 1 on role 0 over the test scenes of each case. Not run by
`make bench`; docs/PREDICTOR.md has the figures. The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

import torch

from predictor.data import TrajectoryDataset
from predictor.evaluation import load_model
from predictor.outputs import expand_attention

MAIN_ROLES = 2  # the synthetic files' first two roles are the main cars


@torch.no_grad()
def weights_by_case(path: Path, run: Path) -> dict:
    """Mean attention of each main role on the other at the last observed step, per case."""
    test = TrajectoryDataset(path, "test")
    batch, observed = test.all(), test.meta.num_observed
    model, _ = load_model(run / "best.pt")
    model.eval()
    out = model.predict(batch.positions, batch.valid, observed, batch.attention, batch.roles)
    attention = expand_attention(out.attention[:, observed - 1])  # (B, N, N)
    scenes = torch.arange(len(batch.roles))
    slot = [(batch.roles == role).float().argmax(1) for role in range(MAIN_ROLES)]  # (B,) each
    names = test.meta.role_names
    result: dict = {"run": run.name, "weights": {}}
    for source, target in ((0, 1), (1, 0)):
        weight = attention[scenes, slot[source], slot[target]]  # (B,)
        result["weights"][f"{names[source]} on {names[target]}"] = {
            name: float(weight[batch.case == case].mean())
            for case, name in enumerate(test.meta.case_names)
        }
    return result


def measure_runs(doc: str, measure: Callable[[Path, Path], dict]) -> list[dict]:
    """The command line FILE.h5 RUN_DIR... of these experiments: `measure(file, run)` of each
    run, one torch thread; a missing or unusable input exits 2 with one line."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("file", type=Path, help="trajectory file (HDF5) the runs trained on")
    parser.add_argument("runs", nargs="+", type=Path, help="run directories (with best.pt)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    try:
        return [measure(args.file, run) for run in args.runs]
    except (OSError, ValueError) as error:
        print(f"{parser.prog}: {error}", file=sys.stderr)
        raise SystemExit(2) from None


def main() -> None:
    rows = measure_runs(__doc__, weights_by_case)
    for row in rows:
        shown = "; ".join(
            f"{pair}: " + ", ".join(f"{case} {w:.2f}" for case, w in cases.items())
            for pair, cases in row["weights"].items()
        )
        print(f"{row['run']}  {shown}")
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
