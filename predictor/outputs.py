"""What the predictor returns and the layout of its attention: bivariate Gaussians over
positions, the per-step and rollout outputs, and the compact (..., N, N-1) attention with its
edge order (`edge_index`, `expand_attention`). Kept apart from the model (predictor.model) so
that losses, metrics and predictions read the outputs without the network."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import torch
from torch import Tensor

LSTMState = tuple[Tensor, Tensor]
LOG_2PI = math.log(2.0 * math.pi)


@dataclass
class Gaussian2D:
    """Bivariate Gaussians over positions [m]: mean (..., 2) and Cholesky entries (..., 3).

    `tril[..., 0] = l11 > 0`, `tril[..., 1] = l21`, `tril[..., 2] = l22 > 0`; Sigma = L L^T.
    """

    mean: Tensor  # (..., 2)
    tril: Tensor  # (..., 3)

    def scale_tril(self) -> Tensor:
        """Full lower-triangular factor L, shape (..., 2, 2)."""
        zero = torch.zeros_like(self.tril[..., 0])  # (...)
        row0 = torch.stack([self.tril[..., 0], zero], dim=-1)  # (..., 2)
        row1 = torch.stack([self.tril[..., 1], self.tril[..., 2]], dim=-1)  # (..., 2)
        return torch.stack([row0, row1], dim=-2)  # (..., 2, 2)

    def covariance(self) -> Tensor:
        """Sigma = L L^T, shape (..., 2, 2)."""
        tril = self.scale_tril()  # (..., 2, 2)
        return tril @ tril.transpose(-1, -2)  # (..., 2, 2)

    def stds(self) -> Tensor:
        """Marginal standard deviations sqrt(Sigma_kk), shape (..., 2)."""
        second = torch.hypot(self.tril[..., 1], self.tril[..., 2])  # (...)
        return torch.stack([self.tril[..., 0], second], -1)  # (..., 2)

    def log_prob(self, x: Tensor) -> Tensor:
        """log N(x | mean, L L^T) of positions x (..., 2) [m], elementwise: (...)."""
        diff = x - self.mean  # (..., 2)
        z0 = diff[..., 0] / self.tril[..., 0]
        z1 = (diff[..., 1] - self.tril[..., 1] * z0) / self.tril[..., 2]
        log_det_half = torch.log(self.tril[..., 0]) + torch.log(self.tril[..., 2])
        return -0.5 * (z0 * z0 + z1 * z1) - log_det_half - LOG_2PI

    def rsample(self) -> Tensor:
        """One reparameterised sample mean + L eps, shape (..., 2)."""
        eps = torch.randn_like(self.mean)  # (..., 2)
        x = self.mean[..., 0] + self.tril[..., 0] * eps[..., 0]  # (...)
        y = self.mean[..., 1] + self.tril[..., 1] * eps[..., 0] + self.tril[..., 2] * eps[..., 1]
        return torch.stack([x, y], dim=-1)  # (..., 2)

    def time_first(self) -> Gaussian2D:
        """Swap the first two dimensions (time-first <-> batch-first)."""
        return Gaussian2D(self.mean.transpose(0, 1), self.tril.transpose(0, 1))

    @staticmethod
    def cat(parts: list[Gaussian2D], dim: int) -> Gaussian2D:
        """Concatenate along a leading dimension."""
        return Gaussian2D(
            torch.cat([p.mean for p in parts], dim), torch.cat([p.tril for p in parts], dim)
        )


class RecurrentState(NamedTuple):
    """LSTM (h, c) of the edge, self-loop and node RNNs, each (1, batch * items, hidden)."""

    edge: LSTMState | None
    self_loop: LSTMState | None
    node: LSTMState | None


@dataclass
class StepOutputs:
    """Outputs of a block of S consecutive steps, time-first."""

    gaussian: Gaussian2D  # (S, B, N, 2) mean, (S, B, N, 3) tril: next-position predictions
    attention: Tensor  # (S, B, N, N-1): theta_ij over the other agents j, 0 off the graph
    state: RecurrentState


@dataclass(frozen=True)
class Rollout:
    """Predictions fed back from step T_obs on, batch-first."""

    gaussian: Gaussian2D  # (B, T_pred, N, .) predictions of t = T_obs .. T-1
    attention: Tensor  # (B, T_pred, N, N-1) theta^t, t = T_obs-1 .. T-2
    present: Tensor  # (B, N) agents rolled out (present at step T_obs-1)
    draws: Tensor | None = None  # (B, T_pred, N, 2) a sampled rollout's draws, if kept


@dataclass(frozen=True)
class ModelOutput:
    """Everything the losses and the evaluation need, batch-first.

    `attention` tensors are compact: entry [..., i, k] is the weight of agent i on its k-th
    other agent (agents 0..N-1 without i, in order), zero where that agent is no neighbour of i
    (`ModelConfig.neighbours`) or absent; `expand_attention` gives (..., N, N).
    The rollout fields are None when the pass made no rollout.
    """

    one_step: Gaussian2D  # (B, S1, N, .) predictions of t = 1 .. S1 (teacher forced)
    attention: Tensor  # (B, S1, N, N-1) theta^t, t = 0 .. S1-1
    rollout: Gaussian2D | None = None  # (B, T_pred, N, .) predictions of t = T_obs .. T-1
    rollout_attention: Tensor | None = None  # (B, T_pred, N, N-1) theta^t, t = T_obs-1 .. T-2
    rollout_present: Tensor | None = None  # (B, N) agents rolled out (present at step T_obs-1)
    # the trajectory modes around the rollout (`ModelConfig.modes` > 1), else None
    modes: TrajectoryMixture | None = None

    def with_rollout(self, rollout: Rollout) -> ModelOutput:
        """A copy holding `rollout`."""
        return replace(
            self,
            rollout=rollout.gaussian,
            rollout_attention=rollout.attention,
            rollout_present=rollout.present,
        )


@dataclass(frozen=True)
class TrajectoryMixture:
    """A mixture of M Gaussian futures per agent, batch-first: mode m has weight pi_m and, at
    every predicted step, a 2-D Gaussian; the modes are whole trajectories (one mode is drawn
    per sampled future, not per step)."""

    log_weights: Tensor  # (B, N, M) log pi_m
    mean: Tensor  # (B, T_pred, N, M, 2) [m]
    tril: Tensor  # (B, T_pred, N, M, 3) Cholesky entries (l11, l21, l22)

    def step_log_prob(self, target: Tensor) -> Tensor:
        """log sum_m pi_m N(target_t | mode m at t): each step's marginal log density of the
        positions target (B, T_pred, N, 2): (B, T_pred, N)."""
        per_mode = Gaussian2D(self.mean, self.tril).log_prob(target.unsqueeze(-2))
        return torch.logsumexp(per_mode + self.log_weights.unsqueeze(1), -1)

    def trajectory_log_prob(self, target: Tensor, mask: Tensor) -> Tensor:
        """log sum_m pi_m prod_t N(target_t | mode m at t) over the steps where `mask`
        (B, T_pred, N): each agent's whole-future log density, (B, N) (log 1 = 0 for an agent
        with no masked step)."""
        per_mode = Gaussian2D(self.mean, self.tril).log_prob(target.unsqueeze(-2))
        per_mode = torch.where(mask.unsqueeze(-1), per_mode, torch.zeros_like(per_mode))
        return torch.logsumexp(per_mode.sum(1) + self.log_weights, -1)

    def sample(self, num_samples: int, generator: torch.Generator | None = None) -> Tensor:
        """K futures (K, B, T_pred, N, 2) [m]: per future and agent a mode drawn by its weight,
        and one standard normal draw shared by the mode's steps (mean_t + L_t eps), so each
        step's samples follow the mode's Gaussian at that step and a future stays smooth."""
        batch, steps, agents, modes, _ = self.mean.shape
        probs = self.log_weights.exp().reshape(batch * agents, modes)
        draw = torch.multinomial(probs, num_samples, replacement=True, generator=generator)
        draw = draw.view(batch, agents, num_samples).permute(2, 0, 1)  # (K, B, N)
        index = draw[:, :, None, :, None, None].expand(-1, -1, steps, -1, 1, 2)  # (K,B,T,N,1,2)
        mean = self.mean.unsqueeze(0).expand(num_samples, -1, -1, -1, -1, -1)
        tril = self.tril.unsqueeze(0).expand(num_samples, -1, -1, -1, -1, -1)
        mean = mean.gather(-2, index).squeeze(-2)  # (K, B, T, N, 2)
        tril = tril.gather(-2, index[..., :1].expand(-1, -1, -1, -1, -1, 3)).squeeze(-2)
        shape = (num_samples, batch, 1, agents, 2)
        eps = torch.randn(shape, generator=generator, dtype=mean.dtype, device=mean.device)
        return sample_with(mean, tril, eps)


def sample_with(mean: Tensor, tril: Tensor, eps: Tensor) -> Tensor:
    """mean + L eps for 2-D Gaussians (mean (..., 2), tril (..., 3)) and standard normal draws
    eps broadcasting to (..., 2)."""
    x = mean[..., 0] + tril[..., 0] * eps[..., 0]
    y = mean[..., 1] + tril[..., 1] * eps[..., 0] + tril[..., 2] * eps[..., 1]
    return torch.stack([x, y], -1)


def edge_index(num_agents: int, device: torch.device | None = None) -> tuple[Tensor, Tensor]:
    """Tail i and head j of the N*(N-1) directed edges, i-major, heads ascending (cached)."""
    return _edge_index(num_agents, str(torch.device(device or "cpu")))


@functools.lru_cache(maxsize=16)
def _edge_index(num_agents: int, device: str) -> tuple[Tensor, Tensor]:
    pairs = torch.arange(num_agents * num_agents, device=device)  # (N*N,)
    tail, head = pairs // num_agents, pairs % num_agents  # (N*N,), (N*N,)
    keep = tail != head  # (N*N,)
    return tail[keep], head[keep]  # (M,), (M,)


def expand_attention(compact: Tensor) -> Tensor:
    """Compact attention (..., N, N-1) to (..., N, N) with zeros on the diagonal."""
    num_agents = compact.shape[-2]
    tail, head = edge_index(num_agents, compact.device)  # (M,), (M,)
    flat = compact.new_zeros(*compact.shape[:-2], num_agents * num_agents)  # (..., N*N)
    flat[..., tail * num_agents + head] = compact.reshape(*compact.shape[:-2], -1)
    return flat.view(*compact.shape[:-2], num_agents, num_agents)  # (..., N, N)
