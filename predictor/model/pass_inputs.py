"""The inputs of one pass of the model (`prepare_pass`): time-first positions, the previous
positions the inputs difference against, presence, labels, frames, roles and the pass's
neighbour graph (predictor.graph), which every part of the model reads."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from predictor.agent_frame import AgentFrame, agent_frames
from predictor.config import ModelConfig
from predictor.graph import Graph, neighbour_graph


@dataclass
class PassInputs:
    """Per-step model inputs, time-first."""

    pos: Tensor  # (T, B, N, 2) [m]
    prev_pos: Tensor  # (T, B, N, 2) [m] previous position (current one if absent before)
    present: Tensor  # (T, B, N) bool
    labels: Tensor | None  # (T, B, N) int64 attention labels, -1 none
    origin: Tensor  # (B, 2) [m]
    num_observed: int
    frame: AgentFrame | None = None  # agent frames (frame="agent") or None (scene frame)
    roles: Tensor | None = None  # (B, N, R) one-hot agent roles (num_roles > 0) or None
    role_index: Tensor | None = None  # (B, N) int64 agent roles (num_roles > 0) or None
    scenes: Tensor | None = None  # (B,) int64 training-split indices (cross-fitted highway)
    graph: Graph | None = None  # the pass's neighbour graph (fixed over its steps)
    pair_bias: Tensor | None = None  # (E,) the role-pair attention bias, once computed


def scene_origin(positions: Tensor, valid: Tensor, step: int) -> Tensor:
    """Mean position [m] of the agents present at `step` (zeros if none): (B, T, N, 2) -> (B, 2)."""
    mask = valid[:, step].unsqueeze(-1).to(positions.dtype)  # (B, N, 1)
    total = (positions[:, step] * mask).sum(dim=1)  # (B, 2)
    return total / mask.sum(dim=1).clamp(min=1.0)  # (B, 2)


def prepare_pass(
    config: ModelConfig,
    positions: Tensor,
    valid: Tensor,
    num_observed: int,
    labels: Tensor | None,
    roles: Tensor | None,
    graph_steps: int | None = None,
) -> PassInputs:
    """A batch (B, T, N, .) as the time-first inputs of a pass of a model with `config`, after
    checking that the batch has what the model reads (a ValueError if not), with the pass's
    neighbour graph of the configured kind, chosen from the first `graph_steps` steps (None:
    all; a prediction reads only the observed ones).

    An agent absent at t-1 takes its current position as the previous one (zero velocity); two
    steps back is the position there where the agent was present then and since, else the one
    that makes the acceleration p^t - 2 p^{t-1} + p^{t-2} zero.
    """
    num_steps = positions.shape[1]
    if not 1 <= num_observed < num_steps:
        raise ValueError(f"num_observed must be in [1, {num_steps - 1}], got {num_observed}")
    if config.attention_mode == "oracle" and labels is None:
        raise ValueError("oracle attention needs attention labels")
    role_inputs = None
    if config.num_roles > 0:
        if roles is None:
            raise ValueError("this model reads agent roles; the data has none")
        if int(roles.max()) >= config.num_roles or int(roles.min()) < 0:
            raise ValueError(f"agent roles must be in [0, {config.num_roles - 1}]")
        role_inputs = F.one_hot(roles.long(), config.num_roles).to(positions.dtype)
    pos = positions.transpose(0, 1)  # (T, B, N, 2)
    present = valid.transpose(0, 1)  # (T, B, N)
    prev_pos = torch.cat([pos[:1], pos[:-1]], 0)  # (T, B, N, 2)
    prev_present = torch.cat([present[:1], present[:-1]], 0)  # (T, B, N)
    prev_pos = torch.where(prev_present.unsqueeze(-1), prev_pos, pos)  # (T, B, N, 2)
    return PassInputs(
        pos=pos,
        prev_pos=prev_pos,
        present=present,
        labels=None if labels is None else labels.transpose(0, 1).long(),  # (T, B, N)
        origin=scene_origin(positions, valid, num_observed - 1),  # (B, 2)
        num_observed=num_observed,
        frame=agent_frames(positions, valid, num_observed) if config.frame == "agent" else None,
        roles=role_inputs if config.role_input else None,
        role_index=None if role_inputs is None else roles.long(),
        graph=neighbour_graph(
            positions[:, :graph_steps],
            valid[:, :graph_steps],
            num_observed,
            config.neighbours,
            config.neighbour_radius_m,
            config.neighbour_k,
        ),
    )
