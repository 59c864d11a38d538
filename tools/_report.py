"""Statistics, tables, figures and the markdown/JSON report of tools/reproduce.py.

Numbers per (setting, variant, seed) come from each run's eval.json (`make_record`). Across
training seeds: mean and sample standard deviation (ddof = 1); comparisons use Welch's two-sided
two-sample t-test (`scipy.stats.ttest_ind(a, b, equal_var=False)`) over the per-seed values.
Cases are named by role: "major" (the frequent case of the setting) and "minor".
Figures use predictor.plots' Figure/Agg helpers (no pyplot state) and are written atomically.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import platform
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from pipeline.cli import atomic_output
from predictor.format import read_meta, read_split
from predictor.plots import (
    Predictions,
    load_predictions,
    new_figure,
    plot_samples,
    role_color,
    save_figure,
)

CASES = ("major", "minor")
METRICS = ("ade", "fde")
GROUPS = ("main_agents", "all_agents")
HEADLINE = "main_agents"
ALPHA_S_ATTN = 0.01  # the paper's threshold for Ours vs S-Attn
ALPHA = 0.05  # every other comparison
LABELS = {
    "ours": "Ours",
    "s_attn": "S-Attn",
    "nonsmooth": "Ours-NonSmooth",
    "average": "Ours-Average",
    "correct": "Ours-Correct",
    "const_vel": "Const-Vel",
}
COLORS = {
    "ours": "#ff7f0e",
    "s_attn": "#1f77b4",
    "nonsmooth": "#2ca02c",
    "average": "#9467bd",
    "correct": "#d62728",
    "const_vel": "#7f7f7f",
}
STATISTICS = (
    "mean +- sample standard deviation (ddof = 1) over training seeds; p-values: "
    "Welch's two-sided two-sample t-test, scipy.stats.ttest_ind(equal_var=False)"
)


# ---------------------------------------------------------------------------------- statistics
def make_record(setting: str, variant: str, seed: int, result: dict) -> dict:
    """Flatten an eval.json into {group: {case: {ade, fde}}, attention_accuracy: {case: acc},
    attention_weight: {case: mean weight on the labelled car}}."""
    names = {"major": result["major_case"]}
    names["minor"] = next(c for c in result["case_names"] if c != result["major_case"])
    record = {
        "setting": setting,
        "variant": variant,
        "seed": seed,
        "case_names": names,
        "train_seconds": result.get("train_seconds"),
        "best_epoch": result.get("best_epoch"),
    }
    for group in GROUPS:
        parts = {role: result[group]["cases"][name] for role, name in names.items()}
        parts["overall"] = result[group]["overall"]
        record[group] = {role: {m: part[m] for m in METRICS} for role, part in parts.items()}
    accuracy = result["attention_accuracy"]
    record["attention_accuracy"] = {
        role: accuracy["cases"][name]["accuracy"] for role, name in names.items()
    }
    record["attention_accuracy"]["overall"] = accuracy["overall"]["accuracy"]
    record["attention_weight"] = {
        role: accuracy["cases"][name].get("mean_weight") for role, name in names.items()
    }
    record["attention_weight"]["overall"] = accuracy["overall"].get("mean_weight")
    return record


def summarize(values: list[float | None]) -> dict:
    """{"mean", "std" (ddof 1; None for fewer than 2 values), "n"} of the non-missing values."""
    kept = [float(v) for v in values if v is not None and math.isfinite(v)]
    if not kept:
        return {"mean": None, "std": None, "n": 0}
    std = float(np.std(kept, ddof=1)) if len(kept) > 1 else None
    return {"mean": float(np.mean(kept)), "std": std, "n": len(kept)}


def welch_test(a: list[float], b: list[float]) -> dict:
    """Welch's two-sided t-test of a against b: {"t", "p"} (None where undefined)."""
    if len(a) < 2 or len(b) < 2:
        return {"t": None, "p": None}
    with warnings.catch_warnings():  # identical samples: scipy warns and returns NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        result = stats.ttest_ind(a, b, equal_var=False)
    t, p = float(result.statistic), float(result.pvalue)
    return {"t": t if math.isfinite(t) else None, "p": p if math.isfinite(p) else None}


def values(records: list[dict], setting: str, variant: str, key: tuple[str, ...]) -> list:
    """Per-seed values (seed order) at record[key[0]][key[1]]...; missing entries skipped."""
    found = []
    for record in sorted(records, key=lambda r: r["seed"]):
        if record["setting"] == setting and record["variant"] == variant:
            value = record
            for part in key:
                value = value[part]
            if value is not None:
                found.append(float(value))
    return found


