"""The attention parts (predictor.model.attention) on a pass's graph: the learned scores
softmaxed over present neighbours, the uniform and oracle weights, the role-balance prior, the
role-pair bias and the attended sum."""

from __future__ import annotations

import math

import pytest
import torch

from predictor.config import ModelConfig
from predictor.model.attention import (
    LearnedAttention,
    OracleAttention,
    RolePairBias,
    UniformAttention,
    build_attention,
    build_role_bias,
)
from predictor.model.pass_inputs import prepare_pass

torch.set_num_threads(1)

SIZES = {"edge_hidden": 4, "attn_dim": 3}
AGENTS = 4


def pass_inputs(config: ModelConfig, roles: torch.Tensor | None = None):
    """One scene of 4 agents over 3 steps, agent 3 absent at step 1; agent 0 labelled to
    attend agent 2, agent 1 to agent 3 (absent at step 1)."""
    gen = torch.Generator().manual_seed(0)
    positions = torch.rand(1, 3, AGENTS, 2, generator=gen) * 20
    valid = torch.ones(1, 3, AGENTS, dtype=torch.bool)
    valid[0, 1, 3] = False
    labels = torch.full((1, 3, AGENTS), -1)
    labels[0, :, 0], labels[0, :, 1] = 2, 3
    return prepare_pass(config, positions, valid, 2, labels, roles)


def outputs(steps, seed: int = 1):
    gen = torch.Generator().manual_seed(seed)
    edges = steps.graph.num_edges
    return torch.randn(3, AGENTS, 4, generator=gen), torch.randn(3, edges, 4, generator=gen)


def dense(theta: torch.Tensor, steps) -> torch.Tensor:
    """(S, E) -> (S, N, N) with row i the weights of agent i."""
    out = torch.zeros(theta.shape[0], AGENTS, AGENTS)
    out[:, steps.graph.tail, steps.graph.head] = theta
    return out


def test_the_config_chooses_the_attention_and_the_role_bias():
    for mode, kind in (
        ("learned", LearnedAttention),
        ("uniform", UniformAttention),
        ("oracle", OracleAttention),
    ):
        assert type(build_attention(ModelConfig(**SIZES, attention_mode=mode))) is kind
    with_bias = ModelConfig(num_roles=3, role_attention_bias=True)
    assert isinstance(build_role_bias(with_bias), RolePairBias)
    assert build_role_bias(ModelConfig(num_roles=3)) is None
    assert build_role_bias(ModelConfig(role_attention_bias=True)) is None  # no roles
    uniform = ModelConfig(num_roles=3, role_attention_bias=True, attention_mode="uniform")
    assert build_role_bias(uniform) is None


def test_learned_weights_are_the_softmax_of_the_attention_products_over_present_neighbours():
    config = ModelConfig(**SIZES, attention_gain=2.0)
    torch.manual_seed(0)
    attention = LearnedAttention(config)
    steps = pass_inputs(config)
    o_self, o_edge = outputs(steps)
    presence = attention.presence(steps.present, steps)
    theta = dense(attention(o_self, o_edge, presence, None, steps.graph), steps)  # (S, N, N)
    f_attn = attention.f_attn
    with torch.no_grad():  # the paper's <F_attn(o_ii), F_attn(o_ij)> on a dense layout
        dense_edges = torch.zeros(3, AGENTS, AGENTS, 4)
        dense_edges[:, steps.graph.tail, steps.graph.head] = o_edge
        scores = torch.einsum("snd,snmd->snm", f_attn(o_self), f_attn(dense_edges)) * 2.0
    present = steps.present[:, 0]  # (S, N)
    mask = present.unsqueeze(-1) & present.unsqueeze(-2) & ~torch.eye(AGENTS, dtype=torch.bool)
    expected = torch.softmax(scores.masked_fill(~mask, -torch.inf), -1).nan_to_num(0.0)
    torch.testing.assert_close(theta, expected)
    assert not theta[1, 3].any() and not theta[1, :, 3].any()  # agent 3 absent at step 1


