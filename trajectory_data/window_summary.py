"""Summary of the influence per predicted-time window (`influence_windows`, schema 4) for
`tools/inspect_data.py`: per window, how the labelled agents' influence compares with the
others', and how often the agent with the most influence on a focal agent changes from one
window to the next (beside how often its attention label does).

Definitions, per window w (the steps t_w .. t_w + L - 1, `window_steps`) over all splits:
- a labelled pair (i, j): agent i carries the attention label j at some step of the window;
- `labelled`: mean influence[w, i, j] [m] over labelled pairs; `others`: mean influence[w, i, k]
  over the other agents k (not i, not labelled by i in the window) of the same agents i;
  `share_above`: share of labelled pairs whose influence exceeds every other agent's on i;
- `top`: per scene and focal agent i, the agent with the largest influence on i in window w
  (none where no agent has any); `top_changed`: share of focal agents with a top agent in w - 1
  and in w whose top agent differs; `label_changed` the same for i's most frequent label;
  `top_labelled`: share of focal agents with a top agent and a label in w whose top agent is
  one their label names in w.

Over the whole predicted span (`influence_moves`): the focal agents whose label names two or
more agents, and how many of them have two or more distinct top agents over the windows. A
window in which no agent has any influence (a car waiting for two others in turn: removing the
first changes nothing while the second still blocks it) breaks a run, so consecutive windows
alone (`top_changed`) understate how often the top agent moves.
"""

from __future__ import annotations

import numpy as np

from trajectory_data.format import INFLUENCE_WINDOWS, DatasetMeta, TrajectorySet


def window_steps(meta: DatasetMeta) -> list[tuple[int, int]]:
    """[first, stop) recorded steps of each window of `meta`'s influence_windows."""
    size, end = meta.influence_window_steps, meta.num_steps
    return [(t, min(t + size, end)) for t in range(meta.num_observed, end, size)]


def influence_window_rows(meta: DatasetMeta, splits: dict[str, TrajectorySet]) -> list[dict]:
    """One row per window (see the module): `window`, `steps`, `pairs`, `labelled`, `others`,
    `share_above` (None without attention labels or labelled pairs), `top_changed` and
    `label_changed` (None for the first window or where nothing is counted). Requires recorded
    influence_windows."""
    if not meta.has(INFLUENCE_WINDOWS):
        raise ValueError("the window summary needs recorded influence_windows")
    labels = meta.has("attention")
    rows = []
    previous_top = previous_label = None
    for w, (first, stop) in enumerate(window_steps(meta)):
        labelled, others, above = [], [], []
        tops, modes, named = [], [], []
        for data in splits.values():
            matrix = data.influence_windows[:, w]  # (n, N, N) [k, i, j]
            tops.append(_top_agents(matrix))
            modes.append(_label_modes(data.attention[:, first:stop]))
            named.append(_top_is_labelled(tops[-1], data.attention[:, first:stop]))
            if labels:
                _labelled_pairs(matrix, data.attention[:, first:stop], labelled, others, above)
        top, mode = np.concatenate(tops), np.concatenate(modes)
        focal = np.concatenate([data.focal for data in splits.values()])
        counted = focal & (top >= 0) & (mode >= 0)
        rows.append(
            {
                "window": w,
                "steps": (first, stop),
                "pairs": len(labelled),
                "labelled": _mean(labelled),
                "others": _mean(others),
                "share_above": float(np.mean(above)) if above else None,
                "top_changed": _changed(previous_top, top, focal),
                "label_changed": _changed(previous_label, mode, focal) if labels else None,
                "top_labelled": (
                    float(np.concatenate(named)[counted].mean()) if counted.any() else None
                ),
            }
        )
        previous_top, previous_label = top, mode
    return rows


def _labelled_pairs(
    matrix: np.ndarray, attention: np.ndarray, labelled: list, others: list, above: list
) -> None:
    """Append one window's labelled-pair influences, other agents' and whether the labelled
    one beats every other, for matrices (n, N, N) and labels (n, t, N)."""
    agents = np.arange(matrix.shape[-1])
    for scene, i in zip(*np.nonzero((attention >= 0).any(axis=1))):
        chosen = np.unique(attention[scene, :, i][attention[scene, :, i] >= 0])
        rest = (agents != i) & ~np.isin(agents, chosen)
        row = matrix[scene, i]  # (N,) influence of each agent on i
        strongest = float(np.nanmax(row[rest], initial=0.0))
        others.extend(row[rest][np.isfinite(row[rest])].tolist())
        for j in chosen:
            labelled.append(float(row[j]))
            above.append(bool(row[j] > strongest))