def aggregate(records: list[dict]) -> dict:
    """{setting: {variant: {"seeds", group: {case: {metric: summary}}, attention_accuracy,
    attention_weight}}}."""
    out: dict = {}
    for setting, variant in dict.fromkeys((r["setting"], r["variant"]) for r in records):
        entry = {"seeds": sum(r["setting"] == setting and r["variant"] == variant for r in records)}
        for group in GROUPS:
            entry[group] = {
                case: {
                    m: summarize(values(records, setting, variant, (group, case, m)))
                    for m in METRICS
                }
                for case in (*CASES, "overall")
            }
        for key in ("attention_accuracy", "attention_weight"):
            entry[key] = {
                case: summarize(values(records, setting, variant, (key, case)))
                for case in (*CASES, "overall")
            }
        out.setdefault(setting, {})[variant] = entry
    return out


def compare(records: list[dict]) -> dict:
    """{setting: {"ours_vs_X": {group: {case: {metric: {t, p, mean_ours, mean_other}}}}}}."""
    out: dict = {}
    for setting in dict.fromkeys(r["setting"] for r in records):
        present = {r["variant"] for r in records if r["setting"] == setting}
        if "ours" not in present:
            continue
        for other in ("s_attn", "nonsmooth", "average", "correct"):
            if other not in present:
                continue
            table: dict = {}
            for group in GROUPS:
                for case in CASES:
                    for metric in METRICS:
                        a = values(records, setting, "ours", (group, case, metric))
                        b = values(records, setting, other, (group, case, metric))
                        cell = {
                            **welch_test(a, b),
                            "mean_ours": summarize(a)["mean"],
                            "mean_other": summarize(b)["mean"],
                        }
                        table.setdefault(group, {}).setdefault(case, {})[metric] = cell
            out.setdefault(setting, {})[f"ours_vs_{other}"] = table
    return out


@dataclass(frozen=True)
class BarInputs:
    """Heights and error bars of one grouped bar chart (groups = cases, bars = variants)."""

    variants: tuple[str, ...]
    cases: tuple[str, ...]
    means: np.ndarray  # (V, C) NaN where missing
    errors: np.ndarray  # (V, C) sample std, 0 where undefined (one seed, the baseline)


def bar_inputs(aggregates: dict, setting: str, metric: str, variants: tuple[str, ...]) -> BarInputs:
    """Bar heights for `metric` of the headline group, variants in the given order."""
    shown = tuple(v for v in variants if v in aggregates.get(setting, {}))
    means = np.full((len(shown), len(CASES)), np.nan)
    errors = np.zeros((len(shown), len(CASES)))
    for i, variant in enumerate(shown):
        for j, case in enumerate(CASES):
            summary = aggregates[setting][variant][HEADLINE][case][metric]
            if summary["mean"] is not None:
                means[i, j] = summary["mean"]
            errors[i, j] = summary["std"] or 0.0
    return BarInputs(shown, CASES, means, errors)


# ---------------------------------------------------------------------------------- claims
def better_verdict(
    mean_ours: float | None, mean_other: float | None, p: float | None, alpha: float
) -> str:
    """ "holds": ours lower and p < alpha; "not significant": lower, p >= alpha or undefined;
    "does not hold": ours not lower; "n/a": missing."""
    if mean_ours is None or mean_other is None:
        return "n/a"
    if mean_ours >= mean_other:
        return "does not hold"
    return "holds" if p is not None and p < alpha else "not significant"


def _p_text(p: float | None) -> str:
    return "p n/a" if p is None else ("p<0.001" if p < 0.001 else f"p={p:.3f}")


def claim_cell(cell: dict | None, kind: str) -> str:
    """Verdict text of one claim for one case and metric."""
    if cell is None:
        return "n/a (not run)"
    ours, other, p = cell["mean_ours"], cell["mean_other"], cell["p"]
    if kind == "comparable":
        if ours is None or other is None:
            return "n/a"
        diff = 100.0 * (ours - other) / other if other else float("nan")
        if p is not None and p < ALPHA:
            verdict = "holds (ours better)" if ours < other else "does not hold"
        else:
            verdict = "holds (no significant difference)"
        return f"{verdict} ({diff:+.0f}%, {_p_text(p)})"
    alpha = ALPHA_S_ATTN if kind == "s_attn" else ALPHA
    return f"{better_verdict(ours, other, p, alpha)} ({_p_text(p)})"


