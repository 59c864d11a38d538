"""The output head: node features o_i -> the Gaussian of agent i's next position.

F_pred gives a mean offset (2) and the raw values of the Cholesky factor (3); with
`ModelConfig.detach_covariance` the raw Cholesky values come from a head of their own, F_cov,
behind a stop-gradient, so that the likelihood trains only that head (`covariance_parameters`
are then a gradient-clipping group of their own). The mean is a fixed prior plus the offset:
with `mean_prior="velocity"` (default) the prior is constant velocity, p^t + (p^t - p^{t-1}),
so the network learns deviations from it; "position" uses p^t alone. The covariance's Cholesky
factor L = [[l11, 0], [l21, l22]] in metres has
l_kk = min_std_m + (init_std_m - min_std_m) * exp(log_std_gain * raw) > 0 and l21 = c * l22
(correlation c / sqrt(1 + c^2)). The layers start at zero: the untrained model predicts the
prior with stds init_std_m. The gain lets Adam (lr 1e-3) move the stds across the decades they
need (1 mm for a car at constant speed, metres late in a rollout) within a paper-length run;
without it a std moves ~0.1 % per step.

Two heads, chosen by `ModelConfig.frame`:

- `SceneFrameHead` (the paper's): the offset in world axes times `step_scale_m`.
- `AgentFrameHead`: offset and Cholesky factor in the agent's frame, rotated to world axes; the
  offset's unit is the training split's RMS one-step deviation from constant velocity
  (`offset_scale="deviation"`, `offset_std`) or `step_scale_m`. With
  `rollout_prior="anchored"` it also has the anchored rollout's head F_roll: the rollout's
  mean is p^t plus the velocity at the last observed step (plus the highway's velocity
  changes), and F_roll's output is the velocity change since then, in units of its training
  RMS (`anchor_std`).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from predictor.agent_frame import rotate, rotate_tril
from predictor.config import ModelConfig
from predictor.model.pass_inputs import PassInputs
from predictor.model.statistics import floored_rms
from predictor.outputs import Gaussian2D

MAX_LOG_GAIN = 12.0  # cap of log(std excess / initial excess): stds stay finite


class SceneFrameHead(nn.Module):
    """F_pred (and F_cov): next-position Gaussians in world axes (the paper's head)."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        hidden = config.node_hidden
        if config.detach_covariance:  # separate heads: offset (2), Cholesky raw (3)
            self.f_pred = nn.Linear(hidden, 2)
            self.f_cov: nn.Linear | None = nn.Linear(hidden, 3)
        else:
            self.f_pred = nn.Linear(hidden, 5)  # offset (2), Cholesky raw (3)
            self.f_cov = None
        self.f_roll: nn.Linear | None = None  # the anchored rollout's layer (AgentFrameHead)
        self.velocity_prior = config.mean_prior == "velocity"
        self.step_scale_m = config.step_scale_m
        self.min_std_m, self.init_std_m = config.min_std_m, config.init_std_m
        self.log_std_gain = config.log_std_gain
        zero_init(self.f_pred, self.f_cov)

    @property
    def anchored(self) -> bool:
        """Whether the head predicts anchored rollout steps (`rollout_prior="anchored"`)."""
        return self.f_roll is not None

    def covariance_parameters(self) -> list[nn.Parameter]:
        """The parameters trained by the likelihood alone (F_cov's), or none."""
        return [] if self.f_cov is None else list(self.f_cov.parameters())

    def forward(
        self, o_node: Tensor, pos: Tensor, prev_pos: Tensor, rotation: Tensor | None
    ) -> Gaussian2D:
        """The Gaussians of the positions after pos (..., B, N, 2) [m], from node features
        o_node (..., B*N, H) (or (..., B, N, H)) and the previous positions; rotation: the
        agent frames' (cos, sin) (B, N, 2), which only the agent-frame head reads."""
        raw = self.raw_outputs(o_node).view(*pos.shape[:-1], 5)  # (..., B, N, 5)
        base = pos + (pos - prev_pos) if self.velocity_prior else pos  # (..., B, N, 2)
        return self.gaussian(raw, base, rotation)

    def raw_outputs(self, o_node: Tensor, anchored: bool = False) -> Tensor:
        """F_pred(o_node) (..., 5): mean offset (2) and Cholesky raw values (3); with
        `detach_covariance` the last three see the features through a stop-gradient; with
        `anchored` the mean offset comes from F_roll (anchored rollout steps)."""
        raw = self.f_pred(o_node)
        cov = raw[..., 2:] if self.f_cov is None else self.f_cov(o_node.detach())
        offset = self.f_roll(o_node) if anchored else raw[..., :2]
        return torch.cat([offset, cov], -1)

    def gaussian(self, raw: Tensor, base: Tensor, rotation: Tensor | None) -> Gaussian2D:
        """Next-position Gaussian from the raw outputs (..., 5) and the base of the mean [m]."""
        mean = base + raw[..., :2] * self.step_scale_m  # (..., 2)
        return Gaussian2D(mean, self.tril(raw))

    def tril(self, raw: Tensor) -> Tensor:
        """Cholesky entries (l11, l21, l22) (..., 3) from the raw outputs' last three."""
        log_gain = (self.log_std_gain * raw[..., 2:4]).clamp(max=MAX_LOG_GAIN)  # (..., 2)
        excess = self.init_std_m - self.min_std_m
        diag = self.min_std_m + excess * torch.exp(log_gain)  # (..., 2)
        off = raw[..., 4:5] * diag[..., 1:]  # (..., 1) l21 = c * l22: correlation c / sqrt(1+c^2)
        return torch.cat([diag[..., :1], off, diag[..., 1:]], -1)  # (..., 3)


class AgentFrameHead(SceneFrameHead):
    """Next-position Gaussians predicted in each agent's frame and rotated to world axes, with
    the output scales fitted on the training split (`fit_scales`, kept as buffers in the
    checkpoint) and, with the anchored rollout prior, F_roll."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__(config)
        anchored = config.rollout_prior == "anchored"
        self.f_roll = nn.Linear(config.node_hidden, 2) if anchored else None  # velocity change
        zero_init(self.f_roll)
        self.deviation = config.offset_scale == "deviation"
        # the one-step offset's and the anchored rollout's units [m/step]: step_scale_m (the
        # paper model's car constant) until fitted
        self.register_buffer("offset_std", torch.full((2,), config.step_scale_m))
        self.register_buffer("anchor_std", torch.full((2,), config.step_scale_m))

    def gaussian(
        self, raw: Tensor, base: Tensor, rotation: Tensor | None, scale: Tensor | None = None
    ) -> Gaussian2D:
        """Next-position Gaussian with offset and Cholesky factor in the agent frame, rotated to
        world axes; the offset unit is `scale` if given, else `offset_std` ("deviation") or
        step_scale_m ("step")."""
        if scale is None:
            scale = self.offset_std if self.deviation else self.step_scale_m
        offset = rotate(raw[..., :2] * scale, rotation)  # (..., 2)
        return Gaussian2D(base + offset, rotate_tril(self.tril(raw), rotation))

    def anchored_step(self, o_node: Tensor, base: Tensor, rotation: Tensor) -> Gaussian2D:
        """An anchored rollout step: the mean is `base` (..., B, N, 2) (p^t plus the anchor
        velocity) plus F_roll's velocity change in units of `anchor_std`; o_node (..., B*N, H)
        (or (..., B, N, H))."""
        raw = self.raw_outputs(o_node, anchored=True).view(*base.shape[:-1], 5)
        return self.gaussian(raw, base, rotation, self.anchor_std)

    @torch.no_grad()
    def fit_scales(self, steps: PassInputs) -> None:
        """`offset_std` (offset_scale "deviation"): the RMS per axis of the agent-frame one-step
        deviation from constant velocity, p^{t+1} - 2 p^t + p^{t-1} (zero mean by
        construction, so a zero output stays constant velocity); `anchor_std` (anchored): the
        RMS per axis of the agent-frame velocity change since the last observed step,
        v^t - v^{T_obs-1}, over the predicted steps; over the training scenes of `steps`."""
        present, rotation = steps.present, steps.frame[1]
        if self.deviation:
            pos, prev = steps.pos, steps.prev_pos
            dev = pos[1:] - 2 * pos[:-1] + prev[:-1]  # (T-1, B, N, 2)
            before = torch.cat([present[:1] & False, present[:-2]], 0)  # (T-1, B, N) at t-1
            ok = present[1:] & present[:-1] & before
            self.offset_std.copy_(floored_rms(rotate(dev, rotation, inverse=True)[ok]))
        if self.anchored:
            t_obs = steps.num_observed
            velocity = steps.pos - steps.prev_pos  # (T, B, N, 2)
            change = velocity[t_obs:] - velocity[t_obs - 1]  # (T_pred, B, N, 2)
            before = present[t_obs - 2] if t_obs >= 2 else torch.zeros_like(present[0])
            ok = present[t_obs:] & present[t_obs - 1 : -1] & present[t_obs - 1] & before
            self.anchor_std.copy_(floored_rms(rotate(change, rotation, inverse=True)[ok]))


def build_head(config: ModelConfig) -> SceneFrameHead:
    """The output head of `config.frame`."""
    return AgentFrameHead(config) if config.frame == "agent" else SceneFrameHead(config)


def zero_init(*layers: nn.Linear | None) -> None:
    """Zero the weights and biases of `layers` (None: none): the head starts at the prior."""
    with torch.no_grad():
        for layer in layers:
            if layer is not None:
                layer.weight.zero_()
                layer.bias.zero_()