def influence_moves(
    meta: DatasetMeta, splits: dict[str, TrajectorySet], case: int | None = None
) -> dict:
    """Over the predicted span, per focal agent (module docstring; of the scenes of case index
    `case` only, if given): `moving` (focal agents whose label names two or more agents at the
    predicted steps), `top_moves` (of those, the share with two or more distinct top agents
    over the windows; None where there are none) and `top_moves_fixed` (the same share among
    focal agents whose label names exactly one agent). Requires recorded influence_windows and
    attention labels."""
    if not (meta.has(INFLUENCE_WINDOWS) and meta.has("attention")):
        raise ValueError("the window summary needs recorded influence_windows and attention")
    label_counts, top_counts = [], []
    for data in splits.values():
        tops = np.stack(
            [_top_agents(data.influence_windows[:, w]) for w in range(len(window_steps(meta)))],
            axis=1,
        )  # (n, W, N)
        focal = data.focal & (True if case is None else (data.case == case)[:, None])
        label_counts.append(_distinct(data.attention[:, meta.num_observed :])[focal])
        top_counts.append(_distinct(tops)[focal])
    labels, tops = np.concatenate(label_counts), np.concatenate(top_counts)
    moving, fixed = labels >= 2, labels == 1
    return {
        "moving": int(moving.sum()),
        "top_moves": float((tops[moving] >= 2).mean()) if moving.any() else None,
        "top_moves_fixed": float((tops[fixed] >= 2).mean()) if fixed.any() else None,
    }


def _distinct(values: np.ndarray) -> np.ndarray:
    """(n, N) number of distinct values >= 0 of each agent over axis 1 of (n, t, N)."""
    agents = values.shape[-1]
    seen = np.zeros((values.shape[0], agents, agents), dtype=bool)
    scene, _, agent = np.nonzero(values >= 0)
    seen[scene, agent, values[values >= 0]] = True
    return seen.sum(axis=2)


def _top_is_labelled(top: np.ndarray, attention: np.ndarray) -> np.ndarray:
    """(n, N) whether each agent's top agent (n, N) is one its labels (n, t, N) name."""
    return (attention == top[:, None, :]).any(axis=1) & (top >= 0)


def _top_agents(matrix: np.ndarray) -> np.ndarray:
    """(n, N) agent with the largest influence on each agent (-1: none has any)."""
    strength = np.where(np.isfinite(matrix), matrix, 0.0)
    diagonal = np.arange(matrix.shape[-1])
    strength[:, diagonal, diagonal] = 0.0
    return np.where(strength.max(axis=2) > 0, strength.argmax(axis=2), -1)


def _label_modes(attention: np.ndarray) -> np.ndarray:
    """(n, N) most frequent attention label of each agent over the steps (n, t, N) (-1: none;
    ties to the lowest index)."""
    n, _, agents = attention.shape
    counts = np.zeros((n, agents, agents + 1), dtype=np.int64)
    scene, _, agent = np.indices(attention.shape).reshape(3, -1)
    np.add.at(counts, (scene, agent, attention.reshape(-1) + 1), 1)
    counts[..., 0] = 0  # -1: no label
    return np.where(counts.max(axis=2) > 0, counts.argmax(axis=2) - 1, -1)


def _changed(before: np.ndarray | None, after: np.ndarray, focal: np.ndarray) -> float | None:
    """Share of focal agents with a value in both windows whose value differs."""
    if before is None:
        return None
    both = focal & (before >= 0) & (after >= 0)
    return float((before[both] != after[both]).mean()) if both.any() else None


def _mean(values: list) -> float | None:
    finite = np.asarray(values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    return float(finite.mean()) if finite.size else None


def influence_window_lines(meta: DatasetMeta, splits: dict[str, TrajectorySet]) -> list[str]:
    """`influence_window_rows` as the summary's table."""
    lines = [
        f"influence per time window of {meta.influence_window_steps} steps (ADE over the window "
        "when an agent is removed from its first step) [m]:",
        f"{'window':<8}{'steps':<10}{'pairs':>7}{'labelled':>10}{'others':>9}"
        f"{'labelled > all':>16}{'top changed':>13}{'label changed':>15}{'top labelled':>14}",
    ]
    for row in influence_window_rows(meta, splits):
        first, stop = row["steps"]
        lines.append(
            f"{row['window']:<8}{f'{first}-{stop - 1}':<10}{row['pairs']:>7}"
            f"{_text(row['labelled'], 10, '.3f')}{_text(row['others'], 9, '.3f')}"
            f"{_text(row['share_above'], 16, '.1%')}{_text(row['top_changed'], 13, '.1%')}"
            f"{_text(row['label_changed'], 15, '.1%')}{_text(row['top_labelled'], 14, '.1%')}"
        )
    if meta.has("attention"):
        lines += [
            "moving labels (focal agents whose label names 2+ agents over the predicted "
            "steps), the share of them with 2+ top agents (of those with 1 labelled agent):"
        ]
        cases = [(None, "all")]
        if meta.has("case"):
            cases += list(enumerate(meta.case_names))
        for case, name in cases:
            moves = influence_moves(meta, splits, case)
            lines.append(
                f"  {name:<12}{moves['moving']:>6}  {_percent(moves['top_moves']):>7}  "
                f"({_percent(moves['top_moves_fixed'])})"
            )
    return lines


def _text(value: float | None, width: int, spec: str) -> str:
    return f"{'-':>{width}}" if value is None else f"{value:>{width}{spec}}"


def _percent(value: float | None) -> str:
    return "-" if value is None else f"{value:.1%}"
