"""A training run's changing state and its checkpoints: what `last.pt` and `best.pt` hold,
how a fresh run's state is built (seeded) and how an interrupted one is restored and checked.

`last.pt` stores the optimizer state, the epoch, the best validation score and the torch,
numpy, python and loader RNG states, so a resumed run reproduces the uninterrupted one bit for
bit (same thread count assumed). A resumed run may change only `RESUME_MAY_CHANGE`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from predictor import __version__
from predictor.compiled_step import compile_graph_step, compiler_missing
from predictor.config import ModelConfig, TrainConfig
from predictor.data import Batch, TrajectoryDataset, make_loader
from predictor.evaluation import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, read_checkpoint
from predictor.model import SmoothAttentionPredictor
from predictor.random_state import rng_state, seed_everything, set_rng_state
from predictor.run_files import RunError, atomic_write_text, check_out_dir, writing
from predictor.stored_config import (
    ADDED_MODEL_FIELDS,
    ADDED_TRAIN_FIELDS,
    config_to_dict,
    model_config_from_dict,
    train_config_from_dict,
)

RESUME_MAY_CHANGE = ("epochs", "threads", "eval_every")  # TrainConfig fields; nothing else may


@dataclass
class RunState:
    """Everything that changes while training."""

    model: SmoothAttentionPredictor
    optimizer: torch.optim.Optimizer
    loader: torch.utils.data.DataLoader
    epoch: int = 0  # completed epochs
    best_score: float | None = None
    best_epoch: int = 0
    history_tail: dict = field(default_factory=dict)  # last epoch's record
    # the training scenes in the order fit_normalisation saw them (ModelConfig.attended_refit
    # refits the highway on them at the start of every epoch); None: no refit
    refit_scenes: Batch | None = None


def checkpoint_dict(
    state: RunState, model_cfg: ModelConfig, train_cfg: TrainConfig, data: dict, full: bool
) -> dict:
    """Checkpoint contents (plain types and tensors only)."""
    out = {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "package_version": __version__,
        "model_state": state.model.state_dict(),
        "model_config": config_to_dict(model_cfg),
        "train_config": config_to_dict(train_cfg),
        "data": data,
        "epoch": state.epoch,
        "best_score": state.best_score,
        "best_epoch": state.best_epoch,
    }
    if full:
        out["optimizer_state"] = state.optimizer.state_dict()
        out["rng"] = rng_state(state.loader.generator)
    return out


def make_optimizer(model: torch.nn.Module, config: TrainConfig) -> torch.optim.Optimizer:
    """Adam (the paper's), or AdamW where config.weight_decay > 0."""
    if config.weight_decay > 0:
        return torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    return torch.optim.Adam(model.parameters(), lr=config.lr)


def build_state(
    model_cfg: ModelConfig, train_cfg: TrainConfig, train_set: TrajectoryDataset
) -> RunState:
    """Seeded model, optimizer and loader of a fresh run (RunError if its graph step is to be
    compiled and cannot be)."""
    seed_everything(train_cfg.seed)
    model = SmoothAttentionPredictor(model_cfg)
    if model_cfg.frame == "agent":  # input/output scales from the training split (checkpointed)
        scenes = train_set.all()
        # with attended_refit the first epoch's refit_attended, before any step, replaces the
        # highway's maps unread (the highway is read only in the rollout), so they are not
        # fitted here: that fit (a grid search per map) took 50-70 s a run (benchmarks/README.md)
        model.fit_normalisation(
            scenes.positions,
            scenes.valid,
            train_set.meta.num_observed,
            scenes.roles,
            fit_maps=not model_cfg.attended_refit,
        )
    if train_cfg.compile_graph_step:
        problem = compiler_missing()
        if problem is not None:
            raise RunError(problem)
        compile_graph_step(model)
    optimizer = make_optimizer(model, train_cfg)
    refit_scenes = train_set.all() if model_cfg.attended_refit else None
    loader = make_loader(
        train_set,
        train_cfg.batch_size,
        shuffle=True,
        seed=train_cfg.seed,
        bucket=train_cfg.bucket_batches,
    )
    return RunState(model, optimizer, loader, refit_scenes=refit_scenes)


def restore_state(state: RunState, checkpoint: dict) -> None:
    """Load model, optimizer, counters and RNG states from a `last.pt` dict."""
    state.model.load_state_dict(state.model.fill_unclamped_range(checkpoint["model_state"]))
    state.optimizer.load_state_dict(checkpoint["optimizer_state"])
    state.epoch = int(checkpoint["epoch"])
    state.best_score = checkpoint["best_score"]
    state.best_epoch = int(checkpoint["best_epoch"])
    set_rng_state(checkpoint["rng"], state.loader.generator)


def resume_configs(
    out_dir: str | os.PathLike, changes: Mapping[str, Any] | None = None
) -> tuple[ModelConfig, TrainConfig]:
    """The configs to resume the run in `out_dir` with: the stored ones (from last.pt) with
    `changes` applied, built through the validating constructors.

    `changes` may hold any ModelConfig or TrainConfig field; those in RESUME_MAY_CHANGE are
    applied, any other must equal the stored value. Raises RunError if there is nothing to
    resume or a change is forbidden or unknown, ValueError for an out-of-range value.
    """
    out = Path(out_dir)
    check_out_dir(out, resume=True, overwrite=False)
    checkpoint = read_checkpoint(out / "last.pt")
    stored = {  # older checkpoints lack the added fields: they take their former values
        **ADDED_MODEL_FIELDS,
        **checkpoint["model_config"],
        **ADDED_TRAIN_FIELDS,
        **checkpoint["train_config"],
    }
    for name, value in (changes or {}).items():
        if name not in stored:
            raise RunError(f"unknown setting {name!r}")
        if name not in RESUME_MAY_CHANGE and value != stored[name]:
            raise RunError(
                f"a resumed run keeps its stored configuration: {name} is {stored[name]!r} there "
                f"(only {', '.join(RESUME_MAY_CHANGE)} may change)"
            )
    allowed = {k: v for k, v in (changes or {}).items() if k in RESUME_MAY_CHANGE}
    return (
        model_config_from_dict(checkpoint["model_config"]),
        train_config_from_dict({**checkpoint["train_config"], **allowed}),
    )


def check_resume(
    checkpoint: dict, model_cfg: ModelConfig, train_cfg: TrainConfig, data: dict
) -> None:
    """Raise RunError unless the checkpoint can be resumed with these configs and data."""
    if checkpoint["model_config"] != config_to_dict(model_cfg):
        raise RunError("a resumed run must use its stored model configuration")
    stored, asked = checkpoint["train_config"], config_to_dict(train_cfg)
    changed = [k for k in asked if k not in RESUME_MAY_CHANGE and stored.get(k) != asked[k]]
    if changed:
        raise RunError(f"a resumed run cannot change {', '.join(changed)} of the stored run")
    keys = [k for k in data if k != "path"]
    if any(checkpoint["data"].get(k) != data[k] for k in keys):
        raise RunError(f"a resumed run needs its data file ({checkpoint['data']['path']})")


def rewrite_metrics(path: Path, last_epoch: int) -> None:
    """Keep only the metrics lines of epochs <= last_epoch (after an interruption)."""
    if not path.exists():
        return
    with writing(path, "read"):
        lines = [line for line in path.read_text().splitlines() if line.strip()]
    kept = [line for line in lines if json.loads(line)["epoch"] <= last_epoch]
    atomic_write_text("".join(line + "\n" for line in kept), path)
