"""Training loop: Adam on the paper's loss, validation ADE, checkpoints, exact resume.

A run directory holds `config.json` (model, training and data description), `metrics.jsonl`
(one JSON object per epoch), `last.pt` (everything needed to resume, written after every epoch)
and `best.pt` (the weights with the lowest validation ADE of the main agents, i.e. the validation
split's focal agents, fed-back means).

Determinism: the seed fixes the initial weights (torch RNG), the batch order (the loader's own
generator) and the rollout samples (torch RNG). `last.pt` stores the optimizer state, the epoch,
the best validation score and the torch, numpy, python and loader RNG states, so a resumed run
reproduces the uninterrupted one bit for bit (same thread count assumed).

Failures: everything that can be checked (run directory, data file, resume compatibility) is
checked before the run directory is touched; a fresh run that fails before its first checkpoint
(`last.pt`) removes the files and directories it created, so it blocks neither a re-run nor
`--resume`. A resumed run may change only `RESUME_MAY_CHANGE` (see `resume_configs`). Write
failures (read-only directory, full disk) are a RunError naming the file (`predictor.run_files`).
"""

from __future__ import annotations

import json
import math
import os
import random
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from tqdm import tqdm

from predictor import __version__
from predictor.config import ModelConfig, TrainConfig, resolve_roles
from predictor.data import Batch, TrajectoryDataset, make_loader
from predictor.evaluation import (
    CHECKPOINT_FORMAT,
    CHECKPOINT_VERSION,
    predict_model,
    read_checkpoint,
    score,
)
from predictor.format import DatasetMeta
from predictor.losses import LossWeights, compute_loss
from predictor.model import SmoothAttentionPredictor
from predictor.predictions import Predictions
from predictor.random_state import rng_state, seed_everything, set_rng_state
from predictor.run_files import (
    RunError,
    atomic_save,
    atomic_write_text,
    check_out_dir,
    claim_out_dir,
    remove_failed_start,
    writing,
)
from predictor.stored_config import (
    ADDED_MODEL_FIELDS,
    ADDED_TRAIN_FIELDS,
    config_to_dict,
    model_config_from_dict,
    train_config_from_dict,
)

RESUME_MAY_CHANGE = ("epochs", "threads", "eval_every")  # TrainConfig fields; nothing else may


def loss_weights(config: TrainConfig) -> LossWeights:
    """The loss weights a training config asks for."""
    return LossWeights(
        config.beta1,
        config.beta2,
        config.tau,
        config.sequence_loss,
        config.mean_loss,
        config.one_step_needs_previous,
        config.main_agent_weight,
        config.one_step_weight,
    )


def learning_rate(config: TrainConfig, step: int, total_steps: int) -> float:
    """The lr of optimiser step `step` (0-based) of `total_steps`: constant, or a cosine decay
    from `lr` to `lr * lr_final_ratio` reached at the last step. A function of the step alone,
    so a resumed run needs no scheduler state."""
    if config.lr_schedule == "constant" or total_steps <= 1:
        return config.lr
    progress = min(step, total_steps - 1) / (total_steps - 1)
    final = config.lr * config.lr_final_ratio
    return final + (config.lr - final) * 0.5 * (1.0 + math.cos(math.pi * progress))


def observed_steps(config: TrainConfig, step: int, num_observed: int, num_steps: int) -> int:
    """Observed steps of optimiser step `step`: num_observed, or with `observed_jitter` j a
    draw from [num_observed - j, num_observed + j] (clipped to [2, num_steps - 2]) that
    depends only on the seed and the step."""
    if config.observed_jitter == 0:
        return num_observed
    low = max(2, num_observed - config.observed_jitter)
    high = min(num_steps - 2, num_observed + config.observed_jitter)
    return random.Random(config.seed * 1_000_003 + step).randint(low, max(low, high))