def test_uniform_and_oracle_weights():
    config = ModelConfig(**SIZES, attention_mode="oracle")
    steps = pass_inputs(config)
    o_self, o_edge = outputs(steps)
    presence = UniformAttention().presence(steps.present, steps)
    uniform = dense(UniformAttention()(o_self, o_edge, presence, None, steps.graph), steps)
    torch.testing.assert_close(uniform[0, 0], torch.tensor([0.0, 1 / 3, 1 / 3, 1 / 3]))
    torch.testing.assert_close(uniform[1, 0], torch.tensor([0.0, 0.5, 0.5, 0.0]))
    labels = steps.labels
    oracle = dense(OracleAttention()(o_self, o_edge, presence, labels, steps.graph), steps)
    assert torch.equal(oracle[:, 0], torch.tensor([0.0, 0.0, 1.0, 0.0]).expand(3, 4))
    torch.testing.assert_close(oracle[1, 1], uniform[1, 1])  # its label is absent: uniform
    assert torch.equal(oracle[0, 1], torch.tensor([0.0, 0.0, 0.0, 1.0]))
    torch.testing.assert_close(oracle[:, 2:], uniform[:, 2:])  # no labels


def test_the_role_balance_prior_is_the_learned_attentions_and_needs_roles():
    roles = torch.tensor([[0, 1, 1, 1]])
    balanced = ModelConfig(**SIZES, num_roles=2, role_balanced_attention=True)
    steps = pass_inputs(balanced, roles)
    prior = dense(LearnedAttention(balanced).presence(steps.present, steps).prior, steps)
    # agent 0 sees three role-1 agents (two at step 1): each gets -log 3 (-log 2)
    torch.testing.assert_close(prior[0, 0, 1:], torch.full((3,), -math.log(3.0)))
    torch.testing.assert_close(prior[1, 0, 1:3], torch.full((2,), -math.log(2.0)))
    plain = LearnedAttention(ModelConfig(**SIZES, num_roles=2))
    assert plain.presence(steps.present, steps).prior is None
    assert UniformAttention().presence(steps.present, steps).prior is None
    without = pass_inputs(ModelConfig(**SIZES))  # no roles: nothing to balance
    assert LearnedAttention(balanced).presence(without.present, without).prior is None


def test_the_role_pair_bias_of_each_edge_is_computed_once_a_pass():
    roles = torch.tensor([[0, 1, 2, 2]])
    steps = pass_inputs(ModelConfig(**SIZES, num_roles=3), roles)
    bias = RolePairBias(3)
    with torch.no_grad():
        bias.role_pair.copy_(torch.arange(9.0).view(3, 3))
    per_edge = bias(steps)
    tail, head = steps.graph.tail, steps.graph.head
    torch.testing.assert_close(per_edge, (3 * roles[0, tail] + roles[0, head]).float())
    assert bias(steps) is per_edge  # kept in the pass
    assert bias(pass_inputs(ModelConfig(**SIZES))) is None  # a pass without roles


@pytest.mark.parametrize("mode", ["learned", "uniform"])
def test_an_agent_attends_to_the_weighted_sum_of_its_edges(mode):
    config = ModelConfig(**SIZES, attention_mode=mode)
    attention = build_attention(config)
    steps = pass_inputs(config)
    o_self, o_edge = outputs(steps)
    theta = attention(o_self, o_edge, attention.presence(steps.present, steps), None, steps.graph)
    read = attention.read(theta, o_edge, steps.graph)  # (S, N, H)
    dense_edges = torch.zeros(3, AGENTS, AGENTS, 4)
    dense_edges[:, steps.graph.tail, steps.graph.head] = o_edge
    expected = torch.einsum("snm,snmh->snh", dense(theta, steps), dense_edges)
    torch.testing.assert_close(read, expected)
