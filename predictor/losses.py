"""Losses of the paper: Gaussian NLL, variance penalty, attention total variation.

Normalisation: the paper writes every term as a sum over agents and steps. We divide each sum by
the number of items it runs over (present agent-steps for NLL and variance, present agent
transitions for the total variation), pooled over the whole batch. The counts of the terms are
nearly equal (T-1 predictions vs. T-2 transitions per agent), so the ratios between terms, and
hence the meaning of beta1 = beta2 = 0.01, are those of the paper's sums; but the loss no longer
grows with the batch size, the number of agents or the sequence length, and its value reads as
"per agent-step" (NLL in nats for positions in metres).

Total variation: sqrt(sum_j d_j^2) has no finite gradient where all d_j = 0 (which happens
exactly, e.g. for constant attention). We use a safe square root: sqrt(x) where x > 0 and 0
(with zero gradient, a valid subgradient) where x == 0; no epsilon enters the value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from predictor.outputs import Gaussian2D, ModelOutput, TrajectoryMixture

LOG_2PI = math.log(2.0 * math.pi)


def gaussian_nll(target: Tensor, mean: Tensor, tril: Tensor) -> Tensor:
    """-log N(target | mean, L L^T) for 2-D Gaussians, elementwise over leading dims.

    target, mean (..., 2); tril (..., 3) = (l11, l21, l22) with l11, l22 > 0. Computed in log
    space from the Cholesky factor: 0.5 |L^-1 d|^2 + log l11 + log l22 + log(2 pi).
    """
    diff = target - mean  # (..., 2)
    z0 = diff[..., 0] / tril[..., 0]  # (...)
    z1 = (diff[..., 1] - tril[..., 1] * z0) / tril[..., 2]  # (...)
    log_det_half = torch.log(tril[..., 0]) + torch.log(tril[..., 2])  # (...)
    return 0.5 * (z0 * z0 + z1 * z1) + log_det_half + LOG_2PI  # (...)


PENALTY_MAX_STD_M = 50.0  # [m] stds above count as this in the paper's variance penalty


def variance_penalty(gaussian: Gaussian2D, tau: float, linear_from_m: float = 0.0) -> Tensor:
    """sum_k p(sigma_k) * 1[sigma_k > tau] with sigma_k = sqrt(Sigma_kk) [m]: (...).

    linear_from_m = 0 (the paper's): p(sigma) = exp(min(sigma, PENALTY_MAX_STD_M)); exp overflows
    float32 beyond ~88 m (an infinite loss ends the run), while exp(50) ~ 5e21 is finite but
    reads as a loss of up to ~1e20 per agent-step, with no gradient above 50 m.

    linear_from_m = c > 0: exp up to c and its tangent beyond,
    p(sigma) = exp(min(sigma, c)) * (1 + max(sigma - c, 0)): continuous with a continuous
    derivative (C1), convex and increasing, with dp/dsigma <= exp(c) everywhere, so the penalty
    grows linearly in the std and stays finite, as does its gradient, for any finite std. Below c
    value and gradient are exp's bit for bit (the factor is exactly 1, the tangent's gradient
    exactly 0).
    """
    stds = gaussian.stds()  # (..., 2)
    if linear_from_m > 0:
        c = linear_from_m
        penalty = torch.exp(stds.clamp(max=c)) * (1.0 + torch.relu(stds - c))  # (..., 2)
    else:
        penalty = torch.exp(stds.clamp(max=PENALTY_MAX_STD_M))  # (..., 2)
    return (penalty * (stds > tau).to(stds.dtype)).sum(-1)  # (...)


def safe_sqrt(x: Tensor) -> Tensor:
    """sqrt(x) for x >= 0 with a zero (sub)gradient at x == 0 instead of infinity."""
    positive = x > 0
    return torch.where(positive, torch.sqrt(torch.where(positive, x, torch.ones_like(x))), 0.0)


def attention_tv(attention: Tensor, present: Tensor) -> tuple[Tensor, Tensor]:
    """Total variation of attention over time: (sum, count) of sqrt(sum_j (d theta_ij)^2).

    attention (B, S, N, K) over consecutive steps; present (B, S, N) bool. A transition
    t-1 -> t of agent i counts only if i is present at both steps.
    """
    diff = attention[:, 1:] - attention[:, :-1]  # (B, S-1, N, K)
    norms = safe_sqrt((diff * diff).sum(-1))  # (B, S-1, N)
    both = present[:, 1:] & present[:, :-1]  # (B, S-1, N)
    return (norms * both.to(norms.dtype)).sum(), both.sum()


def distance(target: Tensor, mean: Tensor) -> Tensor:
    """Euclidean distance |target - mean| over the last dim (..., 2) -> (...), with a zero
    (sub)gradient where it is exactly zero."""
    return safe_sqrt(((target - mean) ** 2).sum(-1))


def masked_sum(
    values: Tensor, mask: Tensor, agent_weight: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    """(sum of values where mask, number of such items); with `agent_weight` broadcasting over
    values (e.g. (B, 1, N)), each item counts with its agent's weight in both."""
    weight = mask.to(values.dtype)
    if agent_weight is not None:
        weight = weight * agent_weight
    return (values * weight).sum(), weight.sum()


