"""Observation noise: Gaussian noise on the observed positions of generated trajectories.

Noisy inputs are where a prior on smooth attention should matter (issue 68), so the generator
can blur what a predictor observes: every present agent's x and y at the observed steps (t <
num_observed) get independent N(0, sigma^2) noise [m]. The predicted steps stay clean (a
prediction is scored against the true motion, not against noise), and so do headings, speeds,
actions, labels and influence (they describe the clean run). The noise of a trajectory is drawn
from its own generator, seeded by the trajectory's seed and NOISE_STREAM, so it depends on
nothing else (not on workers, batches or the other trajectories).
"""

from __future__ import annotations

import math

import numpy as np

NOISE_STREAM = 0x6E6F6973  # the noise's stream beside a trajectory's seed (b"nois")


def check_noise(sigma_m: float) -> float:
    """`sigma_m` as a float; ValueError unless it is a finite number >= 0."""
    if isinstance(sigma_m, bool) or not isinstance(sigma_m, (int, float)):
        raise ValueError(f"observation noise must be a number of metres, got {sigma_m!r}")
    if not math.isfinite(sigma_m) or sigma_m < 0:
        raise ValueError(f"observation noise must be finite and >= 0 m, got {sigma_m}")
    return float(sigma_m)


def add_observation_noise(
    states: np.ndarray,
    valid: np.ndarray,
    seeds: np.ndarray,
    num_observed: int,
    sigma_m: float,
) -> np.ndarray:
    """A copy of `states` (n, T, N, C), x and y first, with N(0, sigma_m^2) noise on x and y of
    the present agents (`valid` (n, T, N)) at the observed steps; trajectory k's noise comes from
    `np.random.default_rng([seeds[k], NOISE_STREAM])`. sigma_m = 0 returns an unchanged copy."""
    sigma_m = check_noise(sigma_m)
    noisy = np.array(states, copy=True)
    if sigma_m == 0 or noisy.shape[0] == 0:
        return noisy
    steps, agents = noisy.shape[1], noisy.shape[2]
    if not 1 <= num_observed <= steps:
        raise ValueError(f"num_observed must be in [1, {steps}], got {num_observed}")
    for k, seed in enumerate(np.asarray(seeds).tolist()):
        rng = np.random.default_rng([int(seed), NOISE_STREAM])
        noise = sigma_m * rng.standard_normal((num_observed, agents, 2))
        present = valid[k, :num_observed, :, None]
        observed = noisy[k, :num_observed, :, :2].astype(np.float64)
        noisy[k, :num_observed, :, :2] = np.where(present, observed + noise, observed)
    return noisy
