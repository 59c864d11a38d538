"""Attention faithfulness: does a predictor's attention follow who actually influences whom?

Three measures, on numpy arrays, against the counterfactual ground truth of a data file
(`TrajectorySet.influence`, (n, 2, N, N) [m]: `influence[k, kind, i, j]`, the ADE of agent i's
future without agent j, kinds `INFLUENCE_KINDS`; docs/dataset_format.md) where it exists:

- `attention_auroc`: how well agent i's attention weights over the others rank the agents that
  influence i above those that do not. Attending agents: the focal agents present at the last
  observed step T_obs-1 (the agents the headline is about, and those the influence matrix
  describes best). Scores: theta_ij averaged over the steps t = T_obs-1 .. T-2 whose attention
  produces the predicted steps (window "predicted"), or theta_ij^(T_obs-1) alone (window
  "last_observed"). Candidates j: the other agents present at T_obs-1 (the attention can weight
  no others) with a finite influence; j is "influential" where influence[i, j] > threshold (kind
  "predicted" by default: j removed from the first predicted step on, i.e. j's future behaviour
  given the same history, what a predictor's attention over the predicted steps can read).
  AUROC per agent is the Mann-Whitney statistic, P(s_pos > s_neg) + P(s_pos = s_neg) / 2;
  pooled as the mean over the agents with both classes among their candidates.
- `removal_shift`: the robustness test of CausalAgents (Roelofs et al., "CausalAgents: A
  Robustness Benchmark for Motion Forecasting", 2022): the change in the prediction of each
  focal agent when every agent that influences no focal agent is removed from the scene. One
  removal set per scene: the non-focal agents whose influence (kind "episode" by default: the
  removal of their whole history, as here) is <= threshold on every focal agent with a finite
  entry. They are removed by marking them absent (and zero-filling their states) in the observed
  steps; a predictor that reads no neighbours scores 0. Per (scene, focal agent predicted) in a
  scene that removes at least one agent present in the observed steps: the mean distance between
  the two predictions over the predicted steps where the agent is present; pooled as the mean
  over those pairs.
- `attention_total_variation`: the paper's total variation of attention over time (the prior's
  term, `predictor.losses.attention_tv`), measured: the mean over (focal agent i, step t) of
  ||theta_i^t - theta_i^(t-1)||_2, separately over the observed steps (t = 1 .. T_obs-1, the
  attention computed from observed states; i present at t-1 and t) and the predicted steps
  (t = T_obs .. T-2, computed from fed-back predictions; i predicted). Needs no influence.

Every measure is None where its attention is NaN (a baseline) or nothing counts.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from predictor.metrics import focal_slots, gather_agents, prediction_mask
from trajectory_data.format import INFLUENCE_KINDS  # axis 1 of TrajectorySet.influence

WINDOWS = ("predicted", "last_observed")  # attention steps scored by attention_auroc

Predict = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (states, valid) -> (n, P, N, 2)


class FaithfulnessError(ValueError):
    """Faithfulness settings or inputs that cannot be used (one line)."""


@dataclass(frozen=True)
class FaithfulnessSettings:
    """How attention faithfulness is measured (see the module docstring)."""

    threshold_m: float = 0.01  # [m] influence[i, j] above it: j influences i
    auroc_kind: str = "predicted"  # influence kind the attention's AUROC is scored against
    auroc_window: str = "predicted"  # attention steps averaged: "predicted" or "last_observed"
    removal_kind: str = "episode"  # influence kind that picks the agents removed

    def __post_init__(self) -> None:
        if not (np.isfinite(self.threshold_m) and self.threshold_m >= 0):
            raise FaithfulnessError(
                f"the influence threshold must be a distance >= 0 [m], got {self.threshold_m}"
            )
        for name in ("auroc_kind", "removal_kind"):
            if getattr(self, name) not in INFLUENCE_KINDS:
                raise FaithfulnessError(
                    f"unknown influence kind {getattr(self, name)!r}; choose from "
                    f"{', '.join(INFLUENCE_KINDS)}"
                )
        if self.auroc_window not in WINDOWS:
            raise FaithfulnessError(
                f"unknown attention window {self.auroc_window!r}; choose from {', '.join(WINDOWS)}"
            )


def mann_whitney_auroc(scores: np.ndarray, positive: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """AUROC of each row: scores, positive, keep (..., M); the items `keep` of a row, `positive`
    ones against the others: P(s_pos > s_neg) + P(s_pos = s_neg) / 2. NaN for a row without
    both classes."""
    pos, neg = keep & positive, keep & ~positive
    diff = scores[..., :, None] - scores[..., None, :]  # (..., M, M): pos row, neg column
    pairs = pos[..., :, None] & neg[..., None, :]
    wins = ((diff > 0) + 0.5 * (diff == 0)) * pairs
    count = pairs.sum(axis=(-2, -1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, wins.sum(axis=(-2, -1)) / np.maximum(count, 1), np.nan)


def attention_auroc(
    attention: np.ndarray,
    influence: np.ndarray,
    valid: np.ndarray,
    focal: np.ndarray,
    num_observed: int,
    settings: FaithfulnessSettings = FaithfulnessSettings(),
) -> dict:
    """{"auroc": mean AUROC over the focal agents with both classes (None: none, or NaN
    attention), "agents": their number, "kind", "window"}. attention (n, T-1, N, N); influence
    (n, 2, N, N) [m]; valid (n, T, N); focal (n, N)."""
    record = {"auroc": None, "agents": 0, "kind": settings.auroc_kind}
    record["window"] = settings.auroc_window
    if np.isnan(attention).any():
        return record
    kind = INFLUENCE_KINDS.index(settings.auroc_kind)
    last = valid[:, num_observed - 1]  # (n, N)
    values = []
    chunk = max(1, 4_000_000 // attention.shape[-1] ** 3)  # scenes per step: memory bounded
    for start in range(0, attention.shape[0], chunk):
        rows = slice(start, start + chunk)
        if settings.auroc_window == "predicted":
            theta = attention[rows, num_observed - 1 :].mean(axis=1)  # (b, N, N)
        else:
            theta = attention[rows, num_observed - 1]
        strength = influence[rows, kind]  # (b, N, N)
        present = last[rows]
        keep = present[:, None, :] & np.isfinite(strength) & ~np.eye(len(present[0]), dtype=bool)
        auroc = mann_whitney_auroc(theta, strength > settings.threshold_m, keep)  # (b, N)
        chosen = focal[rows] & present
        values.append(auroc[chosen & np.isfinite(auroc)])
    pooled = np.concatenate(values) if values else np.zeros(0)
    if len(pooled):
        record.update(auroc=float(pooled.mean()), agents=len(pooled))
    return record


def removal_sets(
    influence: np.ndarray,
    focal: np.ndarray,
    settings: FaithfulnessSettings = FaithfulnessSettings(),
) -> np.ndarray:
    """(n, N) bool: per scene, the non-focal agents whose influence on every focal agent (with
    a finite entry) is at most the threshold: the agents `removal_shift` removes."""
    strength = influence[:, INFLUENCE_KINDS.index(settings.removal_kind)]  # (n, N, N) [i, j]
    on_focal = np.where(focal[:, :, None] & np.isfinite(strength), strength, 0.0)
    return (on_focal <= settings.threshold_m).all(axis=1) & ~focal


def removal_shift(
    predict: Predict,
    base: np.ndarray,
    states: np.ndarray,
    valid: np.ndarray,
    influence: np.ndarray,
    focal: np.ndarray,
    num_observed: int,
    settings: FaithfulnessSettings = FaithfulnessSettings(),
) -> dict:
    """CausalAgents' robustness test: {"shift_m": mean change [m] of a focal agent's predicted
    positions when the agents without influence are removed, "pairs": (scene, focal agent)
    pairs counted, "removed_mean": agents removed per counted scene, "kind"}. `base` (n, P, N, 2)
    is `predict(states, valid)`, computed once by the caller."""
    record = {"shift_m": None, "pairs": 0, "removed_mean": None, "kind": settings.removal_kind}
    removed = removal_sets(influence, focal, settings)
    removed &= valid[:, :num_observed].any(axis=1)  # removing an absent agent changes nothing
    scenes = removed.any(axis=1)
    if not scenes.any():
        return record
    states, valid = states.copy(), valid.copy()
    valid[:, :num_observed] &= ~removed[:, None, :]
    zero = np.zeros((), states.dtype)
    states[:, :num_observed] = np.where(removed[:, None, :, None], zero, states[:, :num_observed])
    moved = predict(states, valid)
    mask = prediction_mask(valid, num_observed)  # the kept agents' own validity is unchanged
    dist = np.linalg.norm(moved - base, axis=-1)  # (n, P, N)
    steps = mask.sum(axis=1)  # (n, N)
    pairs = focal & scenes[:, None] & (steps > 0)
    if not pairs.any():
        return record
    per_agent = np.where(mask, dist, 0.0).sum(axis=1) / np.maximum(steps, 1)  # (n, N)
    return {
        **record,
        "shift_m": float(per_agent[pairs].mean()),
        "pairs": int(pairs.sum()),
        "removed_mean": float(removed[scenes].sum(axis=1).mean()),
    }


def attention_total_variation(
    attention: np.ndarray, valid: np.ndarray, focal: np.ndarray, num_observed: int
) -> dict:
    """{"observed": mean TV, "observed_count", "predicted": mean TV, "predicted_count"} over the
    focal agents (None where nothing counts or the attention is NaN). attention (n, T-1, N, N)
    theta^t; valid (n, T, N); focal (n, N)."""
    slots, chosen = focal_slots(focal)  # (n, K): the focal agents only (memory)
    theta = gather_agents(attention, slots)  # (n, T-1, K, N)
    diff = np.linalg.norm(np.diff(theta, axis=1), axis=-1)  # (n, T-2, K): t = 1 .. T-2
    present = gather_agents(valid[:, : attention.shape[1]], slots) & chosen[:, None, :]
    both = present[:, 1:] & present[:, :-1]  # (n, T-2, K) at t-1 and t
    observed = np.zeros_like(both)
    observed[:, : num_observed - 1] = both[:, : num_observed - 1]  # t = 1 .. T_obs-1
    predicted = np.zeros_like(both)
    predicted[:, num_observed - 1 :] = present[:, num_observed - 1 : num_observed]  # rolled out
    nan = bool(np.isnan(attention).any())
    record = {}
    for name, keep in (("observed", observed), ("predicted", predicted)):
        count = int(keep.sum())
        value = float(diff[keep].mean()) if count and not nan else None
        record.update({name: value, f"{name}_count": count})
    return record


def faithfulness(
    attention: np.ndarray,
    states: np.ndarray,
    valid: np.ndarray,
    focal: np.ndarray,
    influence: np.ndarray | None,
    num_observed: int,
    predict: Predict | None = None,
    base: np.ndarray | None = None,
    settings: FaithfulnessSettings = FaithfulnessSettings(),
) -> dict:
    """eval.json's `faithfulness` block: "attention_tv" always; with `influence` (n, 2, N, N)
    also "auroc" (+ "auroc_agents", "auroc_kind", "auroc_window") and, with `predict` and its
    predictions `base`, "robustness_m" (+ "robustness_pairs", "removed_mean", "removal_kind"
    and "robustness_ratio", robustness_m over the focal agents' ADE `ade_m`), "threshold_m"."""
    block: dict = {"attention_tv": attention_total_variation(attention, valid, focal, num_observed)}
    if influence is None:
        return block
    block["threshold_m"] = settings.threshold_m
    auroc = attention_auroc(attention, influence, valid, focal, num_observed, settings)
    block.update(
        auroc=auroc["auroc"],
        auroc_agents=auroc["agents"],
        auroc_kind=auroc["kind"],
        auroc_window=auroc["window"],
    )
    if predict is None or base is None:
        return block
    shift = removal_shift(predict, base, states, valid, influence, focal, num_observed, settings)
    block.update(
        robustness_m=shift["shift_m"],
        robustness_pairs=shift["pairs"],
        removed_mean=shift["removed_mean"],
        removal_kind=shift["kind"],
    )
    return block


def with_ratio(block: dict, ade_m: float | None) -> dict:
    """`block` with "robustness_ratio": robustness_m over the focal agents' ADE `ade_m` (how
    large the shift is against the prediction's own error; None where either is missing)."""
    if "robustness_m" not in block:
        return block
    shift = block["robustness_m"]
    ratio = shift / ade_m if shift is not None and ade_m else None
    return {**block, "robustness_ratio": ratio}