def train_step(
    model: SmoothAttentionPredictor,
    optimizer: torch.optim.Optimizer,
    batch: Batch,
    num_observed: int,
    config: TrainConfig,
    lr: float | None = None,
) -> dict[str, float]:
    """One optimiser step on a batch (at learning rate `lr`, default config.lr); returns the
    loss terms. Raises on a non-finite loss."""
    for group in optimizer.param_groups:
        group["lr"] = config.lr if lr is None else lr
    model.train()
    weights = loss_weights(config)
    out = model(
        batch.positions,
        batch.valid,
        num_observed,
        batch.attention,
        rollout=weights.sequence,
        sample=config.rollout_feed == "sample",
        roles=batch.roles,
        scenes=batch.index,  # training scenes: the cross-fitted highway maps
    )
    loss, terms = compute_loss(
        out, batch.positions, batch.valid, num_observed, weights, batch.focal
    )
    if not math.isfinite(terms["loss"]):
        raise FloatingPointError(f"non-finite loss {terms}")
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if config.grad_clip_norm > 0:  # per group: one loss's large gradients never shrink another's
        for group in model.parameter_groups():
            torch.nn.utils.clip_grad_norm_(group, config.grad_clip_norm)
    optimizer.step()
    return terms


def validation_scores(
    model: SmoothAttentionPredictor, val_set: TrajectoryDataset
) -> dict[str, float | None]:
    """ADE/FDE [m] of the fed-back means for the main agents and all agents."""
    pred_mean, attention = predict_model(model, val_set.all(), val_set.meta.num_observed)
    predictions = Predictions.from_split(
        val_set.data, val_set.meta, val_set.split, "validation", pred_mean, attention
    )
    result = score(predictions)
    main, every = result["main_agents"]["overall"], result["all_agents"]["overall"]
    return {
        "ade_main": main["ade"],
        "fde_main": main["fde"],
        "ade_all": every["ade"],
        "fde_all": every["fde"],
    }


def selection_score(val: dict[str, float | None]) -> float | None:
    """The number best.pt minimises: main-agent ADE (all-agent ADE if no main agent counts)."""
    return val["ade_main"] if val["ade_main"] is not None else val["ade_all"]


def check_labels(model_cfg: ModelConfig, meta: DatasetMeta, data_path: str | os.PathLike) -> None:
    """RunError if the model reads attention labels (the oracle `correct` variant) and the data
    records none (real data usually has none: every agent would attend to nobody)."""
    if model_cfg.attention_mode == "oracle" and not meta.has("attention"):
        raise RunError(
            f"{data_path}: the oracle attention (variant correct) reads attention labels, "
            "which this file does not record"
        )


def describe_data(path: str, dataset: TrajectoryDataset, val_count: int) -> dict:
    """What a run records about its data file (also checked on resume)."""
    meta = dataset.meta
    return {
        "path": os.path.abspath(path),
        "scenario": meta.scenario,
        "dt": float(meta.dt),
        "num_observed": int(meta.num_observed),
        "num_predicted": int(meta.num_predicted),
        "case_names": list(meta.case_names),
        "role_names": list(meta.role_names),
        "train_count": len(dataset),
        "val_count": val_count,
        "num_agents": dataset.all().num_agents,
    }


# --------------------------------------------------------------------------- the loop
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
    """Seeded model, optimizer and loader of a fresh run."""
    seed_everything(train_cfg.seed)
    model = SmoothAttentionPredictor(model_cfg)
    if model_cfg.frame == "agent":  # input/output scales from the training split (checkpointed)
        scenes = train_set.all()
        model.fit_normalisation(
            scenes.positions, scenes.valid, train_set.meta.num_observed, scenes.roles
        )
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


def run_epoch(
    state: RunState,
    num_observed: int,
    config: TrainConfig,
    bar: tqdm,
    step_callback: Callable[[int], None] | None,
) -> dict[str, float]:
    """One pass over the training loader; returns the mean of each loss term."""
    sums: dict[str, float] = {}
    steps = 0
    first_step = state.epoch * len(state.loader)
    for batch in state.loader:
        if step_callback is not None:
            step_callback(first_step + steps)
        step = first_step + steps
        lr = learning_rate(config, step, config.epochs * len(state.loader))
        observed = observed_steps(config, step, num_observed, batch.num_steps)
        terms = train_step(state.model, state.optimizer, batch, observed, config, lr)
        for name, value in terms.items():
            sums[name] = sums.get(name, 0.0) + value
        steps += 1
        bar.update(1)
        bar.set_postfix(epoch=state.epoch + 1, loss=f"{terms['loss']:.3f}", refresh=False)
    return {name: total / max(steps, 1) for name, total in sums.items()}


