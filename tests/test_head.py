"""The output head (predictor.model.head): the Gaussian parametrisation, the mean priors, the
agent frame's rotation, the detached covariance head and the anchored rollout head."""

from __future__ import annotations

import math

import pytest
import torch

from predictor.config import ModelConfig
from predictor.model.head import MAX_LOG_GAIN, AgentFrameHead, SceneFrameHead, build_head

torch.set_num_threads(1)

HIDDEN = 6
AGENT = {"frame": "agent", "node_hidden": HIDDEN}


def positions(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """pos and prev_pos (S=3, B=2, N=4, 2) [m]."""
    gen = torch.Generator().manual_seed(seed)
    prev = torch.rand(3, 2, 4, 2, generator=gen) * 50
    return prev + torch.rand(3, 2, 4, 2, generator=gen), prev


def randomise(head: torch.nn.Module, seed: int = 1) -> None:
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in head.parameters():
            parameter.copy_(0.3 * torch.randn(parameter.shape, generator=gen))


def rotation_of(angle: torch.Tensor) -> torch.Tensor:
    return torch.stack([angle.cos(), angle.sin()], -1)


def test_the_frame_chooses_the_head():
    assert type(build_head(ModelConfig(node_hidden=HIDDEN))) is SceneFrameHead
    assert type(build_head(ModelConfig(**AGENT))) is AgentFrameHead


@pytest.mark.parametrize("prior", ["velocity", "position"])
def test_an_untrained_head_predicts_the_mean_prior_with_the_initial_std(prior):
    head = SceneFrameHead(ModelConfig(node_hidden=HIDDEN, mean_prior=prior, init_std_m=0.3))
    pos, prev = positions()
    out = head(torch.randn(3, 8, HIDDEN), pos, prev, None)
    torch.testing.assert_close(out.mean, 2 * pos - prev if prior == "velocity" else pos)
    torch.testing.assert_close(out.tril, torch.tensor([0.3, 0.0, 0.3]).expand(3, 2, 4, 3))


def test_the_cholesky_factor_follows_the_gain_the_floor_and_the_correlation():
    config = ModelConfig(node_hidden=HIDDEN, min_std_m=0.01, init_std_m=0.1, log_std_gain=5.0)
    head = SceneFrameHead(config)
    raw = torch.tensor([[0.0, 0.0, 0.2, -0.3, 0.5], [0.0, 0.0, 10.0, -100.0, 0.0]])
    tril = head.tril(raw)
    l11 = 0.01 + 0.09 * math.exp(5.0 * 0.2)
    l22 = 0.01 + 0.09 * math.exp(5.0 * -0.3)
    torch.testing.assert_close(tril[0], torch.tensor([l11, 0.5 * l22, l22]))
    # the gain's exponent is capped (finite stds), and the stds never go below the floor
    torch.testing.assert_close(tril[1, 0], torch.tensor(0.01 + 0.09 * math.exp(MAX_LOG_GAIN)))
    torch.testing.assert_close(tril[1, 2], torch.tensor(0.01))


def test_the_scene_head_offset_is_in_world_axes_at_step_scale():
    head = SceneFrameHead(ModelConfig(node_hidden=HIDDEN, step_scale_m=2.0))
    with torch.no_grad():
        head.f_pred.bias.copy_(torch.tensor([0.5, -1.0, 0.0, 0.0, 0.0]))
    pos, prev = positions()
    out = head(torch.zeros(3, 8, HIDDEN), pos, prev, None)
    torch.testing.assert_close(out.mean, 2 * pos - prev + torch.tensor([1.0, -2.0]))


def test_the_detached_covariance_head_is_trained_by_the_covariance_alone():
    head = SceneFrameHead(ModelConfig(node_hidden=HIDDEN, detach_covariance=True))
    randomise(head)
    assert head.covariance_parameters() == list(head.f_cov.parameters())
    assert SceneFrameHead(ModelConfig(node_hidden=HIDDEN)).covariance_parameters() == []
    features = torch.randn(3, 8, HIDDEN, requires_grad=True)
    pos, prev = positions()
    out = head(features, pos, prev, None)
    out.mean.sum().backward(retain_graph=True)
    assert not head.f_cov.weight.grad.any() and head.f_pred.weight.grad.abs().sum() > 0
    mean_grad = features.grad.clone()
    out.tril.sum().backward()  # through the stop-gradient: no change of the features' gradient
    assert head.f_cov.weight.grad.abs().sum() > 0
    torch.testing.assert_close(features.grad, mean_grad)


@pytest.mark.parametrize("offset_scale", ["step", "deviation"])
def test_the_agent_head_predicts_in_the_agent_frame_and_rotates_to_world_axes(offset_scale):
    """A head whose agent frames are turned by an angle predicts the same Gaussian turned by
    that angle around the prior."""
    head = AgentFrameHead(ModelConfig(**AGENT, offset_scale=offset_scale))
    randomise(head)
    with torch.no_grad():
        head.offset_std.copy_(torch.tensor([0.02, 0.005]))
    pos, prev = positions()
    features = torch.randn(3, 8, HIDDEN)
    angle = torch.rand(2, 4) * 6.0
    turn = 0.9
    base = head(features, pos, prev, rotation_of(angle))
    turned = head(features, pos, prev, rotation_of(angle + turn))
    c, s = math.cos(turn), math.sin(turn)
    rot = torch.tensor([[c, -s], [s, c]])
    prior = 2 * pos - prev
    torch.testing.assert_close(turned.mean - prior, (base.mean - prior) @ rot.T)
    expected = rot @ base.covariance() @ rot.T
    torch.testing.assert_close(turned.covariance(), expected, atol=1e-6, rtol=1e-4)
    # the offset's unit: offset_std (deviation) or step_scale_m (step)
    unit = head.offset_std if offset_scale == "deviation" else torch.tensor(head.step_scale_m)
    raw = head.raw_outputs(features).view(3, 2, 4, 5)
    local = head(features, pos, prev, rotation_of(torch.zeros(2, 4))).mean - prior
    torch.testing.assert_close(local, raw[..., :2] * unit)


def test_the_anchored_head_adds_its_velocity_change_in_units_of_anchor_std():
    head = AgentFrameHead(ModelConfig(**AGENT, rollout_prior="anchored"))
    assert head.anchored and not AgentFrameHead(ModelConfig(**AGENT)).anchored
    assert not SceneFrameHead(ModelConfig(node_hidden=HIDDEN)).anchored
    with torch.no_grad():
        head.f_roll.bias.copy_(torch.tensor([0.5, -2.0]))
        head.f_pred.bias.copy_(torch.tensor([9.0, 9.0, 0.0, 0.0, 0.0]))  # not read: F_roll's
        head.anchor_std.copy_(torch.tensor([0.1, 0.2]))
    base = torch.randn(2, 4, 2)
    out = head.anchored_step(torch.randn(2, 4, HIDDEN), base, rotation_of(torch.zeros(2, 4)))
    torch.testing.assert_close(out.mean, base + torch.tensor([0.05, -0.4]))
    torch.testing.assert_close(out.tril, torch.tensor([0.1, 0.0, 0.1]).expand(2, 4, 3))
