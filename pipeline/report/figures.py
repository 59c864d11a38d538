"""The report's figures: ADE/FDE bars per setting, the training-set size study, and one scene
with its trajectories and attention (the paper's Fig. 3-6).

Each builder returns a `matplotlib.figure.Figure` (predictor.plots' Agg helpers, no pyplot
state); `save` is the one way they are written, atomically.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from pipeline.files import atomic_output
from pipeline.report.records import CASES, LABELS, METRICS, CaseNames, Measure, Results
from pipeline.report.statistics import p_text
from predictor.plots import draw_attention, new_figure, role_color, save_figure
from predictor.predictions import Predictions
from predictor.registry import COLORS

DPI = 110


def save(fig: Figure, path: str | os.PathLike) -> Path:
    """Write a figure atomically (the format follows the suffix); returns the path."""
    path = Path(path)
    with atomic_output(path) as temp:
        save_figure(fig, temp, dpi=DPI)
    return path


# ---------------------------------------------------------------------------------- bars
@dataclass(frozen=True)
class BarInputs:
    """Heights and error bars of one grouped bar chart (groups = cases, bars = variants)."""

    variants: tuple[str, ...]
    cases: tuple[str, ...]
    means: np.ndarray  # (V, C) NaN where missing
    errors: np.ndarray  # (V, C) sample std, 0 where undefined (one seed, the baseline)


def bar_inputs(results: Results, setting: str, metric: str, variants: Sequence[str]) -> BarInputs:
    """Bar heights for `metric` of the headline group, run variants in the given order."""
    shown = tuple(v for v in variants if results.summary(setting, v) is not None)
    means = np.full((len(shown), len(CASES)), np.nan)
    errors = np.zeros((len(shown), len(CASES)))
    for i, variant in enumerate(shown):
        for j, case in enumerate(CASES):
            summary = results.summary(setting, variant)[Measure(metric, case)]
            if summary.mean is not None:
                means[i, j] = summary.mean
            errors[i, j] = summary.std or 0.0
    return BarInputs(shown, CASES, means, errors)


def bar_figure(
    results: Results, setting: str, variants: Sequence[str], names: CaseNames, title: str
) -> Figure:
    """ADE and FDE bars per case and variant with std error bars (the paper's Fig. 3 and 5)."""
    fig = new_figure(10.0, 3.8)
    axes = fig.subplots(1, len(METRICS))
    versus = results.comparison(setting, "s_attn")
    for ax, metric in zip(axes, METRICS):
        bars = bar_inputs(results, setting, metric, variants)
        width = 0.8 / max(len(bars.variants), 1)
        for i, variant in enumerate(bars.variants):
            x = np.arange(len(bars.cases)) + (i - (len(bars.variants) - 1) / 2) * width
            ax.bar(
                x,
                bars.means[i],
                width,
                yerr=bars.errors[i],
                capsize=3,
                color=COLORS[variant],
                label=LABELS[variant],
            )
        ax.set_xticks(np.arange(len(bars.cases)), [f"{c} ({names.of(c)})" for c in bars.cases])
        ax.set_ylabel(f"{metric.upper()} [m] (main cars)")
        if versus:
            ps = ", ".join(f"{c} {p_text(versus[Measure(metric, c)].test.p)}" for c in CASES)
            ax.set_title(f"{metric.upper()}; Ours vs S-Attn: {ps}", fontsize="small")
    _legend_below(fig, axes[0])
    fig.suptitle(title)
    return fig


LEGEND_COLUMNS = 5  # entries per legend row: nine variants in one row overflow a 10-inch figure


def _legend_below(fig: Figure, ax: Axes) -> None:
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(
        handles,
        labels,
        loc="outside lower center",
        ncols=min(len(labels), LEGEND_COLUMNS),
        fontsize="small",
        frameon=False,
    )


# ---------------------------------------------------------------------------------- size study
def series(
    results: Results, settings: Sequence[str], variant: str, measure: Measure
) -> tuple[np.ndarray, np.ndarray]:
    """Means (NaN where missing) and stds (0 where undefined) of one variant across settings."""
    summaries = [results.summary(s, variant) for s in settings]
    mean = np.array(
        [np.nan if s is None or s[measure].mean is None else s[measure].mean for s in summaries]
    )  # (S,)
    std = np.array([0.0 if s is None else s[measure].std or 0.0 for s in summaries])  # (S,)
    return mean, std


def size_figure(
    results: Results, size_settings: Sequence[str], labels: Sequence[str], variants: Sequence[str]
) -> Figure:
    """Test error against training-set size (the paper's Fig. 4): rows metrics, columns cases."""
    fig = new_figure(10.0, 6.0)
    axes = fig.subplots(len(METRICS), len(CASES), squeeze=False)
    x = np.arange(len(size_settings))
    dodge = 0.04 * (np.arange(len(variants)) - (len(variants) - 1) / 2)  # (V,) keep bars apart
    for row, metric in enumerate(METRICS):
        for column, case in enumerate(CASES):
            ax = axes[row, column]
            for offset, variant in zip(dodge, variants):
                mean, std = series(results, size_settings, variant, Measure(metric, case))
                if np.isfinite(mean).any():
                    ax.errorbar(
                        x + offset,
                        mean,
                        yerr=std,
                        marker="o",
                        capsize=3,
                        color=COLORS[variant],
                        label=LABELS[variant],
                    )
            ax.set_xticks(x, labels)
            ax.set_title(f"{case} case", fontsize="small")
            ax.set_ylabel(f"{metric.upper()} [m]")
            if row == len(METRICS) - 1:
                ax.set_xlabel("training trajectories, minor + major")
    _legend_below(fig, axes[0, 0])
    fig.suptitle("Double Merge: test error against training-set size (main cars)")
    return fig


# ---------------------------------------------------------------------------------- one scene
def scene_figure(ours: Predictions, other: Predictions, index: int, title: str) -> Figure:
    """Fig. 6: predicted main-car trajectories of Ours and S-Attn (dot opacity = attention on
    the other main car, size = time) and each main car's attention on the other over time."""
    if not np.array_equal(ours.true_xy[index], other.true_xy[index]):
        raise ValueError("the two prediction files hold different scenes")
    fig = new_figure(10.0, 8.0)
    grid = fig.add_gridspec(3, 1, height_ratios=(2.0, 1.0, 1.0))
    _trajectory_axes(fig.add_subplot(grid[0]), ours, other, index)
    for row, (agent, target) in enumerate(((0, 1), (1, 0)), start=1):
        ax = fig.add_subplot(grid[row])
        _attention_axes(ax, ours, other, index, agent, target)
        if agent == 1:
            _legend_below(fig, ax)
    fig.suptitle(title)
    return fig


def _trajectory_axes(ax: Axes, ours: Predictions, other: Predictions, index: int) -> None:
    valid = ours.valid[index]  # (T, N)
    truth = np.where(valid[..., None], ours.true_xy[index], np.nan)  # (T, N, 2)
    others = ax.plot(truth[:, 2:, 0], truth[:, 2:, 1], color="#cfcfcf", linewidth=0.8, zorder=1)
    mains = ax.plot(truth[:, :2, 0], truth[:, :2, 1], color="#6f6f6f", linewidth=1.2, zorder=2)
    for lines, label in ((mains, "truth, main cars"), (others, "truth, other cars")):
        if lines:
            lines[0].set_label(label)
    steps = ours.num_observed + np.arange(ours.pred_mean.shape[1])  # (P,)
    sizes = 4.0 + 36.0 * (steps - steps[0]) / max(len(steps) - 1, 1)  # (P,)
    for pred, variant in ((other, "s_attn"), (ours, "ours")):
        for agent, target in ((0, 1), (1, 0)):
            theta = np.nan_to_num(pred.attention[index, steps - 1, agent, target])  # (P,)
            rgba = np.tile(np.array(to_rgba(COLORS[variant])), (len(steps), 1))  # (P, 4)
            rgba[:, 3] = 0.15 + 0.85 * np.clip(theta, 0.0, 1.0)
            keep = valid[steps, agent]  # (P,)
            xy = pred.pred_mean[index, :, agent]  # (P, 2)
            ax.scatter(
                xy[keep, 0],
                xy[keep, 1],
                s=sizes[keep],
                c=rgba[keep],
                edgecolors="none",
                zorder=3,
                label=LABELS[variant] if agent == 0 else None,
            )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    # beside the axes, never over the trajectories; the dots' markers at full opacity
    handles = [h for h in ax.get_legend_handles_labels()[0] if isinstance(h, Line2D)]
    handles += [
        Line2D([], [], marker="o", linestyle="", color=COLORS[v], label=LABELS[v])
        for v in ("s_attn", "ours")
    ]
    ax.legend(
        handles=handles,
        fontsize="small",
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        borderaxespad=0.0,
    )
    ax.set_title(
        "predictions (dots; darker = more attention on the other main car, larger = "
        "later) and truth (lines)",
        fontsize="small",
    )


def _attention_axes(
    ax: Axes, ours: Predictions, other: Predictions, index: int, agent: int, target: int
) -> None:
    """Attention of `agent` on `target` over time for both variants, with the ground truth."""
    draw_attention(ax, other, index, agent, target, COLORS["s_attn"], LABELS["s_attn"])
    draw_attention(ax, ours, index, agent, target, COLORS["ours"], LABELS["ours"], context=False)
    ax.set_xlabel("time [s] (vertical line: last observed step)")
    roles = ours.roles[index]
    names = [ours.role_names[roles[k]] for k in (agent, target)]
    ax.set_title(
        f"attention of {names[0]} on {names[1]}", fontsize="small", color=role_color(names[0])
    )
