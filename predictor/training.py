"""Training loop: Adam on the paper's loss, validation ADE, checkpoints, exact resume.

A run directory holds `config.json` (model, training and data description), `metrics.jsonl`
(one JSON object per epoch), `last.pt` (everything needed to resume, written after every epoch)
and `best.pt` (the weights with the lowest validation ADE of the main agents, i.e. the validation
split's focal agents, fed-back means). A data file without validation scenes trains all the
same, but nothing selects: best.pt is the last epoch's weights; `train` says so on stderr at the
start (`NO_VAL_NOTE`) and the summary line says "no validation split".

Determinism: the seed fixes the initial weights (torch RNG), the batch order (the loader's own
generator) and the rollout samples (torch RNG); what `last.pt` keeps to resume a run bit for bit
is in `predictor.run_state`.

Failures: everything that can be checked (run directory, data file, resume compatibility) is
checked before the run directory is touched; a fresh run that fails before its first checkpoint
(`last.pt`) removes the files and directories it created, so it blocks neither a re-run nor
`--resume`; with overwrite, the old run's files are set aside until the new run's first
checkpoint and put back if it fails before. A resumed run may change only
`run_state.RESUME_MAY_CHANGE`. Write failures (read-only directory, full disk) are a RunError
naming the file (`predictor.run_files`).

Interrupts: Ctrl-C (KeyboardInterrupt) during `train` is raised again as `TrainingInterrupted`,
a KeyboardInterrupt that says what the run directory holds afterwards (its `outcome`): nothing
changed, nothing kept, the previous run put back (an overwrite stopped before its first
checkpoint), or a run that `resume=True` continues.

Each checkpoint records the run's preset and whether it is finished (`predictor.run_state`);
the last epoch writes best.pt before last.pt, so a last.pt that says finished has its best.pt.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from predictor import __version__
from predictor.checkpoints import CheckpointError, read_checkpoint
from predictor.config import ModelConfig, TrainConfig, resolve_roles
from predictor.evaluation import json_safe
from predictor.forecasting import predict_model, score
from predictor.losses import LossWeights, compute_loss
from predictor.model import SmoothAttentionPredictor
from predictor.predictions import Predictions
from predictor.run_files import (
    Claim,
    RunError,
    atomic_save,
    atomic_write_text,
    check_out_dir,
    claim_out_dir,
    writing,
)
from predictor.run_state import (
    NO_VAL_NOTE,
    ResumeMismatch,
    RunState,
    best_text,
    build_state,
    check_resume,
    checkpoint_dict,
    restore_state,
    rewrite_metrics,
)
from predictor.stored_config import config_to_dict
from predictor.wording import Wording
from trajectory_data.format import DatasetMeta
from trajectory_data.torch_dataset import Batch, TrajectoryDataset


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
        config.penalty_linear_from_m,
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


def check_device(device: str) -> None:
    """RunError unless torch can train on `device` here (a CUDA device must be present)."""
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise RunError(f"train.device is {device!r}, but torch finds no CUDA device here")
    if device.startswith("cuda:") and int(device[5:]) >= torch.cuda.device_count():
        raise RunError(
            f"train.device is {device!r}, but torch finds {torch.cuda.device_count()} CUDA devices"
        )


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
    batch = batch.to(config.device)
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


# --------------------------------------------------------------------------- interrupts
# what an interrupted `train` left in its run directory
UNTOUCHED = "untouched"  # stopped before the directory was changed
NOTHING_KEPT = "nothing kept"  # a new run stopped before its first checkpoint, removed
RESTORED = "restored"  # an overwrite stopped before its first checkpoint: the old run put back
RESUMABLE = "resumable"  # a run with a checkpoint: resume=True continues it


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during `train`: `outcome` (one of UNTOUCHED, NOTHING_KEPT, RESTORED, RESUMABLE)
    says what `out_dir` holds now, `epoch` the epochs its run has completed (RESUMABLE), of
    `epochs`."""

    def __init__(self, out_dir: str, outcome: str, epoch: int = 0, epochs: int = 0) -> None:
        super().__init__(out_dir, outcome, epoch, epochs)
        self.out_dir, self.outcome, self.epoch, self.epochs = out_dir, outcome, epoch, epochs


