"""What the predictor returns and the layout of its attention: bivariate Gaussians over
positions, the per-step and rollout outputs, and the compact (..., N, N-1) attention with its
edge order (`edge_index`, `expand_attention`). Kept apart from the model (predictor.model) so
that losses, metrics and predictions read the outputs without the network."""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import NamedTuple

import torch
from torch import Tensor

LSTMState = tuple[Tensor, Tensor]


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

    def with_rollout(self, rollout: Rollout) -> ModelOutput:
        """A copy holding `rollout`."""
        return replace(
            self,
            rollout=rollout.gaussian,
            rollout_attention=rollout.attention,
            rollout_present=rollout.present,
        )


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
