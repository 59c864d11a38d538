"""Forecasts of a dataset split: a trained model's (fed-back means and attention) or a
baseline's, shaped alike, and their scores (`score`: ADE/FDE per group and case, attention
accuracy). `predictor.evaluation` runs them as one evaluation of a run or a baseline.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from predictor.baseline_samples import RidgeDistribution, constant_velocity_samples
from predictor.baselines import BASELINES, RidgeBaseline, RidgeConfig, constant_velocity
from predictor.metrics import attention_accuracy, displacement_metrics, prediction_mask
from predictor.model import SmoothAttentionPredictor
from predictor.outputs import TrajectoryMixture, expand_attention
from predictor.predictions import Predictions
from predictor.probabilistic import gaussian_nll, kde_nll, sample_metrics
from trajectory_data.format import DatasetMeta, TrajectorySet
from trajectory_data.torch_dataset import Batch


class EvaluationError(ValueError):
    """An evaluation cannot be done as asked (empty split, data of another kind); one line."""


SAMPLE_METHODS = ("marginal", "rollout")


@dataclass(frozen=True)
class SampleSettings:
    """How a predictor's futures are sampled and scored beside its single prediction."""

    # futures per agent: the best of 20 is the ETH/UCY convention since Social-GAN (Gupta et
    # al., CVPR 2018); 0: no samples (nor minADE_K, minFDE_K, miss rate)
    k: int = 20
    miss_threshold_m: float = 2.0  # [m] a best final error above it is a miss (Argoverse's 2 m)
    seed: int = 0  # of the draws: the same seed and arguments give the same samples
    # how a model with one Gaussian per step samples: "marginal", a standard normal draw per
    # future shared by its steps, mean_t + L_t eps (each step's samples follow the predicted
    # Gaussian, and a future is as smooth as the mean); "rollout", the paper's sampled rollout,
    # feeding back a draw at every step (a random walk of the per-step spreads). Models with
    # trajectory modes draw a mode, then as "marginal".
    method: str = "marginal"

    def __post_init__(self) -> None:
        if self.method not in SAMPLE_METHODS:
            raise EvaluationError(
                f"unknown sampling method {self.method!r}; choose from {', '.join(SAMPLE_METHODS)}"
            )
        if self.k < 0:
            raise EvaluationError(f"the number of samples must be >= 0, got {self.k}")
        if not (math.isfinite(self.miss_threshold_m) and self.miss_threshold_m > 0):
            raise EvaluationError(
                f"the miss threshold must be a positive distance [m], got {self.miss_threshold_m}"
            )


@dataclass(frozen=True)
class Forecast:
    """A predictor's forecasts of a split's scenes, in file order (see `forecast_model`)."""

    pred_mean: np.ndarray  # (n, T_pred, N, 2) [m] the single prediction
    attention: np.ndarray | None  # (n, T-1, N, N); NaN for a baseline; None if not asked for
    nll: np.ndarray | None  # (n, T_pred, N) -log density of the truth per step [nats], or None
    samples: np.ndarray | None  # (n, K, T_pred, N, 2) [m] sampled futures, or None (K = 0)


