"""The focal mask of schema 2: it alone names the scored ("main") agents, schema-1 files score
exactly what they scored before, and data without labels or headings degrades clearly."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import downgrade_to_schema_1, make_meta, make_trajectory_set

from predictor.baselines import RidgeBaseline, RidgeConfig, displacement_heading
from predictor.evaluation import evaluate_baseline
from predictor.forecasting import EvaluationError
from predictor.metrics import prediction_mask
from predictor.presets import make_configs
from predictor.run_files import RunError
from predictor.training import train
from trajectory_data.format import SPLITS, write_dataset
from trajectory_data.reader import read_dataset


def write_small_dataset(path: Path, counts: tuple[int, int, int], num_agents: int):
    """conftest's small dataset with positions that wander off constant velocity (so that
    constant velocity errs by metres, not by float rounding)."""
    meta = make_meta()
    rng = np.random.default_rng(2)
    splits = {}
    for i, (name, count) in enumerate(zip(SPLITS, counts, strict=True)):
        data = make_trajectory_set(count, meta.num_steps, num_agents, seed=i + 1)
        states = data.states.copy()
        states[..., :2] += rng.normal(size=states[..., :2].shape).cumsum(axis=1)
        states[~data.valid] = 0.0
        splits[name] = dataclasses.replace(data, states=states.astype(np.float32))
    write_dataset(path, meta, splits)
    return meta, splits


def _old_main_ade(pred: np.ndarray, true: np.ndarray, mask: np.ndarray) -> float:
    """The main-agent ADE exactly as schema 1's metric computed it: agent slots 0 and 1."""
    agents = slice(0, 2)
    dist = np.linalg.norm(pred[:, :, agents] - true[:, :, agents], axis=-1)
    keep = mask[:, :, agents]
    return float(np.where(keep, dist, 0.0).sum(axis=(1, 2)).sum() / keep.sum())


def _ade_by_hand(data, num_observed: int, agents) -> float:
    """Constant-velocity ADE over the agent slots `agents` (n, N bool), computed directly."""
    pos = data.states[..., :2].astype(np.float64)
    step = pos[:, num_observed - 1] - pos[:, num_observed - 2]
    moving = data.valid[:, num_observed - 1] & data.valid[:, num_observed - 2]
    total, count = 0.0, 0
    for b in range(data.n):
        for a in np.flatnonzero(agents[b]):
            if not data.valid[b, num_observed - 1, a]:
                continue
            for k, t in enumerate(range(num_observed, data.num_steps)):
                if data.valid[b, t, a]:
                    guess = pos[b, num_observed - 1, a] + (k + 1) * step[b, a] * moving[b, a]
                    total += np.linalg.norm(guess - pos[b, t, a])
                    count += 1
    return total / count


def test_schema_1_and_2_files_score_identically(tmp_path: Path) -> None:
    new = tmp_path / "v2.h5"
    write_small_dataset(new, counts=(6, 3, 8), num_agents=5)
    old = tmp_path / "v1.h5"
    shutil.copy(new, old)
    downgrade_to_schema_1(old)
    for name in ("const_vel", "ridge"):
        a, b = evaluate_baseline(name, old, "test"), evaluate_baseline(name, new, "test")
        assert a.scores == b.scores and a.diagnostics == b.diagnostics
    _, splits = read_dataset(old)
    first_two = np.zeros((8, 5), bool)
    first_two[:, :2] = True
    for name in ("const_vel", "ridge"):
        result = evaluate_baseline(name, old, "test")
        p = result.predictions
        mask = prediction_mask(p.valid, p.num_observed)
        ade = result.scores["main_agents"]["overall"]["ade"]
        assert ade == _old_main_ade(p.pred_mean, p.true_xy[:, p.num_observed :], mask)
    assert ade > 0.5  # metres: a real error, not rounding
    ade = evaluate_baseline("const_vel", old, "test").scores["main_agents"]["overall"]["ade"]
    assert ade == pytest.approx(_ade_by_hand(splits["test"], 4, first_two), rel=1e-6)


