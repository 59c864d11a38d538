"""The toolkit from Python in three calls: `generate` a dataset, `train` a predictor on it,
`evaluate` a run or a baseline. Each is what the matching tool does (tools/generate.py,
tools/train.py, tools/evaluate.py), with the same defaults:

    from pipeline import api

    data = api.generate("halting_car_v3", "data/hc.h5")
    run = api.train(data, "runs/hc")  # the default preset, agent
    print(api.evaluate(data, run=run).headline())
    print(api.evaluate(data, baseline="const_vel").headline())

The lower layers stay available for more control: `pipeline.generation`, `predictor.settings`,
`predictor.training`, `predictor.evaluation`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pipeline.generation import (
    DEFAULT_SCENARIO,
    GenerateConfig,
    default_output,
    generate_dataset,
)
from predictor.evaluation import Evaluation, evaluate_baseline, evaluate_run
from predictor.presets import DEFAULT_PRESET
from predictor.run_state import resume_configs
from predictor.settings import parse_assignments, resolve
from predictor.training import train as train_run


def generate(
    scenario: str = DEFAULT_SCENARIO,
    out: str | os.PathLike | None = None,
    *,
    minor_ratio: float | None = None,
    num_major: int = 50,
    num_test: int = 50,
    seed: int = 0,
    workers: int = 1,
    overwrite: bool = False,
    progress: bool = True,
) -> Path:
    """Generate a major/minor trajectory dataset of `scenario` (a version name such as
    "halting_car_v3"; a family name means its latest version) and return its path.

    `out` defaults to data/<scenario>_<case>-major_<counts>_seed<seed>.h5 (as tools/generate.py);
    the minor count is round(minor_ratio x num_major), minor_ratio defaulting to 0.3.

    Raises ValueError for an unknown scenario or a value out of range (one line naming it),
    FileExistsError if `out` exists and not `overwrite`, another OSError if it cannot be
    written, `pipeline.generation.UnsafeExpertError` if the expert policy keeps crashing, and
    KeyboardInterrupt on Ctrl-C; nothing is written unless the whole file is.
    """
    config = GenerateConfig.for_scenario(
        scenario, minor_ratio=minor_ratio, num_major=num_major, num_test=num_test, seed=seed
    )
    if out is None:
        out = default_output(config)
    result = generate_dataset(config, out, workers=workers, overwrite=overwrite, progress=progress)
    return result.path


def train(
    data: str | os.PathLike,
    out: str | os.PathLike,
    *,
    preset: str | None = None,
    variant: str | None = None,
    settings: Mapping[str, Any] | None = None,
    epochs: int | None = None,
    seed: int | None = None,
    device: str | None = None,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
) -> Path:
    """Train `variant` (default "ours") under `preset` (default `DEFAULT_PRESET`, agent),
    changed by `settings` ({"model.neighbours": "knn", "train.lr": 1e-3, ...}: the keys of
    `tools/train.py --list-settings`), on the dataset `data`, into the run directory `out`;
    return `out`. `epochs` defaults to the preset's, `seed` to 0, `device` to "cpu" ("cuda" or
    "cuda:N" where torch finds a CUDA device).

    With `resume`, the interrupted run in `out` continues with its stored configuration;
    arguments given must equal the stored ones, except `epochs` (and the settings
    train.threads and train.eval_every), which may change.

    Raises ValueError for an unknown preset, variant or setting, or a value out of range (one
    line naming the setting and what it allows), `predictor.run_state.ResumeMismatch` for a
    resume that asks for another configuration, `predictor.run_files.RunError` for an unusable
    run directory (e.g. not empty and not `overwrite`),
    `trajectory_data.format.FormatError` for a bad data file, FloatingPointError if training
    diverges, and
    `predictor.training.TrainingInterrupted` on Ctrl-C.
    """
    assignments = [f"{key}={_typed(value)}" for key, value in (settings or {}).items()]
    given = {
        name: value
        for name, value in (("epochs", epochs), ("seed", seed), ("device", device))
        if value is not None
    }
    if resume:
        values = parse_assignments(assignments)
        changes = {**values["model"], **values["train"], **given}
        if variant is not None:
            changes["variant"] = variant
        model_cfg, train_cfg = resume_configs(out, changes, preset=preset)
    else:
        preset = preset or DEFAULT_PRESET
        model_cfg, train_cfg = resolve(
            variant or "ours", preset, assignments, **{"seed": 0, **given}
        )
    train_run(
        data,
        model_cfg,
        train_cfg,
        out,
        resume=resume,
        overwrite=overwrite,
        progress=progress,
        preset=preset,
    )
    return Path(out)


def evaluate(
    data: str | os.PathLike,
    *,
    run: str | os.PathLike | None = None,
    baseline: str | None = None,
    split: str = "test",
    progress: bool = False,
) -> Evaluation:
    """Score a trained `run` (its best.pt) or a `baseline` ("const_vel", "ridge", ...) on a
    split of `data`; give one of the two. The result's `scores` hold ADE/FDE of the main and of
    all agents per case and the attention accuracy; `headline()` is one line of them.

    Raises ValueError unless exactly one of `run` and `baseline` is given,
    `predictor.checkpoints.CheckpointError` for a missing or unreadable run,
    `predictor.forecasting.EvaluationError` for an unknown baseline, an empty split or data of
    another scenario than the run's, `trajectory_data.format.FormatError` for a bad data file.
    """
    if (run is None) == (baseline is None):
        raise ValueError("give one of run and baseline")
    if run is not None:
        return evaluate_run(run, data, split, progress=progress)
    return evaluate_baseline(baseline, data, split, progress=progress)


def _typed(value: Any) -> str:
    """A setting's value as --set takes it."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    return str(value)
