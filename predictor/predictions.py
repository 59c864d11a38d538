"""The predictions of one predictor on a dataset split: one record, one versioned .npz file.

`Predictions` is what the evaluation produces (`predictor.evaluation`), what the plots draw
(`predictor.plots`) and what the predictions file holds; `save` and `load_predictions` write
and read it with numpy alone (no torch), and loading checks the format tag, the version and
every shape. Layout of the file: see docs/dataset_format.md, "Predictions file".
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from trajectory_data.format import DatasetMeta, TrajectorySet, legacy_focal

PREDICTIONS_FORMAT = "smooth-attention-predictions"
# 4 adds `samples` (K = 0 when none); 3 adds `focal`; 2 (read: the first two slots focal) had none
PREDICTIONS_VERSION = 4
READABLE_VERSIONS = (2, 3, 4)  # 1: the untagged layout written before the format tag existed

_SCALARS = ("predictor", "scenario", "split", "num_observed", "dt")
_NAMES = ("case_names", "role_names")
_ARRAYS = {  # field -> (shape in terms of n, T, P = T_pred, N; dtype in the file)
    "scene": (("n",), np.int64),
    "pred_mean": (("n", "P", "N", 2), np.float32),
    "true_xy": (("n", "T", "N", 2), np.float32),
    "valid": (("n", "T", "N"), np.bool_),
    "focal": (("n", "N"), np.bool_),
    "case": (("n",), np.int64),
    "roles": (("n", "N"), np.int64),
    "attention": (("n", "T-1", "N", "N"), np.float32),
    "attention_label": (("n", "T", "N"), np.int16),
    "interaction": (("n", "T"), np.bool_),
    "samples": (("n", "K", "P", "N", 2), np.float32),
}


class PredictionsError(ValueError):
    """Predictions are inconsistent, or a file is not a readable predictions file (one line)."""


@dataclass(frozen=True)
class Predictions:
    """Predictions of n scenes (T steps, N agents, P = T - num_observed predicted steps).

    Arrays are converted to the file's dtypes on construction; shapes are checked then, so a
    `Predictions` that exists is consistent.
    """

    predictor: str  # who predicted: a variant name ("ours") or a baseline ("const_vel")
    scenario: str  # DatasetMeta.scenario of the evaluated file
    split: str  # "train", "val" or "test"
    num_observed: int  # observed steps; predictions cover steps num_observed .. T-1
    dt: float  # [s] between steps
    case_names: tuple[str, ...]  # `case` indexes into it
    role_names: tuple[str, ...]  # `roles` indexes into it
    scene: np.ndarray  # (n,) row of each scene in the split
    pred_mean: np.ndarray  # (n, P, N, 2) predicted mean positions [m]
    true_xy: np.ndarray  # (n, T, N, 2) true positions [m]
    valid: np.ndarray  # (n, T, N) agent present
    focal: np.ndarray  # (n, N) agents scored as the "main_agents" group
    case: np.ndarray  # (n,) index into case_names
    roles: np.ndarray  # (n, N) index into role_names
    attention: np.ndarray  # (n, T-1, N, N) theta[t, i, j], computed at t; NaN if none
    attention_label: np.ndarray  # (n, T, N) ground-truth attended agent, -1 none
    interaction: np.ndarray  # (n, T) inside the interaction period
    # (n, K, P, N, 2) K sampled futures [m] (predictor.forecasting); K = 0 (None given): none
    samples: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.samples is None:
            n, steps, agents = np.shape(self.true_xy)[:3]
            empty = np.zeros((n, 0, steps - int(self.num_observed), agents, 2), np.float32)
            object.__setattr__(self, "samples", empty)
        for name in _NAMES:
            object.__setattr__(self, name, tuple(str(s) for s in getattr(self, name)))
        for name, (_, dtype) in _ARRAYS.items():
            # no copy of an array already of its dtype (a split's attention can be ~1 GB)
            value = np.asarray(getattr(self, name)).astype(dtype, copy=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "num_observed", int(self.num_observed))
        object.__setattr__(self, "dt", float(self.dt))
        self._check()

    @property
    def n(self) -> int:
        """Number of scenes."""
        return int(self.true_xy.shape[0])

    @property
    def num_samples(self) -> int:
        """K, the sampled futures per scene (0: none)."""
        return int(self.samples.shape[1])

    @classmethod
    def from_split(
        cls,
        data: TrajectorySet,
        meta: DatasetMeta,
        split: str,
        predictor: str,
        pred_mean: np.ndarray,
        attention: np.ndarray,
        samples: np.ndarray | None = None,
    ) -> Predictions:
        """Predictions of every scene of a split (`data`, in file order) of a dataset file;
        `samples` (n, K, P, N, 2), if any."""
        return cls(
            predictor=predictor,
            scenario=meta.scenario,
            split=split,
            num_observed=meta.num_observed,
            dt=meta.dt,
            case_names=meta.case_names,
            role_names=meta.role_names,
            scene=np.arange(data.n),
            pred_mean=pred_mean,
            true_xy=data.states[..., :2],
            valid=data.valid,
            focal=data.focal,
            case=data.case,
            roles=data.roles,
            attention=attention,
            attention_label=data.attention,
            interaction=data.interaction,
            samples=samples,
        )

    def select(self, rows: Sequence[int] | np.ndarray) -> Predictions:
        """The scenes at positions `rows` (in that order); `scene` keeps their split rows."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        if rows.size and not (rows.min() >= 0 and rows.max() < self.n):
            raise PredictionsError(f"scene rows must be in [0, {self.n - 1}], got {rows.tolist()}")
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values.update({name: getattr(self, name)[rows] for name in _ARRAYS})
        return Predictions(**values)

    def save(self, path: str | os.PathLike) -> None:
        """Write the predictions file to exactly `path` (not atomic: callers write a temporary
        file and rename it, e.g. with pipeline.cli.atomic_output)."""
        arrays = {name: getattr(self, name) for name in _ARRAYS}
        with open(path, "wb") as stream:  # a file object: numpy adds no ".npz" suffix
            np.savez(
                stream,
                format=np.str_(PREDICTIONS_FORMAT),
                version=np.int64(PREDICTIONS_VERSION),
                predictor=np.str_(self.predictor),
                scenario=np.str_(self.scenario),
                split=np.str_(self.split),
                num_observed=np.int64(self.num_observed),
                dt=np.float64(self.dt),
                case_names=np.array(self.case_names, dtype=str),
                role_names=np.array(self.role_names, dtype=str),
                **arrays,
            )

    def _check(self) -> None:
        """Raise PredictionsError unless every array has its documented shape."""
        true_xy, pred_mean = self.true_xy, self.pred_mean
        if true_xy.ndim != 4 or pred_mean.ndim != 4:
            raise PredictionsError("true_xy and pred_mean must be 4-D (n, steps, agents, 2)")
        n, steps, agents = true_xy.shape[:3]
        sizes = {"n": n, "T": steps, "T-1": steps - 1, "P": steps - self.num_observed, "N": agents}
        sizes["K"] = self.samples.shape[1] if self.samples.ndim == 5 else -1
        if not 1 <= self.num_observed < steps:
            raise PredictionsError(f"num_observed={self.num_observed} does not fit T={steps}")
        for name, (shape, _) in _ARRAYS.items():
            expected = tuple(sizes.get(s, s) for s in shape)
            if getattr(self, name).shape != expected:
                raise PredictionsError(
                    f"{name} has shape {getattr(self, name).shape}, expected {expected}"
                )
        for name, names in (("case", self.case_names), ("roles", self.role_names)):
            values = getattr(self, name)
            if values.size and not (values.min() >= 0 and values.max() < len(names)):
                raise PredictionsError(f"{name} must index into {len(names)} {name} names")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise PredictionsError(f"dt must be a positive number of seconds, got {self.dt}")


