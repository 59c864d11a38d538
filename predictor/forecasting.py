"""Forecasts of a dataset split: a trained model's (fed-back means and attention) or a
baseline's, shaped alike, and their scores (`score`: ADE/FDE per group and case, attention
accuracy). `predictor.evaluation` runs them as one evaluation of a run or a baseline.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from predictor.baselines import BASELINES, RidgeBaseline, RidgeConfig, constant_velocity
from predictor.metrics import attention_accuracy, displacement_metrics, prediction_mask
from predictor.model import SmoothAttentionPredictor
from predictor.outputs import expand_attention
from predictor.predictions import Predictions
from trajectory_data.format import DatasetMeta, TrajectorySet
from trajectory_data.torch_dataset import Batch


class EvaluationError(ValueError):
    """An evaluation cannot be done as asked (empty split, data of another kind); one line."""


def predict_model(
    model: SmoothAttentionPredictor,
    batch: Batch,
    num_observed: int,
    batch_size: int = 32,
    on_batch: Callable[[int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Predict every scene of `batch` from its observed steps, feeding back the predicted means.

    Returns (pred_mean (n, T_pred, N, 2) [m] of steps T_obs .. T-1, attention (n, T-1, N, N)),
    both float32. The attention is theta^t over the teacher-forced observed part
    (t < T_obs-1) followed by the fed-back part (t = T_obs-1 .. T-2). `on_batch(scenes)` is
    called after each batch (progress).
    """
    num_agents, num_steps = batch.num_agents, batch.num_steps
    means = [np.zeros((0, num_steps - num_observed, num_agents, 2), np.float32)]
    attentions = [np.zeros((0, num_steps - 1, num_agents, num_agents), np.float32)]
    model.eval()
    batch = batch.to(next(model.parameters()).device)  # where the model is (training: its device)
    for start in range(0, batch.batch_size, batch_size):
        part = slice(start, start + batch_size)
        roles = None if batch.roles is None else batch.roles[part]
        out = model.predict(
            batch.positions[part], batch.valid[part], num_observed, batch.attention[part], roles
        )
        theta = torch.cat([out.attention[:, :-1], out.rollout_attention], 1)  # (b, T-1, N, N-1)
        means.append(out.rollout.mean.cpu().numpy().astype(np.float32))
        attentions.append(expand_attention(theta).cpu().numpy().astype(np.float32))
        if on_batch is not None:
            on_batch(len(theta))
    return np.concatenate(means), np.concatenate(attentions)


def predict_baseline(
    name: str, data: TrajectorySet, meta: DatasetMeta, fit: TrajectorySet | None = None
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """(pred_mean, attention, details) of baseline `name` on `data`, shaped as `predict_model`'s
    outputs; the attention is NaN. A ridge baseline is fitted on `fit` first (required for them);
    `details` describes the fit (empty for const_vel)."""
    predict, details = fit_baseline(name, meta, fit)
    shape = (data.n, data.num_steps - 1, data.num_agents, data.num_agents)
    return predict(data), np.full(shape, np.nan, dtype=np.float32), details


def fit_baseline(
    name: str, meta: DatasetMeta, fit: TrajectorySet | None = None
) -> tuple[Callable[[TrajectorySet], np.ndarray], dict[str, Any]]:
    """(predict, details): `predict(data)` gives baseline `name`'s predicted means
    (n, T_pred, N, 2) [m] on any scenes of `meta`'s kind; a ridge baseline is fitted on `fit`
    once, here (EvaluationError if it cannot be). `details` describes the fit."""
    if name not in BASELINES:
        raise EvaluationError(f"unknown baseline {name!r}; choose from {', '.join(BASELINES)}")
    if name == "const_vel":
        return lambda data: constant_velocity(
            data.states[..., :2], data.valid, meta.num_observed
        ), {}
    if fit is None or fit.n == 0:
        raise EvaluationError(f"the {name} baseline needs training scenes to fit on")
    config = RidgeConfig.named(name)
    if config.neighbours == "labelled" and not meta.has("attention"):
        raise EvaluationError(
            f"the {name} baseline reads attention labels, which the {meta.scenario} data lacks"
        )
    try:
        ridge = RidgeBaseline(config).fit_set(fit, meta)
    except ValueError as err:
        raise EvaluationError(f"cannot fit the {name} baseline: {err}") from None
    details = {
        "fit_scenes": fit.n,
        "history_steps": ridge.history,
        "alpha": {meta.role_names[role]: alpha for role, alpha in sorted(ridge.alpha.items())},
    }
    return lambda data: ridge.predict_set(data, meta), details


def score(predictions: Predictions) -> dict:
    """ADE/FDE per agent group and case, and attention accuracy (see `predictor.metrics`):
    {"main_agents": ..., "all_agents": ..., "attention_accuracy": ...}."""
    p = predictions
    result = displacement_metrics(
        p.pred_mean,
        p.true_xy[:, p.num_observed :],
        prediction_mask(p.valid, p.num_observed),
        p.case,
        p.case_names,
        p.focal,
    )
    result["attention_accuracy"] = attention_accuracy(
        p.attention, p.attention_label, p.interaction, p.valid, p.num_observed, p.case, p.case_names
    )
    return result
