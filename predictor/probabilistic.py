"""The field's metrics of predictors that give a distribution: best-of-K errors over K sampled
futures, the miss rate, and negative log-likelihoods (NLL) of the truth, on numpy arrays.

Items, groups and pooling are those of `predictor.metrics`: an item is a counted (scene, step,
agent) triple (`prediction_mask`), `main_agents` are the focal agents gathered by `focal_slots`,
and every figure is a sum over the group's items pooled over scenes divided by their pooled
count (not a mean of per-scene means). Samples are (n, K, T_pred, N, 2) [m].

- minADE_K [m]: per (scene, agent) the smallest over the K samples of the *sum* of its errors
  over its counted steps; summed over agents, divided by the number of counted items. At K = 1
  this is `metrics` pooled ADE. (One sample is chosen per agent, for its whole trajectory, as in
  Trajectron++'s best-of-K and Schoeller et al.'s CVM-S evaluation; agents counted at more
  steps weigh more, as in the pooled ADE.)
- minFDE_K [m]: per agent counted at the final step, the smallest final error over the samples
  (chosen independently of minADE's sample), pooled mean. At K = 1: `metrics` FDE.
- miss rate: the share of the agents counted at the final step whose minFDE_K exceeds
  `miss_threshold_m` (2 m by default: Argoverse's and Waymo's "final displacement > 2 m").
- nll [nats, positions in metres]: the mean over counted items of a per-item NLL given by the
  caller: `gaussian_nll` / `mixture_nll` for predictors with closed-form densities, `kde_nll`
  for predictors that only sample (Trajectron++'s KDE NLL).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from predictor.metrics import focal_slots

LOG_2PI = math.log(2.0 * math.pi)
# Trajectron++ (Salzmann et al., ECCV 2020) clips each KDE log-density below at this value
# (`log_pdf_lower_bound` in trajectron/evaluation/evaluation.py): one wild miss costs 20 nats
KDE_LOG_PDF_LOWER_BOUND = -20.0
# [m] smallest standard deviation of a KDE kernel along any axis: a sample set with no spread
# along some direction (an agent standing still, samples on a line) has a singular covariance,
# which scipy refuses (LinAlgError; Trajectron++ then reports NaN). Its kernel is widened to
# this std along that direction instead; a set with spread keeps scipy's kernel exactly.
KDE_MIN_STD_M = 0.01


def gaussian_nll(true: np.ndarray, mean: np.ndarray, tril: np.ndarray) -> np.ndarray:
    """-log N(true | mean, L L^T) [nats] of 2-D Gaussians, elementwise over leading dims.

    true, mean (..., 2) [m]; tril (..., 3) = Cholesky entries (l11, l21, l22), l11, l22 > 0 (the
    model's layout, as `predictor.losses.gaussian_nll` in torch).
    """
    diff = np.asarray(true, np.float64) - mean
    tril = np.asarray(tril, np.float64)
    z0 = diff[..., 0] / tril[..., 0]
    z1 = (diff[..., 1] - tril[..., 1] * z0) / tril[..., 2]
    return 0.5 * (z0 * z0 + z1 * z1) + np.log(tril[..., 0]) + np.log(tril[..., 2]) + LOG_2PI


def _logsumexp(values: np.ndarray, axis: int) -> np.ndarray:
    top = np.max(values, axis=axis, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    return np.log(np.exp(values - top).sum(axis=axis)) + np.squeeze(top, axis)


def mixture_nll(
    true: np.ndarray, log_weights: np.ndarray, means: np.ndarray, trils: np.ndarray
) -> np.ndarray:
    """-log sum_m w_m N(true | mean_m, L_m L_m^T) [nats] of 2-D Gaussian mixtures (log-sum-exp).

    true (..., 2); log_weights (..., M) log mixture weights (normalised here, so logits do);
    means (..., M, 2); trils (..., M, 3) as `gaussian_nll`. Returns (...).
    """
    log_weights = np.asarray(log_weights, np.float64)
    log_weights = log_weights - _logsumexp(log_weights, -1)[..., None]
    component = -gaussian_nll(np.asarray(true)[..., None, :], means, trils)  # (..., M)
    return -_logsumexp(log_weights + component, -1)


def kde_nll(
    samples: np.ndarray,
    true: np.ndarray,
    mask: np.ndarray,
    min_std_m: float = KDE_MIN_STD_M,
    lower_bound: float = KDE_LOG_PDF_LOWER_BOUND,
) -> np.ndarray:
    """Per-item NLL [nats] of the truth under a Gaussian KDE of the K samples, as Trajectron++
    reports it: (n, T_pred, N), NaN where `mask` is False.

    samples (n, K, T_pred, N, 2), true (n, T_pred, N, 2) [m], mask (n, T_pred, N). Per item the
    kernel is scipy.stats.gaussian_kde's with Scott's rule: covariance K^(-1/3) times the
    samples' covariance (ddof 1); the log-density of the truth is clipped below at
    `lower_bound` (Trajectron++: -20). Where the samples have less spread than `min_std_m` along
    some direction (all equal, e.g. an agent standing still, or K = 1) the kernel's variance
    along it is raised to min_std_m^2 (see KDE_MIN_STD_M) instead of failing.
    """
    samples = np.asarray(samples, np.float64)
    num_samples = samples.shape[1]
    mask = np.asarray(mask, bool)
    out = np.full(mask.shape, np.nan)
    points = np.moveaxis(samples, 1, -2)[mask]  # (M, K, 2): counted items only
    x = np.asarray(true, np.float64)[mask]  # (M, 2)
    if num_samples > 1:
        centred = points - points.mean(axis=1, keepdims=True)
        cov = np.einsum("mki,mkj->mij", centred, centred) / (num_samples - 1)  # (M, 2, 2)
    else:
        cov = np.zeros((len(points), 2, 2))
    kernel = cov * num_samples ** (-2.0 / 6.0)  # Scott's factor n^(-1/(d+4)), squared, d = 2
    values, vectors = np.linalg.eigh(kernel)
    floor = min_std_m**2
    narrow = (values < floor).any(-1)  # (M,) widen only these (scipy's kernel otherwise)
    if narrow.any():
        values = np.maximum(values, floor)
        fixed = np.einsum("mij,mj,mkj->mik", vectors, values, vectors)
        kernel = np.where(narrow[:, None, None], fixed, kernel)
    l11 = np.sqrt(kernel[:, 0, 0])
    l21 = kernel[:, 1, 0] / l11
    l22 = np.sqrt(np.prod(values, -1)) / l11  # det = l11^2 l22^2, without cancellation
    tril = np.stack([l11, l21, l22], -1)[:, None]  # (M, 1, 3): one kernel for the K samples
    log_density = _logsumexp(-gaussian_nll(x[:, None], points, tril), -1) - math.log(num_samples)
    out[mask] = -np.maximum(log_density, lower_bound)
    return out


SCENE_CHUNK = 64  # scenes whose sample errors are held at once (memory, not results)


def _gather(array: np.ndarray, slots: np.ndarray, axis: int) -> np.ndarray:
    """The agents `slots` (n, A) of each scene along `axis` of an (n, ...) array."""
    shape = [1] * array.ndim
    shape[0], shape[axis] = slots.shape
    return np.take_along_axis(array, slots.reshape(shape), axis=axis)


def _parts(
    samples: np.ndarray,
    true: np.ndarray,
    keep: np.ndarray,
    nll: np.ndarray | None,
    miss_threshold_m: float,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per scene (sum, count) of each metric. samples (n, K, T, A, 2), true/keep/nll (n, T, A)."""
    min_sum = np.zeros(keep.shape[::2])  # (n, A): best sample's summed error
    min_final = np.zeros(keep.shape[::2])  # (n, A)
    for start in range(0, len(samples), SCENE_CHUNK):  # a chunk's (k, K, T, A) errors at a time
        rows = slice(start, start + SCENE_CHUNK)
        dist = np.linalg.norm(samples[rows] - true[rows, None], axis=-1)  # (k, K, T, A)
        dist = np.where(keep[rows, None], dist, 0.0)
        min_sum[rows] = dist.sum(axis=2).min(axis=1)
        min_final[rows] = dist[:, :, -1].min(axis=1)
    final = keep[:, -1]  # (n, A)
    final_count = final.sum(axis=-1)
    parts = {
        "min_ade": (min_sum.sum(axis=-1), keep.sum(axis=(1, 2))),
        "min_fde": (np.where(final, min_final, 0.0).sum(axis=-1), final_count),
        "miss_rate": ((final & (min_final > miss_threshold_m)).sum(axis=-1), final_count),
    }
    if nll is not None:
        parts["nll"] = (np.where(keep, nll, 0.0).sum(axis=(1, 2)), keep.sum(axis=(1, 2)))
    return parts


def _pool(parts: dict, rows: np.ndarray, num_samples: int) -> dict:
    def ratio(name: str) -> float | None:
        if name not in parts:
            return None
        total, count = parts[name][0][rows].sum(), int(parts[name][1][rows].sum())
        return float(total / count) if count > 0 else None

    return {
        "min_ade": ratio("min_ade"),
        "min_fde": ratio("min_fde"),
        "miss_rate": ratio("miss_rate"),
        "nll": ratio("nll"),
        "k": num_samples,
        "count": int(parts["min_ade"][1][rows].sum()),
        "final_count": int(parts["min_fde"][1][rows].sum()),
        "scenes": int(rows.sum()),
    }


def sample_metrics(
    samples: np.ndarray,
    true: np.ndarray,
    mask: np.ndarray,
    case: np.ndarray,
    case_names: Sequence[str],
    focal: np.ndarray,
    miss_threshold_m: float = 2.0,
    nll: np.ndarray | None = None,
) -> dict:
    """minADE_K, minFDE_K [m], miss rate and mean NLL per agent group, overall and per case
    (definitions: the module docstring).

    samples (n, K, T_pred, N, 2) [m]; true (n, T_pred, N, 2); mask (n, T_pred, N) counted items
    (`metrics.prediction_mask`); case (n,) indices into case_names; focal (n, N) bool; nll
    (n, T_pred, N) per-item NLL [nats] or None. Returns {"all_agents" | "main_agents":
    {"overall": {...}, "cases": {name: {...}}}} with keys min_ade, min_fde, miss_rate, nll (None
    where not given or nothing counts), k, count, final_count, scenes.
    """
    samples, true, mask = np.asarray(samples), np.asarray(true), np.asarray(mask, bool)
    if samples.ndim != 5 or samples.shape[:1] + samples.shape[2:] != true.shape:
        raise ValueError(
            f"samples must be (n, K, T_pred, N, 2) around true {true.shape}, got {samples.shape}"
        )
    if nll is not None and np.shape(nll) != mask.shape:
        raise ValueError(f"nll must be shaped as the mask {mask.shape}, got {np.shape(nll)}")
    slots, present = focal_slots(focal)
    keep_main = _gather(mask, slots, 2) & present[:, None, :]
    groups = {
        "all_agents": (samples, true, mask, nll),
        "main_agents": (
            _gather(samples, slots, 3),
            _gather(true, slots, 2),
            keep_main,
            None if nll is None else _gather(np.asarray(nll), slots, 2),
        ),
    }
    case = np.asarray(case)
    result = {}
    for group, (s, t, keep, item_nll) in groups.items():
        parts = _parts(s, t, keep, item_nll, miss_threshold_m)
        result[group] = {
            "overall": _pool(parts, np.ones(len(case), dtype=bool), samples.shape[1]),
            "cases": {
                name: _pool(parts, case == k, samples.shape[1]) for k, name in enumerate(case_names)
            },
        }
    return result
