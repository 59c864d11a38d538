"""Losses against torch.distributions and hand-computed values."""

from __future__ import annotations

import math

import pytest
import torch
from torch.distributions import MultivariateNormal

from predictor.config import ModelConfig
from predictor.losses import (
    PENALTY_MAX_STD_M,
    LossWeights,
    attention_tv,
    compute_loss,
    gaussian_nll,
    safe_sqrt,
    variance_penalty,
)
from predictor.model.head import MAX_LOG_GAIN, SceneFrameHead
from predictor.outputs import Gaussian2D, ModelOutput


def random_gaussians(shape: tuple[int, ...], seed: int = 0) -> Gaussian2D:
    gen = torch.Generator().manual_seed(seed)
    mean = torch.randn(*shape, 2, generator=gen, dtype=torch.float64)
    diag = torch.rand(*shape, 2, generator=gen, dtype=torch.float64) * 2 + 0.01
    off = torch.randn(*shape, 1, generator=gen, dtype=torch.float64)
    return Gaussian2D(mean, torch.cat([diag[..., :1], off, diag[..., 1:]], -1))


def test_nll_matches_multivariate_normal():
    g = random_gaussians((4, 7))
    target = g.mean + torch.randn(4, 7, 2, dtype=torch.float64)
    expected = -MultivariateNormal(g.mean, scale_tril=g.scale_tril()).log_prob(target)
    torch.testing.assert_close(gaussian_nll(target, g.mean, g.tril), expected)


def test_nll_stays_finite_and_accurate_for_tiny_and_huge_scales():
    mean = torch.zeros(2, 2)
    tril = torch.tensor([[1e-4, 0.0, 1e-4], [1e4, 5e3, 1e4]])
    target = torch.tensor([[1e-4, -2e-4], [3e4, 1e4]])
    got = gaussian_nll(target, mean, tril)
    expected = -MultivariateNormal(
        mean.double(), scale_tril=Gaussian2D(mean.double(), tril.double()).scale_tril()
    ).log_prob(target.double())
    torch.testing.assert_close(got.double(), expected, rtol=1e-5, atol=1e-4)


def test_variance_penalty_by_hand():
    # stds: sqrt(Sigma_11) = l11, sqrt(Sigma_22) = hypot(l21, l22)
    tril = torch.tensor([[0.5, 0.3, 0.4], [5e-4, 0.0, 2.0], [0.5, 0.0, 0.5]])
    g = Gaussian2D(torch.zeros(3, 2), tril)
    got = variance_penalty(g, tau=1e-3)
    expected = torch.tensor([2 * math.exp(0.5), math.exp(2.0), 2 * math.exp(0.5)])
    torch.testing.assert_close(got, expected)
    torch.testing.assert_close(variance_penalty(g, tau=0.6), torch.tensor([0, math.exp(2.0), 0]))


def diagonal(stds: list[float], dtype=torch.float64) -> Gaussian2D:
    """Gaussians with both stds equal to each of `stds` (uncorrelated), as a leaf tril."""
    s = torch.tensor(stds, dtype=dtype)
    tril = torch.stack([s, torch.zeros_like(s), s], -1).requires_grad_(True)
    return Gaussian2D(torch.zeros(len(stds), 2, dtype=dtype), tril)


def test_linear_penalty_by_hand():
    """exp(sigma) up to c = 10 m, exp(c) (1 + sigma - c) beyond; tau still gates."""
    g = diagonal([5e-4, 2.0, 10.0, 12.5, 1e4])
    got = variance_penalty(g, tau=1e-3, linear_from_m=10.0)
    e10 = math.exp(10.0)
    per_std = [0.0, math.exp(2.0), e10, e10 * 3.5, e10 * (1 + 1e4 - 10)]
    torch.testing.assert_close(got, 2 * torch.tensor(per_std, dtype=torch.float64))
    # the paper's form (linear_from_m 0) counts stds above 50 m as 50 m
    capped = variance_penalty(diagonal([60.0]), tau=1e-3)
    torch.testing.assert_close(capped, torch.tensor([2 * math.exp(PENALTY_MAX_STD_M)]).double())


