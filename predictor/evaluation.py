"""Evaluation: predict a dataset split with a trained run or a baseline and score it.

`evaluate_run` and `evaluate_baseline` are the one evaluation path of the package (used by
tools/evaluate.py, the reproduction and the tests); each returns an `Evaluation`: the scores, the
JSON record tools/evaluate.py writes (`to_dict`) and the `Predictions` for the plots. Models
predict by feeding back their predicted means after the observed steps.

Checkpoints and how they are read: `predictor.checkpoints`; the forecasts of a split and their
scores: `predictor.forecasting`.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from predictor.baselines import (
    BASELINES,
)
from predictor.checkpoints import (
    CHECKPOINTS,
    check_data_matches,
    load_model,
)
from predictor.diagnostics import counterfactual_shift, error_curves, one_step_errors
from predictor.faithfulness import faithfulness, with_ratio
from predictor.forecasting import (
    EvaluationError,
    SampleSettings,
    fit_baseline,
    forecast_model,
    score,
)
from predictor.metrics import (
    headline,
)
from predictor.predictions import Predictions
from predictor.wording import Wording
from trajectory_data.format import DatasetMeta
from trajectory_data.torch_dataset import TrajectoryDataset


def json_safe(value: Any) -> Any:
    """`value` with every NaN or infinite float replaced by None, so that json.dumps writes
    strict JSON (null) rather than the bare NaN / Infinity most JSON readers refuse; a score
    is non-finite when a model's predictions are (a diverged checkpoint)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    return value


# --------------------------------------------------------------------------- progress
class _Stages:
    """A progress bar on stderr over an evaluation's passes through the split's scenes: one
    per prediction of them all (the forecast, the diagnostics' passes), with the stage named.
    The number of passes is an upper bound (the counterfactual skips ranks nothing counts in):
    the bar is completed on closing."""

    def __init__(self, predictor: str, scenes: int, passes: int, enabled: bool) -> None:
        self.predictor = predictor
        self.bar = tqdm(
            total=scenes * passes,
            desc=f"evaluate {predictor}",
            unit="scene",
            disable=not enabled,
            file=sys.stderr,
        )

    def stage(self, name: str) -> None:
        self.bar.set_description_str(f"evaluate {self.predictor}: {name}")

    def advance(self, scenes: int) -> None:
        self.bar.update(scenes)

    def close(self) -> None:
        self.bar.total = self.bar.n
        self.bar.set_description_str(f"evaluate {self.predictor}")
        self.bar.close()


def _counterfactual_passes(focal: np.ndarray) -> int:
    """At most how many predictions of the split `counterfactual_shift` makes."""
    return 1 + 2 * int(focal.sum(axis=1).max(initial=0))


# --------------------------------------------------------------------------- evaluating
@dataclass(frozen=True)
class RunSource:
    """The checkpoint an evaluation of a trained run used."""

    run: str  # the run directory, as given
    checkpoint: str  # file name in it, e.g. "best.pt"
    epoch: int  # training epochs behind the checkpoint
    train_data: str  # absolute path of the file the run was trained on


