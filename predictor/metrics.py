"""Evaluation metrics on numpy arrays: ADE, FDE and attention accuracy, per case and overall.

Conventions (shared by every predictor, the constant-velocity baseline included):

- An agent is predicted in a scene if it is present at the last observed step T_obs-1; an error
  counts at a predicted step t >= T_obs where that agent is also present (`prediction_mask`).
- ADE [m] is the mean Euclidean error over all counted (scene, step, agent) triples of a group,
  pooled (not a mean of per-scene means). FDE [m] is the mean error at the final step T-1 over the
  agents counted there.
- Two agent groups are reported: `all_agents` and `main_agents`, the agents the data marks as
  focal in each scene (`focal`, (n, N): the two interacting cars of the synthetic scenarios,
  the fully observed pedestrians of ETH/UCY; see docs/dataset_format.md). The headline is
  `main_agents`: the synthetic distractors drive at constant speed and would otherwise dominate
  the average of 22 agents. The focal agents are gathered scene by scene into a compact
  (n, K) agent axis (`focal_slots`), so where they are the first slots of every scene the sums
  run over exactly the arrays, in the same order, that slicing those slots gives.
- Attention accuracy: over (step t, agent i) pairs with T_obs <= t <= T-2 (the fed-back steps
  whose attention theta^t is computed from predicted states), t inside the interaction period,
  i predicted and present at t and labelled (label >= 0): the share where the labelled agent's
  weight is strictly larger than every other weight (a tie, e.g. uniform attention, is no hit:
  `argmax` would break it toward the lowest index, which is the other main car). Also the mean
  weight on the labelled agent over the same pairs (1/(N-1) for uniform attention), which is
  informative even when the attention is close to uniform.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np


def prediction_mask(valid: np.ndarray, num_observed: int) -> np.ndarray:
    """(n, T, N) validity -> (n, T_pred, N): predicted (present at T_obs-1) and present at t."""
    return valid[:, num_observed:] & valid[:, num_observed - 1 : num_observed]


def focal_slots(focal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, N) focal mask -> (slots (n, K), present (n, K)): each scene's focal agent slots in
    slot order, padded to K = the largest focal count with slot 0 marked not present."""
    focal = np.asarray(focal, dtype=bool)
    count = int(focal.sum(axis=1).max()) if focal.size else 0
    slots = np.argsort(~focal, axis=1, kind="stable")[:, :count]  # (n, K) focal first
    return slots, np.take_along_axis(focal, slots, axis=1)


def gather_agents(array: np.ndarray, slots: np.ndarray) -> np.ndarray:
    """(n, T, N, ...) array -> (n, T, K, ...): the agents `slots` (n, K) of each scene."""
    index = slots.reshape(slots.shape[0], 1, slots.shape[1], *([1] * (array.ndim - 3)))
    return np.take_along_axis(array, index, axis=2)


def focal_view(
    pred: np.ndarray, true: np.ndarray, mask: np.ndarray, focal: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pred, true, mask) restricted to the focal agents: (n, T_pred, K, 2) twice and
    (n, T_pred, K), padding slots masked out."""
    slots, present = focal_slots(focal)
    keep = gather_agents(mask, slots) & present[:, None, :]
    return gather_agents(pred, slots), gather_agents(true, slots), keep


def average_displacement(dist: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ADE's parts per scene: the errors [m] summed over every counted (step, agent), and how
    many were counted. dist, keep (n, T_pred, A)."""
    return dist.sum(axis=(1, 2)), keep.sum(axis=(1, 2))