def test_linear_penalty_equals_exp_bit_for_bit_below_its_start():
    """Value and gradient below c are those of the paper's form exactly (the published runs,
    whose stds stay below c, train the same weights)."""
    stds = torch.linspace(1e-4, 9.99, 257, dtype=torch.float32).tolist()
    a, b = diagonal(stds, torch.float32), diagonal(stds, torch.float32)
    pa, pb = variance_penalty(a, 1e-3), variance_penalty(b, 1e-3, linear_from_m=10.0)
    assert torch.equal(pa, pb)
    (pa * torch.arange(257.0)).sum().backward()
    (pb * torch.arange(257.0)).sum().backward()
    assert torch.equal(a.tril.grad, b.tril.grad)


def test_linear_penalty_is_c1_with_bounded_slope():
    """The slope is exp(sigma) below c, exp(c) at and beyond it (continuous), never more."""
    c = 10.0
    g = diagonal([c - 1e-6, c, c + 1e-6, 1e3, 1e6])
    variance_penalty(g, 0.0, linear_from_m=c).sum().backward()
    slope = g.tril.grad[:, 0]  # d penalty / d sigma_1 (l11 is sigma_1)
    expected = torch.tensor([math.exp(c - 1e-6)] + [math.exp(c)] * 4, dtype=torch.float64)
    torch.testing.assert_close(slope, expected, rtol=1e-6, atol=0.0)
    assert float(slope.max()) <= math.exp(c) * (1 + 1e-12)


def extreme_output(raw_cov: tuple[float, float, float], t_obs: int = 2) -> tuple:
    """A ModelOutput of the real scene-frame head (default ModelConfig, float32) whose raw
    Cholesky outputs are `raw_cov` for every agent-step, with zero means, for 1 scene of 6 steps
    and 3 agents; raw tensors are leaves (their .grad after backward)."""
    head = SceneFrameHead(ModelConfig())
    raws, gaussians = [], []
    for steps in (5, 6 - t_obs):
        raw = torch.zeros(1, steps, 3, 5)
        raw[..., 2:] = torch.tensor(raw_cov)
        raw.requires_grad_(True)
        raws.append(raw)
        gaussians.append(head.gaussian(raw, torch.zeros(1, steps, 3, 2), None))
    attention = torch.softmax(torch.randn(1, 5, 3, 2), -1)
    roll_attention = torch.softmax(torch.randn(1, 6 - t_obs, 3, 2), -1)
    present = torch.ones(1, 3, dtype=torch.bool)
    out = ModelOutput(gaussians[0], attention, gaussians[1], roll_attention, present)
    return out, raws


def test_extreme_batch_with_the_largest_stds_has_a_bounded_loss():
    """The head's largest stds (log gain at MAX_LOG_GAIN: 16.1 km, and with correlation raw 5 a
    second std sqrt(26) times that) and 1 km errors: with the penalty linear from 10 m the loss
    is finite, below the bound computed from the terms' maxima, and so are its gradients; the
    paper's form puts it near beta1 exp(50) ~ 1e20."""
    torch.manual_seed(0)
    config = ModelConfig()
    top = config.min_std_m + (config.init_std_m - config.min_std_m) * math.exp(MAX_LOG_GAIN)
    positions = torch.full((1, 6, 3, 2), 1e3)
    valid = torch.ones(1, 6, 3, dtype=torch.bool)
    weights = LossWeights(penalty_linear_from_m=10.0)
    out, raws = extreme_output((1e3, 1e3, 5.0))
    torch.testing.assert_close(
        out.one_step.stds()[0, 0, 0].double(),
        torch.tensor([top, top * math.sqrt(26)], dtype=torch.float64),
        rtol=1e-5,
        atol=0.0,
    )
    loss, terms = compute_loss(out, positions, valid, 2, weights)
    loss.backward()
    e10 = math.exp(10.0)
    var_max = e10 * (1 + top - 10) + e10 * (1 + top * math.sqrt(26) - 10)
    # NLL <= 0.5 |L^-1 d|^2 + log(l11 l22) + log 2 pi, |L^-1 d| <= |d| (1 + |c|) / l_min
    nll_max = (
        0.5 * (math.hypot(1e3, 1e3) * 6 / top) ** 2 + 2 * math.log(top) + math.log(2 * math.pi)
    )
    bound = 2 * (nll_max + weights.beta1 * var_max + weights.beta2 * math.sqrt(2))
    assert math.isfinite(terms["loss"]) and 0 < terms["loss"] <= bound * (1 + 1e-5)
    assert bound < 1e8
    assert all(torch.isfinite(raw.grad).all() for raw in raws)
    _, paper = compute_loss(extreme_output((1e3, 1e3, 5.0))[0], positions, valid, 2, LossWeights())
    assert paper["loss"] > 1e19


