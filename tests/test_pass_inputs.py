"""A pass's inputs (predictor.model.pass_inputs): time-first steps, the previous positions of
agents that enter, the scene origin, what a model's batch must carry, and the neighbour graph
chosen from the steps the pass may read."""

from __future__ import annotations

import pytest
import torch

from predictor.config import ModelConfig
from predictor.model.pass_inputs import prepare_pass

SIZES = {"embed_dim": 4, "edge_hidden": 4, "node_hidden": 4, "attn_dim": 2}


def scene():
    """One scene, 5 steps, 3 agents; agent 2 enters at step 2."""
    positions = torch.arange(5 * 3 * 2, dtype=torch.float32).view(1, 5, 3, 2)
    valid = torch.ones(1, 5, 3, dtype=torch.bool)
    valid[0, :2, 2] = False
    return positions, valid


def test_steps_are_time_first_and_an_entering_agent_starts_at_rest():
    positions, valid = scene()
    steps = prepare_pass(ModelConfig(**SIZES), positions, valid, 3, None, None)
    assert steps.pos.shape == (5, 1, 3, 2) and steps.present.shape == (5, 1, 3)
    torch.testing.assert_close(steps.prev_pos[1:, :, :2], steps.pos[:-1, :, :2])
    torch.testing.assert_close(steps.prev_pos[0], steps.pos[0])  # no step before the first
    torch.testing.assert_close(steps.prev_pos[2, 0, 2], steps.pos[2, 0, 2])  # entered at 2
    torch.testing.assert_close(steps.origin, positions[:, 2].mean(1))  # last observed step
    assert steps.frame is None and steps.roles is None


def test_a_batch_lacking_what_the_model_reads_is_refused():
    positions, valid = scene()
    with pytest.raises(ValueError, match=r"num_observed must be in \[1, 4\]"):
        prepare_pass(ModelConfig(**SIZES), positions, valid, 5, None, None)
    with pytest.raises(ValueError, match="oracle attention needs attention labels"):
        prepare_pass(ModelConfig(**SIZES, attention_mode="oracle"), positions, valid, 3, None, None)
    roles = ModelConfig(**SIZES, num_roles=2)
    with pytest.raises(ValueError, match="reads agent roles; the data has none"):
        prepare_pass(roles, positions, valid, 3, None, None)
    with pytest.raises(ValueError, match=r"roles must be in \[0, 1\]"):
        prepare_pass(roles, positions, valid, 3, None, torch.tensor([[0, 1, 2]]))
    steps = prepare_pass(roles, positions, valid, 3, None, torch.tensor([[0, 1, 1]]))
    assert steps.roles.tolist() == [[[1.0, 0.0], [0.0, 1.0], [0.0, 1.0]]]
    without_input = ModelConfig(**SIZES, num_roles=2, role_input=False)
    steps = prepare_pass(without_input, positions, valid, 3, None, torch.tensor([[0, 1, 1]]))
    assert steps.roles is None and steps.role_index.tolist() == [[0, 1, 1]]


def test_the_graph_links_the_agents_present_in_the_steps_read():
    positions, valid = scene()
    valid[0, 2:, 2] = False
    valid[0, 4, 2] = True  # agent 2 only at the last step, after the observed ones
    config = ModelConfig(**SIZES)
    assert prepare_pass(config, positions, valid, 3, None, None).graph.num_edges == 6
    observed = prepare_pass(config, positions, valid, 3, None, None, graph_steps=3)
    assert observed.graph.num_edges == 2  # agents 0 and 1: agent 2 is not read
    knn = ModelConfig(**SIZES, neighbours="knn", neighbour_k=1)
    assert prepare_pass(knn, positions, valid, 3, None, None).graph.num_edges == 3
