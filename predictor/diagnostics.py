"""Why a predictor fails: error per predicted step, one-step error, counterfactual sensitivity.

- `error_curve`: mean displacement [m] at each predicted step; a curve growing like k^2 is the
  signature of a drifting (integrated) output offset, a flat one of a constant bias.
- `one_step_errors`: the teacher-forced one-step error of a model over the predicted window next
  to the true one-step deviation from constant velocity (what a model that has learnt nothing
  but the constant-velocity prior would score). A model whose one-step error is not below that
  has not learnt the dynamics, whatever its rollout error.
- `counterfactual_shift`: how far an attending agent's prediction moves [m, mean over the
  predicted steps] when the observed history of the agent it attends to (its label) is replaced
  by that agent slot's history from another scene, next to the same swap of a distractor. An
  interaction pathway that carries information moves the prediction more for the labelled car.

"Main agents" are the focal agents of each scene (the data's `focal` mask, see
`predictor.metrics`); "distractors" are the others.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from predictor.label_slots import scene_labels
from predictor.metrics import focal_slots, focal_view, prediction_mask
from predictor.model import SmoothAttentionPredictor
from trajectory_data.torch_dataset import Batch

# (states (n, T, N, C), valid (n, T, N)) -> predicted means (n, T_pred, N, 2) [m]
Predict = Callable[[np.ndarray, np.ndarray], np.ndarray]


def error_curve(
    pred: np.ndarray, true: np.ndarray, mask: np.ndarray, agents: slice
) -> list[float | None]:
    """Mean displacement [m] per predicted step over the agents `agents` where `mask` holds.

    pred, true (n, T_pred, N, 2); mask (n, T_pred, N). None at a step where nothing counts.
    """
    dist = np.linalg.norm(pred[:, :, agents] - true[:, :, agents], axis=-1)  # (n, T_pred, A)
    keep = mask[:, :, agents]
    totals, counts = np.where(keep, dist, 0.0).sum(axis=(0, 2)), keep.sum(axis=(0, 2))
    return [float(t / c) if c else None for t, c in zip(totals, counts, strict=True)]


def error_curves(
    pred: np.ndarray, true: np.ndarray, valid: np.ndarray, num_observed: int, focal: np.ndarray
) -> dict:
    """`error_curve` of the focal (main) agents (focal (n, N)) and of all agents:
    {"main_agents": [...], "all_agents": [...]}."""
    mask = prediction_mask(valid, num_observed)
    return {
        "main_agents": error_curve(*focal_view(pred, true, mask, focal), slice(None)),
        "all_agents": error_curve(pred, true, mask, slice(None)),
    }


def _mean_over(dist: torch.Tensor, mask: torch.Tensor) -> float | None:
    count = int(mask.sum())
    return float((dist * mask).sum() / count) if count else None


@torch.no_grad()
def one_step_errors(
    model: SmoothAttentionPredictor, batch: Batch, num_observed: int, batch_size: int = 32
) -> dict:
    """Teacher-forced one-step error [m] over the predicted window (targets t = T_obs .. T-1,
    agent present at t-1 and t) and the constant-velocity one-step error on the same items
    (the true deviation |p^t - 2 p^{t-1} + p^{t-2}|, where t-2 is present too), per agent group
    (`main_agents`: the batch's focal agents, which it must have).
    """
    if batch.focal is None:
        raise ValueError("one_step_errors needs the focal mask of the batch")
    model.eval()
    positions, valid = batch.positions, batch.valid
    dists = []
    for start in range(0, batch.batch_size, batch_size):
        part = slice(start, start + batch_size)
        roles = None if batch.roles is None else batch.roles[part]
        out = model(
            positions[part], valid[part], num_observed, batch.attention[part], False, roles=roles
        )
        dists.append((out.one_step.mean - positions[part, 1:]).norm(dim=-1))  # (b, T-1, N)
    model_dist = torch.cat(dists)[:, num_observed - 1 :]  # targets t = T_obs .. T-1
    target = positions[:, num_observed:]
    prior = 2 * positions[:, num_observed - 1 : -1] - positions[:, num_observed - 2 : -2]
    cv_dist = (prior - target).norm(dim=-1)  # (n, T_pred, N)
    mask = valid[:, num_observed:] & valid[:, num_observed - 1 : -1]
    mask = mask & valid[:, num_observed - 2 : -2]
    slots, present = (torch.from_numpy(a) for a in focal_slots(batch.focal.numpy()))
    index = slots.unsqueeze(1).expand(-1, mask.shape[1], -1)  # (n, T_pred, K)
    groups = {
        "main_agents": (
            model_dist.gather(2, index),
            cv_dist.gather(2, index),
            mask.gather(2, index) & present.unsqueeze(1),
        ),
        "all_agents": (model_dist, cv_dist, mask),
    }
    result = {}
    for group, (model_part, cv_part, keep) in groups.items():
        keep = keep.to(model_dist.dtype)
        result[group] = {
            "model_m": _mean_over(model_part, keep),
            "const_vel_m": _mean_over(cv_part, keep),
        }
    return result


def swap_history(
    states: np.ndarray, valid: np.ndarray, agent: np.ndarray, num_observed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Copies of (states (n, T, N, C), valid (n, T, N)) where, in each scene b with
    agent[b] >= 0, that agent's observed states and validity (t < T_obs) are those of the same
    slot in scene (b + 1) mod n."""
    states, valid = states.copy(), valid.copy()
    rows = np.flatnonzero(agent >= 0)
    slots, donors = agent[rows], (rows + 1) % states.shape[0]
    states[rows, :num_observed, slots] = states[donors, :num_observed, slots]
    valid[rows, :num_observed, slots] = valid[donors, :num_observed, slots]
    return states, valid


def counterfactual_shift(
    predict: Predict,
    states: np.ndarray,
    valid: np.ndarray,
    attention: np.ndarray,
    num_observed: int,
    focal: np.ndarray,
) -> dict:
    """Mean shift [m] of each focal (main) agent's prediction when its labelled car's observed
    history is swapped with another scene's ("labelled_m"), and when a distractor's is
    ("distractor_m": the (b mod D)-th of the D non-focal slots of scene b, in slot order, the
    next one where that is the labelled car).

    `predict(states, valid)` returns the predicted means (n, T_pred, N, 2) of the scenes;
    states (n, T, N, C), valid (n, T, N), attention labels (n, T, N), focal (n, N). A (scene,
    main agent) pair counts where the agent has a label, the scene has at least two non-focal
    slots and the swapped agent is present at the last observed step in both scenes. None where
    nothing counts (fewer than 2 scenes, say).
    """
    n = valid.shape[0]
    none = {"labelled_m": None, "distractor_m": None, "pairs": 0}
    others = (~focal).sum(axis=1)  # (n,) non-focal slots per scene
    if n < 2 or not (others >= 2).any():
        return none
    base = predict(states, valid)  # (n, T_pred, N, 2)
    labels = scene_labels(attention)  # (n, N)
    last = valid[:, num_observed - 1]  # (n, N)
    both = last & np.roll(last, -1, axis=0)  # present at T_obs-1 here and in the donor scene
    rows, span = np.arange(n), np.maximum(others, 1)
    order = np.argsort(focal, axis=1, kind="stable")  # (n, N): non-focal slots first
    slots, present = focal_slots(focal)  # (n, K)
    shifts: dict[str, list[float]] = {"labelled": [], "distractor": []}
    for rank in range(slots.shape[1]):
        main = slots[:, rank]  # (n,) the rank-th focal slot of each scene
        labelled = labels[rows, main]
        pick = rows % span
        distractor = order[rows, pick]
        clash = distractor == labelled
        distractor[clash] = order[rows[clash], (pick[clash] + 1) % span[clash]]
        ok = present[:, rank] & (others >= 2) & (labelled >= 0) & last[rows, main]
        ok &= both[rows, np.maximum(labelled, 0)] & both[rows, distractor]
        if not ok.any():
            continue
        for name, agent in (("labelled", labelled), ("distractor", distractor)):
            moved = predict(*swap_history(states, valid, np.where(ok, agent, -1), num_observed))
            dist = np.linalg.norm(moved[rows, :, main] - base[rows, :, main], axis=-1)  # (n, P)
            shifts[name].extend(dist[ok].mean(axis=1).tolist())
    if not shifts["labelled"]:
        return none
    return {
        "labelled_m": float(np.mean(shifts["labelled"])),
        "distractor_m": float(np.mean(shifts["distractor"])),
        "pairs": len(shifts["labelled"]),
    }
