"""What a viewer shows, read and checked: a dataset split, optionally the predictions of one
predictor on its scenes (a predictions file, or a run evaluated here) and the run's description.

Every problem is a one-line `ViewerError`: a missing or malformed file, predictions of another
dataset (scenario, split, shapes or scenes that differ), more data than a browser handles well
without the thinning option. Only the dataset format and the predictions file are read (the
`predictor` readers); a run is evaluated with `predictor.evaluation` where no predictions file
is given.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from predictor.predictions import Predictions, PredictionsError, load_predictions
from trajectory_data.format import SPLITS, DatasetMeta, FormatError, TrajectorySet
from trajectory_data.reader import read_meta, read_split


class ViewerError(ValueError):
    """The viewer cannot be written from these inputs; the message is one line."""


@dataclass(frozen=True)
class RunInfo:
    """What the header says about a training run (from its config.json and metrics.jsonl)."""

    path: str
    variant: str
    preset: str | None
    seed: int
    epochs: int  # asked for
    epochs_done: int
    best_epoch: int | None  # lowest validation ADE of the main agents
    trained_on: str  # scenario of its training data

    def text(self) -> str:
        """One line for the header."""
        preset = f"preset {self.preset}, " if self.preset else ""
        best = f", best epoch {self.best_epoch}" if self.best_epoch is not None else ""
        return (
            f"run {self.path}: {self.variant} ({preset}seed {self.seed}, "
            f"{self.epochs_done} of {self.epochs} epochs{best}), trained on {self.trained_on}"
        )


@dataclass(frozen=True)
class Shown:
    """The scenes a viewer shows, aligned: `data` row k is split row `rows[k]`."""

    data_path: str
    meta: DatasetMeta
    split: str
    data: TrajectorySet
    rows: np.ndarray  # (n,) split rows of the shown scenes
    available: int  # scenes there were to show before thinning
    predictions: Predictions | None  # aligned with data, or None
    predictions_path: str | None
    run: RunInfo | None

    @property
    def n(self) -> int:
        return self.data.n

    @property
    def left_out(self) -> int:
        return self.available - self.n


def read_run(run_dir: str | os.PathLike) -> RunInfo:
    """The description of a training run directory (ViewerError if it is not one)."""
    run = Path(run_dir)
    if not run.is_dir():
        raise ViewerError(f"run directory {run} does not exist")
    try:
        config = json.loads((run / "config.json").read_text())
        train, data = config["train"], config["data"]
        lines = (run / "metrics.jsonl").read_text().splitlines()
        epochs = [json.loads(line) for line in lines if line.strip()]
        info = RunInfo(
            path=str(run),
            variant=str(train["variant"]),
            preset=config.get("preset"),
            seed=int(train["seed"]),
            epochs=int(train["epochs"]),
            epochs_done=len(epochs),
            best_epoch=_best_epoch(epochs),
            trained_on=str(data["scenario"]),
        )
    except FileNotFoundError as err:
        raise ViewerError(f"{run} is not a training run (no {Path(err.filename).name})") from None
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ViewerError(f"{run}: unreadable run files ({type(err).__name__}: {err})") from None
    return info


def _best_epoch(epochs: list[dict]) -> int | None:
    scored = [e for e in epochs if isinstance(e.get("val"), dict) and "ade_main" in e["val"]]
    best = [e for e in scored if e.get("best")]
    return int(best[-1]["epoch"]) if best else None


def read_inputs(
    data_path: str | os.PathLike,
    predictions_path: str | os.PathLike | None = None,
    run_dir: str | os.PathLike | None = None,
    split: str | None = None,
    max_scenes: int | None = None,
    progress: bool = False,
) -> Shown:
    """Read and check everything a viewer shows, thinned to `max_scenes` (the first ones).

    The split defaults to the predictions' (else test). With a run and no predictions file, the
    run's best checkpoint is evaluated on the split (with `progress`, a bar on stderr).
    """
    if split is not None and split not in SPLITS:
        raise ViewerError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    if max_scenes is not None and max_scenes < 1:
        raise ViewerError(f"max_scenes must be at least 1, got {max_scenes}")
    if not Path(data_path).is_file():
        raise ViewerError(f"dataset {data_path} does not exist")
    predictions = _load(predictions_path) if predictions_path is not None else None
    run = read_run(run_dir) if run_dir is not None else None
    split = split or (predictions.split if predictions is not None else "test")
    try:
        meta = read_meta(data_path)
        data = read_split(data_path, split)
    except FormatError as err:
        raise ViewerError(str(err)) from None
    if data.n == 0:
        raise ViewerError(f"{data_path}: the {split} split holds no scenes")
    if run is not None:
        _check_run(run, meta, data_path, predictions, predictions_path)
        if predictions is None:
            predictions = _evaluate(run, data_path, split, progress)
    rows = np.arange(data.n)
    if predictions is not None:
        label = str(predictions_path) if predictions_path is not None else f"run {run_dir}"
        _check_predictions(predictions, label, meta, data, split, data_path)
        rows = predictions.scene
    available = len(rows)
    keep = np.arange(min(available, max_scenes or available))
    rows = rows[keep]
    return Shown(
        data_path=str(data_path),
        meta=meta,
        split=split,
        data=data.subset(rows),
        rows=rows,
        available=available,
        predictions=predictions.select(keep) if predictions is not None else None,
        predictions_path=None if predictions_path is None else str(predictions_path),
        run=run,
    )


def _load(path: str | os.PathLike) -> Predictions:
    if not Path(path).is_file():
        raise ViewerError(f"predictions file {path} does not exist")
    try:
        return load_predictions(path)
    except PredictionsError as err:
        raise ViewerError(str(err)) from None


def _check_run(
    run: RunInfo,
    meta: DatasetMeta,
    data_path: str | os.PathLike,
    predictions: Predictions | None,
    predictions_path: str | os.PathLike | None,
) -> None:
    if run.trained_on != meta.scenario:
        raise ViewerError(
            f"run {run.path} was trained on {run.trained_on} data, but {data_path} holds "
            f"{meta.scenario}"
        )
    if predictions is not None and predictions.predictor != run.variant:
        raise ViewerError(
            f"{predictions_path} holds predictions of {predictions.predictor}, but run "
            f"{run.path} is a run of {run.variant}"
        )


def _evaluate(run: RunInfo, data_path: str | os.PathLike, split: str, progress: bool):
    from predictor.checkpoints import CheckpointError
    from predictor.evaluation import evaluate_run
    from predictor.forecasting import EvaluationError

    try:
        return evaluate_run(run.path, data_path, split, "best", progress=progress).predictions
    except (CheckpointError, EvaluationError, FormatError) as err:
        raise ViewerError(str(err)) from None


def _check_predictions(
    pred: Predictions,
    label: str,
    meta: DatasetMeta,
    data: TrajectorySet,
    split: str,
    data_path: str | os.PathLike,
) -> None:
    """ViewerError unless `pred` holds predictions of scenes of this very split."""
    where = f"{label} does not belong to {data_path}"
    if pred.scenario != meta.scenario:
        raise ViewerError(f"{where}: scenario {pred.scenario}, the dataset's is {meta.scenario}")
    if pred.split != split:
        raise ViewerError(f"{where}: it holds the {pred.split} split, not {split}")
    ours = (pred.true_xy.shape[1], pred.true_xy.shape[2], pred.num_observed)
    theirs = (data.num_steps, data.num_agents, meta.num_observed)
    if ours != theirs or not math.isclose(pred.dt, meta.dt, rel_tol=1e-9):
        raise ViewerError(
            f"{where}: steps, agents, observed steps and dt are {(*ours, pred.dt)}, the "
            f"dataset's {(*theirs, meta.dt)}"
        )
    if pred.n and not (pred.scene.min() >= 0 and pred.scene.max() < data.n):
        raise ViewerError(f"{where}: scene rows beyond the {data.n} scenes of its {split} split")
    xy, valid = data.states[pred.scene, ..., :2], data.valid[pred.scene]
    same = (valid == pred.valid).all(axis=(1, 2)) & (
        np.where(valid[..., None], xy == pred.true_xy, True).all(axis=(1, 2, 3))
    )
    if not same.all():
        first = int(np.flatnonzero(~same)[0])
        raise ViewerError(
            f"{where}: its scene {first} (split row {int(pred.scene[first])}) has other "
            "positions than the dataset's"
        )