def _mean(total: Tensor, count: Tensor) -> Tensor:
    return total / count.clamp(min=1).to(total.dtype)


def main_agent_weights(focal: Tensor | None, main_weight: float, like: Tensor) -> Tensor | None:
    """(B, 1, N) item weights: `main_weight` for the focal agents (focal (B, N) bool), 1 for the
    others; None for weight 1. ValueError if a weight is asked for without a focal mask."""
    if main_weight == 1.0:
        return None
    if focal is None:
        raise ValueError("main_weight != 1 needs the focal mask of the batch")
    one = torch.ones((), dtype=like.dtype, device=like.device)
    return torch.where(focal, one * main_weight, one).unsqueeze(1)  # (B, 1, N)


def mode_nll(
    modes: TrajectoryMixture, target: Tensor, mask: Tensor, agent_weight: Tensor | None = None
) -> Tensor:
    """-log sum_m pi_m prod_t N(target_t | mode m) per agent, summed over the agents and
    divided by their counted steps (so it reads per agent-step, as the NLL terms do).
    target (B, T_pred, N, 2), mask (B, T_pred, N); agent_weight (B, 1, N) or None."""
    log_prob = modes.trajectory_log_prob(target, mask)  # (B, N)
    steps = mask.sum(1).to(log_prob.dtype)  # (B, N)
    if agent_weight is not None:
        log_prob, steps = log_prob * agent_weight[:, 0], steps * agent_weight[:, 0]
    return -log_prob.sum() / steps.sum().clamp(min=1)


@dataclass(frozen=True)
class LossWeights:
    """Weights of the loss terms (paper: beta1 = beta2 = 0.01, tau = 1e-3 m)."""

    beta1: float = 0.01  # variance penalties
    beta2: float = 0.01  # attention total variation
    tau: float = 1e-3  # [m] threshold of the variance penalty
    sequence: bool = True  # include the rollout terms
    # "nll": the NLL trains means and covariances; "displacement": the means' displacement error
    # [m] trains the means, the NLL around the detached means the covariances (TrainConfig)
    mean_loss: str = "nll"
    # score a one-step prediction only where the agent's previous position is known: the first
    # step of a track has no velocity, so its prediction misses by a whole step (~2 m) and that
    # unlearnable error would dominate every other one-step error (~1-10 mm)
    needs_previous: bool = False
    # weight of the focal (main) agents' agent-steps in the NLL, variance and displacement terms
    # (the others count 1; each term stays a weighted mean): the metric and checkpoint choice
    # score only the focal agents, 2 of 22 cars in the synthetic scenarios
    main_weight: float = 1.0
    # [m] where the variance penalty turns linear (`variance_penalty`); 0: the paper's exp
    penalty_linear_from_m: float = 0.0