@dataclass(frozen=True)
class Evaluation:
    """One predictor scored on one split of one dataset file."""

    predictor: str  # variant of the run ("ours", ...) or baseline name ("const_vel")
    data: str  # absolute path of the evaluated file
    meta: DatasetMeta  # of the evaluated file
    scores: dict  # main_agents, all_agents, attention_accuracy (see `score`)
    predictions: Predictions  # every scene of the split, in file order
    source: RunSource | None = None  # None for a baseline
    baseline: dict[str, Any] | None = None  # a fitted baseline's fit: split, scenes, alpha...
    diagnostics: dict[str, Any] | None = None  # error curves, one-step error, counterfactual
    # (trained, evaluated) scenario names of a run evaluated on another scenario's data
    scenario_mismatch: tuple[str, str] | None = None
    sampling: dict[str, Any] | None = None  # K, seed, miss threshold and how it samples

    @property
    def words(self) -> Wording:
        """The words of this data's agents and scenes (`Wording.of`)."""
        return Wording.of(self.meta)

    @property
    def split(self) -> str:
        return self.predictions.split

    @property
    def scenes(self) -> int:
        return self.predictions.n

    def to_dict(self) -> dict[str, Any]:
        """The JSON record of tools/evaluate.py (eval.json): description, then the scores."""
        info: dict[str, Any] = {
            "data": self.data,
            "split": self.split,
            "scenes": self.scenes,
            "num_observed": self.meta.num_observed,
            "num_predicted": self.meta.num_predicted,
            "dt": self.meta.dt,
            "headline": "main_agents",
            "predictor": self.predictor,
        }
        if self.source is not None:
            source = self.source
            info.update(
                run=source.run,
                checkpoint=source.checkpoint,
                epoch=source.epoch,
                train_data=source.train_data,
            )
        if self.scenario_mismatch is not None:
            trained, evaluated = self.scenario_mismatch
            info["scenario_mismatch"] = {"trained_on": trained, "evaluated_on": evaluated}
        if self.baseline is not None:
            info["baseline_fit"] = self.baseline
        if self.sampling is not None:
            info["sampling"] = self.sampling
        extra = {} if self.diagnostics is None else {"diagnostics": self.diagnostics}
        return json_safe({**info, **self.scores, **extra})

    def headline(self) -> str:
        """One line with the headline agents' ADE/FDE (and best-of-K scores, with samples) and
        the attention accuracy."""
        return headline(self.scores, self.words.agents)

    def mismatch_note(self) -> str | None:
        """One line naming the scenario the run was trained on and the one evaluated, when they
        differ (None otherwise)."""
        if self.scenario_mismatch is None:
            return None
        trained, evaluated = self.scenario_mismatch
        return (
            f"scenario mismatch: the run was trained on {trained} data and is evaluated on "
            f"{evaluated} data (same dt, horizons and agent count)"
        )

    def save_predictions(
        self, path: str | os.PathLike, rows: Sequence[int] | np.ndarray | None = None
    ) -> None:
        """Write the predictions file (all scenes, or the split rows `rows`) to exactly `path`."""
        predictions = self.predictions if rows is None else self.predictions.select(rows)
        predictions.save(path)


