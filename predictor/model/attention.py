"""The attention over the neighbour graph: the weights theta_ij of each agent i over its
neighbours j present at a step (zero for an agent without one), and what it attends to,
sum_j theta_ij o_ij. Three kinds, chosen by `ModelConfig.attention_mode` (the paper's
variants):

- `LearnedAttention` ("learned", Ours): theta_ij = softmax over the present neighbours j of
  <F_attn(o_ii), F_attn(o_ij)>, times `attention_gain`, plus (`role_balanced_attention`, with
  roles) the role-balance prior -log(number of i's present neighbours with j's role) and
  (`role_attention_bias`) the learnt bias of the pair of roles (`RolePairBias`);
- `UniformAttention` ("uniform", Average): equal weights over the present neighbours;
- `OracleAttention` ("oracle", Correct): all weight on the labelled agent where there is one,
  uniform otherwise.

The softmax and sums run over the graph's packed edges (predictor.graph), O(edges).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from predictor.config import ModelConfig
from predictor.graph import Graph, role_balance, segment_softmax, segment_uniform
from predictor.model.pass_inputs import PassInputs


@dataclass
class Presence:
    """Per-step edge terms that depend only on which agents are present."""

    together: Tensor  # (S, E) bool: both agents of the edge present
    prior: Tensor | None  # (S, E) role-balance logit prior of the learned attention, or None


class GraphAttention(nn.Module):
    """What every kind of attention shares: the edges' presence terms and the attended sum."""

    def presence(self, present: Tensor, steps: PassInputs) -> Presence:
        """Which edges of the pass's graph have both agents present at each step, for present
        (S, B, N); the learned attention adds its role-balance prior."""
        return Presence(steps.graph.edge_present(present), None)

    def forward(
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
        learned bias of each edge's pair of roles (`RolePairBias`; the learned attention's)."""
        raise NotImplementedError

    def read(self, theta: Tensor, o_edge: Tensor, graph: Graph) -> Tensor:
        """What each agent attends to, sum_j theta_ij o_ij: (S, E), (S, E, H) -> (S, B*N, H)."""
        return graph.sum_by_tail(theta.unsqueeze(-1) * o_edge)


class LearnedAttention(GraphAttention):
    """F_attn's scores, softmaxed over the present neighbours (see the module docstring)."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.f_attn = nn.Linear(config.edge_hidden, config.attn_dim)
        self.gain = config.attention_gain
        self.role_balanced = config.role_balanced_attention
        self.num_roles = config.num_roles

    def presence(self, present: Tensor, steps: PassInputs) -> Presence:
        """The edges' presence and, with `role_balanced_attention` and roles, the role-balance
        prior over them."""
        together = steps.graph.edge_present(present)  # (S, E)
        prior, roles = None, steps.role_index
        if self.role_balanced and roles is not None:
            prior = role_balance(roles, together, steps.graph, self.num_roles, steps.pos.dtype)
        return Presence(together, prior)

    def forward(
        self,
        o_self: Tensor,
        o_edge: Tensor,
        presence: Presence,
        labels: Tensor | None,
        graph: Graph,
        pair_bias: Tensor | None = None,
    ) -> Tensor:
        # <F_attn(o_ii), W o_ij + b> = <W^T F_attn(o_ii), o_ij> + <F_attn(o_ii), b>; the last
        # term is the same for every j of row i and cancels in the softmax, so F_attn need not
        # be applied to the edge outputs (same theta, far cheaper).
        query = self.f_attn(o_self) @ self.f_attn.weight  # (S, B*N, H)
        scores = graph.dot_with_tail(o_edge, query)  # (S, E)
        if pair_bias is not None:
            scores = scores + pair_bias
        logits = scores * self.gain
        if presence.prior is not None:
            logits = logits + presence.prior
        return segment_softmax(logits, presence.together, graph)


class UniformAttention(GraphAttention):
    """Equal weights over the present neighbours (the Average variant)."""

    def forward(
        self,
        o_self: Tensor,
        o_edge: Tensor,
        presence: Presence,
        labels: Tensor | None,
        graph: Graph,
        pair_bias: Tensor | None = None,
    ) -> Tensor:
        return segment_uniform(presence.together, graph, o_edge.dtype)  # (S, E)


class OracleAttention(GraphAttention):
    """All weight on the labelled neighbour, uniform where there is none (the Correct
    variant)."""

    def forward(
        self,
        o_self: Tensor,
        o_edge: Tensor,
        presence: Presence,
        labels: Tensor | None,
        graph: Graph,
        pair_bias: Tensor | None = None,
    ) -> Tensor:
        together = presence.together
        uniform = segment_uniform(together, graph, o_edge.dtype)  # (S, E)
        label = graph.at_tail(labels.flatten(1, 2))  # (S, E) the tail's label
        onehot = (graph.head_slot() == label) & together  # (S, E)
        labelled = graph.sum_by_tail(onehot.to(uniform.dtype)) > 0  # (S, B*N)
        return torch.where(graph.at_tail(labelled), onehot.to(uniform.dtype), uniform)


class RolePairBias(nn.Module):
    """A learnt bias per pair of roles (attending, attended) on the learned attention's scores
    (`ModelConfig.role_attention_bias`), zero at first."""

    def __init__(self, num_roles: int) -> None:
        super().__init__()
        self.role_pair = nn.Parameter(torch.zeros(num_roles, num_roles))

    def forward(self, steps: PassInputs) -> Tensor | None:
        """The bias of each edge's pair of roles (E,), once a pass (kept in `steps`); None for a
        pass without roles."""
        if steps.role_index is None:
            return None
        if steps.pair_bias is None:
            flat = steps.role_index.flatten()  # (B*N,)
            steps.pair_bias = self.role_pair[flat[steps.graph.tail], flat[steps.graph.head]]
        return steps.pair_bias


def build_attention(config: ModelConfig) -> GraphAttention:
    """The attention of `config.attention_mode`."""
    if config.attention_mode == "learned":
        return LearnedAttention(config)
    return UniformAttention() if config.attention_mode == "uniform" else OracleAttention()


def build_role_bias(config: ModelConfig) -> RolePairBias | None:
    """The role-pair bias where it can act: learned attention over roles (without roles every
    pair is one kind, whose bias the softmax cancels; fixed attention has no scores)."""
    learned = config.attention_mode == "learned"
    if config.role_attention_bias and learned and config.num_roles > 0:
        return RolePairBias(config.num_roles)
    return None
