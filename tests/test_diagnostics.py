"""predictor.diagnostics: error curves, one-step errors and the counterfactual check against
hand-computed values and predictors whose dependence on other agents is known."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from predictor.config import ModelConfig
from predictor.diagnostics import (
    counterfactual_shift,
    error_curve,
    one_step_errors,
    swap_history,
)
from predictor.model import SmoothAttentionPredictor
from trajectory_data.torch_dataset import Batch

torch.set_num_threads(1)


def test_error_curve_is_the_mean_distance_per_step_over_counted_agents():
    pred = np.zeros((2, 3, 2, 2))
    true = np.zeros((2, 3, 2, 2))
    true[0, :, 0] = [3.0, 4.0]  # 5 m at every step for scene 0, agent 0
    true[1, 2, 1] = [0.0, 1.0]  # 1 m at the last step for scene 1, agent 1
    mask = np.ones((2, 3, 2), dtype=bool)
    mask[1, 0] = False  # scene 1 does not count at step 0
    curve = error_curve(pred, true, mask, slice(None))
    assert curve == pytest.approx([5.0 / 2, 5.0 / 4, 6.0 / 4])
    assert error_curve(pred, true, np.zeros_like(mask), slice(None)) == [None] * 3


def test_swap_history_copies_the_next_scenes_observed_slot_only():
    states = np.arange(3 * 4 * 3 * 2, dtype=float).reshape(3, 4, 3, 2)
    valid = np.ones((3, 4, 3), dtype=bool)
    valid[1, 0, 2] = False
    new_states, new_valid = swap_history(states, valid, np.array([2, -1, 0]), num_observed=2)
    np.testing.assert_array_equal(new_states[0, :2, 2], states[1, :2, 2])
    assert not new_valid[0, 0, 2]  # validity travels with the history
    np.testing.assert_array_equal(new_states[2, :2, 0], states[0, :2, 0])  # wraps around
    np.testing.assert_array_equal(new_states[1], states[1])  # -1: untouched
    np.testing.assert_array_equal(new_states[:, 2:], states[:, 2:])  # the future is kept
    assert states[0, 0, 2, 0] == 4.0  # inputs are not modified


def FOCAL_01(n: int, agents: int) -> np.ndarray:  # noqa: N802 - reads as a constant
    """(n, N) focal mask of the synthetic scenarios: slots 0 and 1."""
    focal = np.zeros((n, agents), dtype=bool)
    focal[:, :2] = True
    return focal


def labelled_scenes(n: int = 4, steps: int = 6, agents: int = 5):
    rng = np.random.default_rng(0)
    states = rng.normal(size=(n, steps, agents, 4)) * 10
    valid = np.ones((n, steps, agents), dtype=bool)
    attention = np.full((n, steps, agents), -1)
    attention[:, :, 0], attention[:, :, 1] = 1, 0  # the two main cars attend each other
    return states, valid, attention


def test_counterfactual_of_a_predictor_reading_only_the_labelled_car():
    """Agent 0 predicts agent 1's last observed position, agent 1 agent 0's, everyone else
    stands still: swapping the labelled car moves a main agent's prediction by exactly the
    distance between the two scenes' last observed positions of that car; a distractor, 0."""
    states, valid, attention = labelled_scenes()
    num_observed, t_pred = 3, 3

    def predict(s: np.ndarray, v: np.ndarray) -> np.ndarray:
        last = s[:, num_observed - 1, :, :2]  # (n, N, 2)
        out = last.copy()
        out[:, 0], out[:, 1] = last[:, 1], last[:, 0]
        return np.repeat(out[:, None], t_pred, axis=1)

    result = counterfactual_shift(predict, states, valid, attention, num_observed, FOCAL_01(4, 5))
    last = states[:, num_observed - 1, :, :2]
    moved = np.linalg.norm(last - np.roll(last, -1, axis=0), axis=-1)  # (n, N)
    assert result["labelled_m"] == pytest.approx(np.mean([*moved[:, 1], *moved[:, 0]]))
    assert result["distractor_m"] == 0.0
    assert result["pairs"] == 8
    # the focal mask, not the slot order, names the main agents: swap slots 1 and 3 everywhere
    perm = [0, 3, 2, 1, 4]
    relabel = np.argsort(perm)[np.maximum(attention[:, :, perm], 0)]
    moved_focal = FOCAL_01(4, 5)[:, perm]

    def predict_perm(s: np.ndarray, v: np.ndarray) -> np.ndarray:
        return predict(s[:, :, perm], v[:, :, perm])[:, :, perm]

    again = counterfactual_shift(
        predict_perm,
        states[:, :, perm],
        valid[:, :, perm],
        np.where(attention[:, :, perm] >= 0, relabel, -1),
        num_observed,
        moved_focal,
    )
    assert again["labelled_m"] == pytest.approx(result["labelled_m"])
    assert again["pairs"] == 8


def test_counterfactual_counts_nothing_without_labels_or_other_scenes():
    states, valid, attention = labelled_scenes(n=3)

    def predict(s: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.repeat(s[:, 2:3, :, :2], 2, axis=1)

    focal = FOCAL_01(3, 5)
    none = counterfactual_shift(predict, states, valid, np.full_like(attention, -1), 3, focal)
    assert none == {"labelled_m": None, "distractor_m": None, "pairs": 0}
    single = counterfactual_shift(predict, states[:1], valid[:1], attention[:1], 3, focal[:1])
    assert single["pairs"] == 0


def test_one_step_error_of_an_untrained_model_equals_constant_velocity():
    """An untrained model predicts the constant-velocity prior, so both errors must agree."""
    gen = torch.Generator().manual_seed(0)
    positions = torch.cumsum(torch.rand(3, 8, 4, 2, generator=gen), 1)  # accelerating agents
    valid = torch.ones(3, 8, 4, dtype=torch.bool)
    valid[0, 5, 2] = False
    states = torch.cat([positions, torch.zeros(3, 8, 4, 2)], -1)
    batch = Batch(
        states=states,
        valid=valid,
        attention=torch.full((3, 8, 4), -1),
        interaction=torch.zeros(3, 8, dtype=torch.bool),
        case=torch.zeros(3, dtype=torch.long),
        seed=torch.arange(3),
        focal=torch.from_numpy(FOCAL_01(3, 4)),
    )
    model = SmoothAttentionPredictor(ModelConfig(embed_dim=4, edge_hidden=4, node_hidden=4))
    result = one_step_errors(model, batch, num_observed=3)
    for group in ("main_agents", "all_agents"):
        assert result[group]["model_m"] == pytest.approx(result[group]["const_vel_m"], rel=1e-5)
        assert result[group]["const_vel_m"] > 0.05
