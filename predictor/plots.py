"""Figures in the paper's style: trajectories as dots growing with time, attention over time.

Figures are built on `matplotlib.figure.Figure` with the Agg canvas, never through pyplot, so no
global figure state is created or leaked. Main cars are coloured by role ("main_green" green,
"main_brown" brown, other main roles from a fixed palette), every other role grey.

Every figure explains itself: titles, axis labels with units, and a legend of everything drawn,
placed outside the axes (below the figure), so it never covers the data. Sample trajectories
come with each main agent's speed over time beside them, and a stop (speed under
`STOP_SPEED_MPS`) is marked on both: a stop shows as dots piling up in the path, which the eye
misses, but as a curve at zero in the speed (the Halting Car leader's stop is its case).
"""

from __future__ import annotations

import math
import os

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from predictor.predictions import Predictions
from trajectory_data.format import DatasetMeta, TrajectorySet

ROAD_COLOR = "#ececec"  # axes background: the road area
TRUE_COLOR = "#8c8c8c"  # ground-truth lines
DISTRACTOR_COLOR = "#a6a6a6"
_NAMED_COLORS = {
    "green": "#2ca02c",
    "brown": "#8c564b",
    "blue": "#1f77b4",
    "red": "#d62728",
    "orange": "#ff7f0e",
    "purple": "#9467bd",
}
_PALETTE = ("#1f77b4", "#d62728", "#ff7f0e", "#9467bd", "#17becf")
MIN_DPI, MAX_DPI = 10, 1200  # resolution accepted by save_figure [dots per inch]
MAX_PIXELS = 100_000_000  # largest canvas save_figure renders (~400 MB of RGBA)
MAX_SAMPLES_PER_CASE = 20  # plot_samples rows
_MIN_DOT, _MAX_DOT = 3.0, 40.0  # scatter marker areas [pt^2] at the first and last step
STOP_SPEED_MPS = 0.5  # below this speed an agent counts as stopped (plot_samples marks it)
STOP_COLOR = "#d62728"
STOP_MARKER = dict(marker="8", s=110.0, facecolors="none", edgecolors=STOP_COLOR, linewidths=1.6)


class PlotInputError(ValueError):
    """Input for a plot is missing or inconsistent; the message is one line."""


def role_color(name: str, index: int = 0) -> str:
    """Colour of a role: a colour named in it ("main_green"), a palette colour for other main
    roles (by `index`), grey for anything else (distractors)."""
    for word, color in _NAMED_COLORS.items():
        if word in name:
            return color
    if name.startswith("main"):
        return _PALETTE[index % len(_PALETTE)]
    return DISTRACTOR_COLOR


def _is_main(name: str) -> bool:
    return role_color(name) != DISTRACTOR_COLOR


def _dot_sizes(steps: np.ndarray, num_steps: int) -> np.ndarray:
    """Marker areas growing linearly with the time step."""
    return _MIN_DOT + (_MAX_DOT - _MIN_DOT) * steps / max(num_steps - 1, 1)


def _draw_dots(
    ax: Axes,
    xy: np.ndarray,
    mask: np.ndarray,
    steps: np.ndarray,
    roles: np.ndarray,
    role_names: tuple[str, ...],
    num_steps: int,
) -> None:
    """Scatter positions `xy` (T', N, 2) where `mask` (T', N); `steps` (T',) are the time steps.

    One scatter call per role; distractors below main cars.
    """
    order = sorted(set(roles.tolist()), key=lambda r: _is_main(role_names[r]))
    for role in order:
        name = role_names[role]
        select = mask & (roles == role)[None, :]  # (T', N)
        step_index = np.broadcast_to(steps[:, None], select.shape)[select]
        ax.scatter(
            xy[select][:, 0],
            xy[select][:, 1],
            s=_dot_sizes(step_index, num_steps),
            color=role_color(name, role),
            edgecolors="none",
            alpha=0.9 if _is_main(name) else 0.6,
            zorder=3 if _is_main(name) else 2,
        )


def _style_road_axes(ax: Axes, xlabel: bool = True, ylabel: bool = True) -> None:
    ax.set_facecolor(ROAD_COLOR)
    ax.set_aspect("equal", adjustable="datalim")
    if xlabel:
        ax.set_xlabel("x [m]")
    if ylabel:
        ax.set_ylabel("y [m]")


def _role_handles(role_names: tuple[str, ...], what: str = "") -> list[Line2D]:
    """Legend handles of the roles' dots ("main_green" + `what`, e.g. " (predicted)")."""
    return [
        Line2D([], [], marker="o", linestyle="", color=role_color(name, i), label=name + what)
        for i, name in enumerate(role_names)
    ]


