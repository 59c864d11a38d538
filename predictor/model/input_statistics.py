"""The predictor's input scales: fitted on the training split (`fit_normalisation`, kept as
buffers in the checkpoint) or the paper model's car constants, and the standardised agent-frame
inputs and edge embeddings that use them.

`InputStatistics` is a mixin of `SmoothAttentionPredictor` (predictor.model), which owns the
layers it reads (`f_interact`) and the pass it calls (`_prepare`); the buffers it writes
(`input_mean`, `input_std`) are registered here
(`_register_statistics`, called by the model's constructor). The highway's fit
(`_fit_highway`) is in predictor.highway_maps.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from predictor.agent_frame import AgentFrame, own_features, pair_features
from predictor.config import ModelConfig
from predictor.graph import Graph
from predictor.model.statistics import MIN_STAT_STD

# agent-frame features, 2 each: own position, own velocity, relative position, relative velocity
NUM_FEATURES = 8


class InputStatistics:
    """Input standardisation and scales of `SmoothAttentionPredictor` (see the module
    docstring)."""

    config: ModelConfig

    def _register_statistics(self) -> None:
        """Register the agent frame's input statistics and scales as buffers (kept in the
        checkpoint), at the paper model's car constants until `fit_normalisation`."""
        if self.config.frame != "agent":  # the scene frame uses the config's constants
            return
        self.register_buffer("input_mean", torch.zeros(NUM_FEATURES))
        self.register_buffer("input_std", torch.ones(NUM_FEATURES))
        self._default_normalisation()

    def _agent_inputs(
        self, pos: Tensor, prev_pos: Tensor, present: Tensor, frame: AgentFrame, graph: Graph
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Standardised agent-frame inputs: own position (S, B, N, 2), own velocity (S, B, N, 2)
        and the edge embeddings x_ij (S, E, emb) of the graph's edges from (own position,
        relative position [, relative velocity]) in agent i's frame; zeros where an agent (of an
        edge: either agent) is absent."""
        own = own_features(pos, prev_pos, present, frame)  # (S, B, N, 4)
        own = (own - self.input_mean[:4]) / self.input_std[:4]
        own = torch.where(present.unsqueeze(-1), own, 0.0)
        pair = pair_features(pos, prev_pos, present, frame, graph)  # (S, E, 4)
        pair = (pair - self.input_mean[4:]) / self.input_std[4:]
        pair = torch.where(graph.edge_present(present).unsqueeze(-1), pair, 0.0)
        width = 4 if self.config.edge_velocity else 2
        own_per_edge = graph.at_tail(own[..., :2].flatten(1, 2))  # (S, E, 2)
        x_edge = self.f_interact(torch.cat([own_per_edge, pair[..., :width]], -1))
        return own[..., :2], own[..., 2:], x_edge

    @torch.no_grad()
    def fit_normalisation(
        self,
        positions: Tensor,
        valid: Tensor,
        num_observed: int,
        roles: Tensor | None = None,
        fit_maps: bool = True,
    ) -> None:
        """Set the input means/stds (if `standardise`), the output head's scales
        (`AgentFrameHead.fit_scales`) and the highway's maps from (training) scenes
        (B, T, N, 2), (B, T, N).

        Features are those the model sees (agent frames as in `agent_frames`), over present
        agent-steps (edges: the model's graph, both agents present). With `highway_steps` the
        highway's maps are fitted too (`_fit_highway`; roles (B, N) choose the map where the
        model reads roles); fit_maps=False leaves its maps (not its edge statistics) to
        `refit_attended`, as training does, which replaces them unread.
        """
        if self.config.frame != "agent":
            raise ValueError("fit_normalisation needs frame='agent'")
        no_labels = torch.full(valid.shape, -1, dtype=torch.long)  # labels play no part here
        no_roles = torch.zeros(valid.shape[0], valid.shape[2], dtype=torch.long)  # nor roles
        steps = self._prepare(positions, valid, num_observed, no_labels, no_roles)
        present = steps.present
        if self.config.standardise:  # over present agent-steps and the graph's present edges
            graph = steps.graph
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
        self.head.fit_scales(steps)  # the output's units (predictor.model.head)
        if self.config.highway_steps:
            self._fit_highway(steps, roles, fit_maps)

    def _default_normalisation(self) -> None:
        """Unfitted scales: the car constants of the paper model (used when not standardise)."""
        cfg = self.config
        scales = [cfg.position_scale_m] * 2 + [cfg.step_scale_m] * 2
        scales += [cfg.interaction_scale_m] * 2 + [cfg.step_scale_m] * 2
        with torch.no_grad():
            self.input_std.copy_(torch.tensor(scales))

    def _edge_inputs(self, rel: Tensor, graph: Graph) -> Tensor:
        """x_ij = F_interact(concat(s_i, s_j - s_i)) of the graph's edges: (S, B, N, 2) ->
        (S, E, emb).

        s_i is the position at `position_scale_m`, s_j - s_i the offset at `interaction_scale_m`.

        The linear layer is split into a tail part and a head part, evaluated per agent and
        added per edge, which is exact and avoids a matmul over the edges.
        """
        linear = self.f_interact[0]
        gain = self.config.position_scale_m / self.config.interaction_scale_m
        w_tail, w_rel = linear.weight[:, :2], linear.weight[:, 2:] * gain  # (E, 2), (E, 2)
        per_tail = F.linear(rel, w_tail - w_rel, linear.bias).flatten(1, 2)  # (S, B*N, emb)
        per_head = F.linear(rel, w_rel).flatten(1, 2)  # (S, B*N, emb)
        summed = graph.at_tail(per_tail) + graph.at_head(per_head)
        return self.f_interact[1](summed)  # (S, E, emb)
