"""The model's attention over its neighbour graph: the learned, uniform or oracle weights
theta_ij of each agent over its present neighbours, with the learned attention's role-pair bias
and role-balance prior (`ModelConfig.role_attention_bias`, `role_balanced_attention`).

`GraphAttention` is a mixin of `SmoothAttentionPredictor` (predictor.model), which owns the
layers it reads (`f_attn`, `role_pair`) and the role groups (`_groups_of`, predictor.highway_maps).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from predictor.config import ModelConfig
from predictor.graph import Graph, role_balance, segment_softmax, segment_uniform

if TYPE_CHECKING:
    from predictor.model.pass_inputs import PassInputs as _Steps


@dataclass
class Presence:
    """Per-step edge terms that depend only on which agents are present."""

    together: Tensor  # (S, E) bool: both agents of the edge present
    prior: Tensor | None  # (S, E) role-balance logit prior of the learned attention, or None


class GraphAttention:
    """Attention of `SmoothAttentionPredictor` over the graph's edges (see the module
    docstring)."""

    config: ModelConfig

    def _attention(
        self,
        o_self: Tensor,
        o_edge: Tensor,
        presence: Presence,
        labels: Tensor | None,
        graph: Graph,
        pair_bias: Tensor | None = None,
    ) -> Tensor:
        """theta (S, E) of each agent over its graph neighbours present at the step
        (`presence.together` (S, E): both ends present); an agent without one gets zeros.
        o_self (S, B*N, H), o_edge (S, E, H), labels (S, B, N) (oracle), pair_bias (E,) the
        learned bias of each edge's pair of roles (`role_attention_bias`)."""
        mode = self.config.attention_mode
        together = presence.together
        if mode == "learned":
            # <F_attn(o_ii), W o_ij + b> = <W^T F_attn(o_ii), o_ij> + <F_attn(o_ii), b>; the
            # last term is the same for every j of row i and cancels in the softmax, so F_attn
            # need not be applied to the edge outputs (same theta, far cheaper).
            query = self.f_attn(o_self) @ self.f_attn.weight  # (S, B*N, H)
            scores = graph.dot_with_tail(o_edge, query)  # (S, E)
            if pair_bias is not None:
                scores = scores + pair_bias
            logits = scores * self.config.attention_gain
            if presence.prior is not None:
                logits = logits + presence.prior
            return segment_softmax(logits, together, graph)
        uniform = segment_uniform(together, graph, o_edge.dtype)  # (S, E)
        if mode == "uniform":
            return uniform
        label = graph.at_tail(labels.flatten(1, 2))  # (S, E) the tail's label
        onehot = (graph.head_slot() == label) & together  # (S, E)
        labelled = graph.sum_by_tail(onehot.to(uniform.dtype)) > 0  # (S, B*N)
        return torch.where(graph.at_tail(labelled), onehot.to(uniform.dtype), uniform)

    def _presence(self, present: Tensor, steps: _Steps) -> Presence:
        """Which edges have both agents present at each step, and the learned attention's
        role-balance prior over them (`role_balanced_attention`), for present (S, B, N)."""
        together = steps.graph.edge_present(present)  # (S, E)
        prior = None
        roles = steps.role_index
        cfg = self.config
        if cfg.attention_mode == "learned" and cfg.role_balanced_attention and roles is not None:
            prior = role_balance(roles, together, steps.graph, cfg.num_roles, steps.pos.dtype)
        return Presence(together, prior)

    def _pair_bias(self, steps: _Steps) -> Tensor | None:
        """The learned bias of each edge's pair of roles (E,) (`role_attention_bias`), once a
        pass (kept in `steps`); None without it."""
        if self.role_pair is None or steps.role_index is None:
            return None
        if steps.pair_bias is None:
            flat = steps.role_index.flatten()  # (B*N,)
            steps.pair_bias = self.role_pair[flat[steps.graph.tail], flat[steps.graph.head]]
        return steps.pair_bias
