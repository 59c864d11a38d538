"""A training run's changing state and its checkpoints: what `last.pt` and `best.pt` hold,
how a fresh run's state is built (seeded) and how an interrupted one is restored and checked.

`last.pt` stores the optimizer state, the epoch, the best validation score and the torch,
numpy, python and loader RNG states, so a resumed run reproduces the uninterrupted one bit for
bit (same thread count assumed). A resumed run may change only `RESUME_MAY_CHANGE`; any other
setting asked for must equal the stored one (`ResumeMismatch` names both values).

Every checkpoint also records the run's preset (`predictor.presets.PRESETS`; None when it was
built from bare configs) and whether the run is finished (all its epochs done; written with the
last epoch's checkpoint, atomically). Runs written before these two fields existed still load
(`run_status`): their preset counts as not recorded, so a `--preset` asked for on resume is
checked field by field against what that preset sets (`preset_mismatch`), and they count as
finished when their stored epoch reached their configured epochs.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import torch

from predictor import __version__
from predictor.checkpoints import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, read_checkpoint
from predictor.compiled_step import compile_graph_step, compiler_missing
from predictor.config import ModelConfig, TrainConfig, resolve_roles
from predictor.model import SmoothAttentionPredictor
from predictor.presets import PRESET_FIELDS, make_configs
from predictor.random_state import rng_state, seed_everything, set_rng_state
from predictor.run_files import RunError, atomic_write_text, check_out_dir, writing
from predictor.stored_config import (
    ADDED_MODEL_FIELDS,
    ADDED_TRAIN_FIELDS,
    config_to_dict,
    model_config_from_dict,
    train_config_from_dict,
)
from trajectory_data.torch_dataset import Batch, TrajectoryDataset, make_loader

RESUME_MAY_CHANGE = (
    "epochs",
    "threads",
    "eval_every",
    "device",
)  # TrainConfig fields; nothing else may


class ResumeMismatch(RunError):
    """A setting asked for on resume differs from the stored run's: `name` (a config field, or
    "preset"), the `stored` and the `asked` value; `preset` is the preset whose value `asked`
    is, when the setting was not asked for by itself (a run that did not record its preset)."""

    def __init__(self, name: str, stored: Any, asked: Any, preset: str | None = None) -> None:
        self.name, self.stored, self.asked, self.preset = name, stored, asked, preset
        via = f" (set by preset {preset!r})" if preset is not None else ""
        super().__init__(
            f"a resumed run keeps its stored configuration: {name} is {stored!r} there, "
            f"{asked!r} asked{via} (only {', '.join(RESUME_MAY_CHANGE)} may change)"
        )

    def __reduce__(self):  # picklable across process pools
        return (type(self), (self.name, self.stored, self.asked, self.preset))


@dataclass(frozen=True)
class RunStatus:
    """Where a run directory's `last.pt` stands."""

    out_dir: Path
    epoch: int  # completed epochs
    epochs: int  # the epochs the run was configured for
    finished: bool  # all of them done
    preset: str | None  # None: not recorded (bare configs, or a run from before presets were)
    best_epoch: int
    best_score: float | None  # validation ADE [m] of best.pt (main agents)
    has_val: bool = True  # the data had a validation split (False: best.pt is the last epoch)

    def summary(self) -> str:
        """One line: the run is finished, its epochs and best validation score."""
        return (
            f"run {self.out_dir} is finished: {self.epoch} of {self.epochs} epochs trained, "
            f"{best_text(self.best_score, self.best_epoch, self.has_val)}; nothing to resume "
            "(a larger --epochs trains it further)"
        )


NO_VAL_NOTE = (
    "the data has no validation split: no validation ADE, best.pt is the last epoch's weights"
)


def best_text(
    best_score: float | None, best_epoch: int, has_val: bool, agents: str = "main agents"
) -> str:
    """How a summary line names best.pt: its validation ADE and epoch, or why it has none."""
    if not has_val:
        return f"no validation split (best.pt is the last epoch, {best_epoch})"
    if best_score is None:
        return "no validation score (no agent scored; best.pt is the last epoch)"
    return f"best val ADE ({agents}) {best_score:.3f} m at epoch {best_epoch}"


def status_of(checkpoint: Mapping[str, Any], out_dir: str | os.PathLike) -> RunStatus:
    """The `RunStatus` of a `last.pt` dict. A checkpoint without the `finished` field (written
    before it existed) is finished when its epoch reached its configured epochs; one without
    `preset` has none recorded; one whose data description lacks `val_count` had a validation
    split."""
    epoch, epochs = int(checkpoint["epoch"]), int(checkpoint["train_config"]["epochs"])
    finished = checkpoint.get("finished")
    best = checkpoint.get("best_score")
    data = checkpoint.get("data")
    val_count = data.get("val_count") if isinstance(data, Mapping) else None
    return RunStatus(
        out_dir=Path(out_dir),
        epoch=epoch,
        epochs=epochs,
        finished=bool(epoch >= epochs if finished is None else finished),
        preset=checkpoint.get("preset"),
        best_epoch=int(checkpoint.get("best_epoch", 0)),
        best_score=None if best is None else float(best),
        has_val=val_count is None or int(val_count) > 0,
    )


