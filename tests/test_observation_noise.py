"""Tests for the observation noise option: Gaussian noise on the observed positions only,
seeded per trajectory, recorded in the file's config; labels and the rest stay clean."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from pipeline.generation import GenerateConfig, generate_dataset
from scenarios.observation_noise import NOISE_STREAM, add_observation_noise
from trajectory_data.reader import read_dataset


def test_noise_is_the_seeded_gaussian_on_observed_positions_only():
    rng = np.random.default_rng(0)
    states = rng.uniform(0, 100, (3, 8, 4, 4)).astype(np.float32)
    valid = np.ones((3, 8, 4), dtype=bool)
    valid[1, 2, 3] = False
    seeds = np.array([5, 6, 7])
    noisy = add_observation_noise(states, valid, seeds, 5, 0.5)
    np.testing.assert_array_equal(noisy[:, 5:], states[:, 5:])  # predicted steps clean
    np.testing.assert_array_equal(noisy[..., 2:], states[..., 2:])  # heading, speed clean
    assert noisy[1, 2, 3, 0] == states[1, 2, 3, 0]  # absent agents untouched
    expected = 0.5 * np.random.default_rng([6, NOISE_STREAM]).standard_normal((5, 4, 2))
    expected = (states[1, :5, :, :2].astype(np.float64) + expected).astype(np.float32)
    expected[2, 3] = states[1, 2, 3, :2]
    np.testing.assert_array_equal(noisy[1, :5, :, :2], expected)
    np.testing.assert_array_equal(add_observation_noise(states, valid, seeds, 5, 0.0), states)


def test_noise_has_the_asked_standard_deviation():
    states = np.zeros((200, 10, 5, 2), dtype=np.float32)
    noisy = add_observation_noise(states, np.ones((200, 10, 5), bool), np.arange(200), 10, 0.3)
    sample = noisy.reshape(-1).astype(np.float64)
    assert stats.kstest(sample / 0.3, "norm").pvalue > 1e-3
    assert np.std(sample) == pytest.approx(0.3, rel=0.02)


@pytest.mark.parametrize("sigma", [-0.1, float("nan"), float("inf"), "1", True])
def test_bad_sigma_is_refused(sigma):
    with pytest.raises(ValueError, match="observation noise"):
        add_observation_noise(np.zeros((1, 2, 1, 2)), np.ones((1, 2, 1), bool), [0], 1, sigma)


def test_generated_noise_keeps_labels_and_records_sigma(tmp_path):
    config = GenerateConfig.for_scenario("halting_car_v3", num_major=3, num_minor=1, num_test=1)
    clean = generate_dataset(config, tmp_path / "clean.h5", progress=False)
    noisy = generate_dataset(
        config, tmp_path / "noisy.h5", progress=False, observation_noise_m=0.2, influence=True
    )
    again = generate_dataset(config, tmp_path / "again.h5", progress=False, observation_noise_m=0.2)
    meta, splits = read_dataset(noisy.path)
    clean_meta, clean_splits = read_dataset(clean.path)
    _, again_splits = read_dataset(again.path)
    assert meta.config["observation_noise_m"] == 0.2
    assert "observation_noise_m" not in clean_meta.config
    observed = meta.num_observed
    for name, data in splits.items():
        reference = clean_splits[name]
        np.testing.assert_array_equal(data.states, again_splits[name].states)  # deterministic
        np.testing.assert_array_equal(data.states[:, observed:], reference.states[:, observed:])
        if data.n:
            change = data.states[:, :observed, :, :2] - reference.states[:, :observed, :, :2]
            assert 0.1 < np.std(change) < 0.3
        for field in ("actions", "attention", "interaction", "valid", "seed"):
            np.testing.assert_array_equal(getattr(data, field), getattr(reference, field))
    # influence comes from the clean run: equal to a noiseless file's
    _, influence_splits = read_dataset(
        generate_dataset(config, tmp_path / "inf.h5", progress=False, influence=True).path
    )
    for name, data in splits.items():
        np.testing.assert_array_equal(data.influence, influence_splits[name].influence)
