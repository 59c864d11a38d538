"""Checkpoints: the files training writes (`best.pt`, `last.pt`), how they are read back, and
whether a data file is of the kind a checkpoint's run was trained on (`check_data_matches`).

A checkpoint is a plain dict that loads with `torch.load(weights_only=True)`: `format`,
`version`, `model_state`, `model_config`, `train_config` (plain dicts), `epoch`, `data` (file
description), and for `last.pt` also the optimizer and random-number-generator states needed to
resume. `load_model` rebuilds the model from one; a file of another kind, or a run that used an
option this version no longer has, is a `CheckpointError` of one line.
"""

from __future__ import annotations

import math
import os

import torch

from predictor.config import ModelConfig
from predictor.forecasting import EvaluationError
from predictor.model import SmoothAttentionPredictor
from predictor.stored_config import RemovedOptionError, model_config_from_dict
from trajectory_data.format import DatasetMeta

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


MATCHED_DATA = ("scenario", "dt", "num_observed", "num_predicted")  # run vs evaluated file


class ScenarioMismatchError(EvaluationError):
    """The evaluated file is of another scenario than the run was trained on, while its dt,
    horizons and agent count match: `evaluate_run(..., allow_scenario_mismatch=True)` evaluates
    it anyway. `trained` and `evaluated` are the two scenario names."""

    def __init__(self, message: str, trained: str, evaluated: str) -> None:
        super().__init__(message)
        self.trained, self.evaluated = trained, evaluated

    def __reduce__(self):  # picklable across process pools
        return (type(self), (str(self), self.trained, self.evaluated))


def check_data_matches(
    checkpoint: dict,
    meta: DatasetMeta,
    checkpoint_path: str | os.PathLike,
    data_path: str | os.PathLike,
    allow_scenario_mismatch: bool = False,
    num_agents: int | None = None,
) -> tuple[str, str] | None:
    """Check that `meta` has the scenario, dt and horizons the checkpoint's run was trained on
    (`MATCHED_DATA`); returns None, or with `allow_scenario_mismatch` the (trained, evaluated)
    scenario names where only the scenario differs.

    Another scenario is evaluated only when asked and when dt, the horizons and the agent count
    (`num_agents` of the evaluated file, checked where the run recorded its own) match:
    otherwise ScenarioMismatchError (a scenario alone differs, not asked) or EvaluationError.
    """
    trained = checkpoint.get("data")
    if not isinstance(trained, dict) or any(key not in trained for key in MATCHED_DATA):
        raise CheckpointError(f"{checkpoint_path}: inconsistent checkpoint (no data description)")
    now_values = {key: getattr(meta, key) for key in MATCHED_DATA}
    differ = [key for key in MATCHED_DATA if not _same(trained[key], now_values[key])]
    if differ == ["scenario"] and num_agents is not None and "num_agents" in trained:
        # the model reads any number of agents of its own scenario, not of another's
        now_values["num_agents"] = num_agents
        differ += [] if trained["num_agents"] == num_agents else ["num_agents"]
    if not differ:
        return None
    was = ", ".join(f"{key} {trained[key]!r}" for key in differ)
    now = ", ".join(f"{key} {now_values[key]!r}" for key in differ)
    message = f"{checkpoint_path} was trained on data with {was}, but {data_path} has {now}"
    if differ != ["scenario"]:
        raise EvaluationError(message)
    if not allow_scenario_mismatch:
        raise ScenarioMismatchError(message, str(trained["scenario"]), meta.scenario)
    return str(trained["scenario"]), meta.scenario


def _same(a: object, b: object) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return math.isclose(float(a), float(b), rel_tol=1e-9)
    return a == b