def load_predictions(path: str | os.PathLike) -> Predictions:
    """Read and check a predictions file; raises PredictionsError with one line on any problem."""
    path = Path(path)
    if not path.is_file():
        raise PredictionsError(f"{path}: no such file")
    if not zipfile.is_zipfile(path):
        raise PredictionsError(f"{path}: not an .npz file")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {key: npz[key] for key in npz.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise PredictionsError(f"{path}: not a readable .npz file ({err})") from None
    version = _check_version(path, arrays)
    if version == 2 and "true_xy" in arrays and np.ndim(arrays["true_xy"]) == 4:
        arrays["focal"] = legacy_focal(arrays["true_xy"].shape[0], arrays["true_xy"].shape[2])
    if version < 4:
        arrays["samples"] = None  # no samples before version 4: K = 0
    missing = sorted((set(_SCALARS) | set(_NAMES) | set(_ARRAYS)) - set(arrays))
    if missing:
        raise PredictionsError(f"{path}: missing arrays {missing}")
    try:
        return Predictions(
            **{key: arrays[key] for key in (*_NAMES, *_ARRAYS)},
            predictor=str(arrays["predictor"]),
            scenario=str(arrays["scenario"]),
            split=str(arrays["split"]),
            num_observed=int(arrays["num_observed"]),
            dt=float(arrays["dt"]),
        )
    except (PredictionsError, TypeError, ValueError) as err:
        raise PredictionsError(f"{path}: {err}") from None


def _check_version(path: Path, arrays: dict[str, np.ndarray]) -> int:
    if "format" not in arrays:
        raise PredictionsError(
            f"{path}: not a {PREDICTIONS_FORMAT} file version {PREDICTIONS_VERSION} (no format "
            "tag; files from before version 2 must be written again with tools/evaluate.py "
            "--save-predictions)"
        )
    if str(arrays["format"]) != PREDICTIONS_FORMAT:
        raise PredictionsError(f"{path}: not a {PREDICTIONS_FORMAT} file")
    version = arrays["version"].tolist() if "version" in arrays else None
    if version not in READABLE_VERSIONS:
        raise PredictionsError(
            f"{path}: predictions file version {version} is not supported (this reader reads "
            f"versions {', '.join(str(v) for v in READABLE_VERSIONS)})"
        )
    return int(version)
