"""The inputs of one pass of the model (`SmoothAttentionPredictor._prepare`): time-first
positions, presence, labels, frames, roles and the pass's neighbour graph."""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor

from predictor.agent_frame import AgentFrame
from predictor.graph import Graph


@dataclass
class PassInputs:
    """Per-step model inputs, time-first."""

    pos: Tensor  # (T, B, N, 2) [m]
    prev_pos: Tensor  # (T, B, N, 2) [m] previous position (current one if absent before)
    prev2_pos: Tensor  # (T, B, N, 2) [m] two steps back (see _prepare for absent agents)
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