def evaluate_run(
    run_dir: str | os.PathLike,
    data_path: str | os.PathLike,
    split: str = "test",
    checkpoint: str = "best",
    batch_size: int = 32,
    progress: bool = False,
    allow_scenario_mismatch: bool = False,
    sampling: SampleSettings | None = None,
) -> Evaluation:
    """Score checkpoint `checkpoint` ("best" or "last") of a run on a split of `data_path`
    (with `progress`, a bar on stderr through the predictions and diagnostics).

    The file must be of the scenario, dt and horizons of the run's training data; with
    `allow_scenario_mismatch`, of another scenario too when dt, the horizons and the agent count
    match (a transfer study, e.g. a model of one scenario version on another's data): the
    `Evaluation` then names both scenarios (`scenario_mismatch`, also in `to_dict`).

    Raises CheckpointError for a missing or unreadable checkpoint, FormatError for a bad data
    file, ScenarioMismatchError (an EvaluationError) for a file of another scenario that was not
    allowed, EvaluationError for an empty split or a file whose dt, horizons or (with another
    scenario) agent count differ from the run's training data.
    """
    if checkpoint not in CHECKPOINTS:
        raise EvaluationError(f"checkpoint must be one of {CHECKPOINTS}, got {checkpoint!r}")
    if batch_size < 1:
        raise EvaluationError(f"batch_size must be >= 1, got {batch_size}")
    path = Path(run_dir) / f"{checkpoint}.pt"
    model, stored = load_model(path)
    dataset = _load_split(data_path, split)
    mismatch = check_data_matches(
        stored,
        dataset.meta,
        path,
        data_path,
        allow_scenario_mismatch,
        dataset.all().num_agents,
    )
    if model.config.attention_mode == "oracle" and not dataset.meta.has("attention"):
        raise EvaluationError(
            f"{path} uses the oracle attention (variant correct), which reads attention labels; "
            f"{data_path} records none"
        )
    trained_roles = tuple(stored["data"].get("role_names", ()))
    if model.config.num_roles > 0 and trained_roles != tuple(dataset.meta.role_names):
        raise EvaluationError(
            f"{path} reads agent roles {', '.join(trained_roles)}, but {data_path} names "
            f"{', '.join(dataset.meta.role_names)}"
        )
    variant = str(stored["train_config"]["variant"])
    sampling = sampling or SampleSettings()
    passes = 2 + _counterfactual_passes(dataset.data.focal) + _faithfulness_passes(dataset)
    stages = _Stages(variant, len(dataset), passes, progress)
    try:
        stages.stage("predictions" + (f" and {sampling.k} samples" if sampling.k else ""))
        batch, num_observed = dataset.all(), dataset.meta.num_observed
        forecast = forecast_model(
            model,
            batch,
            num_observed,
            sampling.k,
            sampling.seed,
            batch_size,
            stages.advance,
            method=sampling.method,
        )
        pred_mean, attention = forecast.pred_mean, forecast.attention

        def predict(states: np.ndarray, valid: np.ndarray) -> np.ndarray:
            moved = replace(batch, states=torch.from_numpy(states), valid=torch.from_numpy(valid))
            return forecast_model(
                model,
                moved,
                num_observed,
                0,
                0,
                batch_size,
                stages.advance,
                nll=False,
                attention=False,
            ).pred_mean

        stages.stage("one-step error")
        diagnostics = {"one_step": one_step_errors(model, batch, num_observed, batch_size)}
        stages.advance(len(dataset))
        stages.stage("counterfactual")
        diagnostics.update(_common_diagnostics(dataset, pred_mean, predict))
        faithful = _faithfulness(dataset, attention, pred_mean, predict, stages)
    finally:
        stages.close()
    source = RunSource(
        run=os.fspath(run_dir),
        checkpoint=path.name,
        epoch=int(stored["epoch"]),
        train_data=str(stored["data"]["path"]),
    )
    method = {
        "marginal": "one draw per future through its steps' Gaussians",
        "rollout": "sampled rollout (the paper's)",
    }[sampling.method]
    method = f"a mode by its weight, then {method}" if model.modes is not None else method
    evaluation = _evaluation(
        dataset,
        variant,
        pred_mean,
        attention,
        source,
        diagnostics=diagnostics,
        distribution=(forecast.samples, forecast.nll),
        sampling=_sampling_record(sampling, f"{method}; NLL closed form"),
        faithful=faithful,
    )
    return replace(evaluation, scenario_mismatch=mismatch)


def evaluate_baseline(
    name: str,
    data_path: str | os.PathLike,
    split: str = "test",
    fit_split: str = "train",
    progress: bool = False,
    sampling: SampleSettings | None = None,
) -> Evaluation:
    """Score the baseline `name` (one of predictor.baselines.BASELINES) on a split; a ridge
    baseline is first fitted on `fit_split` of the same file (with `progress`, a bar on stderr
    through the fit, the predictions and the diagnostics).

    Raises EvaluationError for an unknown name, an empty split or a ridge baseline that cannot
    be fitted, FormatError for a bad file.
    """
    if name not in BASELINES:
        raise EvaluationError(f"unknown baseline {name!r}; choose from {', '.join(BASELINES)}")
    dataset = _load_split(data_path, split)
    data = dataset.data
    sampling = sampling or SampleSettings()
    passes = 3 + _counterfactual_passes(data.focal) + _faithfulness_passes(dataset)
    stages = _Stages(name, data.n, passes, progress)
    shape = (data.n, data.num_steps - 1, data.num_agents, data.num_agents)
    attention = np.full(shape, np.nan, dtype=np.float32)
    try:
        fit = None
        if name != "const_vel":
            stages.stage(f"fitting on the {fit_split} split")
            fit = dataset.data if fit_split == split else _load_split(data_path, fit_split).data
        fitted = fit_baseline(name, dataset.meta, fit)
        predict_data, details = fitted.predict, fitted.details
        stages.advance(data.n)
        stages.stage("predictions")
        pred_mean = predict_data(data)
        stages.advance(data.n)
        distribution = (None, None)
        if sampling.k:
            stages.stage(f"{sampling.k} samples")
            distribution = fitted.distribution(data, sampling.k, sampling.seed)
        stages.advance(data.n)

        def predict(states: np.ndarray, valid: np.ndarray) -> np.ndarray:
            moved = predict_data(replace(data, states=states, valid=valid))
            stages.advance(data.n)
            return moved

        stages.stage("counterfactual")
        diagnostics = _common_diagnostics(dataset, pred_mean, predict)
        faithful = _faithfulness(dataset, attention, pred_mean, predict, stages)
    finally:
        stages.close()
    if details:
        details = {"fit_split": fit_split, **details}
    return _evaluation(
        dataset,
        name,
        pred_mean,
        attention,
        None,
        details,
        diagnostics,
        distribution,
        _sampling_record(sampling, fitted.sampler),
        faithful,
    )


