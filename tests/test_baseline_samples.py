"""The baselines' distributions: CVM-S samples against constant velocity and their heading
noise, the residual Gaussian's second moment, and ridge samples against the Gaussians they are
drawn from (recovered noise, per-step marginals, fallback agents)."""

from __future__ import annotations

import numpy as np
import pytest
from test_baselines import DT, OBSERVED, STEPS, fitted, predict, random_agents

from predictor.baseline_samples import (
    CVM_S_ANGLE_STD_RAD,
    RidgeDistribution,
    constant_velocity_samples,
)
from predictor.baselines import (
    RidgeBaseline,
    RidgeConfig,
    constant_velocity,
    zero_mean_gaussian,
)
from predictor.probabilistic import gaussian_nll
from trajectory_data.format import DatasetMeta, TrajectorySet


def test_cvm_s_turns_the_last_velocity_and_reduces_to_constant_velocity():
    positions = np.zeros((1, 5, 3, 2))
    positions[0, :, 0] = [[0, 0], [1, 0], [2, 0], [0, 0], [0, 0]]  # 1 m per step along x
    positions[0, :, 1] = [[0, 0], [0, 0], [4, 4], [0, 0], [0, 0]]  # absent before: no velocity
    valid = np.ones((1, 5, 3), bool)
    valid[0, 1, 1] = False
    cv = constant_velocity(positions, valid, 3)
    assert CVM_S_ANGLE_STD_RAD == pytest.approx(np.pi * 25 / 180)  # Schoeller et al.: 25 deg
    one = constant_velocity_samples(positions, valid, 3, 1, seed=0, angle_std_rad=0.0)
    assert one.shape == (1, 1, 2, 3, 2) and one.dtype == np.float32
    np.testing.assert_array_equal(one[:, 0], cv)
    many = constant_velocity_samples(positions, valid, 3, 4000, seed=7)
    np.testing.assert_array_equal(many, constant_velocity_samples(positions, valid, 3, 4000, 7))
    assert not np.array_equal(many, constant_velocity_samples(positions, valid, 3, 4000, 8))
    np.testing.assert_array_equal(many[0, :, :, 1], np.broadcast_to([4.0, 4.0], (4000, 2, 2)))
    moved = many[0, :, :, 0].astype(np.float64) - [2.0, 0.0]  # (K, 2 steps, 2)
    np.testing.assert_allclose(np.linalg.norm(moved, axis=-1), [[1, 2]] * 4000, rtol=1e-6)
    angle = np.arctan2(moved[:, 1, 1], moved[:, 1, 0])  # one angle for the whole future
    np.testing.assert_allclose(np.arctan2(moved[:, 0, 1], moved[:, 0, 0]), angle, atol=1e-6)
    assert abs(angle.mean()) < 0.03 and angle.std() == pytest.approx(np.deg2rad(25), rel=0.05)
    speedy = constant_velocity_samples(positions, valid, 3, 4000, 7, speed_std=0.2)
    turned = speedy[0, :, 1, 0].astype(np.float64) - [2.0, 0.0]
    np.testing.assert_allclose(np.arctan2(turned[:, 1], turned[:, 0]), angle, atol=1e-5)
    assert (np.linalg.norm(turned, axis=-1) / 2).std() == pytest.approx(0.2, rel=0.07)
    with pytest.raises(ValueError, match="at least 1"):
        constant_velocity_samples(positions, valid, 3, 0, seed=0)


def test_zero_mean_gaussian_is_the_second_moment_shrunk_only_where_singular():
    rng = np.random.default_rng(11)
    rows = rng.normal(0, 1, (50, 4)) @ np.array(
        [[1, 0, 0, 0], [0.5, 2, 0, 0], [0, 0, 1, 0], [0, 0, 0, 0.3]]
    )
    low = zero_mean_gaussian(rows)
    np.testing.assert_allclose(low @ low.T, rows.T @ rows / 50, rtol=1e-10)
    few = zero_mean_gaussian(rows[:3])  # 3 residuals in 4 dimensions: shrunk
    assert np.all(np.diag(few) > 0) and np.all(np.isfinite(few))
    trace = np.trace(rows[:3].T @ rows[:3] / 3)
    assert np.trace(few @ few.T) == pytest.approx(trace)  # shrinking keeps the total variance
    np.testing.assert_array_equal(zero_mean_gaussian(np.zeros((9, 3)), 0.01), 0.01 * np.eye(3))


SPREAD_ALONG, SPREAD_ACROSS = 0.5, 0.1  # [m] future noise along and across the heading


def noisy_futures(rng: np.random.Generator, n: int) -> np.ndarray:
    """Constant speed, plus independent noise on each future position: std SPREAD_ALONG along
    the agent's heading, SPREAD_ACROSS across it (the ridge's residual Gaussian to find)."""
    states = random_agents(rng, n, 3, 0.0)
    noise = rng.normal(0, 1, (n, STEPS - OBSERVED, 3, 2)) * [SPREAD_ALONG, SPREAD_ACROSS]
    heading = states[:, 0, :, 2][:, None]  # (n, 1, N)
    cos, sin = np.cos(heading), np.sin(heading)
    world = np.stack(
        [cos * noise[..., 0] - sin * noise[..., 1], sin * noise[..., 0] + cos * noise[..., 1]], -1
    )
    states[:, OBSERVED:, :, :2] += world
    return states


