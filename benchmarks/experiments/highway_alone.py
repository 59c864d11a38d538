"""Experiment (issue 10): the highway alone, per main role and case, under several presets.

Usage: python benchmarks/experiments/highway_alone.py FILE.h5 [FILE.h5 ...]
       [--presets agent,agent_zero_cv] [--seed 0]

For each file and preset, builds the Ours model as training does (`build_state`: the training
split's normalisation and the highway's first fit), refits the highway's maps with the
untrained model's attention as the first epoch does (`refit_attended`), and predicts the test
split with the highway alone: constant velocity plus the highway's velocity changes, no
network. Printed per case: the test ADE [m] of each main role and of all agents present over
the whole window, with constant velocity's beside it, and which of the maps chose the form that
is zero at constant velocity (`ModelConfig.highway_zero_at_cv`; a fitted map with bias exactly
zero). Not run by `make bench`; docs/PREDICTOR.md has the figures. The last line of stdout is one
JSON object.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from predictor.config import resolve_roles
from predictor.data import TrajectoryDataset
from predictor.presets import PRESETS, make_configs
from predictor.run_state import build_state

MAIN_ROLES = 2  # the synthetic files' first two roles are the main cars


@torch.no_grad()
def highway_alone(path: Path, preset: str, seed: int) -> dict:
    """Test ADE of the highway alone and of constant velocity, per case and main role."""
    train, test = TrajectoryDataset(path, "train"), TrajectoryDataset(path, "test")
    model_cfg, train_cfg = make_configs("ours", preset=preset, seed=seed, threads=1)
    model_cfg = resolve_roles(model_cfg, train.meta.role_names)
    state = build_state(model_cfg, train_cfg, train)
    model, observed = state.model.eval(), train.meta.num_observed
    if state.refit_scenes is not None:  # the first epoch's refit
        scenes = state.refit_scenes
        model.refit_attended(
            scenes.positions, scenes.valid, observed, scenes.attention, scenes.roles
        )
    batch = test.all()
    steps = model._prepare(batch.positions, batch.valid, observed, batch.attention, batch.roles)
    theta = model._block(steps, 0, observed, None).attention[-1]
    change = model._highway(steps, theta)  # (B, N, horizon, 2), world axes
    pos = batch.positions  # (B, T, N, 2)
    ahead = min(pos.shape[1] - observed, change.shape[2])
    k = torch.arange(1, ahead + 1, dtype=pos.dtype).view(1, -1, 1, 1)
    last, velocity = pos[:, observed - 1], pos[:, observed - 1] - pos[:, observed - 2]
    constant = last.unsqueeze(1) + k * velocity.unsqueeze(1)  # (B, ahead, N, 2)
    highway = constant + change[:, :, :ahead].cumsum(2).permute(0, 2, 1, 3)
    truth = pos[:, observed : observed + ahead]
    errors = {
        "highway": (highway - truth).norm(dim=-1).mean(1),  # (B, N)
        "const_vel": (constant - truth).norm(dim=-1).mean(1),
    }
    whole = batch.valid.all(1)  # (B, N)
    result: dict = {"file": path.name, "preset": preset, "cases": {}}
    for case, name in enumerate(test.meta.case_names):
        of_case = whole & (batch.case == case).unsqueeze(1)
        groups = {test.meta.role_names[r]: of_case & (batch.roles == r) for r in range(MAIN_ROLES)}
        groups["all agents"] = of_case
        result["cases"][name] = {
            group: {kind: float(err[rows].mean()) for kind, err in errors.items()}
            for group, rows in groups.items()
            if rows.any()
        }
    fitted = model.highway_weight.flatten(1).any(1)
    result["zero_form_maps"] = [
        int(i) for i in torch.nonzero(fitted & ~model.highway_bias.flatten(1).any(1)).flatten()
    ]
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", type=Path, help="trajectory files (HDF5)")
    parser.add_argument(
        "--presets",
        default="agent,agent_zero_cv",
        help="comma-separated presets (default agent,agent_zero_cv)",
    )
    parser.add_argument("--seed", type=int, default=0, help="model seed (default 0)")
    args = parser.parse_args()
    presets = args.presets.split(",")
    unknown = sorted(set(presets) - set(PRESETS))
    if unknown:
        parser.error(f"unknown presets {unknown}; choose from {sorted(PRESETS)}")
    torch.set_num_threads(1)
    rows = [highway_alone(path, preset, args.seed) for path in args.files for preset in presets]
    for row in rows:
        print(f"{row['file']}  {row['preset']}  zero-form maps {row['zero_form_maps']}")
        for case, groups in row["cases"].items():
            shown = ", ".join(
                f"{group} {v['highway']:.3f} (cv {v['const_vel']:.3f})"
                for group, v in groups.items()
            )
            print(f"  {case}: {shown}")
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