@dataclass(frozen=True)
class TrainResult:
    """What a finished `train` call reports."""

    out_dir: Path
    epochs: int  # completed epochs
    best_epoch: int
    best_score: float | None  # validation ADE [m] of best.pt (main agents)
    final_loss: float | None  # mean training loss of the last epoch run now (None if none ran)
    seconds: float  # wall time of this call

    def summary(self, variant: str) -> str:
        """One-line summary."""
        best = "n/a" if self.best_score is None else f"{self.best_score:.3f} m"
        loss = "n/a" if self.final_loss is None else f"{self.final_loss:.4f}"
        return (
            f"trained {variant} for {self.epochs} epochs in {self.seconds:.1f} s; final loss "
            f"{loss}; best val ADE (main agents) {best} at epoch {self.best_epoch}; "
            f"run in {self.out_dir}"
        )


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


def _check_resume(
    checkpoint: dict, model_cfg: ModelConfig, train_cfg: TrainConfig, data: dict
) -> None:
    if checkpoint["model_config"] != config_to_dict(model_cfg):
        raise RunError("a resumed run must use its stored model configuration")
    stored, asked = checkpoint["train_config"], config_to_dict(train_cfg)
    changed = [k for k in asked if k not in RESUME_MAY_CHANGE and stored.get(k) != asked[k]]
    if changed:
        raise RunError(f"a resumed run cannot change {', '.join(changed)} of the stored run")
    keys = [k for k in data if k != "path"]
    if any(checkpoint["data"].get(k) != data[k] for k in keys):
        raise RunError(f"a resumed run needs its data file ({checkpoint['data']['path']})")


def _load_splits(
    data_path: str | os.PathLike,
) -> tuple[TrajectoryDataset, TrajectoryDataset | None, dict]:
    train_set = TrajectoryDataset(data_path, "train")
    if len(train_set) == 0:
        raise RunError(f"{data_path}: the train split is empty")
    val_set = TrajectoryDataset(data_path, "val")
    data = describe_data(os.fspath(data_path), train_set, len(val_set))
    return train_set, val_set if len(val_set) else None, data


def _rewrite_metrics(path: Path, last_epoch: int) -> None:
    """Keep only the metrics lines of epochs <= last_epoch (after an interruption)."""
    if not path.exists():
        return
    with writing(path, "read"):
        lines = [line for line in path.read_text().splitlines() if line.strip()]
    kept = [line for line in lines if json.loads(line)["epoch"] <= last_epoch]
    atomic_write_text("".join(line + "\n" for line in kept), path)


def train(
    data_path: str | os.PathLike,
    model_cfg: ModelConfig,
    train_cfg: TrainConfig,
    out_dir: str | os.PathLike,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    step_callback: Callable[[int], None] | None = None,
) -> TrainResult:
    """Train (or resume) a run in `out_dir`; see the module docstring for the files written.

    Raises RunError for an unusable run directory (or a failed write), FormatError for a bad
    data file, CheckpointError for an unreadable last.pt. A fresh run that fails before its
    first checkpoint leaves nothing behind. `step_callback(global_step)` is called before every
    optimiser step (for tests).
    """
    started = time.perf_counter()
    out = Path(out_dir)
    check_out_dir(out, resume, overwrite)
    torch.set_num_threads(train_cfg.threads)
    train_set, val_set, data = _load_splits(data_path)
    try:
        model_cfg = resolve_roles(model_cfg, train_set.meta.role_names)
    except ValueError as err:
        raise RunError(f"{data_path}: {err}") from None
    check_labels(model_cfg, train_set.meta, data_path)
    state = build_state(model_cfg, train_cfg, train_set)
    if resume:
        checkpoint = read_checkpoint(out / "last.pt")
        _check_resume(checkpoint, model_cfg, train_cfg, data)
        restore_state(state, checkpoint)
        _rewrite_metrics(out / "metrics.jsonl", state.epoch)
        created: list[Path] = []
    else:
        created = claim_out_dir(out, overwrite)
    try:
        final_loss = _train_epochs(
            state, model_cfg, train_cfg, data, val_set, out, progress, step_callback
        )
    except BaseException:
        if not resume and not (out / "last.pt").exists():
            remove_failed_start(out, created)
        raise
    return TrainResult(
        out,
        state.epoch,
        state.best_epoch,
        state.best_score,
        final_loss,
        time.perf_counter() - started,
    )