CLAIMS = (  # (other variant, kind, text)
    ("s_attn", "s_attn", f"Ours beats S-Attn with p < {ALPHA_S_ATTN}"),
    ("nonsmooth", "better", f"Ours beats Ours-NonSmooth (p < {ALPHA})"),
    ("average", "better", f"Ours beats Ours-Average (p < {ALPHA})"),
    ("correct", "comparable", "Ours is comparable to Ours-Correct (oracle)"),
)


def claims(tests: dict, aggregates: dict, settings: list, size_settings: list) -> list[dict]:
    """Rows {setting, claim, cells: {"major ade": text, ...}} of the paper-claims table."""
    rows = []
    for setting in settings:
        for other, kind, text in CLAIMS:
            table = tests.get(setting, {}).get(f"ours_vs_{other}")
            cells = {
                f"{case} {metric}": claim_cell(
                    table[HEADLINE][case][metric] if table else None, kind
                )
                for case in CASES
                for metric in METRICS
            }
            rows.append({"setting": setting, "claim": text, "cells": cells})
    rows.append(
        {
            "setting": "size study",
            "cells": size_claim(aggregates, size_settings),
            "claim": "margin Ours-NonSmooth minus Ours grows as the data shrinks",
        }
    )
    return rows


def size_margins(aggregates: dict, size_settings: list, case: str, metric: str) -> list:
    """Mean(nonsmooth) - mean(ours) per size setting (smallest first); None where missing."""
    margins = []
    for setting in size_settings:
        entry = aggregates.get(setting, {})
        if "ours" in entry and "nonsmooth" in entry:
            a = entry["nonsmooth"][HEADLINE][case][metric]["mean"]
            b = entry["ours"][HEADLINE][case][metric]["mean"]
            margins.append(None if a is None or b is None else a - b)
        else:
            margins.append(None)
    return margins


def size_claim(aggregates: dict, size_settings: list) -> dict:
    """ "holds" if the margin falls strictly from the smallest to the largest set at every
    step, "partly" if only smallest > largest, else "does not hold"."""
    cells = {}
    for case in CASES:
        for metric in METRICS:
            margins = [
                m for m in size_margins(aggregates, size_settings, case, metric) if m is not None
            ]
            if len(margins) < 2:
                cells[f"{case} {metric}"] = "n/a (needs two size settings)"
                continue
            steps = [a > b for a, b in zip(margins, margins[1:])]
            verdict = (
                "holds" if all(steps) else "partly" if margins[0] > margins[-1] else "does not hold"
            )
            text = ", ".join(f"{m:+.3f}" for m in margins)
            cells[f"{case} {metric}"] = f"{verdict} (margins {text} m, smallest set first)"
    return cells


# ---------------------------------------------------------------------------------- figures
def bar_figure(
    aggregates: dict,
    setting: str,
    variants: tuple[str, ...],
    tests: dict,
    case_names: dict,
    title: str,
):
    """ADE and FDE bars per case and variant with std error bars (the paper's Fig. 3 and 5)."""
    fig = new_figure(10.0, 3.8)
    axes = fig.subplots(1, len(METRICS))
    versus = tests.get(setting, {}).get("ours_vs_s_attn")
    for ax, metric in zip(axes, METRICS):
        bars = bar_inputs(aggregates, setting, metric, variants)
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
        ax.set_xticks(
            np.arange(len(bars.cases)), [f"{c} ({case_names.get(c, '?')})" for c in bars.cases]
        )
        ax.set_ylabel(f"{metric.upper()} [m] (main cars)")
        if versus:
            ps = ", ".join(
                f"{case} {_p_text(versus[HEADLINE][case][metric]['p'])}" for case in CASES
            )
            ax.set_title(f"{metric.upper()}; Ours vs S-Attn: {ps}", fontsize="small")
    _legend_below(fig, axes[0])
    fig.suptitle(title)
    return fig


def _legend_below(fig, ax) -> None:
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(
        handles,
        labels,
        loc="outside lower center",
        ncols=len(labels),
        fontsize="small",
        frameon=False,
    )