def compute_loss(
    out: ModelOutput,
    positions: Tensor,
    valid: Tensor,
    num_observed: int,
    weights: LossWeights,
    focal: Tensor | None = None,
) -> tuple[Tensor, dict[str, float]]:
    """Total loss L = nll + nll_seq + beta1 (var + var_seq) + beta2 (tv + tv_seq) and its terms
    (with mean_loss "displacement", plus de and de_seq: the one-step and rollout means' mean
    displacement errors [m], while the NLL terms see detached means).

    positions (B, T, N, 2) [m], valid (B, T, N); focal (B, N), needed for a main_weight other
    than 1 (`main_agent_weights`). One-step terms cover t = 1 .. T-1 where the agent
    is present at t and t-1; rollout terms cover t = T_obs .. T-1 where the agent is present at t
    and was rolled out (present at T_obs-1).
    """
    terms: dict[str, Tensor] = {}
    target = positions[:, 1:]  # (B, T-1, N, 2)
    mask = valid[:, 1:] & valid[:, :-1]  # (B, T-1, N)
    if weights.needs_previous:
        mask = mask & torch.cat([torch.zeros_like(valid[:, :1]), valid[:, :-2]], 1)
    one = out.one_step
    w = main_agent_weights(focal, weights.main_weight, positions)
    displacement = weights.mean_loss == "displacement"
    one_mean = one.mean.detach() if displacement else one.mean
    linear_from = weights.penalty_linear_from_m
    terms["nll"] = _mean(*masked_sum(gaussian_nll(target, one_mean, one.tril), mask, w))
    terms["var"] = _mean(*masked_sum(variance_penalty(one, weights.tau, linear_from), mask, w))
    terms["tv"] = _mean(*attention_tv(out.attention, valid[:, :-1]))
    total = terms["nll"] + weights.beta1 * terms["var"] + weights.beta2 * terms["tv"]
    if displacement:
        terms["de"] = _mean(*masked_sum(distance(target, one.mean), mask, w))
        total = total + terms["de"]
    if weights.sequence:
        if out.rollout is None:
            raise ValueError("the sequence loss needs a rollout")
        roll = out.rollout
        seq_mask = valid[:, num_observed:] & out.rollout_present.unsqueeze(1)  # (B, T_pred, N)
        seq_target = positions[:, num_observed:]  # (B, T_pred, N, 2)
        roll_mean = roll.mean.detach() if displacement else roll.mean
        seq_nll = gaussian_nll(seq_target, roll_mean, roll.tril)  # (B, T_pred, N)
        if displacement:
            terms["de_seq"] = _mean(*masked_sum(distance(seq_target, roll.mean), seq_mask, w))
            total = total + terms["de_seq"]
        terms["nll_seq"] = _mean(*masked_sum(seq_nll, seq_mask, w))
        seq_var = variance_penalty(roll, weights.tau, linear_from)  # (B, T_pred, N)
        terms["var_seq"] = _mean(*masked_sum(seq_var, seq_mask, w))
        # rollout attention theta^t, t = T_obs-1 .. T-2: agents rolled out are present throughout
        roll_present = out.rollout_present.unsqueeze(1).expand(-1, roll.mean.shape[1], -1)
        terms["tv_seq"] = _mean(*attention_tv(out.rollout_attention, roll_present))
        total = (
            total
            + terms["nll_seq"]
            + weights.beta1 * terms["var_seq"]
            + weights.beta2 * terms["tv_seq"]
        )
        if out.modes is not None:  # the modes' likelihood of each agent's whole future
            terms["nll_modes"] = mode_nll(out.modes, seq_target, seq_mask, w)
            total = total + terms["nll_modes"]
    summary = {name: float(value.detach()) for name, value in terms.items()}
    summary["loss"] = float(total.detach())
    return total, summary
