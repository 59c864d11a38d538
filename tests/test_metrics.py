"""ADE/FDE, attention accuracy and the constant-velocity baseline on hand-made predictions."""

from __future__ import annotations

import numpy as np
import pytest

from predictor.baselines import constant_velocity
from predictor.metrics import attention_accuracy, displacement_metrics, prediction_mask


def test_ade_fde_by_hand():
    # 2 scenes, 2 predicted steps, 3 agents; errors are 3-4-5 triangles and axis offsets
    true = np.zeros((2, 2, 3, 2))
    pred = np.zeros((2, 2, 3, 2))
    pred[0, 0, 0] = [3, 4]  # error 5
    pred[0, 1, 0] = [6, 8]  # error 10 (final)
    pred[0, :, 1] = [1, 0]  # error 1 at both steps
    pred[0, :, 2] = [0, 2]  # error 2 at both steps
    pred[1, :, 0] = [0, 1]  # error 1 at both steps
    pred[1, :, 2] = [0, 100]  # absent: ignored
    mask = np.ones((2, 2, 3), dtype=bool)
    mask[1, :, 2] = False
    mask[1, 1, 1] = False  # scene 1, agent 1 absent at the final step
    case = np.array([0, 1])
    focal = np.array([[True, True, False]] * 2)
    got = displacement_metrics(pred, true, mask, case, ["major", "minor"], focal)
    main, every = got["main_agents"], got["all_agents"]
    # main agents (0, 1): errors 5, 10, 1, 1 | 1, 1, 0
    assert main["overall"]["ade"] == pytest.approx((5 + 10 + 1 + 1 + 1 + 1 + 0) / 7)
    assert main["overall"]["fde"] == pytest.approx((10 + 1 + 1) / 3)
    assert main["cases"]["major"]["ade"] == pytest.approx(17 / 4)
    assert main["cases"]["minor"]["fde"] == pytest.approx(1.0)
    assert every["overall"]["ade"] == pytest.approx((17 + 4 + 2) / 9)
    assert every["overall"]["fde"] == pytest.approx((10 + 1 + 2 + 1) / 4)
    assert every["overall"]["count"] == 9 and every["overall"]["scenes"] == 2


def test_focal_mask_chooses_the_main_agents_scene_by_scene():
    # 3 scenes, 1 predicted step, 3 agents; agent a of scene s misses by 10 s + a metres
    true = np.zeros((3, 1, 3, 2))
    pred = np.zeros((3, 1, 3, 2))
    pred[..., 0] = (10 * np.arange(3)[:, None] + np.arange(3)[None, :])[:, None]
    mask = np.ones((3, 1, 3), dtype=bool)
    mask[2, 0, 0] = False  # focal but absent: not counted
    focal = np.array([[False, False, True], [True, False, True], [True, False, False]])
    got = displacement_metrics(pred, true, mask, np.zeros(3, int), ["all"], focal)
    main = got["main_agents"]["overall"]
    assert main["count"] == 3  # scene 0 agent 2, scene 1 agents 0 and 2
    assert main["ade"] == pytest.approx((2 + 10 + 12) / 3)
    assert main["fde"] == pytest.approx((2 + 10 + 12) / 3) and main["scenes"] == 3
    assert got["all_agents"]["overall"]["count"] == 8
    none = displacement_metrics(pred, true, mask, np.zeros(3, int), ["all"], focal & False)
    assert none["main_agents"]["overall"]["ade"] is None
    assert none["main_agents"]["overall"]["count"] == 0


def test_empty_case_gives_none():
    got = displacement_metrics(
        np.zeros((1, 2, 2, 2)),
        np.zeros((1, 2, 2, 2)),
        np.ones((1, 2, 2), bool),
        np.array([0]),
        ["a", "b"],
        np.ones((1, 2), bool),
    )
    assert got["all_agents"]["cases"]["b"] == {
        "ade": None,
        "fde": None,
        "count": 0,
        "final_count": 0,
        "scenes": 0,
    }


def test_prediction_mask_needs_presence_at_last_observed_step():
    valid = np.ones((1, 5, 3), dtype=bool)
    valid[0, 1, 1] = False  # agent 1 missing at T_obs-1 = 1: never predicted
    valid[0, 3, 2] = False  # agent 2 missing at one predicted step
    mask = prediction_mask(valid, 2)
    assert mask.shape == (1, 3, 3)
    assert mask[0, :, 1].sum() == 0 and mask[0, :, 2].tolist() == [True, False, True]


