"""Whom each agent's attention label names over a scene: the most attended agent, every agent
it attends to in the order it first does, and how many (the ridge baseline's "labelled"
neighbour slots, `predictor.baselines`; the diagnostics' labelled car)."""

from __future__ import annotations

import numpy as np


def attended_mask(attention: np.ndarray) -> np.ndarray:
    """(n, T, N) labels -> (n, N, N) bool: agent i attends to agent j at some step."""
    n, _, num_agents = attention.shape
    seen = np.zeros((n, num_agents, num_agents + 1), dtype=bool)
    labels = np.where(attention >= 0, attention, num_agents)
    scenes = np.arange(n)[:, None, None]
    agents = np.arange(num_agents)[None, None, :]
    seen[np.broadcast_to(scenes, labels.shape), np.broadcast_to(agents, labels.shape), labels] = (
        True
    )
    return seen[..., :num_agents]


def attended_count(attention: np.ndarray) -> np.ndarray:
    """(n, T, N) labels -> (n, N): how many distinct agents each agent attends to."""
    return attended_mask(attention).sum(axis=-1)


def attended_agents(attention: np.ndarray, slots: int) -> np.ndarray:
    """(n, T, N) labels -> (slots, n, N): slot 0 each agent's most attended agent
    (`scene_labels`), the next slots the other agents it attends to in the order it first does
    (-1 where there are fewer)."""
    first = scene_labels(attention)
    result = np.full((slots, *first.shape), -1, dtype=first.dtype)
    result[0] = first
    if slots == 1:
        return result
    n, num_steps, num_agents = attention.shape
    # step at which each agent first attends to each other agent (num_steps: never)
    onset = np.full((n, num_agents, num_agents + 1), num_steps, dtype=np.int64)
    labels = np.where(attention >= 0, attention, num_agents)
    steps = np.broadcast_to(np.arange(num_steps)[None, :, None], labels.shape)
    scenes = np.broadcast_to(np.arange(n)[:, None, None], labels.shape)
    agents = np.broadcast_to(np.arange(num_agents)[None, None, :], labels.shape)
    np.minimum.at(onset, (scenes, agents, labels), steps)
    onset = onset[..., :num_agents]  # (n, N, N)
    rows, cols = np.nonzero(first >= 0)
    onset[rows, cols, first[rows, cols]] = num_steps  # the most attended one is slot 0
    order = np.argsort(onset, axis=-1, kind="stable")  # (n, N, N)
    for k in range(1, slots):
        index = order[..., k - 1]
        attended = np.take_along_axis(onset, index[..., None], -1)[..., 0] < num_steps
        result[k] = np.where(attended, index, -1)
    return result


def scene_labels(attention: np.ndarray) -> np.ndarray:
    """(n, T, N) labels -> (n, N): each agent's most frequent attended agent (-1: none)."""
    n, _, num_agents = attention.shape
    counts = np.zeros((n, num_agents, num_agents + 1), dtype=np.int64)
    labels = np.where(attention >= 0, attention, num_agents)  # "none" in the last bin
    scenes = np.arange(n)[:, None, None]
    agents = np.arange(num_agents)[None, None, :]
    np.add.at(
        counts,
        (np.broadcast_to(scenes, labels.shape), np.broadcast_to(agents, labels.shape), labels),
        1,
    )
    counts[..., num_agents] = 0
    best = counts.argmax(-1)  # (n, N)
    return np.where(counts.max(-1) > 0, best, -1)
