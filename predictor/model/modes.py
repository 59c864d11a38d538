"""Trajectory modes (`ModelConfig.modes` = M > 1): a mixture of M futures around the rollout,
trained by the mixture's likelihood of each agent's whole future (multiple-trajectory
prediction as in Cui et al., "Multimodal Trajectory Predictions for Autonomous Driving using
Deep Convolutional Networks", ICRA 2019, here on top of the recurrent rollout).

From each agent's node features at its last observed step, a small network gives per mode m a
weight pi_m (softmax), a velocity change c1 and an acceleration c2 (agent frame, in units of the
anchored rollout's `anchor_std` [m/step]) and a spread factor s_m. Mode m's mean at predicted step
k = 1 .. P is the rollout's mean plus rotate(anchor_std * (c1 k + c2 k^2 / P)); its covariance is
the rollout's times s_m^2, s_m = exp(MAX_LOG_SPREAD tanh(raw)) (bounded). So the modes are
smooth, whole-trajectory alternatives (a turn, a stop, a faster walk) of any horizon, and the
rollout (attention, highway, its own losses) is unchanged by them. The last layer starts with
small random weights, not zeros, so that the modes can separate.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from predictor.agent_frame import rotate
from predictor.config import ModelConfig
from predictor.outputs import Gaussian2D, TrajectoryMixture

MODE_HIDDEN = 64  # hidden width of the mode network
MAX_LOG_SPREAD = 2.0  # |log s_m| <= 2: a mode's covariance is the rollout's times e^-4 .. e^4
OUTPUTS_PER_MODE = 6  # logit, c1 (2), c2 (2), spread


class ModeHead(nn.Module):
    """The mode network: node features at the last observed step -> a `TrajectoryMixture`."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.num_modes = config.modes
        self.net = nn.Sequential(
            nn.Linear(config.node_hidden, MODE_HIDDEN),
            nn.Tanh(),
            nn.Linear(MODE_HIDDEN, config.modes * OUTPUTS_PER_MODE),
        )
        with torch.no_grad():  # small distinct modes at the start, equal weights
            last = self.net[-1]
            last.weight.mul_(0.1)
            last.bias.zero_()

    def forward(
        self, o_last: Tensor, rollout: Gaussian2D, rotation: Tensor, unit: Tensor
    ) -> TrajectoryMixture:
        """o_last (B, N, H): node features at step T_obs-1; rollout (B, P, N, .): the rolled
        out Gaussians; rotation (B, N, 2): the agent frames' (cos, sin); unit (2,) [m/step]."""
        batch, steps, agents, _ = rollout.mean.shape
        raw = self.net(o_last).view(batch, agents, self.num_modes, OUTPUTS_PER_MODE)
        log_weights = torch.log_softmax(raw[..., 0], -1)  # (B, N, M)
        k = torch.arange(1, steps + 1, dtype=raw.dtype, device=raw.device)  # (P,)
        c1, c2 = raw[..., 1:3], raw[..., 3:5]  # (B, N, M, 2)
        offset = (
            c1.unsqueeze(1) * k[:, None, None, None]
            + c2.unsqueeze(1) * (k * k / steps)[:, None, None, None]
        )  # (B, P, N, M, 2)
        offset = rotate(offset * unit, rotation[:, None, :, None, :])
        spread = torch.exp(MAX_LOG_SPREAD * torch.tanh(raw[..., 5]))  # (B, N, M)
        mean = rollout.mean.unsqueeze(-2) + offset  # (B, P, N, M, 2)
        tril = rollout.tril.unsqueeze(-2) * spread[:, None, :, :, None]  # (B, P, N, M, 3)
        return TrajectoryMixture(log_weights, mean, tril)


def build_modes(config: ModelConfig) -> ModeHead | None:
    """The mode network for `config.modes` > 1, else None (the model's one Gaussian)."""
    return ModeHead(config) if config.modes > 1 else None