def test_ridge_residual_gaussian_recovers_the_future_noise():
    rng = np.random.default_rng(12)
    train = noisy_futures(rng, 300)
    model = fitted(train, np.zeros((300, 3), np.int8), RidgeConfig(history_steps=4))
    steps = STEPS - OBSERVED
    low = model.residual_chol[0]
    want = np.diag(np.tile([SPREAD_ALONG**2, SPREAD_ACROSS**2], steps))
    np.testing.assert_allclose(low @ low.T, want, atol=0.2 * SPREAD_ACROSS**2 + 0.02)
    fallback = model.fallback_chol @ model.fallback_chol.T  # per axis: the mean of both
    np.testing.assert_allclose(
        fallback, np.eye(steps) * (SPREAD_ALONG**2 + SPREAD_ACROSS**2) / 2, atol=0.02
    )
    # held out: the expected NLL of a 2-D Gaussian at its truth is log(2 pi s1 s2) + 1
    test = noisy_futures(rng, 200)
    roles = np.zeros((200, 3), np.int8)
    valid, attention = np.ones(test.shape[:3], bool), np.full(test.shape[:3], -1, np.int16)
    mean, tril = RidgeDistribution(model).step_gaussians_of(test, valid, attention, roles)
    np.testing.assert_array_equal(mean, predict(model, test, roles))
    nll = gaussian_nll(test[:, OBSERVED:, :, :2], mean, tril)
    expected = np.log(2 * np.pi * SPREAD_ALONG * SPREAD_ACROSS) + 1
    assert nll.mean() == pytest.approx(expected, abs=0.05)


def test_ridge_samples_follow_its_step_gaussians_and_fallback_agents_are_isotropic():
    rng = np.random.default_rng(13)
    train, test = noisy_futures(rng, 300), noisy_futures(rng, 2)
    model = fitted(train, np.zeros((300, 3), np.int8), RidgeConfig(history_steps=4))
    roles = np.zeros((2, 3), np.int8)
    valid, attention = np.ones(test.shape[:3], bool), np.full(test.shape[:3], -1, np.int16)
    valid[:, OBSERVED - 3, 2] = False  # agent 2: incomplete history, constant velocity
    samples = RidgeDistribution(model).sample(test, valid, attention, roles, 4000, seed=3)
    assert samples.shape == (2, 4000, STEPS - OBSERVED, 3, 2) and samples.dtype == np.float32
    np.testing.assert_array_equal(
        samples, RidgeDistribution(model).sample(test, valid, attention, roles, 4000, 3)
    )
    mean, tril = RidgeDistribution(model).step_gaussians_of(test, valid, attention, roles)
    np.testing.assert_array_equal(
        mean[:, :, 2], constant_velocity(test[..., :2], valid, OBSERVED)[:, :, 2]
    )
    np.testing.assert_allclose(samples.mean(axis=1), mean, atol=5 * SPREAD_ALONG / np.sqrt(4000))
    centred = samples - samples.mean(axis=1, keepdims=True)
    empirical = np.einsum("nktai,nktaj->ntaij", centred, centred) / 3999
    l11, l21, l22 = tril[..., 0], tril[..., 1], tril[..., 2]
    cov = np.stack(
        [np.stack([l11**2, l11 * l21], -1), np.stack([l11 * l21, l21**2 + l22**2], -1)], -2
    )
    np.testing.assert_allclose(empirical, cov, atol=6 * SPREAD_ALONG**2 * np.sqrt(2 / 4000))
    heading = test[:, 0, 0, 2]  # agent 0 (modelled): its largest spread lies along its heading
    along = np.stack([np.cos(heading), np.sin(heading)], -1)
    spread = np.einsum("ni,ntij,nj->nt", along, cov[:, :, 0], along)
    np.testing.assert_allclose(spread, SPREAD_ALONG**2, rtol=0.2)
    assert np.all(tril[:, :, 2, 1] == 0) and np.allclose(tril[:, :, 2, 0], tril[:, :, 2, 2])
    with pytest.raises(ValueError, match="fit"):
        RidgeDistribution(RidgeBaseline()).sample(test, valid, attention, roles, 2, 0)


def test_ridge_sample_set_and_step_gaussians_read_a_split_as_the_arrays():
    rng = np.random.default_rng(14)
    states = noisy_futures(rng, 40).astype(np.float32)
    shape = states.shape[:3]
    split = TrajectorySet(
        states=states,
        actions=np.zeros((*shape, 2), np.float32),
        valid=np.ones(shape, bool),
        attention=np.full(shape, -1, np.int16),
        interaction=np.ones(shape[:2], bool),
        case=np.zeros(40, np.int8),
        seed=np.arange(40, dtype=np.int64),
        roles=np.zeros((40, 3), np.int8),
    )
    meta = DatasetMeta(
        scenario="noisy",
        dt=DT,
        num_observed=OBSERVED,
        num_predicted=STEPS - OBSERVED,
        case_names=("only",),
        major_case="only",
        role_names=("car",),
        config={},
    )
    model = RidgeBaseline(RidgeConfig(history_steps=4)).fit_set(split, meta)
    xyh = states[..., :3]  # x, y, heading: what ridge_states picks
    arrays = (xyh, split.valid, split.attention, split.roles)
    np.testing.assert_array_equal(
        RidgeDistribution(model).sample_set(split, meta, 5, 2),
        RidgeDistribution(model).sample(*arrays, 5, 2),
    )
    for got, want in zip(
        RidgeDistribution(model).step_gaussians(split, meta),
        RidgeDistribution(model).step_gaussians_of(*arrays),
    ):
        np.testing.assert_array_equal(got, want)