# --------------------------------------------------------------------------- the loop
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
        terms = train_step(state.model, state.optimizer, batch, num_observed, config, lr)
        for name, value in terms.items():
            sums[name] = sums.get(name, 0.0) + value
        steps += 1
        bar.set_postfix(epoch=state.epoch + 1, loss=f"{terms['loss']:.3f}", refresh=False)
        bar.update(1)
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
    has_val: bool = True  # the data had a validation split (False: best.pt is the last epoch)
    agents: str = "main agents"  # the scored agents' name (`predictor.wording.Wording`)

    def summary(self, variant: str) -> str:
        """One-line summary."""
        loss = "n/a" if self.final_loss is None else f"{self.final_loss:.4f}"
        return (
            f"trained {variant} for {self.epochs} epochs in {self.seconds:.1f} s; final loss "
            f"{loss}; {best_text(self.best_score, self.best_epoch, self.has_val, self.agents)}; "
            f"run in {self.out_dir}"
        )


def _load_splits(
    data_path: str | os.PathLike,
) -> tuple[TrajectoryDataset, TrajectoryDataset | None, dict]:
    train_set = TrajectoryDataset(data_path, "train")
    if len(train_set) == 0:
        raise RunError(f"{data_path}: the train split is empty")
    val_set = TrajectoryDataset(data_path, "val")
    data = describe_data(os.fspath(data_path), train_set, len(val_set))
    return train_set, val_set if len(val_set) else None, data


def train(
    data_path: str | os.PathLike,
    model_cfg: ModelConfig,
    train_cfg: TrainConfig,
    out_dir: str | os.PathLike,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    step_callback: Callable[[int], None] | None = None,
    preset: str | None = None,
) -> TrainResult:
    """Train (or resume) a run in `out_dir`; see the module docstring for the files written.

    `preset` is recorded in the checkpoints (the name the configs were made from, if any); a
    resumed run keeps the recorded one (ResumeMismatch if another is given). Raises RunError
    for an unusable run directory (or a failed write), FormatError for a bad data file,
    CheckpointError for an unreadable last.pt, TrainingInterrupted on Ctrl-C. A fresh run that
    fails before its first checkpoint leaves nothing behind. `step_callback(global_step)` is
    called before every optimiser step (for tests).
    """
    out = Path(out_dir)
    check_device(train_cfg.device)
    check_out_dir(out, resume, overwrite)
    try:
        return _train(
            data_path, model_cfg, train_cfg, out, resume, overwrite, progress, step_callback, preset
        )
    except TrainingInterrupted:
        raise
    except KeyboardInterrupt as err:  # before the directory was claimed: nothing changed
        outcome = _interruption(out, resume, None)
        raise TrainingInterrupted(str(out), outcome, *outcome_epochs(out, train_cfg)) from err


