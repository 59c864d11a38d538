"""predictor.faithfulness: attention AUROC against influence (hand-computed and sklearn as the
independent truth), CausalAgents' removal test, and attention total variation over time."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.metrics import roc_auc_score

from predictor.baselines import constant_velocity
from predictor.faithfulness import (
    FaithfulnessError,
    FaithfulnessSettings,
    attention_auroc,
    attention_total_variation,
    mann_whitney_auroc,
    removal_sets,
    removal_shift,
)

LAST = FaithfulnessSettings(auroc_window="last_observed")


def _scene(n=1, steps=4, agents=4, observed=2):
    attention = np.zeros((n, steps - 1, agents, agents), np.float32)
    influence = np.zeros((n, 2, agents, agents), np.float32)
    valid = np.ones((n, steps, agents), bool)
    focal = np.zeros((n, agents), bool)
    focal[:, 0] = True
    return attention, influence, valid, focal, observed


def test_auroc_of_a_hand_computed_scene():
    attention, influence, valid, focal, observed = _scene()
    attention[0, 1, 0] = [0, 0.5, 0.3, 0.2]  # t = T_obs - 1 = 1
    influence[0, 1, 0] = [0, 0.5, 0.0, 0.02]  # "predicted": agents 1 and 3 influence agent 0
    # pairs (pos, neg): (0.5 vs 0.3) a win, (0.2 vs 0.3) a loss: 1/2
    assert attention_auroc(attention, influence, valid, focal, observed, LAST)["auroc"] == 0.5
    influence[0, 1, 0, 3] = 0.01  # at the threshold: not influential; 0.5 vs 0.3 and 0.2
    record = attention_auroc(attention, influence, valid, focal, observed, LAST)
    assert record == {"auroc": 1.0, "agents": 1, "kind": "predicted", "window": "last_observed"}
    attention[0, 1, 0] = [0, 0.3, 0.3, 0.4]  # a tie with one negative counts 1/2
    assert attention_auroc(attention, influence, valid, focal, observed, LAST)["auroc"] == 0.25
    # the episode kind is another matrix: all zero there, one class only, nothing counts
    episode = FaithfulnessSettings(auroc_kind="episode", auroc_window="last_observed")
    assert attention_auroc(attention, influence, valid, focal, observed, episode)["agents"] == 0


def test_auroc_window_averages_the_predicted_steps_and_skips_absent_candidates():
    attention, influence, valid, focal, observed = _scene(steps=5)
    attention[0, 1, 0] = [0, 0.1, 0.6, 0.3]
    attention[0, 2, 0] = [0, 0.5, 0.2, 0.3]
    attention[0, 3, 0] = [0, 0.6, 0.1, 0.3]  # mean over t = 1..3: [0, 0.4, 0.3, 0.3]
    influence[0, 1, 0] = [0, 1.0, 0.0, 0.0]
    assert attention_auroc(attention, influence, valid, focal, observed)["auroc"] == 1.0
    assert attention_auroc(attention, influence, valid, focal, observed, LAST)["auroc"] == 0.0
    valid[0, observed - 1, 2] = False  # candidate 2 absent at T_obs-1: only 1 vs 3 remains
    attention[0, 1, 0] = [0, 0.1, 0.6, 0.05]
    assert attention_auroc(attention, influence, valid, focal, observed, LAST)["auroc"] == 1.0
    influence[0, 1, 0, 3] = np.nan  # no finite entry: no negative left
    assert attention_auroc(attention, influence, valid, focal, observed, LAST)["agents"] == 0


def test_auroc_pools_the_mean_over_agents_and_matches_sklearn():
    rng = np.random.default_rng(3)
    n, steps, agents, observed = 6, 6, 7, 3
    attention = rng.random((n, steps - 1, agents, agents)).astype(np.float32)
    attention[:, :, :, 2] = attention[:, :, :, 3]  # ties
    influence = (rng.random((n, 2, agents, agents)) * 0.03).astype(np.float32)
    valid = rng.random((n, steps, agents)) < 0.85
    focal = rng.random((n, agents)) < 0.5
    record = attention_auroc(attention, influence, valid, focal, observed)
    expected = []
    for k in range(n):
        theta = attention[k, observed - 1 :].mean(axis=0)
        for i in np.flatnonzero(focal[k] & valid[k, observed - 1]):
            others = [j for j in range(agents) if j != i and valid[k, observed - 1, j]]
            labels = influence[k, 1, i, others] > 0.01
            if 0 < labels.sum() < len(labels):
                expected.append(roc_auc_score(labels, theta[i, others]))
    assert record["agents"] == len(expected) > 5
    assert record["auroc"] == pytest.approx(np.mean(expected), abs=1e-6)


def test_mann_whitney_rows_without_both_classes_are_nan():
    scores = np.array([[0.1, 0.2, 0.3], [0.3, 0.2, 0.1]])
    positive = np.array([[True, True, True], [True, False, False]])
    out = mann_whitney_auroc(scores, positive, np.ones_like(positive))
    assert np.isnan(out[0]) and out[1] == 1.0


def test_baselines_nan_attention_gives_none():
    attention, influence, valid, focal, observed = _scene()
    attention[:] = np.nan
    influence[0, 1, 0] = [0, 0.5, 0.0, 0.02]
    assert attention_auroc(attention, influence, valid, focal, observed)["auroc"] is None
    tv = attention_total_variation(attention, valid, focal, observed)
    assert tv["observed"] is None and tv["predicted"] is None and tv["predicted_count"] == 1


def test_removal_sets_keep_agents_influencing_any_focal_agent():
    influence = np.zeros((1, 2, 4, 4), np.float32)
    focal = np.array([[True, True, False, False]])
    influence[0, 0, 1, 2] = 0.5  # agent 2 influences focal agent 1 (episode kind)
    influence[0, 0, 2, 3] = 0.5  # agent 3 influences agent 2 only, not a focal one: removed
    influence[0, 1, 0, 3] = 0.5  # the predicted kind does not pick the removal set
    np.testing.assert_array_equal(removal_sets(influence, focal), [[False, False, False, True]])
    influence[0, 0, 0, 3] = np.nan  # NaN: no information, not influential
    np.testing.assert_array_equal(removal_sets(influence, focal), [[False, False, False, True]])


def _neighbour_mean(num_observed: int):
    """A predictor that reads neighbours: every agent's prediction is, at each predicted step,
    the mean of the last observed x of the agents present then."""

    def predict(states: np.ndarray, valid: np.ndarray) -> np.ndarray:
        last = valid[:, num_observed - 1]  # (n, N)
        x = np.where(last, states[:, num_observed - 1, :, 0], 0.0)
        mean = x.sum(axis=1) / last.sum(axis=1)  # (n,)
        shape = (states.shape[0], states.shape[1] - num_observed, states.shape[2], 2)
        out = np.zeros(shape)
        out[..., 0] = mean[:, None, None]
        return out

    return predict


def test_removal_shift_hand_computed_and_zero_without_neighbours():
    n, steps, agents, observed = 2, 5, 4, 2
    states = np.zeros((n, steps, agents, 4))
    states[:, :, :, 0] = np.array([0.0, 2.0, 4.0, 10.0])  # x of each agent, constant
    states[:, :, :, 2] = 0.0
    valid = np.ones((n, steps, agents), bool)
    focal = np.zeros((n, agents), bool)
    focal[:, :2] = True
    influence = np.zeros((n, 2, agents, agents), np.float32)
    influence[0, 0, 0, 2] = 1.0  # scene 0: agent 3 influences nobody; agent 2 does
    influence[1, 0, 1, 2] = 1.0
    influence[1, 0, 0, 3] = 1.0  # scene 1: every non-focal agent influences: nothing removed
    predict = _neighbour_mean(observed)
    base = predict(states, valid)
    record = removal_shift(predict, base, states, valid, influence, focal, observed)
    # scene 0 without agent 3: mean x 16/4 = 4 -> 6/3 = 2, a shift of 2 m for both focal agents
    assert record == {"shift_m": 2.0, "pairs": 2, "removed_mean": 1.0, "kind": "episode"}
    valid[0, observed:, 1] = False  # focal agent 1 not present in the predicted steps
    record = removal_shift(predict, base, states, valid, influence, focal, observed)
    assert record["pairs"] == 1 and record["shift_m"] == 2.0

    def cv(s: np.ndarray, v: np.ndarray) -> np.ndarray:
        return constant_velocity(s[..., :2], v, observed)

    zero = removal_shift(cv, cv(states, valid), states, valid, influence, focal, observed)
    assert zero["shift_m"] == 0.0 and zero["pairs"] == 1
    influence[0, 0, 0, 3] = 1.0  # nobody to remove anywhere
    none = removal_shift(cv, cv(states, valid), states, valid, influence, focal, observed)
    assert none == {"shift_m": None, "pairs": 0, "removed_mean": None, "kind": "episode"}


def test_attention_total_variation_hand_computed():
    attention, _, valid, focal, observed = _scene(steps=6, observed=3)  # theta^0 .. theta^4
    attention[0, :, 0] = [
        [0, 1, 0, 0],
        [0, 1, 0, 0],  # t=1: 0
        [0, 0, 1, 0],  # t=2: sqrt(2) (observed: t = 1, 2)
        [0, 0, 0.4, 0.6],  # t=3: sqrt(0.36 + 0.36)  (predicted: t = 3, 4)
        [0, 0, 0.4, 0.6],  # t=4: 0
    ]
    attention[0, :, 1] = 1.0  # not focal: ignored
    tv = attention_total_variation(attention, valid, focal, observed)
    assert tv["observed"] == pytest.approx(np.sqrt(2) / 2)
    assert tv["predicted"] == pytest.approx(np.sqrt(0.72) / 2)
    assert (tv["observed_count"], tv["predicted_count"]) == (2, 2)
    valid[0, 0, 0] = False  # t=1 transition needs agent 0 at t=0 too
    valid[0, 4, 0] = False  # the predicted steps count every predicted agent (rolled out)
    tv = attention_total_variation(attention, valid, focal, observed)
    assert tv["observed"] == pytest.approx(np.sqrt(2)) and tv["observed_count"] == 1
    assert tv["predicted_count"] == 2
    valid[0, observed - 1, 0] = False  # not predicted, and t = 2 no longer counts
    tv = attention_total_variation(attention, valid, focal, observed)
    assert tv == {"observed": None, "observed_count": 0, "predicted": None, "predicted_count": 0}


def test_settings_refuse_bad_values():
    with pytest.raises(FaithfulnessError, match="influence kind"):
        FaithfulnessSettings(auroc_kind="future")
    with pytest.raises(FaithfulnessError, match="window"):
        FaithfulnessSettings(auroc_window="all")
    with pytest.raises(FaithfulnessError, match="threshold"):
        FaithfulnessSettings(threshold_m=-1.0)