def series(
    aggregates: dict, settings: list, variant: str, case: str, metric: str
) -> tuple[np.ndarray, np.ndarray]:
    """Means (NaN where missing) and stds (0 where undefined) of one variant across settings."""
    summaries = [
        aggregates.get(s, {})
        .get(variant, {})
        .get(HEADLINE, {})
        .get(case, {})
        .get(metric, {"mean": None, "std": None})
        for s in settings
    ]
    mean = np.array([np.nan if v["mean"] is None else v["mean"] for v in summaries])  # (S,)
    std = np.array([v["std"] or 0.0 for v in summaries])  # (S,)
    return mean, std


def size_figure(aggregates: dict, size_settings: list, labels: list, variants: tuple[str, ...]):
    """Test error against training-set size (the paper's Fig. 4): rows metrics, columns cases."""
    fig = new_figure(10.0, 6.0)
    axes = fig.subplots(len(METRICS), len(CASES), squeeze=False)
    x = np.arange(len(size_settings))
    dodge = 0.04 * (np.arange(len(variants)) - (len(variants) - 1) / 2)  # (V,) keep bars apart
    cells = [
        (r, metric, c, case) for r, metric in enumerate(METRICS) for c, case in enumerate(CASES)
    ]
    for row, metric, column, case in cells:
        ax = axes[row, column]
        for offset, variant in zip(dodge, variants):
            mean, std = series(aggregates, size_settings, variant, case, metric)
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


def _shade(ax, interaction: np.ndarray, dt: float) -> None:
    """Shade each run of True in `interaction` (T,)."""
    padded = np.concatenate([[0], interaction.astype(np.int8), [0]])
    edges = np.flatnonzero(np.diff(padded))
    for k, (first, stop) in enumerate(zip(edges[::2], edges[1::2])):
        ax.axvspan(
            (first - 0.5) * dt,
            (stop - 0.5) * dt,
            color="#f2d7a6",
            alpha=0.6,
            zorder=0,
            label="interaction period" if k == 0 else None,
        )


def scene_figure(ours: Predictions, other: Predictions, index: int, title: str):
    """Fig. 6: predicted main-car trajectories of Ours and S-Attn (dot opacity = attention on
    the other main car, size = time) and each main car's attention on the other over time."""
    if not np.array_equal(ours.true_xy[index], other.true_xy[index]):
        raise ValueError("the two prediction files hold different scenes")
    fig = new_figure(10.0, 8.0)
    grid = fig.add_gridspec(3, 1, height_ratios=(2.0, 1.0, 1.0))
    ax = fig.add_subplot(grid[0])
    valid = ours.valid[index]  # (T, N)
    truth = np.where(valid[..., None], ours.true_xy[index], np.nan)  # (T, N, 2)
    ax.plot(truth[:, 2:, 0], truth[:, 2:, 1], color="#cfcfcf", linewidth=0.8, zorder=1)
    ax.plot(truth[:, :2, 0], truth[:, :2, 1], color="#6f6f6f", linewidth=1.2, zorder=2)
    steps = ours.num_observed + np.arange(ours.pred_mean.shape[1])  # (P,)
    sizes = 4.0 + 36.0 * (steps - steps[0]) / max(len(steps) - 1, 1)  # (P,)
    for pred, variant in ((other, "s_attn"), (ours, "ours")):
        for agent, target in ((0, 1), (1, 0)):
            theta = np.nan_to_num(pred.attention[index, steps - 1, agent, target])  # (P,)
            rgba = np.tile(np.array(_rgba(COLORS[variant])), (len(steps), 1))  # (P, 4)
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
    ax.legend(fontsize="small", loc="upper left")
    ax.set_title(
        "predictions (dots; darker = more attention on the other main car, larger = "
        "later) and truth (lines)",
        fontsize="small",
    )
    for row, (agent, target) in enumerate(((0, 1), (1, 0)), start=1):
        _attention_axes(fig.add_subplot(grid[row]), ours, other, index, agent, target)
    fig.suptitle(title)
    return fig


def _rgba(color: str) -> tuple[float, float, float, float]:
    from matplotlib.colors import to_rgba

    return to_rgba(color)