def test_focal_mask_drives_the_metric(tmp_path: Path) -> None:
    path = tmp_path / "data.h5"
    meta, splits = write_small_dataset(path, counts=(6, 3, 8), num_agents=5)
    before = evaluate_baseline("const_vel", path, "test").scores
    rng = np.random.default_rng(1)
    focal = rng.random((8, 5)) < 0.4  # any agents, a different choice per scene
    focal[0] = False  # a scene without focal agents
    moved = {**splits, "test": dataclasses.replace(splits["test"], focal=focal)}
    other = tmp_path / "other.h5"
    write_dataset(other, meta, moved)
    after = evaluate_baseline("const_vel", other, "test").scores
    want = _ade_by_hand(splits["test"], meta.num_observed, focal)
    assert after["main_agents"]["overall"]["ade"] == pytest.approx(want, rel=1e-6)
    assert after["main_agents"]["overall"]["ade"] != before["main_agents"]["overall"]["ade"]
    assert after["all_agents"] == before["all_agents"]


def _unlabelled(tmp_path: Path) -> Path:
    path = tmp_path / "data.h5"
    meta, splits = write_small_dataset(path, counts=(6, 3, 4), num_agents=4)
    bare = {
        name: dataclasses.replace(
            data,
            attention=np.full_like(data.attention, -1),
            interaction=np.zeros_like(data.interaction),
        )
        for name, data in splits.items()
    }
    recorded = ("actions", "case", "seed", "roles")
    out = tmp_path / "unlabelled.h5"
    write_dataset(out, dataclasses.replace(meta, recorded=recorded), bare)
    return out


def test_data_without_labels_refuses_the_oracles_in_one_line(tmp_path: Path) -> None:
    path = _unlabelled(tmp_path)
    with pytest.raises(EvaluationError, match="reads attention labels, which the unit_test"):
        evaluate_baseline("ridge_labelled", path, "test")
    model_cfg, train_cfg = make_configs("correct", epochs=1, batch_size=4, preset="paper")
    with pytest.raises(RunError, match="variant correct.*does not record") as err:
        train(path, model_cfg, train_cfg, tmp_path / "run", progress=False)
    assert "\n" not in str(err.value) and not (tmp_path / "run").exists()
    scores = evaluate_baseline("ridge", path, "test").scores  # needs no labels
    assert scores["attention_accuracy"]["overall"]["count"] == 0


def test_ridge_without_heading_uses_the_last_displacement() -> None:
    """Positions only: the same features as with a heading channel holding the last
    displacement's direction (the agent frame at the last observed step is all the heading is
    used for), except that the last velocity's lateral component, zero in that frame, is
    exactly zero instead of rounding noise (which standardising would make a feature)."""
    meta = make_meta(num_observed=5, num_predicted=3)
    rng = np.random.default_rng(0)
    n, steps, agents = 30, meta.num_steps, 3
    velocity = rng.normal(size=(n, 1, agents, 2))
    turn = rng.normal(scale=0.2, size=(n, steps, agents, 2)).cumsum(axis=1)
    positions = velocity * np.arange(steps)[None, :, None, None] + turn  # float64
    valid = np.ones((n, steps, agents), bool)
    labels = np.full((n, steps, agents), -1)
    roles = np.zeros((n, agents), np.int8)
    heading = displacement_heading(positions, meta.num_observed - 1)
    with_heading = np.concatenate([positions, heading[..., None]], -1)
    features = []
    for states in (positions, with_heading):
        ridge = RidgeBaseline(RidgeConfig(history_steps=3, folds=3))
        ridge.fit(states, valid, labels, roles, meta.num_observed, meta.dt)
        assert ridge.predict(states, valid, labels, roles).shape == (n, 3, agents, 2)
        features.append(ridge.features(states, valid, labels)[0])  # (n, N, 3 * 2 + 2 * 2)
    last_lateral = [5, 9]  # the last velocity's y and the last acceleration's y
    np.testing.assert_array_equal(features[0][..., 5], 0.0)
    assert 0 < np.abs(features[1][..., 5]).max() < 1e-9  # rounding noise with the channel
    others = [k for k in range(features[0].shape[-1]) if k not in last_lateral]
    np.testing.assert_allclose(features[0][..., others], features[1][..., others], atol=1e-9)
    np.testing.assert_allclose(features[0][..., 9], features[1][..., 9], atol=1e-6)
    step = positions[:, 4] - positions[:, 3]
    assert np.allclose(heading[:, 4], np.arctan2(step[..., 1], step[..., 0]))
