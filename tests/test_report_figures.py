"""pipeline.report's files: figures (legends inside, nothing covered, atomic writes), the scene
figure's checks, the dataset and machine context, the listed figures and the viewer pages."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import make_meta, make_trajectory_set, write_predictions_npz
from report_runs import ADE_FDE, fake_eval, hand_runs

from pipeline.report import context, figures, records, statistics
from pipeline.report.records import (
    CaseNames,
    RunRecord,
)
from predictor.predictions import load_predictions
from trajectory_data.format import write_dataset


def test_every_legend_entry_lies_inside_the_figure():
    every = tuple(records.LABELS)  # nine variants: one legend row was wider than the figure
    runs = [RunRecord.from_eval("hc_go", v, 0, fake_eval(*ADE_FDE)) for v in every]
    results = statistics.analyse(runs)
    drawn = (
        figures.bar_figure(results, "hc_go", every, CaseNames("go", "stop"), "t"),
        figures.size_figure(results, ["hc_go"], ["1+1"], every),
    )
    for fig in drawn:
        fig.canvas.draw()
        (legend,) = fig.legends
        assert [t.get_text() for t in legend.get_texts()] == list(records.LABELS.values())
        inside = fig.bbox.padded(1.0)  # pixels; allow rounding at the edge
        for box in [legend.get_window_extent()] + [
            t.get_window_extent() for t in legend.get_texts()
        ]:
            assert inside.x0 <= box.x0 and box.x1 <= inside.x1, box
            assert inside.y0 <= box.y0 and box.y1 <= inside.y1, box


def test_no_legend_covers_the_data_of_a_report_figure(tmp_path):
    from test_plots import assert_legends_clear_of_the_axes

    every = tuple(records.LABELS)
    runs = [RunRecord.from_eval("hc_go", v, 0, fake_eval(*ADE_FDE)) for v in every]
    results = statistics.analyse(runs)
    ours = load_predictions(write_predictions_npz(tmp_path / "a.npz", seed=0))
    other = load_predictions(write_predictions_npz(tmp_path / "b.npz", seed=0))
    drawn = (
        figures.bar_figure(results, "hc_go", every, CaseNames("go", "stop"), "t"),
        figures.size_figure(results, ["hc_go"], ["1+1"], every),
        figures.scene_figure(ours, other, 0, "scene"),
    )
    for fig in drawn:
        assert_legends_clear_of_the_axes(fig)
    trajectories = drawn[2].axes[0].get_legend()
    assert [t.get_text() for t in trajectories.get_texts()] == [
        "truth, other cars",
        "truth, main cars",
        "S-Attn",
        "Ours",
    ]


def test_figures_are_saved_atomically(tmp_path, monkeypatch):
    results = statistics.analyse(hand_runs())
    fig = figures.bar_figure(results, "hc_go", ("ours", "s_attn"), CaseNames("go", "stop"), "t")
    path = figures.save(fig, tmp_path / "bars.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    def broken(fig, path, dpi):
        Path(path).write_bytes(b"partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(figures, "save_figure", broken)
    with pytest.raises(OSError):
        figures.save(fig, tmp_path / "other.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bars.png"]  # no partial, no temp


def test_scene_figure_needs_the_same_scenes(tmp_path):
    ours = load_predictions(write_predictions_npz(tmp_path / "a.npz", seed=0))
    same = load_predictions(write_predictions_npz(tmp_path / "b.npz", seed=0))
    other = load_predictions(write_predictions_npz(tmp_path / "c.npz", seed=1))
    fig = figures.scene_figure(ours, same, 0, "scene")
    assert len(fig.axes) == 3 and fig.axes[1].get_ylabel() == "attention"
    with pytest.raises(ValueError, match="different scenes"):
        figures.scene_figure(ours, other, 0, "scene")


# ---------------------------------------------------------------------------------- context
def test_dataset_info_counts_each_case_per_split(dataset_file):
    info = context.dataset_info(str(dataset_file))
    assert info.case_names == CaseNames("major", "minor")
    # conftest: cases alternate 0 (major), 1 (minor); train 6, val 3, test 4 trajectories
    assert [(c.major, c.minor) for c in info.counts.values()] == [(3, 3), (2, 1), (2, 2)]
    assert list(info.counts) == ["train", "val", "test"]
    assert info.training_pool.label == "4+5"


def test_cpu_model_reads_cpuinfo_or_falls_back(tmp_path):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nmodel name\t: Test CPU 3000\nflags\t: x\n")
    assert context.cpu_model(cpuinfo) == "Test CPU 3000"
    assert context.cpu_model(tmp_path / "missing") != ""


def test_listed_figures_reads_plain_png_and_html_names_only(tmp_path):
    from pipeline.report.document import listed_figures

    path = tmp_path / "results.json"
    assert listed_figures(path) == set()  # no previous report
    path.write_text("{not json")
    assert listed_figures(path) == set()
    path.write_text(json.dumps({"runs": []}))  # a report older than the list
    assert listed_figures(path) == set()
    names = ["bars_a.png", "../outside.png", "sub/b.png", "notes.md", 3, "../v.html"]
    listed = {"bars": names, "size": ["size_study.png"], "viewers": ["view_a.html"]}
    path.write_text(json.dumps({"figures": listed}))
    assert listed_figures(path) == {"bars_a.png", "size_study.png", "view_a.html"}


def test_viewers_of_the_main_settings_whose_scene_files_match_their_dataset(tmp_path, capsys):
    """dm_r0.3's scene file belongs to its dataset: a page of its scenes; hc_stop's dataset is
    another draw: one line on stderr and no page; dm_r0.8 is not a figure setting: no page."""
    from types import SimpleNamespace

    from test_viewer import page_content

    from pipeline.report.document import write_viewers

    data = {}
    for seed in (0, 1):
        sets = {s: make_trajectory_set(3, 10, 4, seed=seed) for s in ("train", "val", "test")}
        data[seed] = write_dataset(tmp_path / f"d{seed}.h5", make_meta(), sets)
    scenes = {"ours": str(write_predictions_npz(tmp_path / "ours.npz", seed=0)), "s_attn": ""}
    names = ("dm_r0.3", "hc_stop", "dm_r0.8")
    source = SimpleNamespace(
        protocol=SimpleNamespace(settings=[SimpleNamespace(name=n) for n in names]),
        data_paths={"dm_r0.3": data[0], "hc_stop": data[1], "dm_r0.8": data[0]},
        scene_files=dict.fromkeys(names, scenes),
    )
    out = tmp_path / "results"
    out.mkdir()
    assert write_viewers(source, out) == ("view_dm_r0.3.html",)
    assert [p.name for p in out.iterdir()] == ["view_dm_r0.3.html"]
    spec, arrays = page_content((out / "view_dm_r0.3.html").read_text())
    assert spec["source"]["predictor"] == "ours" and spec["title"].startswith("dm_r0.3: ")
    assert np.array_equal(arrays["xy"], make_trajectory_set(3, 10, 4, seed=0).states[..., :2])
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("report: no viewer of hc_stop: ")
    assert "has other positions than the dataset's" in err