def run_status(out_dir: str | os.PathLike) -> RunStatus:
    """The status of the run in `out_dir` (RunError if there is nothing to resume,
    CheckpointError if its last.pt cannot be read)."""
    out = Path(out_dir)
    check_out_dir(out, resume=True, overwrite=False)
    return status_of(read_checkpoint(out / "last.pt"), out)


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
    state: RunState,
    model_cfg: ModelConfig,
    train_cfg: TrainConfig,
    data: dict,
    full: bool,
    preset: str | None = None,
) -> dict:
    """Checkpoint contents (plain types and tensors only); `finished` says whether the state's
    epoch reached the configured epochs."""
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
        "preset": preset,
        "finished": state.epoch >= train_cfg.epochs,
    }
    if full:
        out["optimizer_state"] = state.optimizer.state_dict()
        out["rng"] = rng_state(state.loader.generator)
    return out


def make_optimizer(model: torch.nn.Module, config: TrainConfig) -> torch.optim.Optimizer:
    """Adam, the paper's optimiser."""
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
    device = torch.device(train_cfg.device)
    model.to(device)  # after the statistics' fit on the CPU; a no-op there
    if train_cfg.compile_graph_step:
        problem = compiler_missing()
        if problem is not None:
            raise RunError(problem)
        compile_graph_step(model)
    optimizer = make_optimizer(model, train_cfg)
    refit_scenes = train_set.all().to(device) if model_cfg.attended_refit else None
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
    out_dir: str | os.PathLike,
    changes: Mapping[str, Any] | None = None,
    preset: str | None = None,
) -> tuple[ModelConfig, TrainConfig]:
    """The configs to resume the run in `out_dir` with: the stored ones (from last.pt) with
    `changes` applied, built through the validating constructors.

    `changes` may hold any ModelConfig or TrainConfig field; those in RESUME_MAY_CHANGE are
    applied, any other must equal the stored value. `preset`, if given, must be the stored
    run's; a run that did not record its preset must hold what that preset (with `changes`)
    sets. Raises ResumeMismatch (a RunError) naming the stored and the asked value, RunError
    if there is nothing to resume, a setting is unknown or `epochs` is fewer than the run has
    done, ValueError for an out-of-range value.
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
    changes = dict(changes or {})
    for name, value in changes.items():
        if name not in stored:
            raise RunError(f"unknown setting {name!r}")
        if name not in RESUME_MAY_CHANGE and value != stored[name]:
            raise ResumeMismatch(name, stored[name], value)
    if preset is not None:
        recorded = checkpoint.get("preset")
        if recorded is not None and recorded != preset:
            raise ResumeMismatch("preset", recorded, preset)
        if recorded is None:
            roles = checkpoint.get("data", {}).get("role_names", ())
            mismatch = preset_mismatch(stored, preset, changes, roles)
            if mismatch is not None:
                raise mismatch
    allowed = {k: v for k, v in changes.items() if k in RESUME_MAY_CHANGE}
    configs = (
        model_config_from_dict(checkpoint["model_config"]),
        train_config_from_dict({**checkpoint["train_config"], **allowed}),
    )
    done = int(checkpoint["epoch"])
    if configs[1].epochs < done:
        raise RunError(
            f"{out} has trained {done} epochs already; epochs {configs[1].epochs} asks for "
            "fewer (a run cannot be shortened)"
        )
    return configs


def preset_mismatch(
    stored: Mapping[str, Any],
    preset: str,
    changes: Mapping[str, Any],
    role_names: Sequence[str] = (),
) -> ResumeMismatch | None:
    """For a run that did not record its preset: the first field among those presets set
    (`PRESET_FIELDS`) where the stored config differs from what `preset`, with the stored
    variant and `changes`, gives for training data of `role_names` (None if none differs, or
    the configs cannot be built: the fields asked for are checked one by one anyway)."""
    model_fields, train_fields = PRESET_FIELDS
    model_names = {item.name for item in fields(ModelConfig)} - {"attention_mode"}
    train_names = {item.name for item in fields(TrainConfig)} - {"variant", "sequence_loss"}
    model_changes = {k: v for k, v in changes.items() if k in model_names}
    train_changes = {k: v for k, v in changes.items() if k in train_names}
    try:
        model_cfg, train_cfg = make_configs(
            str(stored["variant"]), model_changes, preset=preset, **train_changes
        )
        model_cfg = resolve_roles(model_cfg, tuple(role_names))
    except ValueError:
        return None  # the asked settings are checked against the stored ones field by field
    expected = {**config_to_dict(model_cfg), **config_to_dict(train_cfg)}
    for name in (*model_fields, *train_fields):
        if name in RESUME_MAY_CHANGE or name not in expected:
            continue
        if expected[name] != stored.get(name, expected[name]):
            return ResumeMismatch(name, stored[name], expected[name], preset=preset)
    return None


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
        trained = checkpoint["data"]["path"]
        if os.path.abspath(trained) == data["path"]:
            raise RunError(f"a resumed run needs the data it was trained on: {trained} changed")
        raise RunError(
            f"a resumed run needs its data file: it was trained on {trained}, not {data['path']}"
        )


def rewrite_metrics(path: Path, last_epoch: int) -> None:
    """Keep only the metrics lines of epochs <= last_epoch (after an interruption)."""
    if not path.exists():
        return
    with writing(path, "read"):
        lines = [line for line in path.read_text().splitlines() if line.strip()]
    kept = [line for line in lines if json.loads(line)["epoch"] <= last_epoch]
    atomic_write_text("".join(line + "\n" for line in kept), path)