def legend_below(fig: Figure, handles: list, columns: int = 6) -> None:
    """The figure's legend, below all axes (outside them: it never covers data)."""
    fig.legend(
        handles=handles,
        loc="outside lower center",
        ncols=max(1, min(len(handles), columns)),
        fontsize="small",
        frameon=False,
    )


def new_figure(width: float, height: float) -> Figure:
    """A Figure with an Agg canvas attached (no pyplot)."""
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: str | os.PathLike, dpi: int = 120) -> None:
    """Write the figure; the format follows the file suffix (e.g. .png, .pdf, .svg).

    Raises PlotInputError if `dpi` is outside [MIN_DPI, MAX_DPI] or the canvas would exceed
    MAX_PIXELS (the renderer would otherwise run out of memory).
    """
    if not MIN_DPI <= dpi <= MAX_DPI:
        raise PlotInputError(f"dpi must be in [{MIN_DPI}, {MAX_DPI}], got {dpi}")
    width, height = (math.ceil(inches * dpi) for inches in fig.get_size_inches())
    if width * height > MAX_PIXELS:
        raise PlotInputError(
            f"the figure would be {width} x {height} pixels at dpi {dpi}, more than the limit of "
            f"{MAX_PIXELS // 10**6} million; lower the dpi"
        )
    fig.savefig(path, dpi=dpi)


# ---------------------------------------------------------------------------------------------
# Sample trajectories from a dataset


def speeds(xy: np.ndarray, valid: np.ndarray, dt: float) -> np.ndarray:
    """Speed [m/s] of each agent at each step from consecutive positions: (T, N) from xy
    (T, N, 2) and valid (T, N), NaN where the agent or its previous step is missing (step 0)."""
    out = np.full(valid.shape, np.nan)
    moved = np.linalg.norm(np.diff(xy.astype(np.float64), axis=0), axis=-1) / dt  # (T-1, N)
    both = valid[1:] & valid[:-1]
    out[1:][both] = moved[both]
    return out


def stop_starts(speed: np.ndarray) -> np.ndarray:
    """Steps where a stop begins: speed (T,) under STOP_SPEED_MPS after a step that was not."""
    stopped = np.nan_to_num(speed, nan=np.inf) < STOP_SPEED_MPS
    return np.array([first for first, _ in _runs(stopped)], dtype=int)


def _shown_agents(roles: np.ndarray, focal: np.ndarray, role_names: tuple[str, ...]) -> list:
    """The agents whose speed plot_samples draws: the main cars, else the focal agents."""
    main = [k for k, role in enumerate(roles) if _is_main(role_names[role])]
    return main or [int(k) for k in np.flatnonzero(focal)][: len(_PALETTE)]


def _draw_speeds(
    path_ax: Axes, speed_ax: Axes, xy, valid, roles, focal, meta: DatasetMeta, last_row: bool
) -> bool:
    """Speed over time of the shown agents of one scene into `speed_ax`, with the stops marked
    there and at their positions in `path_ax`; returns whether any stop was marked."""
    speed = speeds(xy, valid, meta.dt)  # (T, N)
    time = np.arange(speed.shape[0]) * meta.dt
    stopped = False
    for agent in _shown_agents(roles, focal, meta.role_names):
        color = role_color(meta.role_names[roles[agent]], roles[agent])
        speed_ax.plot(time, speed[:, agent], color=color, linewidth=1.4)
        starts = stop_starts(speed[:, agent])
        if len(starts):
            stopped = True
            speed_ax.scatter(time[starts], speed[starts, agent], zorder=4, **STOP_MARKER)
            path_ax.scatter(xy[starts, agent, 0], xy[starts, agent, 1], zorder=5, **STOP_MARKER)
    speed_ax.axvline((meta.num_observed - 1) * meta.dt, color="black", linestyle=":", linewidth=1)
    speed_ax.set_ylim(bottom=0.0)
    speed_ax.set_ylabel("speed [m/s]")
    if last_row:
        speed_ax.set_xlabel("time [s]")
    return stopped


