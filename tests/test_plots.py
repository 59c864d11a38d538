"""Tests for predictor.plots and tools/plot.py: figures built, files written, bad input refused."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    REPO_ROOT,
    load_tool,
    make_meta,
    make_predictions,
    make_trajectory_set,
    run_tool,
    tool_env,
    write_predictions_npz,
)
from matplotlib.colors import to_hex
from matplotlib.image import imread

from predictor.plots import (
    DISTRACTOR_COLOR,
    MAX_PIXELS,
    PlotInputError,
    _runs,
    new_figure,
    plot_attention,
    plot_predictions,
    plot_samples,
    role_color,
    save_figure,
)


def _run_plot(*args: object) -> subprocess.CompletedProcess:
    return run_tool("plot.py", *args)


def _assert_usage_error(result: subprocess.CompletedProcess, fragment: str) -> None:
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert fragment in lines[0]


def _assert_png(path: Path) -> None:
    image = imread(path)
    assert image.ndim == 3 and image.shape[0] > 50 and image.shape[1] > 50
    assert image.std() > 0  # not a blank canvas


# ---------------------------------------------------------------------------------------------
# Library


def test_role_colors() -> None:
    assert role_color("main_green") == "#2ca02c"
    assert role_color("main_brown") == "#8c564b"
    assert role_color("distractor") == DISTRACTOR_COLOR
    assert role_color("main_leader", 0) != role_color("main_leader", 1)  # palette by index


def test_runs_of_true_values() -> None:
    mask = np.array([0, 1, 1, 0, 0, 1, 0, 1, 1, 1], dtype=bool)
    assert _runs(mask) == [(1, 2), (5, 5), (7, 9)]
    assert _runs(np.zeros(4, bool)) == []


def test_samples_dots_grow_with_time() -> None:
    meta = make_meta()
    data = make_trajectory_set(5, meta.num_steps)
    fig = plot_samples(data, meta, num_per_case=2)
    axes = [ax for ax in fig.axes if ax.get_xlabel() != "time [s]" and ax.collections]
    assert len(axes) == 4  # 2 cases x 2 scenes (and beside each its speed plot)
    green = [c for c in axes[0].collections if to_hex(c.get_facecolor()[0]) == "#2ca02c"]
    assert len(green) == 1
    sizes = green[0].get_sizes()  # agent 0 is valid at every step: sizes from 3 to 40 pt^2
    np.testing.assert_allclose(sizes, np.linspace(3.0, 40.0, meta.num_steps))
    np.testing.assert_allclose(green[0].get_offsets(), data.states[0, :, 0, :2])


def assert_legends_clear_of_the_axes(fig) -> None:
    """The figure has a legend, every legend lies inside the figure, and none overlaps an axes
    box (the plotting area, which holds all the data)."""
    from matplotlib.transforms import Bbox

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend())]
    assert legends and all(legend.get_texts() for legend in legends)
    boxes = [ax.get_window_extent(renderer) for ax in fig.axes if ax.axison]
    assert boxes
    for legend in legends:
        box = legend.get_window_extent(renderer)
        assert fig.bbox.padded(1.0).contains(box.x0, box.y0)
        assert fig.bbox.padded(1.0).contains(box.x1, box.y1)
        for axes_box in boxes:
            overlap = Bbox.intersection(box, axes_box)
            assert overlap is None or overlap.width * overlap.height == 0, (box, axes_box)


def _labelled(fig) -> None:
    """Every visible axes has a title, and the figure labels its x and y axes (axes in a grid
    share the labels of the outer row and column)."""
    shown = [ax for ax in fig.axes if ax.axison]
    assert all(ax.get_title() for ax in shown)
    assert any(ax.get_xlabel() for ax in shown) and any(ax.get_ylabel() for ax in shown)


@pytest.mark.parametrize("figure", ["samples", "predictions", "attention"])
def test_every_figure_explains_itself_beside_the_data(figure: str) -> None:
    pred = make_predictions(n=3)
    if figure == "samples":
        meta = make_meta()
        fig = plot_samples(make_trajectory_set(5, meta.num_steps), meta, num_per_case=2)
    elif figure == "predictions":
        fig = plot_predictions(pred, 1)
    else:
        fig = plot_attention(pred, 1, agent=0, target=1)
    assert_legends_clear_of_the_axes(fig)
    _labelled(fig)
    texts = [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    wanted = {
        "samples": ["main_green", "last observed step (speed plots)"],
        "predictions": ["main_green (predicted)", "true trajectories", "last observed position"],
        "attention": ["interaction period", "true label (1: attends to it)", "last observed step"],
    }[figure]
    assert set(wanted) <= set(texts), texts


def _stopping_set(stop_at: int):
    """Two scenes of make_trajectory_set where main agent 0 of scene 0 moves at 10 m/s along x
    up to step `stop_at` and stands there from then on: its speed, from the step before, is 0
    from step stop_at + 1 (scene 1, the other case, never stops)."""
    meta = make_meta()
    data = make_trajectory_set(2, meta.num_steps)
    x = 5.0 + 10.0 * meta.dt * np.minimum(np.arange(meta.num_steps), stop_at)
    data.states[0, :, 0, 0] = x
    data.states[0, :, 0, 1] = 0.0
    return data, meta


def stop_marks(ax) -> list:
    """The axes' scatter collections drawn with the stop marker's red edge."""
    from matplotlib.colors import to_rgba

    from predictor.plots import STOP_COLOR

    red = np.array(to_rgba(STOP_COLOR))
    return [
        c
        for c in ax.collections
        if len(c.get_edgecolor()) and np.allclose(c.get_edgecolor(), red[None, :])
    ]


def test_samples_show_the_speed_and_mark_a_stop() -> None:
    stop_at = 6
    data, meta = _stopping_set(stop_at)
    fig = plot_samples(data, meta, num_per_case=1)
    path_ax, speed_ax = fig.axes[0], fig.axes[1]  # scene 0 (case "major") and its speed
    assert speed_ax.get_ylabel() == "speed [m/s]" and speed_ax.get_xlabel() == "time [s]"
    green = next(line for line in speed_ax.get_lines() if line.get_color() == "#2ca02c")
    expected = np.where(np.arange(meta.num_steps) <= stop_at, 10.0, 0.0)
    expected[0] = np.nan  # no previous step
    np.testing.assert_allclose(green.get_ydata(), expected, atol=1e-4)
    (mark,) = stop_marks(path_ax)  # one stop: where agent 0 stands
    np.testing.assert_allclose(mark.get_offsets(), [data.states[0, stop_at, 0, :2]])
    (mark,) = stop_marks(speed_ax)
    np.testing.assert_allclose(mark.get_offsets(), [[(stop_at + 1) * meta.dt, 0.0]], atol=1e-4)
    assert stop_marks(fig.axes[2]) == [] and stop_marks(fig.axes[3]) == []  # never stops
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "stops (speed < 0.5 m/s)" in texts
    moving = plot_samples(make_trajectory_set(2, meta.num_steps), meta, num_per_case=1)
    assert "stops (speed < 0.5 m/s)" not in [t.get_text() for t in moving.legends[0].get_texts()]


def test_halting_car_samples_show_the_leaders_stop_in_the_stop_case(tmp_path: Path) -> None:
    """On generated Halting Car v3 data: every `stop` scene marks the leader's (brown) stop
    where its recorded speed first falls under 0.5 m/s; no `go` scene marks one."""
    from pipeline.generation import GenerateConfig, generate_dataset
    from trajectory_data.reader import read_meta, read_split

    path = tmp_path / "hc.h5"
    config = GenerateConfig.for_scenario("halting_car_v3", num_major=2, num_minor=1, num_test=2)
    generate_dataset(config, path, progress=False)
    meta, test = read_meta(path), read_split(path, "test")
    fig = plot_samples(test, meta, num_per_case=2)
    leader = meta.role_names.index("main_brown")
    for column, case in enumerate(meta.case_names):
        for row, scene in enumerate(np.flatnonzero(test.case == column)[:2]):
            path_ax = fig.axes[4 * column + 2 * row]  # per case and row: paths, then speed
            marks = stop_marks(path_ax)
            agent = int(np.flatnonzero(test.roles[scene] == leader)[0])
            recorded = test.states[scene, :, agent, 3]  # the leader's recorded speed
            if case == "stop":
                first = int(np.argmax(recorded < 0.5))
                assert recorded.min() < 0.5
                points = np.concatenate([m.get_offsets() for m in marks])
                xy = test.states[scene, :, agent, :2]
                assert min(np.linalg.norm(points - xy[first], axis=1)) < 1.0  # within a metre
            else:
                assert recorded.min() > 0.5 and marks == []


def test_samples_rejects_empty_split_and_bad_count() -> None:
    meta = make_meta()
    with pytest.raises(PlotInputError, match="no trajectories"):
        plot_samples(make_trajectory_set(0, meta.num_steps), meta)
    with pytest.raises(PlotInputError, match="num_per_case"):
        plot_samples(make_trajectory_set(2, meta.num_steps), meta, num_per_case=0)
    with pytest.raises(PlotInputError, match=r"num_per_case must be in \[1, 20\]"):
        plot_samples(make_trajectory_set(2, meta.num_steps), meta, num_per_case=21)


def test_save_figure_bounds_dpi_and_pixels(tmp_path: Path) -> None:
    fig = new_figure(10.0, 10.0)
    for dpi in (9, 1201, 100_000):
        with pytest.raises(PlotInputError, match=r"dpi must be in \[10, 1200\]"):
            save_figure(fig, tmp_path / "x.png", dpi=dpi)
    side = int((MAX_PIXELS**0.5) / 1000) + 1  # inches: just over the budget at 1000 dpi
    with pytest.raises(PlotInputError, match="pixels at dpi 1000"):
        save_figure(new_figure(side, side), tmp_path / "x.png", dpi=1000)
    assert not list(tmp_path.iterdir())
    save_figure(new_figure(2.0, 1.0), tmp_path / "small.png", dpi=50)
    assert imread(tmp_path / "small.png").shape[:2] == (50, 100)


def test_prediction_and_attention_figures() -> None:
    pred = make_predictions(n=3)
    assert pred.n == 3 and pred.case_names == ("major", "minor")
    fig = plot_predictions(pred, 1)
    assert len(fig.axes[0].collections) >= 2  # predicted dots per role
    assert fig.axes[0].get_title().startswith("test scene 1 (minor)")
    subset = pred.select([2, 1])
    assert plot_predictions(subset, 0).axes[0].get_title().startswith("test scene 2 (major)")
    fig = plot_attention(pred, 2, agent=0, target=1)
    line = next(x for x in fig.axes[0].get_lines() if x.get_label().startswith("attention on"))
    np.testing.assert_allclose(line.get_ydata(), pred.attention[2, :, 0, 1])
    np.testing.assert_allclose(line.get_xdata(), np.arange(pred.attention.shape[1]) * 0.1)
    with pytest.raises(PlotInputError, match="out of range"):
        plot_attention(pred, 3, agent=0, target=1)
    with pytest.raises(PlotInputError, match="target 4 out of range"):
        plot_attention(pred, 0, agent=0, target=4)


def test_prediction_figure_counts_or_refuses_non_finite_predictions() -> None:
    pred = make_predictions(n=2)
    pred_steps = pred.num_observed + np.arange(pred.pred_mean.shape[1])
    present = pred.valid[0][pred_steps]
    assert present.sum() > 2
    drawn = plot_predictions(pred, 0).axes[0]
    assert "not finite" not in drawn.get_title()
    first, second = np.argwhere(present)[:2]
    pred.pred_mean[0, first[0], first[1]] = np.nan
    pred.pred_mean[0, second[0], second[1], 1] = np.inf
    title = plot_predictions(pred, 0).axes[0].get_title()
    assert title.endswith("; 2 predicted points not finite, not drawn")
    pred.pred_mean[0] = np.nan
    with pytest.raises(PlotInputError, match="no predicted position of test scene 0 .* is finite"):
        plot_predictions(pred, 0)
    plot_predictions(pred, 1)  # the other scene still draws


def test_plots_do_not_touch_pyplot() -> None:
    code = (
        "import sys; sys.path.insert(0, 'tests'); import conftest\n"
        "from predictor.plots import plot_samples\n"
        "meta = conftest.make_meta()\n"
        "plot_samples(conftest.make_trajectory_set(4, meta.num_steps), meta)\n"
        "print('matplotlib.pyplot' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env=tool_env(),
        cwd=REPO_ROOT,
        check=True,
        timeout=120,
    )
    assert out.stdout.strip() == "False"


# ---------------------------------------------------------------------------------------------
# Command line


def test_plot_tool_writes_all_three_figures(tmp_path: Path, dataset_file: Path) -> None:
    pred = write_predictions_npz(tmp_path / "pred.npz")
    commands = {
        "samples.png": ["samples", dataset_file, "--split", "test", "--num", "2"],
        "pred.png": ["predictions", pred, "--index", "1"],
        "attn.png": ["attention", pred, "--index", "0", "--agent", "1", "--target", "0"],
    }
    for name, args in commands.items():
        out = tmp_path / name
        result = _run_plot(*args, "--out", out)
        assert result.returncode == 0, result.stderr
        assert result.stdout.strip().splitlines()[-1] == str(out)
        _assert_png(out)
    before = (tmp_path / "pred.png").read_bytes()
    result = _run_plot("predictions", pred, "--index", "2", "--out", tmp_path / "pred.png")
    _assert_usage_error(result, "already exists; pass --overwrite")
    assert (tmp_path / "pred.png").read_bytes() == before
    args = ("predictions", pred, "--index", "2", "--out", tmp_path / "pred.png", "--overwrite")
    result = _run_plot(*args)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "pred.png").read_bytes() != before
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == sorted(["attn.png", "data.h5", "pred.npz", "pred.png", "samples.png"])


def test_plot_tool_bad_input_is_one_line_exit_2(tmp_path: Path, dataset_file: Path) -> None:
    pred = write_predictions_npz(tmp_path / "pred.npz", n=3)
    no_attn = write_predictions_npz(tmp_path / "const_vel.npz", with_attention=False)
    legacy = tmp_path / "legacy.npz"  # the untagged layout of version 1
    np.savez(legacy, **{k: v for k, v in np.load(pred).items() if k not in ("format", "version")})
    out = tmp_path / "out.png"
    cases = [
        (["predictions", pred, "--index", "3"], "scene index 3 out of range"),
        (["attention", pred, "--agent", "1", "--target", "1"], "agent and target must differ"),
        (["attention", no_attn], "no attention"),
        (["predictions", tmp_path / "absent.npz"], "does not exist"),
        (["predictions", legacy], "no format tag"),
        (["samples", pred], "not an HDF5 file"),
        (["samples", dataset_file, "--split", "dev"], "invalid choice"),
        (["samples", dataset_file, "--num", "1000"], "num_per_case must be in [1, 20]"),
        (["predictions", pred, "--dpi", "100000"], "--dpi must be in [10, 1200]"),
        (["predictions", pred, "--dpi", "0"], "--dpi must be in [10, 1200]"),
    ]
    for args, fragment in cases:
        _assert_usage_error(_run_plot(*args, "--out", out), fragment)
    _assert_usage_error(_run_plot("samples", dataset_file), "--out")
    for name in ("x.nope", "noext"):
        _assert_usage_error(
            _run_plot("samples", dataset_file, "--out", tmp_path / name),
            "--out must end in an image format's suffix (",
        )
    (tmp_path / "file").write_text("")
    _assert_usage_error(
        _run_plot("samples", dataset_file, "--out", tmp_path / "file" / "sub" / "x.png"),
        f"output directory {tmp_path / 'file' / 'sub'} cannot be created: "
        f"{tmp_path / 'file'} is not a directory",
    )
    names = ["const_vel.npz", "data.h5", "file", "legacy.npz", "pred.npz"]
    assert sorted(p.name for p in tmp_path.iterdir()) == names


def test_plot_tool_creates_missing_output_folders(tmp_path: Path) -> None:
    pred = write_predictions_npz(tmp_path / "pred.npz")
    out = tmp_path / "figures" / "scene0" / "pred.png"
    result = _run_plot("predictions", pred, "--out", out)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == str(out)
    _assert_png(out)


def test_plot_tool_removes_the_folders_it_created_when_the_write_fails(
    tmp_path: Path, capsys, monkeypatch
) -> None:
    plot = load_tool("plot.py")
    pred = write_predictions_npz(tmp_path / "pred.npz")

    def refuse(src, dst) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(dst))

    monkeypatch.setattr(os, "replace", refuse)
    out = tmp_path / "new" / "deeper" / "pred.png"
    with pytest.raises(SystemExit) as exit_info:
        plot.main(["predictions", str(pred), "--out", str(out)])
    assert exit_info.value.code == 1  # a full disk is failed work, not a usage error
    assert capsys.readouterr().err == f"error: cannot write {out}: No space left on device\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pred.npz"]


def test_plot_tool_unwritable_output_is_one_line(tmp_path: Path, capsys, monkeypatch) -> None:
    """A read-only output directory, simulated (root ignores permission bits): the rename of the
    finished temporary file raises EACCES. One line, exit 2, nothing left behind."""
    plot = load_tool("plot.py")
    pred = write_predictions_npz(tmp_path / "pred.npz")

    def refuse(src, dst) -> None:
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(dst))

    monkeypatch.setattr(os, "replace", refuse)
    out = tmp_path / "pred.png"
    with pytest.raises(SystemExit) as exit_info:
        plot.main(["predictions", str(pred), "--out", str(out)])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err == f"error: cannot write {out}: Permission denied\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pred.npz"]


def test_plot_tool_refuses_an_unwritable_directory_before_drawing(
    tmp_path: Path, capsys, monkeypatch
) -> None:
    """The directory's permission is checked first (simulated: root may write anywhere), so a
    long job does not run to fail at its end."""
    plot = load_tool("plot.py")
    pred = write_predictions_npz(tmp_path / "pred.npz")
    monkeypatch.setattr(os, "access", lambda path, mode: Path(path) != tmp_path)
    monkeypatch.setattr(plot, "_make_figure", lambda args: pytest.fail("drew a figure"))
    with pytest.raises(SystemExit) as exit_info:
        plot.main(["predictions", str(pred), "--out", str(tmp_path / "pred.png")])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err == f"error: cannot write in output directory {tmp_path}\n"


def test_prediction_figure_draws_each_predicted_agents_samples() -> None:
    pred = make_predictions(n=2)
    assert plot_predictions(pred, 0).axes[0].get_lines()  # truth only: no sample lines
    rng = np.random.default_rng(0)
    k, steps = 3, pred.pred_mean.shape[1]
    samples = pred.pred_mean[:, None] + rng.normal(0, 0.5, (2, k, *pred.pred_mean.shape[1:]))
    with_samples = replace(pred, samples=samples)
    ax = plot_predictions(with_samples, 1).axes[0]
    assert f"{k} sampled futures" in ax.get_title()
    last = pred.num_observed - 1
    agents = np.flatnonzero(pred.valid[1, last])
    thin = [line for line in ax.get_lines() if line.get_linewidth() == 0.6]
    assert len(thin) == k * len(agents)
    # each line starts at the agent's last observed position and follows one sampled future
    first = thin[0].get_xydata()
    np.testing.assert_allclose(first[0], pred.true_xy[1, last, agents[0]], rtol=1e-6)
    np.testing.assert_allclose(first[1:], samples[1, 0, :, agents[0]], rtol=1e-6)
    assert len(first) == steps + 1