def test_attention_accuracy_by_hand():
    # T = 5, T_obs = 2: counted steps t = 2, 3; 3 agents
    n, steps, agents = 1, 5, 3
    attention = np.zeros((n, steps - 1, agents, agents), dtype=np.float32)
    attention[0, :, 0] = [0.0, 0.7, 0.3]  # agent 0 attends agent 1
    attention[0, 2, 1] = [0.9, 0.0, 0.1]  # agent 1 attends 0 at t = 2
    attention[0, 3, 1] = [0.2, 0.0, 0.8]  # ... and 2 at t = 3
    labels = np.full((n, steps, agents), -1, dtype=np.int16)
    labels[0, :, 0], labels[0, :, 1] = 1, 0
    interaction = np.ones((n, steps), dtype=bool)
    valid = np.ones((n, steps, agents), dtype=bool)
    got = attention_accuracy(attention, labels, interaction, valid, 2, np.array([0]), ["x"])
    # hits: (2,0) (3,0) (2,1); weights on the label: 0.7, 0.7, 0.9, 0.2
    assert got["overall"] == {"accuracy": 0.75, "mean_weight": pytest.approx(0.625), "count": 4}
    interaction[0, 3] = False
    got = attention_accuracy(attention, labels, interaction, valid, 2, np.array([0]), ["x"])
    assert got["overall"] == {"accuracy": 1.0, "mean_weight": pytest.approx(0.8), "count": 2}
    nan = np.full_like(attention, np.nan)
    got = attention_accuracy(nan, labels, interaction, valid, 2, np.array([0]), ["x"])
    assert got["cases"]["x"]["accuracy"] is None and got["cases"]["x"]["count"] == 2


def test_uniform_attention_is_never_a_hit():
    # argmax of a tie picks the lowest index, which is the labelled agent here: must not count
    n, steps, agents = 1, 4, 3
    attention = np.full((n, steps - 1, agents, agents), 0.5, dtype=np.float32)
    for i in range(agents):
        attention[:, :, i, i] = 0.0
    labels = np.zeros((n, steps, agents), dtype=np.int16)
    labels[..., 0] = 1
    interaction = np.ones((n, steps), dtype=bool)
    valid = np.ones((n, steps, agents), dtype=bool)
    got = attention_accuracy(attention, labels, interaction, valid, 2, np.array([0]), ["x"])
    assert got["overall"]["accuracy"] == 0.0 and got["overall"]["count"] == 3
    assert got["overall"]["mean_weight"] == pytest.approx(0.5)


def test_constant_velocity_extrapolates_the_last_step():
    positions = np.zeros((1, 5, 2, 2), dtype=np.float32)
    positions[0, :, 0, 0] = [0, 1, 3, 99, 99]  # last observed step +2 m in x
    positions[0, :, 1] = [[5, 5], [0, 0], [6, 7], [0, 0], [0, 0]]
    valid = np.ones((1, 5, 2), dtype=bool)
    valid[0, 1, 1] = False  # agent 1 absent at T_obs-2: zero velocity
    pred = constant_velocity(positions, valid, 3)
    assert pred.shape == (1, 2, 2, 2) and pred.dtype == np.float32
    np.testing.assert_allclose(pred[0, :, 0, 0], [5, 7])
    np.testing.assert_allclose(pred[0, :, 1], [[6, 7], [6, 7]])
    with pytest.raises(ValueError):
        constant_velocity(positions, valid, 5)


def test_json_safe_writes_non_finite_scores_as_null():
    import json
    import math

    from predictor.evaluation import json_safe

    scores = {"ade": math.nan, "per_step": [0.5, math.inf, -math.inf], "n": 3, "case": ("a", 1.0)}
    safe = json_safe(scores)
    assert safe == {"ade": None, "per_step": [0.5, None, None], "n": 3, "case": ["a", 1.0]}
    assert json.loads(json.dumps(safe, allow_nan=False)) == safe


def test_a_metric_added_to_the_registry_is_scored_per_group_and_case(monkeypatch):
    """One function and one ERROR_METRICS line: a 2 m miss rate at the final step, checked
    against a hand count; the report's METRICS are the registry's names."""
    import predictor.metrics as metrics
    from pipeline.report.records import METRICS

    assert METRICS == tuple(m.name for m in metrics.ERROR_METRICS) == ("ade", "fde")

    def misses(dist, keep):
        return ((dist[:, -1] > 2.0) & keep[:, -1]).sum(axis=-1), keep[:, -1].sum(axis=-1)

    added = (*metrics.ERROR_METRICS, metrics.ErrorMetric("miss_rate", misses))
    monkeypatch.setattr(metrics, "ERROR_METRICS", added)
    true = np.zeros((2, 3, 2, 2))
    pred = true.copy()
    pred[0, -1, 0, 0] = 3.0  # scene 0: agent 0 misses by 3 m at the final step
    pred[1, -1, 1, 0] = 1.0  # scene 1: agent 1 is 1 m off, not a miss
    mask = np.ones((2, 3, 2), dtype=bool)
    focal = np.array([[True, False], [True, False]])
    result = metrics.displacement_metrics(pred, true, mask, np.array([0, 1]), ["a", "b"], focal)
    assert result["all_agents"]["overall"]["miss_rate"] == 1 / 4
    assert result["all_agents"]["cases"]["a"]["miss_rate"] == 1 / 2
    assert result["all_agents"]["cases"]["b"]["miss_rate"] == 0.0
    assert result["main_agents"]["overall"]["miss_rate"] == 1 / 2
    assert result["all_agents"]["overall"]["fde"] == (3.0 + 1.0) / 4