def _attention_axes(
    ax, ours: Predictions, other: Predictions, index: int, agent: int, target: int
) -> None:
    time = np.arange(ours.attention.shape[1]) * ours.dt  # (T-1,) [s]
    _shade(ax, ours.interaction[index], ours.dt)
    label = (ours.attention_label[index, :-1, agent] == target).astype(float)  # (T-1,)
    ax.step(
        time, label, where="mid", color="black", linestyle="--", linewidth=1.0, label="ground truth"
    )
    for pred, variant in ((other, "s_attn"), (ours, "ours")):
        ax.plot(
            time,
            pred.attention[index, :, agent, target],
            color=COLORS[variant],
            marker="o",
            markersize=2.5,
            label=LABELS[variant],
        )
    ax.axvline((ours.num_observed - 1) * ours.dt, color="black", linewidth=1.0)
    roles = ours.roles[index]
    names = [ours.role_names[roles[k]] for k in (agent, target)]
    ax.set_ylim(-0.05, 1.05)
    ax.set_ylabel("attention")
    ax.set_xlabel("time [s] (vertical line: last observed step)")
    ax.set_title(
        f"attention of {names[0]} on {names[1]}", fontsize="small", color=role_color(names[0])
    )
    if agent == 1:
        _legend_below(ax.figure, ax)


def save(fig, path: Path) -> None:
    """Write a figure atomically."""
    with atomic_output(path) as temp:
        save_figure(fig, temp, dpi=110)


# ---------------------------------------------------------------------------------- the report
@dataclass(frozen=True)
class ReportInput:
    """Everything the report needs from tools/reproduce.py."""

    protocol: object  # reproduce.Protocol
    records: list  # make_record dicts
    data_paths: dict  # setting -> dataset file
    scene_files: dict  # setting -> {"ours": scenes.npz, "s_attn": scenes.npz} where both exist
    command: str
    counts: dict  # datasets/runs generated, trained, resumed, reused, failed
    jobs: int
    seconds: float  # wall time of the reproduction before the report
    history: list = ()  # invocations that trained runs into the cache (reproduce.log_invocation)


def machine_info(jobs: int) -> dict:
    """Cores, CPU model (/proc/cpuinfo), torch version and threads, python, platform."""
    import torch

    model = platform.processor() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cores": os.cpu_count(),
        "cpu_model": model,
        "torch": torch.__version__,
        "torch_threads_per_job": 1,
        "jobs": jobs,
        "python": platform.python_version(),
        "platform": platform.platform(),
    }


def dataset_info(path: str) -> dict:
    """Case names and per-split, per-case trajectory counts of a dataset file."""
    meta = read_meta(path)
    minor = next(c for c in meta.case_names if c != meta.major_case)
    names = {"major": meta.major_case, "minor": minor}
    counts = {}
    for split in ("train", "val", "test"):
        case = read_split(path, split).case
        counts[split] = {
            role: int((case == meta.case_names.index(name)).sum()) for role, name in names.items()
        }
    return {"path": path, "scenario": meta.scenario, "case_names": names, "counts": counts}


def fmt(summary: dict, digits: int = 3) -> str:
    """ "mean ± std", "mean" (one value) or "n/a"."""
    if summary["mean"] is None:
        return "n/a"
    if summary["std"] is None:
        return f"{summary['mean']:.{digits}f}"
    return f"{summary['mean']:.{digits}f} ± {summary['std']:.{digits}f}"


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in rows])


def results_table(aggregates: dict, setting: str, variants: tuple, group: str, names: dict) -> str:
    """Mean ± std of ADE/FDE per case (and, for the headline group, attention accuracy and the
    mean attention weight on the labelled car)."""
    header = ["variant"] + [f"{c} ({names[c]}) {m.upper()}" for c in CASES for m in METRICS]
    if group == HEADLINE:
        header += [f"attn. {k} {c}" for k in ("acc.", "weight") for c in CASES]
    rows = []
    for variant in variants:
        entry = aggregates.get(setting, {}).get(variant)
        if entry is None:
            continue
        row = [LABELS[variant]] + [fmt(entry[group][c][m]) for c in CASES for m in METRICS]
        if group == HEADLINE:
            fixed = variant in ("average", "correct", "const_vel")  # nothing learned to score
            row += [
                "n/a" if fixed else fmt(entry[key][c], digits)
                for key, digits in (("attention_accuracy", 2), ("attention_weight", 3))
                for c in CASES
            ]
        rows.append(row + [str(entry["seeds"])])
    return table(header + ["runs"], rows)