def plot_samples(data: TrajectorySet, meta: DatasetMeta, num_per_case: int = 4) -> Figure:
    """One column pair per case, the first `num_per_case` trajectories of that case as rows:
    the paths (dots growing with time) and beside them the main agents' speed over time, with
    every stop (speed under STOP_SPEED_MPS) marked in both."""
    if not 1 <= num_per_case <= MAX_SAMPLES_PER_CASE:
        raise PlotInputError(
            f"num_per_case must be in [1, {MAX_SAMPLES_PER_CASE}], got {num_per_case}"
        )
    if data.n == 0:
        raise PlotInputError("the split has no trajectories to plot")
    cases = list(meta.case_names)
    rows = num_per_case
    fig = new_figure(9.0 * len(cases), 1.9 * rows + 1.2)
    grid = fig.add_gridspec(rows, 2 * len(cases), width_ratios=[2.0, 1.0] * len(cases))
    steps = np.arange(data.num_steps)
    any_stop = False
    for column, case_name in enumerate(cases):
        picked = np.flatnonzero(data.case == column)[:rows]
        for row in range(rows):
            ax = fig.add_subplot(grid[row, 2 * column])
            speed_ax = fig.add_subplot(grid[row, 2 * column + 1])
            if row >= len(picked):
                ax.set_axis_off()
                speed_ax.set_axis_off()
                if row == 0:
                    ax.set_title(f"{case_name}: no trajectories")
                continue
            i = picked[row]
            _draw_dots(
                ax,
                data.states[i, :, :, :2],
                data.valid[i],
                steps,
                data.roles[i],
                meta.role_names,
                data.num_steps,
            )
            last = row == len(picked) - 1
            any_stop |= _draw_speeds(
                ax,
                speed_ax,
                data.states[i, :, :, :2],
                data.valid[i],
                data.roles[i],
                data.focal[i],
                meta,
                last,
            )
            _style_road_axes(ax, xlabel=last, ylabel=column == 0)
            ax.set_title(f"{case_name}, seed {int(data.seed[i])}: paths", fontsize="small")
            speed_ax.set_title("speed of the main agents", fontsize="small")
    fig.suptitle(
        f"{meta.scenario}: sample trajectories (dot size grows with time, dt = {meta.dt:g} s)"
    )
    handles = _role_handles(meta.role_names)
    handles.append(
        Line2D([], [], color="black", linestyle=":", label="last observed step (speed plots)")
    )
    if any_stop:
        handles.append(
            Line2D(
                [],
                [],
                linestyle="",
                marker="8",
                markersize=9,
                markerfacecolor="none",
                markeredgecolor=STOP_COLOR,
                label=f"stops (speed < {STOP_SPEED_MPS:g} m/s)",
            )
        )
    legend_below(fig, handles)
    return fig


# ---------------------------------------------------------------------------------------------
# Predictions (predictor.predictions; written by tools/evaluate.py)


def _check_index(pred: Predictions, index: int) -> None:
    if not 0 <= index < pred.n:
        raise PlotInputError(f"scene index {index} out of range: the file has {pred.n} scenes")


def _scene_name(pred: Predictions, index: int) -> str:
    """E.g. "test scene 7 (late)": the scene's row in its split and its case."""
    return f"{pred.split} scene {int(pred.scene[index])} ({pred.case_names[int(pred.case[index])]})"


def plot_predictions(pred: Predictions, index: int) -> Figure:
    """True trajectories of scene `index` as grey lines, predicted means as dots sized by time,
    and the sampled futures (if the predictions hold any) as thin lines in the agents' colours."""
    _check_index(pred, index)
    pred_steps = pred.num_observed + np.arange(pred.pred_mean.shape[1])  # (T_pred,)
    present = pred.valid[index][pred_steps]  # (T_pred, N)
    finite = np.isfinite(pred.pred_mean[index]).all(axis=-1)  # (T_pred, N)
    not_finite = int((present & ~finite).sum())
    if present.any() and not_finite == int(present.sum()):
        raise PlotInputError(
            f"no predicted position of {_scene_name(pred, index)} is finite (NaN or inf: "
            "did the model diverge?); nothing to draw"
        )
    true_xy = np.where(pred.valid[index][..., None], pred.true_xy[index], np.nan)  # (T, N, 2)
    steps = true_xy.shape[0]
    fig = new_figure(10.0, 3.6)
    ax = fig.subplots()
    ax.plot(true_xy[:, :, 0], true_xy[:, :, 1], color=TRUE_COLOR, linewidth=1.0, zorder=1)
    ax.plot(
        true_xy[pred.num_observed - 1, :, 0],
        true_xy[pred.num_observed - 1, :, 1],
        "|",
        color="black",
        markersize=8,
        zorder=4,
    )
    drawn_samples = _draw_samples(ax, pred, index)
    _draw_dots(
        ax,
        pred.pred_mean[index],
        present & finite,
        pred_steps,
        pred.roles[index],
        pred.role_names,
        steps,
    )
    _style_road_axes(ax)
    missing = f"; {not_finite} predicted points not finite, not drawn" if not_finite else ""
    sampled = f", {pred.num_samples} sampled futures (thin lines)" if drawn_samples else ""
    ax.set_title(
        f"{_scene_name(pred, index)}: predicted means (dots, size grows "
        f"with time){sampled} vs truth (grey lines){missing}",
        fontsize="small",
    )
    handles = _role_handles(pred.role_names, " (predicted)")
    handles += [
        Line2D([], [], color=TRUE_COLOR, linewidth=1.0, label="true trajectories"),
        Line2D([], [], color="black", marker="|", linestyle="", label="last observed position"),
    ]
    legend_below(fig, handles)
    return fig


