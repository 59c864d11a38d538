"""The input encoders: the states of a pass's steps -> the embeddings the recurrent core reads.

- F_embed(s_i) of each agent's own state (the node LSTM's input),
- F_self(s_i^t, s_i^t - s_i^{t-1}) of each agent (the self-loop LSTM's input),
- F_interact(s_i, s_j - s_i) of each edge (i, j) of the pass's graph (the edge LSTM's input),

each a linear layer and a ReLU. With agent roles as inputs (`ModelConfig.role_input`) F_embed
and F_self also read the agent's one-hot role, never the edges, so the attention must still find
the relevant car from its motion. The inputs are fixed invertible linear recombinations of the
paper's concatenations, which the first linear layer absorbs (same function class, better
conditioned). Two encoders, chosen by `ModelConfig.frame`:

- `SceneFrameEncoder` (the paper's): positions relative to the scene origin, divided by
  `position_scale_m`; the edges read (s_i, (p_j - p_i) / interaction_scale_m), the self-loop
  (s_i^t, (p^t - p^{t-1}) / step_scale_m); absent agents get zeros.
- `AgentFrameEncoder`: each agent's inputs in its own frame (predictor.agent_frame): own
  position and velocity, and each edge's relative position (and, `edge_velocity`, velocity) of
  j in i's frame, standardised with statistics of the training split (`fit_statistics`, kept as
  buffers in the checkpoint; the paper model's car constants until fitted).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from predictor.agent_frame import own_features, pair_features
from predictor.config import ModelConfig
from predictor.graph import Graph
from predictor.model.pass_inputs import PassInputs
from predictor.model.statistics import MIN_STAT_STD

# agent-frame features, 2 each: own position, own velocity, relative position, relative velocity
NUM_FEATURES = 8


class Encoded(NamedTuple):
    """The embeddings of S steps, time-first."""

    node: Tensor  # (S, B, N, emb) F_embed of each agent's own state
    self_loop: Tensor  # (S, B, N, emb) F_self of each agent's state and step
    edge: Tensor  # (S, E, emb) F_interact of the graph's edges


class SceneFrameEncoder(nn.Module):
    """F_embed, F_self and F_interact on scene-frame inputs (the paper's; see the module
    docstring)."""

    has_statistics = False  # no input statistics to fit: the config's constants

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        emb = config.embed_dim
        roles = max(config.num_roles, 0) if config.role_input else 0  # one-hot role inputs
        self.f_embed = nn.Sequential(nn.Linear(2 + roles, emb), nn.ReLU())
        self.f_self = nn.Sequential(nn.Linear(4 + roles, emb), nn.ReLU())
        edge_in = 6 if config.edge_velocity else 4
        self.f_interact = nn.Sequential(nn.Linear(edge_in, emb), nn.ReLU())
        self.position_scale_m = config.position_scale_m
        self.interaction_scale_m = config.interaction_scale_m
        self.step_scale_m = config.step_scale_m

    def forward(self, pos: Tensor, prev_pos: Tensor, present: Tensor, steps: PassInputs) -> Encoded:
        """The embeddings of S steps of a pass: positions pos (S, B, N, 2) [m], the previous
        ones prev_pos, presence (S, B, N); `steps` gives the pass's origin or frames, graph and
        roles."""
        own, step, x_edge = self.features(pos, prev_pos, present, steps)
        node = own
        if steps.roles is not None:  # one-hot roles (B, N, R) at every step
            role = steps.roles.unsqueeze(0).expand(pos.shape[0], -1, -1, -1)  # (S, B, N, R)
            node = torch.cat([own, role], -1)
            step = torch.cat([step, role], -1)
        x_self = self.f_self(torch.cat([node[..., :2], step], -1))  # (S, B, N, emb)
        return Encoded(self.f_embed(node), x_self, x_edge)

    def features(
        self, pos: Tensor, prev_pos: Tensor, present: Tensor, steps: PassInputs
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Own position (S, B, N, 2) and step (S, B, N, 2) at their scales, zero where absent,
        and the edge embeddings (S, E, emb)."""
        mask = present.unsqueeze(-1)  # (S, B, N, 1)
        rel = (pos - steps.origin[None, :, None]) / self.position_scale_m  # (S, B, N, 2)
        rel = torch.where(mask, rel, torch.zeros_like(rel))  # (S, B, N, 2)
        step = torch.where(mask, (pos - prev_pos) / self.step_scale_m, torch.zeros_like(pos))
        return rel, step, self.edge_inputs(rel, steps.graph)

    def edge_inputs(self, rel: Tensor, graph: Graph) -> Tensor:
        """x_ij = F_interact(concat(s_i, s_j - s_i)) of the graph's edges: (S, B, N, 2) ->
        (S, E, emb).

        s_i is the position at `position_scale_m`, s_j - s_i the offset at `interaction_scale_m`.

        The linear layer is split into a tail part and a head part, evaluated per agent and
        added per edge, which is exact and avoids a matmul over the edges.
        """
        linear = self.f_interact[0]
        gain = self.position_scale_m / self.interaction_scale_m
        w_tail, w_rel = linear.weight[:, :2], linear.weight[:, 2:] * gain  # (E, 2), (E, 2)
        per_tail = F.linear(rel, w_tail - w_rel, linear.bias).flatten(1, 2)  # (S, B*N, emb)
        per_head = F.linear(rel, w_rel).flatten(1, 2)  # (S, B*N, emb)
        summed = graph.at_tail(per_tail) + graph.at_head(per_head)
        return self.f_interact[1](summed)  # (S, E, emb)


