"""The input encoders (predictor.model.encoders): scene-frame inputs at their scales, the split
edge layer, role columns on the nodes only, the agent frame's standardisation and its
invariance to moving the scene."""

from __future__ import annotations

import math

import pytest
import torch

from predictor.config import ModelConfig
from predictor.graph import neighbour_graph
from predictor.model.encoders import AgentFrameEncoder, SceneFrameEncoder, build_encoder
from predictor.model.pass_inputs import PassInputs, prepare_pass
from predictor.outputs import edge_index

torch.set_num_threads(1)

SMALL = {"embed_dim": 8, "edge_hidden": 8, "node_hidden": 12, "attn_dim": 4}
AGENT = {**SMALL, "frame": "agent", "standardise": True, "edge_velocity": True}
OBSERVED = 4


def scene(batch: int = 2, steps: int = 6, agents: int = 4, seed: int = 0):
    """Agents on curved paths, agent 3 absent at the first two steps."""
    gen = torch.Generator().manual_seed(seed)
    t = torch.arange(steps, dtype=torch.float32).view(1, steps, 1, 1)
    start = 40 * torch.rand(batch, 1, agents, 2, generator=gen)
    velocity = 1.0 + torch.rand(batch, 1, agents, 2, generator=gen)
    positions = start + velocity * t + 0.05 * torch.randn(batch, 1, agents, 2, generator=gen) * t**2
    valid = torch.ones(batch, steps, agents, dtype=torch.bool)
    valid[:, :2, 3] = False
    return torch.where(valid.unsqueeze(-1), positions, 0.0), valid


def pass_of(config: ModelConfig, positions, valid, roles=None) -> PassInputs:
    return prepare_pass(config, positions, valid, OBSERVED, None, roles)


def encode(encoder, steps: PassInputs):
    return encoder(steps.pos, steps.prev_pos, steps.present, steps)


def test_the_frame_chooses_the_encoder():
    assert type(build_encoder(ModelConfig(**SMALL))) is SceneFrameEncoder
    assert type(build_encoder(ModelConfig(**AGENT))) is AgentFrameEncoder


def test_scene_inputs_are_positions_about_the_origin_and_steps_at_their_scales():
    config = ModelConfig(**SMALL, position_scale_m=50.0, step_scale_m=2.0)
    encoder = SceneFrameEncoder(config)
    positions, valid = scene()
    steps = pass_of(config, positions, valid)
    own, step, _ = encoder.features(steps.pos, steps.prev_pos, steps.present, steps)
    origin = steps.origin[None, :, None]  # (1, B, 1, 2): mean of the last observed step
    mask = steps.present.unsqueeze(-1)
    torch.testing.assert_close(own, torch.where(mask, (steps.pos - origin) / 50.0, 0.0))
    torch.testing.assert_close(step, torch.where(mask, (steps.pos - steps.prev_pos) / 2.0, 0.0))
    assert not step[2, :, 3].any()  # agent 3's first step: no previous position, no step


def test_the_split_edge_layer_equals_the_concatenated_input():
    config = ModelConfig(**SMALL, position_scale_m=50.0, interaction_scale_m=5.0)
    encoder = SceneFrameEncoder(config)
    rel = torch.randn(3, 2, 5, 2)  # (S, B, N, 2) positions at position_scale
    tail, head = edge_index(5)
    gain = 50.0 / 5.0  # offsets between agents are read at interaction_scale
    direct = encoder.f_interact(
        torch.cat([rel[:, :, tail], (rel[:, :, head] - rel[:, :, tail]) * gain], -1)
    )  # (S, B, M, E)
    graph = neighbour_graph(rel.transpose(0, 1), torch.ones(2, 3, 5, dtype=torch.bool), 3)
    packed = encoder.edge_inputs(rel, graph)  # (S, B*M, E): the complete graph, scene-major
    torch.testing.assert_close(packed, direct.flatten(1, 2))


@pytest.mark.parametrize("settings", [SMALL, AGENT])
def test_roles_enter_the_nodes_and_self_loops_but_not_the_edges(settings):
    config = ModelConfig(**settings, num_roles=3)
    torch.manual_seed(0)
    encoder = build_encoder(config)
    assert encoder.f_embed[0].in_features == 2 + 3 and encoder.f_self[0].in_features == 4 + 3
    positions, valid = scene()
    roles = torch.tensor([[0, 1, 2, 2], [1, 0, 2, 2]])
    first = encode(encoder, pass_of(config, positions, valid, roles))
    second = encode(encoder, pass_of(config, positions, valid, roles.flip(-1)))
    assert not torch.allclose(first.node, second.node)
    assert not torch.allclose(first.self_loop, second.self_loop)
    torch.testing.assert_close(first.edge, second.edge)
    without = ModelConfig(**settings, num_roles=3, role_input=False)
    assert build_encoder(without).f_embed[0].in_features == 2


def test_unfitted_agent_statistics_are_the_car_constants():
    scales = {"position_scale_m": 80.0, "interaction_scale_m": 8.0, "step_scale_m": 3.0}
    encoder = AgentFrameEncoder(ModelConfig(**AGENT, **scales))
    expected = torch.tensor([80.0, 80.0, 3.0, 3.0, 8.0, 8.0, 3.0, 3.0])
    assert torch.equal(encoder.input_std, expected) and not encoder.input_mean.any()
    positions, valid = scene()
    plain_config = ModelConfig(**{**AGENT, "standardise": False})
    plain = AgentFrameEncoder(plain_config)
    plain.fit_statistics(pass_of(plain_config, positions, valid))  # not standardise: kept
    assert torch.equal(plain.input_std, AgentFrameEncoder(plain_config).input_std)
    assert not plain.input_mean.any()


def test_agent_statistics_standardise_the_features_of_the_fitted_scenes():
    """After fitting, the own features over present agent-steps have mean 0 and std 1."""
    config = ModelConfig(**AGENT)
    encoder = AgentFrameEncoder(config)
    positions, valid = scene(batch=4)
    steps = pass_of(config, positions, valid)
    encoder.fit_statistics(steps)
    own, velocity, _ = encoder.features(steps.pos, steps.prev_pos, steps.present, steps)
    features = torch.cat([own, velocity], -1)[steps.present]  # (K, 4)
    torch.testing.assert_close(features.mean(0), torch.zeros(4), atol=1e-5, rtol=0)
    torch.testing.assert_close(features.std(0), torch.ones(4), atol=1e-5, rtol=1e-5)


def test_agent_frame_embeddings_do_not_move_with_the_scene():
    config = ModelConfig(**AGENT)
    torch.manual_seed(0)
    encoder = AgentFrameEncoder(config)
    positions, valid = scene()
    encoder.fit_statistics(pass_of(config, positions, valid))
    c, s = math.cos(0.7), math.sin(0.7)
    moved = positions @ torch.tensor([[c, -s], [s, c]]).T + torch.tensor([12.0, -5.0])
    moved = torch.where(valid.unsqueeze(-1), moved, 0.0)
    base = encode(encoder, pass_of(config, positions, valid))
    other = encode(encoder, pass_of(config, moved, valid))
    for got, expected in zip(other, base, strict=True):
        torch.testing.assert_close(got, expected, atol=1e-4, rtol=1e-4)