def _train_epochs(
    state: RunState,
    model_cfg: ModelConfig,
    train_cfg: TrainConfig,
    data: dict,
    val_set: TrajectoryDataset | None,
    out: Path,
    progress: bool,
    step_callback: Callable[[int], None] | None,
) -> float | None:
    """Write config.json, run the remaining epochs with their checkpoints and metrics lines;
    returns the last epoch's mean training loss (None if no epoch was left to run)."""
    run_config = {
        "model": config_to_dict(model_cfg),
        "train": config_to_dict(train_cfg),
        "data": data,
        "package_version": __version__,
    }
    atomic_write_text(json.dumps(run_config, indent=2) + "\n", out / "config.json")
    per_epoch = len(state.loader)
    bar = tqdm(
        total=train_cfg.epochs * per_epoch,
        initial=min(state.epoch, train_cfg.epochs) * per_epoch,
        desc=f"train {train_cfg.variant}",
        unit="step",
        disable=not progress,
    )
    final_loss = None
    with bar:
        for epoch in range(state.epoch + 1, train_cfg.epochs + 1):
            record = _one_epoch(
                state, epoch, data["num_observed"], train_cfg, val_set, bar, step_callback
            )
            final_loss = record["train"]["loss"]
            with writing(out / "metrics.jsonl"), open(out / "metrics.jsonl", "a") as stream:
                stream.write(json.dumps(record) + "\n")
            if record["best"]:
                atomic_save(
                    checkpoint_dict(state, model_cfg, train_cfg, data, False), out / "best.pt"
                )
            atomic_save(checkpoint_dict(state, model_cfg, train_cfg, data, True), out / "last.pt")
    if not (out / "best.pt").exists():  # no epoch had a validation score
        atomic_save(checkpoint_dict(state, model_cfg, train_cfg, data, False), out / "best.pt")
    return final_loss


def _one_epoch(
    state: RunState,
    epoch: int,
    num_observed: int,
    config: TrainConfig,
    val_set: TrajectoryDataset | None,
    bar: tqdm,
    step_callback: Callable[[int], None] | None,
) -> dict:
    """Train one epoch, validate if due, update the best score; returns the metrics record."""
    started = time.perf_counter()
    model_cfg = state.model.config
    changes = model_cfg.attention_mode == "learned" and not model_cfg.refit_on_prior
    # the highway read with this epoch's attention; uniform or oracle attention never changes,
    # nor does the prior of refit_on_prior, so the fit at the first epoch (kept in the
    # checkpoint) holds for every later one
    if state.refit_scenes is not None and (changes or epoch == 1):
        scenes = state.refit_scenes
        state.model.refit_attended(
            scenes.positions, scenes.valid, num_observed, scenes.attention, scenes.roles
        )
    terms = run_epoch(state, num_observed, config, bar, step_callback)
    state.epoch = epoch
    val, best = None, False
    due = epoch % config.eval_every == 0 or epoch == config.epochs
    if val_set is not None and due:
        val = validation_scores(state.model, val_set)
        current = selection_score(val)
        if current is not None and (state.best_score is None or current < state.best_score):
            state.best_score, state.best_epoch, best = current, epoch, True
        bar.set_postfix(
            epoch=epoch,
            loss=f"{terms['loss']:.3f}",
            val_ade=f"{current:.3f}" if current is not None else "n/a",
        )
    elif val_set is None:  # nothing to select on: best.pt follows the last epoch
        state.best_epoch, best = epoch, True
    return {
        "epoch": epoch,
        "train": terms,
        "val": val,
        "best": best,
        "seconds": round(time.perf_counter() - started, 3),
    }