class AgentFrameEncoder(SceneFrameEncoder):
    """F_embed, F_self and F_interact on standardised agent-frame inputs (see the module
    docstring)."""

    has_statistics = True

    def __init__(self, config: ModelConfig) -> None:
        super().__init__(config)
        self.standardise = config.standardise
        self.edge_width = 4 if config.edge_velocity else 2  # relative position [, velocity]
        # unfitted: the car constants of the paper model (kept when not standardise)
        scales = [config.position_scale_m] * 2 + [config.step_scale_m] * 2
        scales += [config.interaction_scale_m] * 2 + [config.step_scale_m] * 2
        self.register_buffer("input_mean", torch.zeros(NUM_FEATURES))
        self.register_buffer("input_std", torch.tensor(scales))

    def features(
        self, pos: Tensor, prev_pos: Tensor, present: Tensor, steps: PassInputs
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Standardised agent-frame inputs: own position (S, B, N, 2), own velocity (S, B, N, 2)
        and the edge embeddings x_ij (S, E, emb) of the graph's edges from (own position,
        relative position [, relative velocity]) in agent i's frame; zeros where an agent (of an
        edge: either agent) is absent."""
        frame, graph = steps.frame, steps.graph
        own = own_features(pos, prev_pos, present, frame)  # (S, B, N, 4)
        own = (own - self.input_mean[:4]) / self.input_std[:4]
        own = torch.where(present.unsqueeze(-1), own, 0.0)
        pair = pair_features(pos, prev_pos, present, frame, graph)  # (S, E, 4)
        pair = (pair - self.input_mean[4:]) / self.input_std[4:]
        pair = torch.where(graph.edge_present(present).unsqueeze(-1), pair, 0.0)
        own_per_edge = graph.at_tail(own[..., :2].flatten(1, 2))  # (S, E, 2)
        x_edge = self.f_interact(torch.cat([own_per_edge, pair[..., : self.edge_width]], -1))
        return own[..., :2], own[..., 2:], x_edge

    @torch.no_grad()
    def fit_statistics(self, steps: PassInputs) -> None:
        """With `standardise`: the inputs' means and stds over the present agent-steps and the
        graph's present edges of (training) scenes, as the model sees them (agent frames as in
        `agent_frames`)."""
        if not self.standardise:
            return
        present, graph = steps.present, steps.graph
        own = own_features(steps.pos, steps.prev_pos, present, steps.frame)[present]  # (K, 4)
        pair = pair_features(steps.pos, steps.prev_pos, present, steps.frame, graph)[
            graph.edge_present(present)
        ]  # (K2, 4)
        pair_mean, pair_std = pair.new_zeros(4), pair.new_ones(4)  # no pairs: identity
        if len(pair) >= 2:  # (scenes of one agent have no pairs to measure)
            pair_mean, pair_std = pair.mean(0), pair.std(0)
        self.input_mean.copy_(torch.cat([own.mean(0), pair_mean]))
        std = torch.cat([own.std(0), pair_std])
        self.input_std.copy_(std.clamp(min=MIN_STAT_STD))


def build_encoder(config: ModelConfig) -> SceneFrameEncoder:
    """The input encoder of `config.frame`."""
    return AgentFrameEncoder(config) if config.frame == "agent" else SceneFrameEncoder(config)
