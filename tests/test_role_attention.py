"""The learned attention's role switches (ModelConfig.role_attention_bias,
role_balanced_attention, role_bias_by_group): a bias per pair of roles and one share per kind of
neighbour, on the mirrored pair scenes of the attended highway's tests."""

from __future__ import annotations

import torch
from test_attended_highway import REFIT, mirrored_pair_scenes

from predictor.config import ModelConfig
from predictor.model import SmoothAttentionPredictor

torch.set_num_threads(1)


def test_role_attention_bias_moves_the_attention_to_a_role():
    """A large learnt bias for (role 0 attends role 1) puts role 0's attention on the role-1
    agent; zero bias leaves the scores as they were."""
    positions, valid, labels, roles = mirrored_pair_scenes(4, 10, 8, seed=6)
    roles = torch.tensor([0, 1, 2]).expand(4, 3)
    config = ModelConfig(**REFIT, num_roles=3, role_attention_bias=True)
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(config)
    role_pair = model.role_bias.role_pair
    assert role_pair.shape == (3, 3) and role_pair.abs().sum() == 0
    plain = ModelConfig(**REFIT, num_roles=3)
    torch.manual_seed(0)
    without = SmoothAttentionPredictor(plain)
    without.load_state_dict(
        {k: v for k, v in model.state_dict().items() if k != "role_pair"}, strict=True
    )
    before = model(positions, valid, 8, sample=False, roles=roles).attention
    torch.testing.assert_close(
        before, without(positions, valid, 8, sample=False, roles=roles).attention
    )
    with torch.no_grad():
        role_pair[0, 1] = 20.0
    after = model(positions, valid, 8, sample=False, roles=roles).attention  # (B, T, N, N-1)
    assert after[:, :, 0, 0].min() > 0.99  # agent 0 (role 0) attends agent 1 (its edge 0)
    torch.testing.assert_close(after[:, :, 1:], before[:, :, 1:])  # the others unchanged
    # without roles every agent is of one kind, and one bias for every pair would shift all
    # scores alike (the softmax ignores it): the model then has none
    no_roles = SmoothAttentionPredictor(ModelConfig(**REFIT, role_attention_bias=True))
    assert no_roles.role_bias is None


def test_role_balanced_attention_divides_each_weight_by_its_roles_count():
    """With role_balanced_attention the learned attention is the plain one with each weight
    divided by the number of the agent's neighbours of that role, renormalised (a softmax of
    logits minus log counts); without roles (num_roles 0) it changes nothing."""
    positions, valid, _, _ = mirrored_pair_scenes(4, 10, 8, seed=6)
    positions = torch.cat([positions, positions[:, :, 2:] + 40.0], 2)  # two role-2 agents
    valid = torch.cat([valid, valid[:, :, 2:]], 2)
    roles = torch.tensor([0, 1, 2, 2]).expand(4, 4)
    models = []
    for balanced in (False, True):
        torch.manual_seed(0)
        config = ModelConfig(**REFIT, num_roles=3, role_balanced_attention=balanced)
        models.append(SmoothAttentionPredictor(config))
    plain, balanced = (m(positions, valid, 8, sample=False, roles=roles).attention for m in models)
    counts = torch.tensor([[1.0, 2.0, 2.0], [1.0, 2.0, 2.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
    expected = plain / counts  # (B, T, N, N-1): columns are the other agents in slot order
    expected = expected / expected.sum(-1, keepdim=True)
    torch.testing.assert_close(balanced, expected)
    without = []
    for balanced in (False, True):  # num_roles 0: one kind of agent, nothing to balance
        torch.manual_seed(0)
        model = SmoothAttentionPredictor(ModelConfig(**REFIT, role_balanced_attention=balanced))
        without.append(model(positions, valid, 8, sample=False).attention)
    torch.testing.assert_close(without[0], without[1])