def _train(
    data_path: str | os.PathLike,
    model_cfg: ModelConfig,
    train_cfg: TrainConfig,
    out: Path,
    resume: bool,
    overwrite: bool,
    progress: bool,
    step_callback: Callable[[int], None] | None,
    preset: str | None,
) -> TrainResult:
    started = time.perf_counter()
    torch.set_num_threads(train_cfg.threads)
    train_set, val_set, data = _load_splits(data_path)
    try:
        model_cfg = resolve_roles(model_cfg, train_set.meta.role_names)
    except ValueError as err:
        raise RunError(f"{data_path}: {err}") from None
    check_labels(model_cfg, train_set.meta, data_path)
    if val_set is None:  # always said, progress bar or not: nothing will select the weights
        print(f"train {train_cfg.variant}: {data_path}: {NO_VAL_NOTE}", file=sys.stderr, flush=True)
    if progress:  # seconds before the bar: the optimiser's first use imports much of torch
        print(
            f"train {train_cfg.variant}: building the model and optimiser on "
            f"{len(train_set)} training {Wording.of(train_set.meta).scenes}",
            file=sys.stderr,
            flush=True,
        )
    state = build_state(model_cfg, train_cfg, train_set)
    if resume:
        checkpoint = read_checkpoint(out / "last.pt")
        check_resume(checkpoint, model_cfg, train_cfg, data)
        recorded = checkpoint.get("preset")
        if preset is not None and recorded is not None and preset != recorded:
            raise ResumeMismatch("preset", recorded, preset)
        preset = preset if recorded is None else recorded
        try:
            restore_state(state, checkpoint)
        except (KeyError, RuntimeError, TypeError, ValueError) as err:
            message = " ".join(str(err).split())[:200]
            raise CheckpointError(f"{out / 'last.pt'}: cannot resume from it ({message})") from None
        rewrite_metrics(out / "metrics.jsonl", state.epoch)
        claim = Claim(out)
    else:
        claim = claim_out_dir(out, overwrite)
    try:
        final_loss = _train_epochs(
            state, model_cfg, train_cfg, data, val_set, out, progress, step_callback, preset
        )
    except BaseException as err:
        if not resume and not (out / "last.pt").exists():
            claim.undo()
        else:
            claim.commit()
        if isinstance(err, KeyboardInterrupt):
            outcome = _interruption(out, resume, claim)
            raise TrainingInterrupted(str(out), outcome, *outcome_epochs(out, train_cfg)) from err
        raise
    claim.commit()
    return TrainResult(
        out,
        state.epoch,
        state.best_epoch,
        state.best_score,
        final_loss,
        time.perf_counter() - started,
        has_val=val_set is not None,
        agents=Wording.of(train_set.meta).agents,
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
    preset: str | None = None,
) -> float | None:
    """Write config.json, run the remaining epochs with their checkpoints and metrics lines;
    returns the last epoch's mean training loss (None if no epoch was left to run)."""
    run_config = {
        "model": config_to_dict(model_cfg),
        "train": config_to_dict(train_cfg),
        "data": data,
        "preset": preset,
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
                stream.write(json.dumps(json_safe(record), allow_nan=False) + "\n")
            # at the last epoch best.pt exists before last.pt says the run is finished (the
            # last epoch's weights when no epoch had a validation score)
            no_best = epoch == train_cfg.epochs and not (out / "best.pt").exists()
            if record["best"] or no_best:
                best = checkpoint_dict(state, model_cfg, train_cfg, data, False, preset)
                atomic_save(best, out / "best.pt")
            last = checkpoint_dict(state, model_cfg, train_cfg, data, True, preset)
            atomic_save(last, out / "last.pt")
    if not (out / "best.pt").exists():  # no epoch left to run, none with a validation score
        atomic_save(
            checkpoint_dict(state, model_cfg, train_cfg, data, False, preset), out / "best.pt"
        )
    return final_loss


def _interruption(out: Path, resume: bool, claim: Claim | None) -> str:
    """What an interrupted `train` left in `out` (after its claim was undone or committed)."""
    if resume:
        return RESUMABLE
    if claim is None:
        return UNTOUCHED
    if claim.restored:  # before the new run's first checkpoint: last.pt is the old run's
        return RESTORED
    return RESUMABLE if (out / "last.pt").exists() else NOTHING_KEPT


def outcome_epochs(out: Path, train_cfg: TrainConfig) -> tuple[int, int]:
    """(epochs completed by the run in `out` as its last.pt says, 0 if it has none or it cannot
    be read; the epochs `train_cfg` asks for)."""
    try:
        return int(read_checkpoint(out / "last.pt")["epoch"]), train_cfg.epochs
    except (CheckpointError, KeyError, TypeError, ValueError):
        return 0, train_cfg.epochs


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
    changes = model_cfg.attention_mode == "learned"
    # the highway read with this epoch's attention; uniform or oracle attention never changes,
    # so the fit at the first epoch (kept in the checkpoint) holds for every later one
    if state.refit_scenes is not None and (changes or epoch == 1):
        bar.set_postfix_str(f"epoch {epoch}: refitting the highway", refresh=True)
        scenes = state.refit_scenes
        state.model.refit_attended(
            scenes.positions, scenes.valid, num_observed, scenes.attention, scenes.roles
        )
    terms = run_epoch(state, num_observed, config, bar, step_callback)
    state.epoch = epoch
    val, best = None, False
    due = epoch % config.eval_every == 0 or epoch == config.epochs
    if val_set is not None and due:
        bar.set_postfix_str(f"epoch {epoch}: validating", refresh=True)
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
