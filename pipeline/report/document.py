"""A reproduction's report: RESULTS.md, results.json beside it and the figures in results/.

`write_report(ReportInput, path)` gathers the statistics (statistics.analyse), the datasets'
and the machine's description (context), draws the figures (figures), writes a viewer page of
each figure setting's scenes (pipeline.viewer) and writes the markdown (markdown.render) and
the JSON, each file atomically.
"""

from __future__ import annotations

import datetime
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.files import atomic_output
from pipeline.report import figures, markdown
from pipeline.report.context import dataset_info, machine_info
from pipeline.report.report_input import Report, ReportInput
from pipeline.report.statistics import analyse, claims
from pipeline.viewer import ViewerError, write_viewer
from predictor.plots import plot_samples
from predictor.predictions import load_predictions
from trajectory_data.reader import read_meta, read_split

NOTES_FILE = "results_notes.md"  # the lead's discussion, beside the report, quoted verbatim
FIGURE_SETTINGS = ("dm_r0.3", "hc_stop")  # settings whose scenes are drawn when run


def build_report(source: ReportInput) -> Report:
    """Statistics, dataset and machine descriptions and claim verdicts of a reproduction."""
    protocol = source.protocol
    results = analyse(source.runs)
    datasets = {s.name: dataset_info(source.data_paths[s.name]) for s in protocol.settings}
    size = tuple(
        s.name
        for s in sorted(
            (s for s in protocol.settings if s.group == "size"),
            key=lambda s: s.num_major + s.num_minor,
        )
    )
    rows = claims(results, [s.name for s in protocol.settings], size)
    return Report(
        source,
        results,
        datasets,
        size,
        tuple(rows),
        machine_info(source.jobs),
        datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
    )


def draw_figures(report: Report, out: Path) -> dict[str, tuple[str, ...]]:
    """Write every figure under `out`; returns section -> file names."""
    source, results = report.input, report.results
    protocol, shown = source.protocol, {}

    def keep(section: str, fig, name: str) -> None:
        figures.save(fig, out / name)
        shown[section] = (*shown.get(section, ()), name)

    for setting in protocol.settings:
        if results.has_setting(setting.name):
            names = report.datasets[setting.name].case_names
            fig = figures.bar_figure(results, setting.name, protocol.variants, names, setting.title)
            keep("bars", fig, f"bars_{setting.name}.png")
    size = report.size_settings
    if any(results.has_setting(s) for s in size):
        labels = [f"{s}\n({report.datasets[s].training_pool.label})" for s in size]
        keep(
            "size", figures.size_figure(results, size, labels, protocol.variants), "size_study.png"
        )
    for setting in scene_settings(source):
        files = source.scene_files[setting]
        ours, other = load_predictions(files["ours"]), load_predictions(files["s_attn"])
        case_names = report.datasets[setting].case_names
        for role in ("major", "minor"):
            name = case_names.of(role)
            rows = np.flatnonzero(ours.case == ours.case_names.index(name))
            if len(rows):
                title = (
                    f"{setting}: {role} case ({name}), first test scene with an interaction "
                    "period; Ours vs S-Attn (training seed 0)"
                )
                fig = figures.scene_figure(ours, other, int(rows[0]), title)
                keep("scenes", fig, f"scene_{setting}_{role}.png")
    for scenario in dict.fromkeys(s.scenario for s in protocol.settings):
        path = source.data_paths[next(s.name for s in protocol.settings if s.scenario == scenario)]
        fig = plot_samples(read_split(path, "test"), read_meta(path), num_per_case=2)
        keep("samples", fig, f"samples_{scenario}.png")
    viewers = write_viewers(source, out)
    if viewers:
        shown["viewers"] = viewers
    return shown


def scene_settings(source: ReportInput) -> list[str]:
    """The settings whose figure scenes are drawn: FIGURE_SETTINGS where they have scene files,
    else the first setting that has them."""
    drawn = [s.name for s in source.protocol.settings if s.name in source.scene_files]
    return [s for s in drawn if s in FIGURE_SETTINGS] or drawn[:1]


def write_viewers(source: ReportInput, out: Path) -> tuple[str, ...]:
    """For each setting whose scenes are drawn, `view_<setting>.html` under `out`: the viewer
    of those test scenes with Ours' predictions and attention (training seed 0). A scene file
    that does not belong to the setting's dataset gets a line on stderr and no page."""
    names = []
    for setting in scene_settings(source):
        name = f"view_{setting}.html"
        title = f"{setting}: the report's test scenes, Ours (training seed 0)"
        try:
            write_viewer(
                source.data_paths[setting],
                out / name,
                predictions=source.scene_files[setting]["ours"],
                title=title,
            )
        except ViewerError as err:
            print(f"report: no viewer of {setting}: {err}", file=sys.stderr, flush=True)
            continue
        names.append(name)
    return tuple(names)


def write_report(source: ReportInput, path: Path) -> int:
    """Write the figures (results/ beside `path`), results.json and the markdown at `path`;
    returns the number of figures. Figures that the previous report listed in its results.json
    and this one does not draw are removed, so the folder holds this report's figures only."""
    report = build_report(source)
    out = path.parent / "results"
    out.mkdir(parents=True, exist_ok=True)
    results_json = path.with_name("results.json")
    previous = listed_figures(results_json)
    report = replace(report, figures=draw_figures(report, out))
    drawn = {name for names in report.figures.values() for name in names}
    for name in sorted(previous - drawn):
        (out / name).unlink(missing_ok=True)
    with atomic_output(results_json) as temp:
        temp.write_text(json.dumps(report.to_json(), indent=1) + "\n")
    notes = path.with_name(NOTES_FILE)
    text = markdown.render(report, notes.read_text() if notes.is_file() else None, NOTES_FILE)
    with atomic_output(path) as temp:
        temp.write_text(text)
    return len(drawn)


def listed_figures(results_json: Path) -> set[str]:
    """The figure and viewer files (plain .png and .html names in results/) a report's
    results.json lists; none if the file is missing, unreadable or older than the list (then
    nothing is removed)."""
    try:
        listed = json.loads(results_json.read_text()).get("figures", {})
        names = [name for section in listed.values() for name in section]
    except (OSError, ValueError, AttributeError, TypeError):
        return set()
    return {
        n
        for n in names
        if isinstance(n, str) and Path(n).name == n and n.endswith((".png", ".html"))
    }