def _load_split(data_path: str | os.PathLike, split: str) -> TrajectoryDataset:
    dataset = TrajectoryDataset(data_path, split)
    if len(dataset) == 0:
        raise EvaluationError(f"{data_path}: the {split} split is empty")
    return dataset


def _evaluation(
    dataset: TrajectoryDataset,
    predictor: str,
    pred_mean: np.ndarray,
    attention: np.ndarray,
    source: RunSource | None,
    baseline: dict[str, Any] | None = None,
    diagnostics: dict[str, Any] | None = None,
    distribution: tuple[np.ndarray | None, np.ndarray | None] = (None, None),
    sampling: dict[str, Any] | None = None,
    faithful: dict[str, Any] | None = None,
) -> Evaluation:
    samples, nll = distribution
    predictions = Predictions.from_split(
        dataset.data, dataset.meta, dataset.split, predictor, pred_mean, attention, samples
    )
    threshold = (
        SampleSettings().miss_threshold_m if sampling is None else sampling["miss_threshold_m"]
    )
    scores = score(predictions, nll, threshold)
    if faithful is not None:
        scores["faithfulness"] = with_ratio(faithful, scores["main_agents"]["overall"]["ade"])
    return Evaluation(
        predictor=predictor,
        data=str(Path(dataset.path).resolve()),
        meta=dataset.meta,
        scores=scores,
        predictions=predictions,
        source=source,
        baseline=baseline or None,
        diagnostics=diagnostics,
        sampling=sampling,
    )


def _sampling_record(sampling: SampleSettings, method: str) -> dict[str, Any] | None:
    """eval.json's description of the samples behind min_ade, min_fde, miss_rate (None: K=0)."""
    if not sampling.k:
        return None
    return {
        "k": sampling.k,
        "seed": sampling.seed,
        "miss_threshold_m": sampling.miss_threshold_m,
        "method": method,
    }


def _faithfulness_passes(dataset: TrajectoryDataset) -> int:
    """How many predictions of the split `_faithfulness` makes (the removal test's one)."""
    return int(dataset.data.influence is not None)


def _faithfulness(
    dataset: TrajectoryDataset, attention: np.ndarray, pred_mean: np.ndarray, predict, stages
) -> dict:
    """eval.json's `faithfulness` block (predictor.faithfulness, default settings): the
    attention's total variation, and with the file's influence its AUROC and the removal test."""
    data = dataset.data
    if data.influence is not None:
        stages.stage("faithfulness")
    return faithfulness(
        attention,
        data.states,
        data.valid,
        data.focal,
        data.influence,
        dataset.meta.num_observed,
        predict,
        pred_mean,
    )


def _common_diagnostics(dataset: TrajectoryDataset, pred_mean: np.ndarray, predict) -> dict:
    """Error curves and the counterfactual check of any predictor (see predictor.diagnostics)."""
    data, num_observed = dataset.data, dataset.meta.num_observed
    true = data.states[:, num_observed:, :, :2]
    return {
        "error_curve": error_curves(pred_mean, true, data.valid, num_observed, data.focal),
        "counterfactual": counterfactual_shift(
            predict, data.states, data.valid, data.attention, num_observed, data.focal
        ),
    }