def test_extreme_batch_with_the_smallest_stds_has_a_finite_loss_and_gradient():
    """The NLL is left as the likelihood: at the std floor (1 mm) a 1 km miss per axis costs
    0.5 (2 * 1e6^2) - 2 log(1e-3) + log 2 pi nats, finite in float32 (the floor bounds it), with
    finite gradients, which training clips per parameter group (`grad_clip_norm`)."""
    torch.manual_seed(0)
    positions = torch.full((1, 6, 3, 2), 1e3)
    valid = torch.ones(1, 6, 3, dtype=torch.bool)
    out, raws = extreme_output((-1e3, -1e3, 0.0))
    loss, terms = compute_loss(out, positions, valid, 2, LossWeights(penalty_linear_from_m=10.0))
    loss.backward()
    nll = 0.5 * 2 * 1e6**2 - 2 * math.log(1e-3) + math.log(2 * math.pi)
    assert terms["nll"] == pytest.approx(nll, rel=1e-5)
    assert terms["nll_seq"] == pytest.approx(nll, rel=1e-5)
    assert terms["var"] == pytest.approx(0.0)  # 1 mm is tau: not above it
    assert all(torch.isfinite(raw.grad).all() for raw in raws)


def test_total_variation_by_hand():
    # one scene, 3 agents (K = 2 other agents each), 4 steps
    theta = torch.zeros(1, 4, 3, 2)
    theta[0, :, 0] = torch.tensor([[1.0, 0.0], [0.5, 0.5], [0.5, 0.5], [0.0, 1.0]])
    theta[0, :, 1] = torch.tensor([[0.2, 0.8], [0.8, 0.2], [0.8, 0.2], [0.8, 0.2]])
    present = torch.ones(1, 4, 3, dtype=torch.bool)
    present[0, 3, 1] = False  # agent 1 absent at t = 3: transition 2 -> 3 not counted
    total, count = attention_tv(theta, present)
    agent0 = math.sqrt(0.5) + 0.0 + math.sqrt(0.5)
    agent1 = math.sqrt(0.72) + 0.0
    torch.testing.assert_close(total, torch.tensor(agent0 + agent1))
    assert int(count) == 3 + 2 + 3  # agent 2 contributes zero over 3 transitions


def test_safe_sqrt_value_and_gradient():
    x = torch.tensor([0.0, 0.25, 4.0], requires_grad=True)
    y = safe_sqrt(x)
    y.sum().backward()
    torch.testing.assert_close(y.detach(), torch.tensor([0.0, 0.5, 2.0]))
    torch.testing.assert_close(x.grad, torch.tensor([0.0, 1.0, 0.25]))


def test_tv_gradient_is_finite_for_constant_attention():
    theta = torch.full((1, 3, 2, 1), 1.0, requires_grad=True)
    total, _ = attention_tv(theta, torch.ones(1, 3, 2, dtype=torch.bool))
    total.backward()
    assert torch.isfinite(theta.grad).all() and float(total.detach()) == 0.0


def hand_output(batch: int, steps: int, agents: int, num_observed: int) -> ModelOutput:
    one = random_gaussians((batch, steps - 1, agents), seed=1)
    roll = random_gaussians((batch, steps - num_observed, agents), seed=2)
    attention = torch.softmax(torch.randn(batch, steps - 1, agents, agents - 1).double(), -1)
    roll_attention = torch.softmax(
        torch.randn(batch, steps - num_observed, agents, agents - 1).double(), -1
    )
    present = torch.ones(batch, agents, dtype=torch.bool)
    return ModelOutput(one, attention, roll, roll_attention, present)