def pvalue_table(tests: dict, setting: str) -> str:
    """p-values and mean differences of Ours against S-Attn and Ours-NonSmooth."""
    rows = []
    for other in ("s_attn", "nonsmooth"):
        cells = tests.get(setting, {}).get(f"ours_vs_{other}")
        if cells is None:
            continue
        row = [f"Ours vs {LABELS[other]}"]
        for case in CASES:
            for metric in METRICS:
                cell = cells[HEADLINE][case][metric]
                diff = (
                    None
                    if cell["mean_ours"] is None or cell["mean_other"] is None
                    else cell["mean_ours"] - cell["mean_other"]
                )
                p = "n/a" if cell["p"] is None else f"{cell['p']:.2g}"
                row.append(p + ("" if diff is None else f" (Δ {diff:+.3f} m)"))
        rows.append(row)
    if not rows:
        return "_No comparison: Ours and S-Attn/Ours-NonSmooth were not both run._"
    header = ["Welch t-test, p (Δ = Ours − other)"] + [
        f"{c} {m.upper()}" for c in CASES for m in METRICS
    ]
    return table(header, rows)


def make_figures(
    report: ReportInput, aggregates: dict, tests: dict, info: dict, size: list, out: Path
) -> dict[str, list[str]]:
    """Write every figure under `out`; returns section -> file names."""
    protocol, shown = report.protocol, {}
    for setting in protocol.settings:
        if setting.name in aggregates:
            fig = bar_figure(
                aggregates,
                setting.name,
                protocol.variants,
                tests,
                info[setting.name]["case_names"],
                setting.title,
            )
            shown.setdefault("bars", []).append(_save(fig, out, f"bars_{setting.name}.png"))
    if any(s in aggregates for s in size):
        fig = size_figure(
            aggregates, size, [f"{s}\n({size_label(info[s])})" for s in size], protocol.variants
        )
        shown["size"] = [_save(fig, out, "size_study.png")]
    main = [s.name for s in protocol.settings if s.name in report.scene_files]
    preferred = [s for s in main if s in ("dm_r0.3", "hc_stop")] or main[:1]
    for setting in preferred:
        ours, other = (load_predictions(report.scene_files[setting][v]) for v in ("ours", "s_attn"))
        for role, name in info[setting]["case_names"].items():
            rows = np.flatnonzero(ours.case == ours.case_names.index(name))
            if len(rows):
                title = (
                    f"{setting}: {role} case ({name}), first test scene with an interaction "
                    "period; Ours vs S-Attn (training seed 0)"
                )
                fig = scene_figure(ours, other, int(rows[0]), title)
                shown.setdefault("scenes", []).append(
                    _save(fig, out, f"scene_{setting}_{role}.png")
                )
    for scenario in dict.fromkeys(s.scenario for s in protocol.settings):
        path = report.data_paths[next(s.name for s in protocol.settings if s.scenario == scenario)]
        fig = plot_samples(read_split(path, "test"), read_meta(path), num_per_case=2)
        shown.setdefault("samples", []).append(_save(fig, out, f"samples_{scenario}.png"))
    return shown


def _save(fig, out: Path, name: str) -> str:
    with atomic_output(out / name) as temp:
        save_figure(fig, temp, dpi=110)
    return name


def size_label(info: dict) -> str:
    """ "minor+major" training-pool size (train + val) of a dataset."""
    total = {r: info["counts"]["train"][r] + info["counts"]["val"][r] for r in CASES}
    return f"{total['minor']}+{total['major']}"


def write_report(report: ReportInput, results: Path) -> int:
    """Write the figures, results.json and the markdown; returns the number of figures."""
    protocol = report.protocol
    aggregates, tests = aggregate(report.records), compare(report.records)
    info = {s.name: dataset_info(report.data_paths[s.name]) for s in protocol.settings}
    size = [
        s.name
        for s in sorted(
            (s for s in protocol.settings if s.group == "size"),
            key=lambda s: s.num_major + s.num_minor,
        )
    ]
    claim_rows = claims(tests, aggregates, [s.name for s in protocol.settings], size)
    out = results.parent / "results"
    out.mkdir(parents=True, exist_ok=True)
    figures = make_figures(report, aggregates, tests, info, size, out)
    context = {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "machine": machine_info(report.jobs),
    }
    document = {
        **context,
        "command": report.command,
        "wall_seconds": round(report.seconds, 1),
        "statistics": STATISTICS,
        "protocol": {
            **{k: v for k, v in asdict(protocol).items() if k != "settings"},
            "settings": [asdict(s) for s in protocol.settings],
        },
        "datasets": info,
        "counts": {k: v for k, v in report.counts.items() if k != "job_seconds"},
        "runs": report.records,
        "aggregates": aggregates,
        "tests": tests,
        "claims": claim_rows,
    }
    with atomic_output(results.with_name("results.json")) as temp:
        temp.write_text(json.dumps(document, indent=1) + "\n")
    text = render(report, context, aggregates, tests, info, size, claim_rows, figures, results)
    with atomic_output(results) as temp:
        temp.write_text(text)
    return sum(len(names) for names in figures.values())


