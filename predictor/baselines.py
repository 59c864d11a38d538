"""Prediction baselines that need no training."""

from __future__ import annotations

import numpy as np

BASELINES = ("const_vel",)


def constant_velocity(positions: np.ndarray, valid: np.ndarray, num_observed: int) -> np.ndarray:
    """Extrapolate each agent with its last observed per-step displacement.

    positions (n, T, N, 2) [m], valid (n, T, N). The velocity is p[T_obs-1] - p[T_obs-2] per step
    when the agent is present at both steps, else zero (the agent stands still). Returns the
    predicted positions of steps T_obs .. T-1, (n, T_pred, N, 2) float32.
    """
    num_steps = positions.shape[1]
    if not 1 <= num_observed < num_steps:
        raise ValueError(f"num_observed must be in [1, {num_steps - 1}], got {num_observed}")
    last = positions[:, num_observed - 1].astype(np.float64)  # (n, N, 2)
    if num_observed >= 2:
        both = valid[:, num_observed - 1] & valid[:, num_observed - 2]  # (n, N)
        step = last - positions[:, num_observed - 2]  # (n, N, 2)
        step = np.where(both[..., None], step, 0.0)  # (n, N, 2)
    else:
        step = np.zeros_like(last)
    ahead = np.arange(1, num_steps - num_observed + 1, dtype=np.float64)  # (T_pred,)
    pred = last[:, None] + ahead[None, :, None, None] * step[:, None]  # (n, T_pred, N, 2)
    return pred.astype(np.float32)
