"""Baselines that sample, so that a best-of-K figure has a floor: CVM-S (constant velocity
with its heading turned by Gaussian noise, Schöller et al. 2020) and a fitted ridge baseline's
residual distribution (`RidgeDistribution`: its mean plus the Gaussian of its training
residuals over the whole predicted future, with each step's marginal for closed-form NLLs)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from predictor.baselines import AgentFrames, RidgeBaseline, constant_velocity, ridge_states

if TYPE_CHECKING:  # annotations only: the baselines run on plain numpy arrays
    from trajectory_data.format import DatasetMeta, TrajectorySet

# CVM-S (Schoeller et al., "What the Constant Velocity Model Can Teach Us About Pedestrian
# Motion Prediction", RA-L 2020; github cschoeller/constant_velocity_pedestrian_motion,
# evaluate.py: `sample_angle_std = 25` [deg], `num_samples = 20`): each sample rotates the last
# observed velocity by one Gaussian angle for the whole future and keeps its speed
CVM_S_ANGLE_STD_RAD = float(np.deg2rad(25.0))
CVM_S_SPEED_STD = 0.0  # they do not perturb the speed


def constant_velocity_samples(
    positions: np.ndarray,
    valid: np.ndarray,
    num_observed: int,
    k: int,
    seed: int,
    angle_std_rad: float = CVM_S_ANGLE_STD_RAD,
    speed_std: float = CVM_S_SPEED_STD,
) -> np.ndarray:
    """K sampled futures of CVM-S: constant velocity with the heading of the last observed
    per-step displacement (`constant_velocity`) rotated by an angle ~ N(0, angle_std_rad^2),
    one angle per (scene, sample, agent) for the whole future; with speed_std > 0 the speed is
    also scaled by max(0, 1 + speed_std * N(0, 1)) (relative; CVM-S itself keeps it). Agents
    without a velocity stand still. Deterministic for a seed (numpy Generator: the angles are
    drawn first, shaped (n, K, N), so a speed_std leaves them unchanged).

    positions (n, T, N, 2) [m], valid (n, T, N). Returns (n, K, T_pred, N, 2) float32.
    """
    if k < 1:
        raise ValueError(f"the number of samples must be at least 1, got {k}")
    if angle_std_rad < 0 or speed_std < 0:
        raise ValueError("angle_std_rad and speed_std must be >= 0")
    mean = constant_velocity(positions, valid, num_observed)  # validates num_observed
    last = positions[:, num_observed - 1].astype(np.float64)  # (n, N, 2)
    if num_observed >= 2:
        both = valid[:, num_observed - 1] & valid[:, num_observed - 2]  # (n, N)
        step = np.where(both[..., None], last - positions[:, num_observed - 2], 0.0)
    else:
        step = np.zeros_like(last)
    n, num_agents = last.shape[:2]
    rng = np.random.default_rng(seed)
    angle = rng.normal(0.0, 1.0, (n, k, num_agents)) * angle_std_rad  # (n, K, N)
    cos, sin = np.cos(angle), np.sin(angle)
    step = step[:, None]  # (n, 1, N, 2)
    turned = np.stack(
        [cos * step[..., 0] - sin * step[..., 1], sin * step[..., 0] + cos * step[..., 1]], -1
    )  # (n, K, N, 2)
    if speed_std > 0:
        turned = turned * np.maximum(0.0, 1.0 + speed_std * rng.normal(size=angle.shape))[..., None]
    ahead = np.arange(1, mean.shape[1] + 1, dtype=np.float64)  # (T_pred,)
    pred = last[:, None, None] + ahead[None, None, :, None, None] * turned[:, :, None]
    return pred.astype(np.float32)  # (n, K, T_pred, N, 2)


@dataclass(frozen=True)
class RidgeDistribution:
    """The predictive distribution of a fitted `RidgeBaseline`: the Gaussian of its training
    residuals (`RidgeBaseline.residual_chol`, `fallback_chol`, set by `fit`) around its mean."""

    ridge: RidgeBaseline

    def sample_set(self, data: TrajectorySet, meta: DatasetMeta, k: int, seed: int) -> np.ndarray:
        """`sample` the scenes of `data`, a split of a file described by `meta`."""
        states = ridge_states(data.states, meta.state_names)
        return self.sample(states, data.valid, data.attention, data.roles, k, seed, data.case)

    def step_gaussians(
        self, data: TrajectorySet, meta: DatasetMeta
    ) -> tuple[np.ndarray, np.ndarray]:
        """`step_gaussians_of` the scenes of `data`, a split of a file described by `meta`."""
        states = ridge_states(data.states, meta.state_names)
        return self.step_gaussians_of(states, data.valid, data.attention, data.roles, data.case)

    def sample(
        self,
        states: np.ndarray,
        valid: np.ndarray,
        attention: np.ndarray,
        roles: np.ndarray,
        k: int,
        seed: int,
        case: np.ndarray | None = None,
    ) -> np.ndarray:
        """K sampled futures (n, K, T_pred, N, 2) float32 [m]: the prediction (`predict`) plus
        L z, z ~ N(0, I) (numpy Generator of `seed`), L the Cholesky factor of the agent's
        group's training-residual Gaussian over the whole predicted trajectory (in the agent's
        frame, rotated back to world axes). Agents constant velocity predicts (incomplete
        history, or a group without a fit) get constant velocity plus an isotropic Gaussian
        whose covariance over the steps is that of constant velocity's errors on the training
        agents (not CVM-S: a Gaussian keeps their NLL closed-form, `step_gaussians_of`).

        The residuals are in-sample, so the spread is slightly optimistic (by about the share
        of effective parameters in the training samples)."""
        if k < 1:
            raise ValueError(f"the number of samples must be at least 1, got {k}")
        mean, chol, modelled, frames = self._distribution(states, valid, attention, roles, case)
        n, num_steps, num_agents, _ = mean.shape
        z = np.random.default_rng(seed).standard_normal((n, num_agents, k, 2 * num_steps))
        local = np.einsum("nmij,nmkj->nmki", chol, z).reshape(n, num_agents, k, num_steps, 2)
        world = np.einsum("nmji,nmktj->nmkti", frames.rotation, local)  # R^T: to world axes
        noise = np.where(modelled[:, :, None, None, None], world, local)  # isotropic: as drawn
        return (mean[:, None] + noise.transpose(0, 2, 3, 1, 4)).astype(np.float32)

    def step_gaussians_of(
        self,
        states: np.ndarray,
        valid: np.ndarray,
        attention: np.ndarray,
        roles: np.ndarray,
        case: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Each step's marginal 2-D Gaussian of `sample`'s distribution, in world axes: means
        (n, T_pred, N, 2) [m] (`predict`) and Cholesky entries (l11, l21, l22) (n, T_pred, N, 3),
        for closed-form NLLs (`predictor.probabilistic.gaussian_nll`)."""
        mean, chol, modelled, frames = self._distribution(states, valid, attention, roles, case)
        n, num_steps, num_agents, _ = mean.shape
        cov = np.einsum("nmij,nmkj->nmik", chol, chol)  # (n, N, D, D) in the agent frame
        blocks = cov.reshape(n, num_agents, num_steps, 2, num_steps, 2)
        steps = np.arange(num_steps)
        local = blocks[:, :, steps, :, steps].transpose(1, 2, 0, 3, 4)  # (n, N, T_pred, 2, 2)
        rotation = frames.rotation[:, :, None]  # (n, N, 1, 2, 2)
        world = np.einsum("...ji,...jk,...kl->...il", rotation, local, rotation)  # R^T S R
        step_cov = np.where(modelled[:, :, None, None, None], world, local)
        l11 = np.sqrt(step_cov[..., 0, 0])
        l21 = step_cov[..., 1, 0] / l11
        l22 = np.sqrt(np.maximum(step_cov[..., 1, 1] - l21 * l21, 0.0))
        tril = np.stack([l11, l21, l22], -1).transpose(0, 2, 1, 3)  # (n, T_pred, N, 3)
        return mean, tril

    def _distribution(
        self,
        states: np.ndarray,
        valid: np.ndarray,
        attention: np.ndarray,
        roles: np.ndarray,
        case: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, AgentFrames]:
        """Mean (n, T_pred, N, 2) float64, each agent's Cholesky factor (n, N, D, D) in its
        frame (D = T_pred * 2), whether its group's regression predicts it (n, N), frames."""
        if self.ridge.fallback_chol is None:
            raise ValueError(
                "the ridge baseline's spread needs a fit on complete training agents first"
            )
        mean = self.ridge.predict(states, valid, attention, roles, case).astype(np.float64)
        _, usable, frames = self.ridge.features(states, valid, attention, roles)
        groups = self.ridge.group_keys(states, attention, roles, case)
        num_dims = 2 * mean.shape[1]
        chol = np.broadcast_to(
            np.kron(self.ridge.fallback_chol, np.eye(2)), usable.shape + (num_dims,) * 2
        )
        chol, modelled = chol.copy(), np.zeros(usable.shape, dtype=bool)
        for group, factor in self.ridge.residual_chol.items():
            rows = usable & (groups == group)
            chol[rows], modelled[rows] = factor, True
        return mean, chol, modelled, frames
