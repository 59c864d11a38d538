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
    # (cos x - sin y, sin x + cos y) = (x, y) cos + (y, x) (-sin, sin): the same products and
    # sums (bit for bit), in 4 differentiable ops instead of 9 (the rollout rotates ~260 times
    # a training pass)
    cos, sin = rotation[..., :1], rotation[..., 1:]  # (B, N, 1)
    signed = torch.cat([sin, -sin] if inverse else [-sin, sin], -1)  # (B, N, 2)
    return vectors * cos + vectors.flip(-1) * signed


def rotate_tril(tril: Tensor, rotation: Tensor) -> Tensor:
    """Cholesky entries (l11, l21, l22) of R Sigma R^T from those of Sigma (closed form).

    l22 comes from det(Sigma) = (l11 l22)^2, which rotation keeps, so it stays positive.
    """
    # R L's columns (p, q) with q = l22 (-sin, cos): R Sigma R^T = p p^T + q q^T, so its
    # (1, 1) entry is p_x^2 + sin^2 l22^2 and its (2, 1) entry p_x p_y - sin cos l22^2
    # (closed form; fewer and cheaper ops than the 2 x 2 products it replaced)
    l11, l22 = tril[..., 0], tril[..., 2]
    p = rotate(tril[..., :2], rotation)  # (..., 2): R (l11, l21)
    cos, sin = rotation[..., 0], rotation[..., 1]
    l22_squared = l22 * l22
    world_11 = p[..., 0] * p[..., 0] + (sin * sin) * l22_squared
    world_21 = p[..., 0] * p[..., 1] - (sin * cos) * l22_squared
    new_l11 = world_11.sqrt()
    return torch.stack([new_l11, world_21 / new_l11, l11 * l22 / new_l11], -1)


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
    both = torch.stack([pos - origin, vel], -2)  # (S, B, N, 2 vectors, 2)
    return rotate(both, rotation.unsqueeze(-2), inverse=True).flatten(-2)  # one rotation


def pair_features(
    pos: Tensor, prev_pos: Tensor, present: Tensor, frame: AgentFrame, graph: Graph
) -> Tensor:
    """Raw position and velocity of head j relative to tail i, in i's frame [m, m/step], for
    the graph's packed edges: (S, E, 4). Inputs time-first (S, B, N, 2)."""
    rotation = graph.at_tail(frame[1].flatten(0, 1).unsqueeze(0))[0]  # (E, 2) the tail's frame
    vel = torch.where(present.unsqueeze(-1), pos - prev_pos, 0.0)  # (S, B, N, 2)
    both = torch.cat([pos, vel], -1).flatten(1, 2)  # (S, B*N, 4): one gather per end
    rel = (graph.at_head(both) - graph.at_tail(both)).unflatten(-1, (2, 2))  # (S, E, 2, 2)
    return rotate(rel, rotation.unsqueeze(-2), inverse=True).flatten(-2)
