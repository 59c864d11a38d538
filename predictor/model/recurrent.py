"""The recurrent core: the LSTMs of the graph's edges, self-loops and nodes.

- `EdgeRecurrence`: o_ij = G_interact(x_ij) over each edge (i, j) of the pass's graph and
  o_ii = G_self(x_ii) over each agent's self-loop (each edge and agent keeps its state across
  the steps of a pass, so the graph is fixed per pass);
- `NodeRecurrence`: o_i = G_pred(F_embed(s_i), sum_j theta_ij o_ij, o_ii), after the attention.

Two parts, because the attention sits between them (and its F_attn is initialised between
them, which the random initialisation's order keeps). All are one-layer, unidirectional,
time-first LSTMs, run through `run_lstm`.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor, nn

from predictor.config import ModelConfig
from predictor.outputs import LSTMState


def run_lstm(lstm: nn.LSTM, inputs: Tensor, state: LSTMState | None) -> tuple[Tensor, LSTMState]:
    """`lstm(inputs, state)` for the model's one-layer, unidirectional, time-first LSTMs
    without nn.LSTM.forward's Python-level checks: the same op (`torch.lstm`) on the same
    weights, so the same outputs and gradients. The rollout calls its three LSTMs once per
    step (156 calls a training step), where those checks cost ~4 % of the step."""
    if state is None:  # nn.LSTM's zero initial state
        zeros = inputs.new_zeros(1, inputs.shape[1], lstm.hidden_size)
        state = (zeros, zeros)
    weights = [lstm.weight_ih_l0, lstm.weight_hh_l0, lstm.bias_ih_l0, lstm.bias_hh_l0]
    output, h, c = torch.lstm(inputs, state, weights, True, 1, 0.0, lstm.training, False, False)
    return output, (h, c)


class EdgeOutputs(NamedTuple):
    """The edge and self-loop LSTMs' outputs over S steps and their final states."""

    edge: Tensor  # (S, E, H) o_ij over the packed edges
    self_loop: Tensor  # (S, B*N, H) o_ii over the agents
    edge_state: LSTMState
    self_state: LSTMState


class EdgeRecurrence(nn.Module):
    """G_self over the agents' self-loops and G_interact over the graph's edges."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.g_self = nn.LSTM(config.embed_dim, config.edge_hidden)
        self.g_interact = nn.LSTM(config.embed_dim, config.edge_hidden)

    def forward(
        self,
        self_inputs: Tensor,
        edge_inputs: Tensor,
        self_state: LSTMState | None,
        edge_state: LSTMState | None,
    ) -> EdgeOutputs:
        """S steps: self-loop inputs (S, B, N, emb) and edge inputs (S, E, emb) from the
        states after the previous steps (None: the start of a pass)."""
        o_edge, h_edge = run_lstm(self.g_interact, edge_inputs, edge_state)
        o_self, h_self = run_lstm(self.g_self, self_inputs.flatten(1, 2), self_state)
        return EdgeOutputs(o_edge, o_self, h_edge, h_self)


class NodeRecurrence(nn.Module):
    """G_pred over the agents: their embedding, what they attend to and their self-loop."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.g_pred = nn.LSTM(config.embed_dim + 2 * config.edge_hidden, config.node_hidden)

    def forward(
        self, node: Tensor, attended: Tensor, self_loop: Tensor, state: LSTMState | None
    ) -> tuple[Tensor, LSTMState]:
        """o_i (S, B*N, Hn) and the final state, from F_embed(s_i) (S, B, N, emb), the attended
        edge outputs sum_j theta_ij o_ij (S, B, N, H) and o_ii (S, B, N, H)."""
        node_in = torch.cat([node, attended, self_loop], -1)  # (S, B, N, emb + 2H)
        return run_lstm(self.g_pred, node_in.flatten(1, 2), state)