def predict_model(
    model: SmoothAttentionPredictor,
    batch: Batch,
    num_observed: int,
    batch_size: int = 32,
    on_batch: Callable[[int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Predict every scene of `batch` from its observed steps, feeding back the predicted means.

    Returns (pred_mean (n, T_pred, N, 2) [m] of steps T_obs .. T-1, attention (n, T-1, N, N)),
    both float32. The attention is theta^t over the teacher-forced observed part
    (t < T_obs-1) followed by the fed-back part (t = T_obs-1 .. T-2). `on_batch(scenes)` is
    called after each batch (progress).
    """
    forecast = forecast_model(model, batch, num_observed, 0, 0, batch_size, on_batch, nll=False)
    return forecast.pred_mean, forecast.attention


def forecast_model(
    model: SmoothAttentionPredictor,
    batch: Batch,
    num_observed: int,
    num_samples: int = 0,
    seed: int = 0,
    batch_size: int = 32,
    on_batch: Callable[[int], None] | None = None,
    nll: bool = True,
    method: str = "marginal",
    attention: bool = True,
) -> Forecast:
    """`predict_model`'s predictions plus, with `nll`, each predicted step's negative log
    density of the truth under the model's distribution (its Gaussian, or with trajectory modes
    their mixture; closed form) and `num_samples` sampled futures per scene: drawn from the
    modes (`TrajectoryMixture.sample`) or, with one Gaussian, by `method` (`SampleSettings`;
    "rollout": `SmoothAttentionPredictor.sample_rollouts`), seeded by `seed` and the batch.

    With `attention` False the attention is not kept (None): a split's (n, T-1, N, N) array is
    the largest of an evaluation (0.6 GB for ETH/UCY univ's 947 windows of up to 93 agents).
    Each batch is cut to the agent slots observed in it (memory and time follow the agents
    present, not the file's padded maximum), and its outputs padded back to N.
    """
    num_agents, num_steps = batch.num_agents, batch.num_steps
    num_predicted = num_steps - num_observed
    n = batch.batch_size
    means = np.zeros((n, num_predicted, num_agents, 2), np.float32)
    attentions = (
        np.zeros((n, num_steps - 1, num_agents, num_agents), np.float32) if attention else None
    )
    nlls = np.full((n, num_predicted, num_agents), np.nan, np.float32) if nll else None
    samples = np.zeros((n, num_samples, num_predicted, num_agents, 2), np.float32)
    model.eval()
    batch = batch.to(next(model.parameters()).device)  # where the model is (training: its device)
    for number, start in enumerate(range(0, n, batch_size)):
        rows = slice(start, min(start + batch_size, n))
        width = _present_width(batch.valid[rows, :num_observed])
        positions = batch.positions[rows, :, :width]
        valid = batch.valid[rows, :, :width]
        labels = batch.attention[rows, :, :width]
        roles = None if batch.roles is None else batch.roles[rows, :width]
        out = model.predict(positions, valid, num_observed, labels, roles)
        means[rows, :, :width] = out.rollout.mean.cpu().numpy()
        if attention:
            theta = torch.cat([out.attention[:, :-1], out.rollout_attention], 1)  # (b, T-1, w, w-1)
            attentions[rows, :, :width, :width] = expand_attention(theta).cpu().numpy()
        if nll:
            target = positions[:, num_observed:]
            if out.modes is not None:
                log_density = out.modes.step_log_prob(target)
            else:
                log_density = out.rollout.log_prob(target)
            nlls[rows, :, :width] = (-log_density).cpu().numpy()
        if num_samples:
            generator = torch.Generator(device=positions.device).manual_seed(seed + number)
            if out.modes is not None:
                drawn = out.modes.sample(num_samples, generator)
            elif method == "marginal":
                one = TrajectoryMixture(
                    torch.zeros_like(out.rollout.mean[:, 0, :, :1]),  # log 1: one mode
                    out.rollout.mean.unsqueeze(-2),
                    out.rollout.tril.unsqueeze(-2),
                )
                drawn = one.sample(num_samples, generator)
            else:
                with torch.random.fork_rng(devices=[]):
                    torch.manual_seed(int(torch.randint(2**62, (), generator=generator)))
                    drawn = model.sample_rollouts(
                        positions, valid, num_observed, num_samples, labels, roles
                    )
            samples[rows, :, :, :width] = drawn.permute(1, 0, 2, 3, 4).cpu().numpy()
        if on_batch is not None:
            on_batch(rows.stop - rows.start)
    return Forecast(means, attentions, nlls, samples if num_samples else None)


def _present_width(valid: torch.Tensor) -> int:
    """1 + the last agent slot present at any step of any scene of `valid` (b, T_obs, N), at
    least 1: the slots after it are predicted as absent (zeros), which they are to a model
    that reads the observed steps alone."""
    present = valid.any(dim=1).any(dim=0).nonzero()
    return int(present.max()) + 1 if len(present) else 1


def predict_baseline(
    name: str, data: TrajectorySet, meta: DatasetMeta, fit: TrajectorySet | None = None
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """(pred_mean, attention, details) of baseline `name` on `data`, shaped as `predict_model`'s
    outputs; the attention is NaN. A ridge baseline is fitted on `fit` first (required for them);
    `details` describes the fit (empty for const_vel)."""
    fitted = fit_baseline(name, meta, fit)
    shape = (data.n, data.num_steps - 1, data.num_agents, data.num_agents)
    return fitted.predict(data), np.full(shape, np.nan, dtype=np.float32), fitted.details


@dataclass(frozen=True)
class FittedBaseline:
    """A baseline ready to forecast any scenes of the kind it was fitted for."""

    predict: Callable[[TrajectorySet], np.ndarray]  # scenes -> means (n, T_pred, N, 2) [m]
    # (scenes, K, seed) -> (samples (n, K, T_pred, N, 2) [m], per-step NLL (n, T_pred, N))
    distribution: Callable[[TrajectorySet, int, int], tuple[np.ndarray, np.ndarray]]
    details: dict[str, Any]  # the fit (empty for const_vel)
    sampler: str  # how it samples (eval.json)


def fit_baseline(name: str, meta: DatasetMeta, fit: TrajectorySet | None = None) -> FittedBaseline:
    """Baseline `name` for scenes of `meta`'s kind; a ridge baseline is fitted on `fit` once,
    here (EvaluationError if it cannot be). Its samples: constant velocity's are CVM-S's
    (heading noise, Schöller et al. 2020; NLL by kernel density, as Trajectron++ scores
    samplers); a ridge's are its mean plus its training residuals' Gaussian (closed-form NLL)."""
    if name not in BASELINES:
        raise EvaluationError(f"unknown baseline {name!r}; choose from {', '.join(BASELINES)}")
    num_observed = meta.num_observed
    if name == "const_vel":

        def cv_distribution(data: TrajectorySet, k: int, seed: int):
            xy = data.states[..., :2]
            samples = constant_velocity_samples(xy, data.valid, num_observed, k, seed)
            mask = prediction_mask(data.valid, num_observed)
            return samples, kde_nll(samples, xy[:, num_observed:], mask)

        return FittedBaseline(
            lambda data: constant_velocity(data.states[..., :2], data.valid, num_observed),
            cv_distribution,
            {},
            "CVM-S: constant velocity, heading rotated by N(0, 25 deg) per sample; NLL by KDE",
        )
    if fit is None or fit.n == 0:
        raise EvaluationError(f"the {name} baseline needs training scenes to fit on")
    config = RidgeConfig.named(name)
    if config.neighbours == "labelled" and not meta.has("attention"):
        raise EvaluationError(
            f"the {name} baseline reads attention labels, which the {meta.scenario} data lacks"
        )
    try:
        ridge = RidgeBaseline(config).fit_set(fit, meta)
    except ValueError as err:
        raise EvaluationError(f"cannot fit the {name} baseline: {err}") from None
    details = {
        "fit_scenes": fit.n,
        "history_steps": ridge.history,
        "alpha": {meta.role_names[role]: alpha for role, alpha in sorted(ridge.alpha.items())},
    }

    spread = RidgeDistribution(ridge)

    def ridge_distribution(data: TrajectorySet, k: int, seed: int):
        mean, tril = spread.step_gaussians(data, meta)
        nll = gaussian_nll(data.states[:, num_observed:, :, :2], mean, tril)
        return spread.sample_set(data, meta, k, seed), nll

    return FittedBaseline(
        lambda data: ridge.predict_set(data, meta),
        ridge_distribution,
        details,
        "ridge mean plus its training residuals' Gaussian over the whole future; NLL closed form",
    )


def score(
    predictions: Predictions, nll: np.ndarray | None = None, miss_threshold_m: float = 2.0
) -> dict:
    """ADE/FDE per agent group and case, and attention accuracy (see `predictor.metrics`):
    {"main_agents": ..., "all_agents": ..., "attention_accuracy": ...}; with samples (K > 0)
    each group's entries also hold min_ade, min_fde, miss_rate, nll and k
    (`predictor.probabilistic`), nll from the per-step NLL `nll` (n, T_pred, N) if given."""
    p = predictions
    true, mask = p.true_xy[:, p.num_observed :], prediction_mask(p.valid, p.num_observed)
    result = displacement_metrics(p.pred_mean, true, mask, p.case, p.case_names, p.focal)
    if p.num_samples:
        sampled = sample_metrics(
            p.samples, true, mask, p.case, p.case_names, p.focal, miss_threshold_m, nll
        )
        for group, parts in sampled.items():
            for entry, target in _entries(result[group]):
                source = parts["overall"] if entry == "overall" else parts["cases"][entry]
                target.update({key: source[key] for key in SAMPLE_KEYS})
    result["attention_accuracy"] = attention_accuracy(
        p.attention, p.attention_label, p.interaction, p.valid, p.num_observed, p.case, p.case_names
    )
    return result


SAMPLE_KEYS = ("min_ade", "min_fde", "miss_rate", "nll", "k")  # score's keys from the samples


def _entries(group: dict) -> list[tuple[str, dict]]:
    return [("overall", group["overall"]), *group["cases"].items()]