def render(
    report: ReportInput,
    context: dict,
    aggregates: dict,
    tests: dict,
    info: dict,
    size: list,
    claim_rows: list,
    figures: dict,
    results: Path,
) -> str:
    """The markdown text."""
    protocol, counts, machine = report.protocol, report.counts, context["machine"]
    parts = [
        "# Reproduction of the paper's synthetic experiments\n",
        "Written by `tools/reproduce.py`; do not edit by hand (the discussion at the end "
        "comes from `results_notes.md` beside this file).",
    ]
    if protocol.quick:
        parts.append(
            "\n> **Quick smoke run (`--quick`)**: tiny datasets, few epochs and seeds. "
            "These numbers exercise the pipeline and say nothing about the paper."
        )
    seeds = f"training seeds 0..{protocol.seeds - 1}" if protocol.seeds > 1 else "seed 0"
    compute_h = sum(r["train_seconds"] or 0.0 for r in report.records) / 3600
    parts += [
        "\n## How this was produced\n",
        "\n".join(
            [
                f"- Command: `{report.command}`",
                f"- Date: {context['date']}",
                f"- Wall time: {report.seconds / 60:.1f} min for this invocation; "
                f"the training time recorded in all runs sums to {compute_h:.2f} h "
                "(one thread each)",
                history_line(report.history),
                f"- Machine: {machine['cores']} cores, {machine['cpu_model']}; torch "
                f"{machine['torch']}, {machine['torch_threads_per_job']} torch thread per job, "
                f"{machine['jobs']} parallel jobs; Python {machine['python']}",
                f"- Epochs: {protocol.epochs}; "
                f"seeds per trained variant: {protocol.seeds} ({seeds}); "
                f"`const_vel` once per setting (deterministic)",
                f"- Runs: {counts['runs']} ({counts['trained']} trained now, {counts['resumed']} "
                f"resumed, {counts['reused']} reused from the cache, {counts['failed']} failed); "
                f"datasets: {counts['datasets_generated']} generated, "
                f"{counts['datasets_reused']} reused",
                f"- Statistics: {STATISTICS}",
                "- Machine-readable results (per run and aggregated): "
                "`results.json` beside this file",
            ]
        ),
    ]
    if counts.get("failures"):
        parts.append(
            "\nFailed runs (diverged):\n\n"
            + "\n".join(f"- `{line}`" for line in counts["failures"])
        )
    parts += ["\n## Settings and datasets\n", settings_table(report, info), "", NOTES]
    parts.append("\n## Results (main cars: the two interacting cars)\n")
    for setting in protocol.settings:
        names = info[setting.name]["case_names"]
        parts += [
            f"\n### `{setting.name}`: {setting.title}\n",
            results_table(aggregates, setting.name, protocol.variants, HEADLINE, names),
            "",
            pvalue_table(tests, setting.name),
            "",
            "<details><summary>All agents (22 cars)</summary>\n",
            results_table(aggregates, setting.name, protocol.variants, "all_agents", names),
            "\n</details>",
        ]
        if f"bars_{setting.name}.png" in figures.get("bars", []):
            parts.append(f"\n![ADE/FDE {setting.name}](results/bars_{setting.name}.png)")
    parts += [
        "\n## Training-set size study (Double Merge, Fig. 4)\n",
        size_section(aggregates, size, info, figures),
    ]
    parts += [
        "\n## Paper claims\n",
        CLAIM_RULES,
        "",
        table(
            ["setting", "claim"] + [f"{c} {m.upper()}" for c in CASES for m in METRICS],
            [[f"`{r['setting']}`", r["claim"], *r["cells"].values()] for r in claim_rows],
        ),
    ]
    parts.append("\n## Trajectories and attention (Fig. 6)\n")
    parts += [f"![scene](results/{name})\n" for name in figures.get("scenes", [])] or [
        "_Needs Ours and S-Attn (seed 0) of at least one setting._"
    ]
    parts.append("\n## Sample trajectories (test split, ground-truth experts)\n")
    parts += [f"![samples](results/{name})\n" for name in figures.get("samples", [])]
    notes = results.with_name("results_notes.md")
    parts += [
        "\n## Discussion\n",
        notes.read_text().rstrip()
        if notes.is_file()
        else f"_No `{notes.name}` yet: the lead writes it after looking at the results._",
    ]
    return "\n".join(parts) + "\n"