def _draw_samples(ax: Axes, pred: Predictions, index: int) -> bool:
    """Each predicted agent's sampled futures of scene `index`, from its last observed position,
    as thin translucent lines of its role's colour (under the means); False if none."""
    if not pred.num_samples:
        return False
    last = pred.num_observed - 1
    predicted = pred.valid[index, last]  # (N,) agents predicted
    start = pred.true_xy[index, last]  # (N, 2)
    drawn = False
    for agent in np.flatnonzero(predicted):
        paths = pred.samples[index, :, :, agent]  # (K, T_pred, 2)
        paths = np.concatenate([np.broadcast_to(start[agent], (len(paths), 1, 2)), paths], 1)
        finite = np.isfinite(paths).all(axis=(1, 2))
        if not finite.any():
            continue
        name = pred.role_names[pred.roles[index, agent]]
        color = role_color(name, int(pred.roles[index, agent]))
        ax.plot(
            paths[finite, :, 0].T,
            paths[finite, :, 1].T,
            color=color,
            linewidth=0.6,
            alpha=0.25,
            zorder=2,
        )
        drawn = True
    return drawn


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) indices of each run of True values in a 1-D boolean array."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def draw_attention(
    ax: Axes,
    pred: Predictions,
    index: int,
    agent: int,
    target: int,
    color: str | None = None,
    label: str | None = None,
    context: bool = True,
) -> None:
    """Draw the attention of `agent` on `target` over time in scene `index` into `ax`.

    attention[t] is computed at step t (time t*dt) to predict step t+1. With `context`, also the
    interaction period (shaded), the ground-truth label (dashed: 1 where `agent` attends to
    `target`), the last observed step (vertical line) and the axis limits and labels; without,
    only the curve, to overlay another model's attention in the same scene. The curve's colour
    and label default to the target's role.
    """
    theta = pred.attention[index, :, agent, target]  # (T-1,)
    time = np.arange(theta.shape[0]) * pred.dt  # (T-1,) [s]
    if context:
        for k, (first, last) in enumerate(_runs(pred.interaction[index])):
            ax.axvspan(
                (first - 0.5) * pred.dt,
                (last + 0.5) * pred.dt,
                color="#f2d7a6",
                alpha=0.6,
                zorder=0,
                label="interaction period" if k == 0 else None,
            )
        label_on = (pred.attention_label[index, :-1, agent] == target).astype(float)  # (T-1,)
        ax.step(
            time,
            label_on,
            where="mid",
            color="black",
            linestyle="--",
            linewidth=1.0,
            label="true label (1: attends to it)",
            zorder=2,
        )
    roles = pred.roles[index]
    target_role = pred.role_names[roles[target]]
    ax.plot(
        time,
        theta,
        marker="o",
        markersize=3,
        color=color or role_color(target_role, roles[target]),
        label=label or f"attention on agent {target} ({target_role})",
        zorder=3,
    )
    if context:
        ax.axvline(
            (pred.num_observed - 1) * pred.dt,
            color="black",
            linewidth=1.0,
            label="last observed step",
        )
        ax.set_xlim(-0.5 * pred.dt, (theta.shape[0] - 0.5) * pred.dt)
        ax.set_ylim(-0.05, 1.05)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("attention")


def plot_attention(pred: Predictions, index: int, agent: int, target: int) -> Figure:
    """Attention of `agent` on `target` over time in scene `index` (the paper's Fig. 6).

    See `draw_attention`; after the last observed step the model runs on its own predictions.
    """
    _check_index(pred, index)
    agents = pred.valid.shape[2]
    for name, value in (("agent", agent), ("target", target)):
        if not 0 <= value < agents:
            raise PlotInputError(f"{name} {value} out of range: the scenes have {agents} agents")
    if agent == target:
        raise PlotInputError("agent and target must differ")
    if not np.isfinite(pred.attention[index, :, agent, target]).any():
        raise PlotInputError(
            "the predictions file has no attention for this scene (NaN), e.g. "
            "from a model without attention such as const_vel"
        )
    fig = new_figure(8.0, 3.2)
    ax = fig.subplots()
    draw_attention(ax, pred, index, agent, target)
    roles = pred.roles[index]
    agent_role = pred.role_names[roles[agent]]
    ax.set_title(
        f"{_scene_name(pred, index)}: attention of agent {agent} ({agent_role}) on agent {target}",
        fontsize="small",
    )
    handles, _ = ax.get_legend_handles_labels()
    legend_below(fig, handles, columns=4)
    return fig
