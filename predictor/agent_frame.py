"""Agent-centric frames: each agent's origin and heading at its last observed step, rotations
into and out of it, and the agent-frame features the model reads (`frame="agent"`).

Pure tensor geometry, no parameters: `SmoothAttentionPredictor` expresses inputs in these frames
and rotates its outputs (means and Cholesky factors) back to world axes.
"""

from __future__ import annotations

import torch
from torch import Tensor

from predictor.graph import Graph

MIN_HEADING_STEP_M = 1e-3  # [m] below this last displacement the heading is the world x axis

AgentFrame = tuple[Tensor, Tensor]  # origins (B, N, 2) [m], rotations (cos, sin) (B, N, 2)


def rotate(vectors: Tensor, rotation: Tensor, inverse: bool = False) -> Tensor:
    """Rotate (..., B, N, 2) vectors by per-agent (cos, sin) (B, N, 2); `inverse`: by minus."""
    cos, sin = rotation[..., 0], rotation[..., 1]  # (B, N)
    if inverse:
        sin = -sin
    x, y = vectors[..., 0], vectors[..., 1]
    return torch.stack([cos * x - sin * y, sin * x + cos * y], -1)


def rotate_tril(tril: Tensor, rotation: Tensor) -> Tensor:
    """Cholesky entries (l11, l21, l22) of R Sigma R^T from those of Sigma (closed form).

    l22 comes from det(Sigma) = (l11 l22)^2, which rotation keeps, so it stays positive.
    """
    l11, l21, l22 = tril[..., 0], tril[..., 1], tril[..., 2]
    cov = torch.stack(  # L L^T, (..., 2, 2)
        [
            torch.stack([l11 * l11, l11 * l21], -1),
            torch.stack([l11 * l21, l21 * l21 + l22 * l22], -1),
        ],
        -2,
    )
    cos, sin = rotation[..., 0], rotation[..., 1]
    rot = torch.stack([torch.stack([cos, -sin], -1), torch.stack([sin, cos], -1)], -2)
    world = rot @ cov @ rot.transpose(-1, -2)  # (..., 2, 2)
    l11 = world[..., 0, 0].sqrt()
    l21 = world[..., 1, 0] / l11
    l22 = tril[..., 0] * tril[..., 2] / l11
    return torch.stack([l11, l21, l22], -1)


def agent_frames(positions: Tensor, valid: Tensor, num_observed: int) -> AgentFrame:
    """Each agent's frame: origin at its last observed position (first present one if it
    enters later), heading along its displacement into that step (world x if it did not move
    or was absent before). positions (B, T, N, 2), valid (B, T, N)."""
    num_steps = positions.shape[1]
    steps = torch.arange(num_steps, device=positions.device).view(1, -1, 1)  # (1, T, 1)
    observed = valid & (steps < num_observed)  # (B, T, N)
    last = torch.where(observed, steps, -1).amax(1)  # (B, N)
    first = torch.where(valid, steps, num_steps).amin(1).clamp(max=num_steps - 1)  # (B, N)
    anchor = torch.where(last >= 0, last, first)  # (B, N)
    before = (anchor - 1).clamp(min=0)

    def take(index: Tensor) -> Tensor:  # positions at per-agent steps: (B, N) -> (B, N, 2)
        return positions.gather(1, index[:, None, :, None].expand(-1, 1, -1, 2))[:, 0]

    was = valid.gather(1, before[:, None])[:, 0] & (anchor > 0)  # (B, N)
    origin = take(anchor)  # (B, N, 2)
    step = torch.where(was.unsqueeze(-1), origin - take(before), 0.0)  # (B, N, 2)
    length = step.norm(dim=-1, keepdim=True)  # (B, N, 1)
    moving = length > MIN_HEADING_STEP_M
    unit = torch.tensor([1.0, 0.0], dtype=positions.dtype, device=positions.device)
    rotation = torch.where(moving, step / length.clamp(min=MIN_HEADING_STEP_M), unit)
    origin = torch.where(valid.any(1).unsqueeze(-1), origin, 0.0)
    return origin, rotation


def own_features(pos: Tensor, prev_pos: Tensor, present: Tensor, frame: AgentFrame) -> Tensor:
    """Raw own position and velocity of each agent in its frame [m, m/step], (S, B, N, 4);
    inputs time-first (S, B, N, 2)."""
    origin, rotation = frame
    vel = torch.where(present.unsqueeze(-1), pos - prev_pos, 0.0)  # (S, B, N, 2)
    own = rotate(pos - origin, rotation, inverse=True)  # (S, B, N, 2)
    return torch.cat([own, rotate(vel, rotation, inverse=True)], -1)


def pair_features(
    pos: Tensor, prev_pos: Tensor, present: Tensor, frame: AgentFrame, graph: Graph
) -> Tensor:
    """Raw position and velocity of head j relative to tail i, in i's frame [m, m/step], for
    the graph's packed edges: (S, E, 4). Inputs time-first (S, B, N, 2)."""
    rotation = graph.at_tail(frame[1].flatten(0, 1).unsqueeze(0))[0]  # (E, 2) the tail's frame
    vel = torch.where(present.unsqueeze(-1), pos - prev_pos, 0.0).flatten(1, 2)  # (S, B*N, 2)
    flat = pos.flatten(1, 2)  # (S, B*N, 2)
    rel = graph.at_head(flat) - graph.at_tail(flat)  # (S, E, 2)
    rel_vel = graph.at_head(vel) - graph.at_tail(vel)  # (S, E, 2)
    return torch.cat(
        [rotate(rel, rotation, inverse=True), rotate(rel_vel, rotation, inverse=True)], -1
    )