def test_compute_loss_is_the_weighted_sum_of_masked_means():
    torch.manual_seed(0)
    batch, steps, agents, t_obs = 2, 6, 3, 2
    out = hand_output(batch, steps, agents, t_obs)
    positions = torch.randn(batch, steps, agents, 2, dtype=torch.float64)
    valid = torch.ones(batch, steps, agents, dtype=torch.bool)
    valid[0, 4:, 2] = False
    out.rollout_present[1, 1] = False
    weights = LossWeights(beta1=0.3, beta2=0.7, tau=1e-3)
    total, terms = compute_loss(out, positions, valid, t_obs, weights)
    # independent one-step NLL: average of -log_prob over (b, t, i) present at t and t-1
    dist = MultivariateNormal(out.one_step.mean, scale_tril=out.one_step.scale_tril())
    logp = dist.log_prob(positions[:, 1:])  # (B, T-1, N)
    keep = valid[:, 1:] & valid[:, :-1]
    assert abs(terms["nll"] - float(-logp[keep].mean())) < 1e-9
    roll = MultivariateNormal(out.rollout.mean, scale_tril=out.rollout.scale_tril())
    roll_keep = valid[:, t_obs:] & out.rollout_present.unsqueeze(1)
    roll_nll = -roll.log_prob(positions[:, t_obs:])[roll_keep].mean()
    assert abs(terms["nll_seq"] - float(roll_nll)) < 1e-9
    expected = (
        terms["nll"]
        + terms["nll_seq"]
        + 0.3 * (terms["var"] + terms["var_seq"])
        + 0.7 * (terms["tv"] + terms["tv_seq"])
    )
    assert abs(float(total) - expected) < 1e-9 and abs(terms["loss"] - expected) < 1e-9
    # the step-only loss leaves the rollout out
    _, one_terms = compute_loss(out, positions, valid, t_obs, LossWeights(sequence=False))
    assert "nll_seq" not in one_terms and one_terms["nll"] == terms["nll"]


def test_absent_agents_do_not_enter_the_loss():
    out = hand_output(1, 5, 3, 2)
    positions = torch.randn(1, 5, 3, 2, dtype=torch.float64)
    valid = torch.ones(1, 5, 3, dtype=torch.bool)
    valid[0, :, 2] = False
    out.rollout_present[0, 2] = False
    _, a = compute_loss(out, positions, valid, 2, LossWeights())
    positions[0, :, 2] += 100.0
    out.one_step.mean[0, :, 2] -= 7.0
    _, b = compute_loss(out, positions, valid, 2, LossWeights())
    assert a == b


def test_main_agent_weight_makes_weighted_means_over_agent_steps():
    batch, steps, agents, t_obs = 2, 6, 4, 3
    out = hand_output(batch, steps, agents, t_obs)
    positions = torch.randn(batch, steps, agents, 2, dtype=torch.float64)
    valid = torch.ones(batch, steps, agents, dtype=torch.bool)
    valid[1, 2:, 3] = False  # a distractor that leaves
    base = dict(mean_loss="displacement", sequence=True)
    _, plain = compute_loss(out, positions, valid, t_obs, LossWeights(**base))
    focal = torch.tensor([[True, True, False, False], [False, True, False, True]])
    weights = LossWeights(**base, main_weight=4.0)
    _, weighted = compute_loss(out, positions, valid, t_obs, weights, focal)
    # by hand: focal agents count 4 times, the others once, in sum and count alike
    w = torch.tensor([[4.0, 4.0, 1.0, 1.0], [1.0, 4.0, 1.0, 4.0]], dtype=torch.float64)
    w = w[:, None, :]  # (B, 1, N)
    keep = (valid[:, 1:] & valid[:, :-1]).double() * w
    err = (positions[:, 1:] - out.one_step.mean).norm(dim=-1)
    assert abs(weighted["de"] - float((err * keep).sum() / keep.sum())) < 1e-9
    roll_keep = (valid[:, t_obs:] & out.rollout_present.unsqueeze(1)).double() * w
    roll_err = (positions[:, t_obs:] - out.rollout.mean).norm(dim=-1)
    assert abs(weighted["de_seq"] - float((roll_err * roll_keep).sum() / roll_keep.sum())) < 1e-9
    nll = -MultivariateNormal(out.one_step.mean, scale_tril=out.one_step.scale_tril()).log_prob(
        positions[:, 1:]
    )
    assert abs(weighted["nll"] - float((nll * keep).sum() / keep.sum())) < 1e-9
    # weight 1 is the plain mean; attention smoothness is not weighted
    unweighted = (err * (keep > 0)).sum() / (keep > 0).sum()
    assert abs(plain["de"] - float(unweighted)) < 1e-9 and plain["de"] != weighted["de"]
    assert weighted["tv"] == plain["tv"] and weighted["tv_seq"] == plain["tv_seq"]
    with pytest.raises(ValueError, match="needs the focal mask"):
        compute_loss(out, positions, valid, t_obs, weights)
