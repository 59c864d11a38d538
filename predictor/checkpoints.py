"""Checkpoints: the files training writes (`best.pt`, `last.pt`) and how they are read back.

A checkpoint is a plain dict that loads with `torch.load(weights_only=True)`: `format`,
`version`, `model_state`, `model_config`, `train_config` (plain dicts), `epoch`, `data` (file
description), and for `last.pt` also the optimizer and random-number-generator states needed to
resume. `load_model` rebuilds the model from one; a file of another kind, or a run that used an
option this version no longer has, is a `CheckpointError` of one line.
"""

from __future__ import annotations

import os

import torch

from predictor.config import ModelConfig
from predictor.model import SmoothAttentionPredictor
from predictor.stored_config import RemovedOptionError, model_config_from_dict

CHECKPOINT_FORMAT = "smooth-attention-checkpoint"
CHECKPOINT_VERSION = 1


CHECKPOINTS = ("best", "last")  # a run's checkpoint files, without ".pt"


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
        model.load_state_dict(model.fill_unclamped_range(checkpoint["model_state"]))
    except RemovedOptionError as err:
        raise CheckpointError(f"{path}: {err}") from None
    except (KeyError, TypeError, ValueError, RuntimeError) as err:
        raise CheckpointError(f"{path}: inconsistent checkpoint ({err})") from None
    model.eval()
    return model, checkpoint
