"""Experiment (issue 10): which of the highway's maps each main car reads, per case, for trained
runs with `attended_fit` "edge_relations" (the agent presets).

Usage: python benchmarks/experiments/map_routing.py FILE.h5 RUN_DIR [RUN_DIR ...]

Under "edge_relations" an agent's highway reading mixes one map per part of its attention: the
attended agent's role group (`highway_head_groups`) and whether it is ahead or behind
(`predictor.highway.edge_relations`), each map refitted every epoch on the training scenes
whose attention falls in that part. So the attention at the last observed step also chooses
which fitted map an agent reads. For each run (its `best.pt`) and main role, this prints per
case of the test split the part holding most of that role's attention (mean share over the
case's scenes), how many of the case's scenes put most of their attention in the part the
other case's scenes use ("routed to the other case's map") and the role's test ADE [m] over
the rolled-out steps in those scenes and in the rest. Not run by `make bench`; docs/PREDICTOR.md
has the figures. The last line of stdout is one JSON object.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from attention_by_case import measure_runs

from predictor.data import TrajectoryDataset
from predictor.evaluation import load_model
from predictor.highway import history_features

MAIN_ROLES = 2  # the synthetic files' first two roles are the main cars


def part_names(model, role_names: tuple[str, ...]) -> list[str]:
    """Names of the 2K attention parts of `edge_relations`, kind-major (ahead, then behind)."""
    if model.num_kinds == 1:
        kinds = ["any"]
    elif not model.config.highway_role_groups:
        kinds = list(role_names)
    else:
        kinds = [f"group {k}" for k in range(model.num_kinds)]
    return [f"{kind} {side}" for kind in kinds for side in ("ahead", "behind")]


def _mean_ade(ade: torch.Tensor, slot: torch.Tensor, scenes: torch.Tensor) -> float | None:
    """Mean of ade (B, N) over the scenes selected by the mask (B,), at each scene's agent slot
    (B,); None where no scene is selected."""
    if not scenes.any():
        return None
    return float(ade[scenes.nonzero().squeeze(1), slot[scenes]].mean())


def _describe(case: str, c: dict) -> str:
    """One case's routing as text."""
    text = f"{case}: {c['part']} {c['share']:.2f}, routed {c['routed']}/{c['scenes']}"
    if c["routed"]:
        text += f" (ADE {c['ade_routed']:.3f} m vs {c['ade_kept']:.3f} m)"
    return text


@torch.no_grad()
def routing(path: Path, run: Path) -> dict:
    """Per main role and case: the dominant attention part, the scenes routed to the other
    case's part, and the role's ADE in routed and in the other scenes."""
    test = TrajectoryDataset(path, "test")
    batch, observed = test.all(), test.meta.num_observed
    model, _ = load_model(run / "best.pt")
    model.eval()
    if model.config.attended_fit != "edge_relations":
        fit = model.config.attended_fit
        raise ValueError(f"{run}: attended_fit is {fit!r}, not 'edge_relations'")
    out = model.predict(batch.positions, batch.valid, observed, batch.attention, batch.roles)
    steps = model._prepare(
        batch.positions, batch.valid, observed, batch.attention, batch.roles, observed
    )
    theta = out.attention[:, observed - 1]  # (B, N, N-1): what the highway reads
    _, usable = history_features(
        steps.pos, steps.present, observed, steps.frame[1], model.config.highway_steps
    )
    edges, mask = model._neighbour_features(steps)
    groups = model._groups_of(steps.role_index, usable)
    _, masses, _, _ = model._edge_relations(groups, theta, edges, mask, False)  # (2K, B, N)
    truth = batch.positions[:, observed:]
    ade = (out.rollout.mean - truth).norm(dim=-1).mean(1)  # (B, N)
    names, scenes = part_names(model, test.meta.role_names), torch.arange(len(batch.roles))
    result: dict = {"run": run.name, "roles": {}}
    for role in range(MAIN_ROLES):
        slot = (batch.roles == role).float().argmax(1)  # (B,) the role's agent in each scene
        share = masses[:, scenes, slot]  # (2K, B)
        dominant = share.argmax(0)  # (B,) each scene's main part
        cases = {}
        case_part = {
            c: int(share[:, batch.case == c].mean(1).argmax())
            for c in range(len(test.meta.case_names))
        }
        for case, name in enumerate(test.meta.case_names):
            here = batch.case == case
            others = {p for c, p in case_part.items() if c != case and p != case_part[case]}
            routed = here & torch.isin(dominant, torch.tensor(sorted(others), dtype=torch.long))
            kept = here & ~routed
            cases[name] = {
                "part": names[case_part[case]],
                "share": float(share[case_part[case], here].mean()),
                "scenes": int(here.sum()),
                "routed": int(routed.sum()),
                "ade_routed": _mean_ade(ade, slot, routed),
                "ade_kept": _mean_ade(ade, slot, kept),
            }
        result["roles"][test.meta.role_names[role]] = cases
    return result


def main() -> None:
    rows = measure_runs(__doc__, routing)
    for row in rows:
        for role, cases in row["roles"].items():
            shown = "; ".join(_describe(case, c) for case, c in cases.items())
            print(f"{row['run']}  {role}  {shown}")
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
