"""Using a trained model: load checkpoints, predict a split by feeding back means, score it.

Checkpoints (written by `predictor.training`) are plain dicts that load with
`torch.load(weights_only=True)`: `format`, `version`, `model_state`, `model_config`,
`train_config` (plain dicts), `epoch`, `data` (file description), and for `last.pt` also the
optimizer and random-number-generator states needed to resume.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch

from predictor.baselines import constant_velocity
from predictor.config import ModelConfig, model_config_from_dict
from predictor.data import Batch
from predictor.metrics import attention_accuracy, displacement_metrics, prediction_mask
from predictor.model import SmoothAttentionPredictor, expand_attention

CHECKPOINT_FORMAT = "smooth-attention-checkpoint"
CHECKPOINT_VERSION = 1


class CheckpointError(ValueError):
    """A file is not a readable checkpoint of this package; the message is one line."""


def read_checkpoint(path: str | os.PathLike) -> dict:
    """Load a checkpoint dict (weights only, CPU) and check its format tag."""
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise CheckpointError(f"{path}: no such checkpoint") from None
    except Exception as err:  # noqa: BLE001 - torch raises many types for foreign files
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise CheckpointError(f"{path}: not a readable checkpoint ({first})") from None
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a {CHECKPOINT_FORMAT} file")
    if checkpoint.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"{path}: unsupported checkpoint version {checkpoint.get('version')}")
    return checkpoint


def load_model(path: str | os.PathLike) -> tuple[SmoothAttentionPredictor, dict]:
    """Model (in eval mode) and checkpoint dict from a checkpoint file."""
    checkpoint = read_checkpoint(path)
    try:
        config: ModelConfig = model_config_from_dict(checkpoint["model_config"])
        model = SmoothAttentionPredictor(config)
        model.load_state_dict(checkpoint["model_state"])
    except (KeyError, TypeError, ValueError, RuntimeError) as err:
        raise CheckpointError(f"{path}: inconsistent checkpoint ({err})") from None
    model.eval()
    return model, checkpoint


@dataclass
class Predictions:
    """Test-time predictions of n scenes (numpy)."""

    pred_mean: np.ndarray  # (n, T_pred, N, 2) float32 [m], steps T_obs .. T-1
    attention: np.ndarray  # (n, T-1, N, N) float32 theta^t_ij, t = 0 .. T-2 (NaN: no attention)


def predict_model(
    model: SmoothAttentionPredictor, batch: Batch, num_observed: int, batch_size: int = 32
) -> Predictions:
    """Predict every scene of `batch` from its observed steps, feeding back the predicted means.

    The attention is theta^t over the teacher-forced observed part (t < T_obs-1) followed by the
    fed-back part (t = T_obs-1 .. T-2).
    """
    means, attentions = [], []
    model.eval()
    for start in range(0, batch.batch_size, batch_size):
        part = slice(start, start + batch_size)
        out = model.predict(
            batch.positions[part], batch.valid[part], num_observed, batch.attention[part]
        )
        theta = torch.cat([out.attention[:, :-1], out.rollout_attention], 1)  # (b, T-1, N, N-1)
        means.append(out.rollout.mean.numpy().astype(np.float32))
        attentions.append(expand_attention(theta).numpy().astype(np.float32))
    num_agents, num_steps = batch.num_agents, batch.num_steps
    if not means:
        return Predictions(
            np.zeros((0, num_steps - num_observed, num_agents, 2), np.float32),
            np.zeros((0, num_steps - 1, num_agents, num_agents), np.float32),
        )
    return Predictions(np.concatenate(means), np.concatenate(attentions))


def predict_const_vel(batch: Batch, num_observed: int) -> Predictions:
    """Constant-velocity predictions (no attention: NaN)."""
    pred = constant_velocity(batch.positions.numpy(), batch.valid.numpy(), num_observed)
    shape = (batch.batch_size, batch.num_steps - 1, batch.num_agents, batch.num_agents)
    return Predictions(pred, np.full(shape, np.nan, dtype=np.float32))


def score(
    predictions: Predictions, batch: Batch, num_observed: int, case_names: tuple[str, ...]
) -> dict:
    """ADE/FDE per agent group and case, and attention accuracy (see `predictor.metrics`)."""
    valid = batch.valid.numpy()
    true = batch.positions.numpy()[:, num_observed:]  # (n, T_pred, N, 2)
    case = batch.case.numpy()
    result = displacement_metrics(
        predictions.pred_mean, true, prediction_mask(valid, num_observed), case, case_names
    )
    result["attention_accuracy"] = attention_accuracy(
        predictions.attention,
        batch.attention.numpy(),
        batch.interaction.numpy(),
        valid,
        num_observed,
        case,
        case_names,
    )
    return result


def save_predictions(
    path: str | os.PathLike,
    predictions: Predictions,
    batch: Batch,
    num_observed: int,
    dt: float,
    case_names: tuple[str, ...],
    role_names: tuple[str, ...],
) -> None:
    """Write the predictions file read by the plotting tool (np.savez to exactly `path`)."""
    roles = batch.roles if batch.roles is not None else torch.zeros(batch.valid.shape[::2])
    with open(path, "wb") as stream:  # a file object: numpy adds no ".npz" suffix
        _savez(stream, predictions, batch, roles, num_observed, dt, case_names, role_names)


def _savez(
    stream,
    predictions: Predictions,
    batch: Batch,
    roles: torch.Tensor,
    num_observed: int,
    dt: float,
    case_names: tuple[str, ...],
    role_names: tuple[str, ...],
) -> None:
    np.savez(
        stream,
        pred_mean=predictions.pred_mean.astype(np.float32),
        true_xy=batch.positions.numpy().astype(np.float32),
        valid=batch.valid.numpy().astype(bool),
        case=batch.case.numpy().astype(np.int64),
        case_names=np.array(case_names, dtype=str),
        role_names=np.array(role_names, dtype=str),
        roles=roles.numpy().astype(np.int64),
        attention=predictions.attention.astype(np.float32),
        attention_label=batch.attention.numpy().astype(np.int16),
        interaction=batch.interaction.numpy().astype(bool),
        num_observed=np.int64(num_observed),
        dt=np.float64(dt),
    )