NOTES = """Notes on the protocol:
- One dataset per setting, generated with dataset seed 0; all variants and training seeds see
  the same trajectories, so the spread over seeds is training randomness only (initial weights,
  batch order, rollout samples), not data sampling.
- The size study uses the paper's explicit counts (minor + major) 3+10, 15+30 and 30+100; note
  that 15/30 = 0.5, not the 0.3 ratio the paper's text mentions (3/10 and 30/100 are 0.3).
- Every trained run is evaluated from its `best.pt` (lowest validation ADE of the main cars) on
  the test split, predicting from the observed steps and feeding back the predicted means.
- Attention accuracy: over the fed-back prediction steps inside the interaction period, the
  share of (step, main car) pairs where the labelled car has strictly the largest attention
  weight of the main car; attention weight: the mean weight on the labelled car over the same
  pairs (uniform attention over the 21 other cars gives 1/21 = 0.048). Neither is shown for
  Ours-Average and Ours-Correct, whose attention is fixed (by construction accuracy 0 and
  weight 1/21 for Average, 1 and 1 for Correct); the raw numbers are in `results.json`."""

CLAIM_RULES = (
    f"Rules: **holds** = Ours has the lower mean and p < alpha (alpha = "
    f"{ALPHA_S_ATTN} against S-Attn, as in the paper; {ALPHA} otherwise); **not "
    "significant** = lower mean, p >= alpha; **does not hold** = Ours' mean is not "
    f"lower. For Ours-Correct: **holds** unless Correct is better with p < {ALPHA} "
    "(difference relative to Correct). Size study: the mean margin NonSmooth − Ours "
    "should fall from the smallest to the largest training set (**partly**: only "
    "smallest > largest)."
)


def history_line(history) -> str:
    """Markdown bullet of the invocations that trained runs into the cache (wall time)."""
    if not history:
        return "- Training invocations logged in the cache: none"
    total = sum(entry["seconds"] for entry in history) / 60
    items = "; ".join(
        f"{entry['date']}: {entry['seconds'] / 60:.1f} min, "
        f"{entry['runs']} runs, `{entry['command']}`"
        for entry in history
    )
    return (
        f"- Training invocations logged in the cache: {len(history)}, {total:.1f} min wall "
        f"in all ({items})"
    )


def settings_table(report: ReportInput, info: dict) -> str:
    rows = []
    for setting in report.protocol.settings:
        data = info[setting.name]
        counts, names = data["counts"], data["case_names"]
        times = [
            r["train_seconds"]
            for r in report.records
            if r["setting"] == setting.name and r["variant"] != "const_vel" and r["train_seconds"]
        ]
        median = f"{float(np.median(times)) / 60:.1f}" if times else "n/a"
        rows.append(
            [
                f"`{setting.name}`",
                data["scenario"],
                names["major"],
                names["minor"],
                *(f"{counts[s]['minor']}+{counts[s]['major']}" for s in counts),
                median,
                f"`{Path(data['path']).name}`",
            ]
        )
    return table(
        [
            "setting",
            "scenario",
            "major case",
            "minor case",
            "train (minor+major)",
            "val",
            "test",
            "median train min/run",
            "dataset",
        ],
        rows,
    )


def size_section(aggregates: dict, size: list, info: dict, figures: dict) -> str:
    if not any(s in aggregates for s in size):
        return "_No size-study setting was run._"
    rows = []
    for k, setting in enumerate(size):
        cells = [size_margins(aggregates, size, c, m)[k] for c in CASES for m in METRICS]
        rows.append(
            [
                f"`{setting}`",
                size_label(info[setting]),
                *("n/a" if v is None else f"{v:+.3f}" for v in cells),
            ]
        )
    text = table(
        ["setting", "minor+major"]
        + [f"NonSmooth − Ours {c} {m.upper()} [m]" for c in CASES for m in METRICS],
        rows,
    )
    if "size" in figures:
        text += "\n\n![size study](results/size_study.png)"
    return text