def final_displacement(dist: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """FDE's parts per scene: the errors [m] at the final step summed over the agents counted
    there, and their number."""
    return dist[:, -1].sum(axis=-1), keep[:, -1].sum(axis=-1)


@dataclass(frozen=True)
class ErrorMetric:
    """A pooled error metric: `parts(dist, keep)` gives per scene a sum over counted items and
    their count (dist: the Euclidean errors [m] with uncounted items at 0); the metric is the
    pooled sum over the pooled count. The evaluation, eval.json and the report's tables and
    figures read every metric of `ERROR_METRICS`."""

    name: str
    parts: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    count_key: str | None = None  # the eval.json key of its item count, if it records one


ERROR_METRICS: tuple[ErrorMetric, ...] = (
    ErrorMetric("ade", average_displacement, "count"),
    ErrorMetric("fde", final_displacement, "final_count"),
)


def _errors(pred: np.ndarray, true: np.ndarray, keep: np.ndarray) -> dict:
    dist = np.linalg.norm(pred - true, axis=-1)  # (n, T_pred, A)
    dist = np.where(keep, dist, 0.0)
    return {metric.name: metric.parts(dist, keep) for metric in ERROR_METRICS}


def _ratio(total: float, count: int) -> float | None:
    return float(total / count) if count > 0 else None


def _pool(parts: dict, rows: np.ndarray) -> dict:
    sums = {
        name: (float(total[rows].sum()), int(count[rows].sum()))
        for name, (total, count) in parts.items()
    }
    pooled: dict = {name: _ratio(total, count) for name, (total, count) in sums.items()}
    for metric in ERROR_METRICS:
        if metric.count_key is not None:
            pooled[metric.count_key] = sums[metric.name][1]
    pooled["scenes"] = int(rows.sum())
    return pooled


def displacement_metrics(
    pred: np.ndarray,
    true: np.ndarray,
    mask: np.ndarray,
    case: np.ndarray,
    case_names: Sequence[str],
    focal: np.ndarray,
) -> dict:
    """ADE/FDE [m] per agent group, overall and per case.

    pred, true (n, T_pred, N, 2) [m]; mask (n, T_pred, N) bool; case (n,) indices into case_names;
    focal (n, N) bool, the `main_agents` group. Returns {group: {"overall": {...}, "cases":
    {name: {...}}}} with keys ade, fde, count, final_count, scenes (ade/fde None where nothing
    counts).
    """
    groups = {"all_agents": (pred, true, mask), "main_agents": focal_view(pred, true, mask, focal)}
    case = np.asarray(case)
    result = {}
    for group, arrays in groups.items():
        parts = _errors(*arrays)
        result[group] = {
            "overall": _pool(parts, np.ones(len(case), dtype=bool)),
            "cases": {name: _pool(parts, case == k) for k, name in enumerate(case_names)},
        }
    return result


def attention_hits(
    attention: np.ndarray,
    labels: np.ndarray,
    interaction: np.ndarray,
    valid: np.ndarray,
    num_observed: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-scene (hits, counted pairs, summed weight on the label) of the attention accuracy.

    attention (n, T-1, N, N) theta^t_ij; labels (n, T, N) int (-1 none); interaction (n, T) bool;
    valid (n, T, N) bool. Returns three (n,) arrays (see the module docstring).
    """
    steps = slice(num_observed, attention.shape[1])  # t = T_obs .. T-2
    label = labels[:, steps]  # (n, S, N)
    if not (label >= 0).any():  # nothing labelled (real data): no copy of the attention
        zeros = np.zeros(len(labels), dtype=np.int64)
        return zeros, zeros, np.zeros(len(labels))
    theta = attention[:, steps]  # (n, S, N, N)
    keep = (
        (label >= 0)
        & interaction[:, steps, None]
        & valid[:, steps]
        & valid[:, num_observed - 1 : num_observed]
    )  # (n, S, N)
    index = np.clip(label, 0, None)[..., None]  # (n, S, N, 1)
    on_label = np.take_along_axis(theta, index, axis=-1)[..., 0]  # (n, S, N)
    others = theta.copy()
    np.put_along_axis(others, index, -np.inf, axis=-1)
    hit = (on_label > others.max(axis=-1)) & keep  # (n, S, N): strictly the largest weight
    weight = np.where(keep, on_label, 0.0)  # (n, S, N)
    return hit.sum(axis=(1, 2)), keep.sum(axis=(1, 2)), weight.sum(axis=(1, 2))


def attention_accuracy(
    attention: np.ndarray,
    labels: np.ndarray,
    interaction: np.ndarray,
    valid: np.ndarray,
    num_observed: int,
    case: np.ndarray,
    case_names: Sequence[str],
) -> dict:
    """Attention accuracy overall and per case: {"overall": {...}, "cases": {...}}.

    Each entry has accuracy and mean_weight (None if nothing counts or the attention is NaN, as
    for constant velocity) and count. Only labelled agents count, so in practice the main agents.
    """
    hits, counts, weights = attention_hits(attention, labels, interaction, valid, num_observed)
    undefined = bool(counts.any()) and bool(np.isnan(attention).any())
    case = np.asarray(case)

    def pool(rows: np.ndarray) -> dict:
        count = int(counts[rows].sum())
        accuracy = None if undefined else _ratio(float(hits[rows].sum()), count)
        mean_weight = None if undefined else _ratio(float(weights[rows].sum()), count)
        return {"accuracy": accuracy, "mean_weight": mean_weight, "count": count}

    return {
        "overall": pool(np.ones(len(case), dtype=bool)),
        "cases": {name: pool(case == k) for k, name in enumerate(case_names)},
    }


def headline(metrics: dict, agents: str = "main agents") -> str:
    """One-line text of the headline numbers of an evaluation result; `agents` names the
    headline group (the data's focal agents)."""
    main, every = metrics["main_agents"]["overall"], metrics["all_agents"]["overall"]
    accuracy = metrics["attention_accuracy"]["overall"]["accuracy"]

    def fmt(value: float | None, spec: str = ".3f") -> str:
        return "n/a" if value is None or math.isnan(value) else format(value, spec)

    sampled = ""
    if main.get("k"):
        sampled = (
            f"; best of {main['k']}: minADE {fmt(main['min_ade'])} m minFDE "
            f"{fmt(main['min_fde'])} m, miss rate {fmt(main['miss_rate'])}, NLL "
            f"{fmt(main['nll'], '.2f')}"
        )
    return (
        f"{agents} ADE {fmt(main['ade'])} m FDE {fmt(main['fde'])} m; all agents ADE "
        f"{fmt(every['ade'])} m FDE {fmt(every['fde'])} m{sampled}; attention accuracy "
        f"{fmt(accuracy)}"
    )
