"""The recurrent core (predictor.model.recurrent): `run_lstm` is nn.LSTM, the edge and self-loop
LSTMs carry their states across chunks of steps and keep edges apart, and the node LSTM reads
the embedding, the attended edges and the self-loop."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from predictor.config import ModelConfig
from predictor.model.recurrent import EdgeRecurrence, NodeRecurrence, run_lstm

torch.set_num_threads(1)

CONFIG = ModelConfig(embed_dim=5, edge_hidden=4, node_hidden=6)


@pytest.mark.parametrize("with_state", [False, True])
def test_run_lstm_is_nn_lstm_outputs_and_gradients(with_state: bool):
    # the model calls torch.lstm directly: outputs, final states and every gradient (inputs,
    # initial state, the four weights) must be nn.LSTM's own
    torch.manual_seed(0)
    lstm = nn.LSTM(5, 4).double()
    x = torch.randn(3, 7, 5, dtype=torch.float64, requires_grad=True)
    state = None
    if with_state:
        h0 = torch.randn(1, 7, 4, dtype=torch.float64, requires_grad=True)
        c0 = torch.randn(1, 7, 4, dtype=torch.float64, requires_grad=True)
        state = (h0, c0)
    leaves = [x, *lstm.parameters(), *(state or ())]
    results = []
    for call in (lstm, lambda inputs, hx: run_lstm(lstm, inputs, hx)):
        out, (h, c) = call(x, state)
        loss = (out * torch.linspace(-1, 1, 4, dtype=torch.float64)).sum() + h.sum() + 2 * c.sum()
        results.append((out, h, c, torch.autograd.grad(loss, leaves)))
    (out_a, h_a, c_a, grads_a), (out_b, h_b, c_b, grads_b) = results
    for a, b in [(out_a, out_b), (h_a, h_b), (c_a, c_b), *zip(grads_a, grads_b, strict=True)]:
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12)


def test_edge_recurrence_carries_its_states_across_chunks():
    """Steps run in chunks with the states carried give what one call over them gives."""
    torch.manual_seed(0)
    core = EdgeRecurrence(CONFIG)
    self_inputs, edge_inputs = torch.randn(7, 2, 3, 5), torch.randn(7, 12, 5)
    whole = core(self_inputs, edge_inputs, None, None)
    first = core(self_inputs[:3], edge_inputs[:3], None, None)
    rest = core(self_inputs[3:], edge_inputs[3:], first.self_state, first.edge_state)
    torch.testing.assert_close(torch.cat([first.edge, rest.edge]), whole.edge)
    torch.testing.assert_close(torch.cat([first.self_loop, rest.self_loop]), whole.self_loop)
    assert whole.self_loop.shape == (7, 6, 4) and whole.edge.shape == (7, 12, 4)
    for got, expected in zip(
        rest.edge_state + rest.self_state, whole.edge_state + whole.self_state
    ):
        torch.testing.assert_close(got, expected)


def test_each_edge_and_agent_is_a_sequence_of_its_own():
    torch.manual_seed(0)
    core = EdgeRecurrence(CONFIG)
    self_inputs, edge_inputs = torch.randn(4, 2, 3, 5), torch.randn(4, 12, 5)
    base = core(self_inputs, edge_inputs, None, None)
    order = torch.randperm(12)
    moved = core(self_inputs.flip(2), edge_inputs[:, order], None, None)
    torch.testing.assert_close(moved.edge, base.edge[:, order])
    flipped = base.self_loop.view(4, 2, 3, 4).flip(2).flatten(1, 2)
    torch.testing.assert_close(moved.self_loop, flipped)


def test_the_node_lstm_reads_embedding_attended_edges_and_self_loop_in_that_order():
    torch.manual_seed(0)
    node = NodeRecurrence(CONFIG)
    assert node.g_pred.input_size == 5 + 2 * 4 and node.g_pred.hidden_size == 6
    embedding, attended, self_loop = (
        torch.randn(3, 2, 4, 5),
        torch.randn(3, 2, 4, 4),
        torch.randn(3, 2, 4, 4),
    )
    out, state = node(embedding, attended, self_loop, None)
    expected, (h, c) = node.g_pred(torch.cat([embedding, attended, self_loop], -1).flatten(1, 2))
    torch.testing.assert_close(out, expected)
    torch.testing.assert_close(state[0], h)
    torch.testing.assert_close(state[1], c)
