"""pipeline.report: records, tables, context and figure inputs on hand-made numbers (its
statistics: test_report_statistics.py; its figures and files: test_report_figures.py)."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
from dataclasses import replace

import numpy as np
import pytest
from report_runs import (
    ADE_FDE,
    MAJOR_ADE,
    fake_eval,
    hand_runs,
    sampled_runs,
    with_samples,
)
from scipy import stats

from pipeline.protocol import SETTING_BY_NAME, Protocol
from pipeline.report import context, figures, markdown, records, statistics, tables
from pipeline.report.records import (
    MEASURES,
    CaseNames,
    Measure,
    RunRecord,
)


# ---------------------------------------------------------------------------------- records
def test_records_map_case_names_to_major_and_minor():
    run = hand_runs()[0]
    assert run.case_names == CaseNames("go", "stop")
    assert run.values[Measure("ade", "major")] == 1.0
    assert run.values[Measure("fde", "minor")] == 4.0
    assert run.values[Measure("ade", "minor", "all_agents")] == pytest.approx(0.2)
    assert run.values[Measure("attention_weight", "overall")] == 0.25
    assert set(run.values) == set(MEASURES)


def test_run_json_keeps_the_results_json_layout():
    document = hand_runs()[1].to_json()
    assert document["main_agents"]["major"] == {"ade": 3.0, "fde": 6.0}
    assert document["all_agents"]["overall"]["ade"] == pytest.approx(0.3)
    assert document["attention_accuracy"] == {"major": 0.5, "minor": 0.5, "overall": 0.5}
    assert document["case_names"] == {"major": "go", "minor": "stop"}
    assert (document["setting"], document["variant"], document["seed"]) == ("hc_go", "ours", 1)


def test_a_run_scored_on_samples_records_them_and_an_older_one_none():
    from predictor.forecasting import SAMPLE_KEYS

    assert set(records.SAMPLED) | {"k"} == set(SAMPLE_KEYS)  # every score but K is a measure
    old = hand_runs()[1]
    run = sampled_runs()[1]  # ours seed 1: ADE major 3, minor 4
    assert set(run.values) == set(MEASURES) | set(records.SAMPLE_MEASURES)
    assert run.values[Measure("min_ade", "major")] == 1.5
    assert run.values[Measure("min_fde", "minor")] == 4.0
    assert run.values[Measure("min_ade", "minor", "all_agents")] == pytest.approx(0.2)
    assert run.values[Measure("miss_rate", "overall")] == pytest.approx(0.3)
    assert run.values[Measure("nll", "major", "all_agents")] == 2.0
    assert (run.sample_k, run.miss_threshold_m) == (20, 2.0)
    assert (old.sample_k, old.miss_threshold_m) == (None, None)
    document, before = run.to_json(), old.to_json()
    assert document["main_agents"]["major"] == {
        "ade": 3.0,
        "fde": 6.0,
        "min_ade": 1.5,
        "min_fde": 3.0,
        "miss_rate": pytest.approx(0.3),
        "nll": 2.0,
    }
    assert (document["sample_k"], document["miss_threshold_m"]) == (20, 2.0)
    assert set(document) - set(before) == {"sample_k", "miss_threshold_m"}
    assert "sample_k" not in before and "min_ade" not in str(before)  # listed as it always was
    unrecorded = RunRecord.from_eval(
        "hc_go", "ours", 0, with_samples(fake_eval(*ADE_FDE), 0, 5, None)
    )
    assert (unrecorded.sample_k, unrecorded.miss_threshold_m) == (5, None)
    no_samples = with_samples(fake_eval(*ADE_FDE), 0, k=0)  # K = 0: nothing sampled
    assert set(RunRecord.from_eval("hc_go", "ours", 0, no_samples).values) == set(MEASURES)


# ---------------------------------------------------------------------------------- tables
def test_results_table_with_attention_columns():
    results = statistics.analyse(hand_runs())
    names = CaseNames("go", "stop")
    lines = tables.results_table(
        results, "hc_go", ("ours", "nonsmooth", "const_vel"), "main_agents", names
    ).splitlines()
    assert lines[0].startswith("| variant | major (go) ADE | major (go) FDE | minor (stop) ADE")
    assert "attn. weight major" in lines[0] and lines[0].endswith("| runs |")
    assert lines[2].startswith("| Ours | 2.000 ± 1.414 | 4.000 ± 2.828 | 3.000 ± 1.414 |")
    assert lines[2].count("0.250 ± 0.000") == 2 and lines[2].count("0.50 ± 0.00") == 2
    assert lines[3] == "| Const-Vel | 9.000 | 18.000 | 9.000 | 18.000 | n/a | n/a | n/a | n/a | 1 |"
    assert len(lines) == 4  # nonsmooth was not run


def section(runs: list[RunRecord]) -> str:
    """The `hc_go` section of a report of `runs` (Ours, S-Attn, NonSmooth, Const-Vel)."""
    from types import SimpleNamespace

    report = SimpleNamespace(
        results=statistics.analyse(runs),
        input=SimpleNamespace(
            protocol=SimpleNamespace(variants=("ours", "s_attn", "nonsmooth", "const_vel"))
        ),
        datasets={"hc_go": SimpleNamespace(case_names=CaseNames("go", "stop"))},
        figures={},
    )
    return "\n".join(markdown.setting_section(report, SETTING_BY_NAME["hc_go"]))


def test_a_setting_with_samples_shows_their_table_and_one_without_none():
    """Ours: minADE 0.5, 1.5 (major), 1, 2 (minor); minFDE twice that; miss rate 0.2, 0.3; NLL
    -1, 2. S-Attn: seed 0 alone (minADE 2.5, 4; miss 0.2, NLL -1); Const-Vel: no samples."""
    plain, sampled = section(hand_runs()), section(sampled_runs())
    for word in ("minADE", "minFDE", "miss rate", "NLL", "Sampled", "samples"):
        assert word not in plain
    lead = next(line for line in sampled.splitlines() if line.startswith("Sampled futures"))
    assert "K = 20 per car" in lead and "above 2 m" in lead
    lines = sampled.splitlines()
    start = lines.index(lead)
    header, rows = lines[start + 2], lines[start + 4 : start + 6]
    assert header == (
        "| variant | major (go) minADE_20 | major (go) minFDE_20 | major (go) miss rate | "
        "major (go) NLL | minor (stop) minADE_20 | minor (stop) minFDE_20 | minor (stop) miss "
        "rate | minor (stop) NLL | runs |"
    )
    assert rows == [
        "| Ours | 1.000 ± 0.707 | 2.000 ± 1.414 | 0.25 ± 0.07 | 0.50 ± 2.12 | 1.500 ± 0.707 | "
        "3.000 ± 1.414 | 0.25 ± 0.07 | 0.50 ± 2.12 | 2 |",
        "| S-Attn | 2.500 | 5.000 | 0.20 | -1.00 | 4.000 | 8.000 | 0.20 | -1.00 | 1 |",
    ]
    assert lines[start + 6] == ""  # Const-Vel and NonSmooth have no row
    block = "\n".join(lines[start : start + 6]) + "\n\n"
    assert sampled.count(block) == 1 and sampled.replace(block, "") == plain  # else unchanged
    assert tables.sample_section(statistics.analyse(hand_runs()), "hc_go", ("ours",), None) is None
    mixed = sampled_runs()[:2] + [
        RunRecord.from_eval("hc_go", "s_attn", 0, with_samples(fake_eval(*ADE_FDE), 0, 5, None))
    ]
    text = tables.sample_section(
        statistics.analyse(mixed), "hc_go", ("ours", "s_attn"), CaseNames("go", "stop")
    )
    assert "K = 5, 20 per car" in text and "| major (go) minADE_K |" in text
    assert "the evaluation's threshold (2 m by default)" in text


def test_bar_table_against_the_better_oracle_ridge_and_constant_velocity():
    """Ours (means: major 2.0, minor 3.0 m; all agents a tenth of that) against the better
    of the two oracle ridges per case and constant velocity's all-agent ADE (0.9 m)."""
    oracles = [  # variant, major ADE, minor ADE
        ("ridge_labelled", 2.5, 3.5),
        ("ridge_labelled_relation", 1.5, 4.0),
    ]
    runs = hand_runs() + [
        RunRecord.from_eval(
            "hc_go", v, 0, fake_eval({"major": a, "minor": m}, {"major": a, "minor": m})
        )
        for v, a, m in oracles
    ]
    lines = markdown.bar_table(statistics.analyse(runs), ["hc_go", "dm_r0.3"]).splitlines()
    assert len(lines) == 4  # header, rule, two cases of hc_go (dm_r0.3 was not run)
    major = "| `hc_go` | major | 2.000 | 1.500 (Ridge+label per relation (oracle)) | not met |"
    assert lines[2] == major + " 0.200 | 0.900 | met |"
    minor = "| `hc_go` | minor | 3.000 | 3.500 (Ridge+label (oracle)) | met |"
    assert lines[3] == minor + " 0.300 | 0.900 | met |"
    assert markdown.bar_verdict(1.0, None) == "n/a" and markdown.bar_verdict(1.0, 1.0) == "not met"
    assert markdown.bar_table(statistics.analyse(runs), ["dm_r0.3"]).startswith("_Needs Ours")


def compared_runs() -> list[RunRecord]:
    """hand_runs plus Ours under a compared preset (major ADE 0.5 / 1.5, minor 1.0 / 5.0)."""
    rows = [(0, 0.5, 1.0), (1, 1.5, 5.0)]
    return hand_runs() + [
        RunRecord.from_eval(
            "hc_go",
            "ours@agent_zero_cv",
            seed,
            fake_eval({"major": a, "minor": m}, {"major": 2 * a, "minor": 2 * m}),
        )
        for seed, a, m in rows
    ]


def test_a_compared_preset_is_tested_against_the_same_variant():
    results = statistics.analyse(compared_runs())
    comparison = results.comparison("hc_go", "ours", "ours@agent_zero_cv")
    cell = comparison[MAJOR_ADE]
    assert cell.mean_ours == 1.0 and cell.mean_other == 2.0
    assert cell.test.p == pytest.approx(stats.ttest_ind([0.5, 1.5], [1, 3], equal_var=False).pvalue)
    assert results.comparison("hc_go", "s_attn", "ours@agent_zero_cv") is None
    assert records.label("ours@agent_zero_cv") == "Ours [agent_zero_cv]"
    assert records.split_variant("ours") == ("ours", None)


def test_presets_table_and_bar_rows_per_preset():
    setting = SETTING_BY_NAME["hc_go"]
    protocol = Protocol(
        (setting,), ("ours",), 2, 5, preset="agent", compare_presets=("agent_zero_cv",)
    )
    results = statistics.analyse(compared_runs())
    lines = markdown.presets_table(results, "hc_go", protocol).splitlines()
    assert len(lines) == 4
    assert lines[2].startswith("| Ours [agent] | 2.000 ± 1.414 | 3.000 ± 1.414 | 0.200 ± 0.141 |")
    p_major = stats.ttest_ind([0.5, 1.5], [1, 3], equal_var=False).pvalue
    p_minor = stats.ttest_ind([1, 5], [2, 4], equal_var=False).pvalue
    assert lines[3].startswith("| Ours [agent_zero_cv] | 1.000 ± 0.707 | 3.000 ± 2.828 |")
    assert lines[3].endswith(f"| 2 | {p_major:.2g}, {p_minor:.2g} |")
    assert markdown.presets_table(results, "dm_r0.3", protocol) == "_Not run._"
    models = markdown.compared_models(protocol)
    assert models == ("ours", "ours@agent_zero_cv")
    runs = compared_runs() + [
        RunRecord.from_eval("hc_go", "const_vel", 0, fake_eval(*ADE_FDE)),
    ]
    bar = markdown.bar_table(statistics.analyse(runs), ["hc_go"], models).splitlines()
    assert bar[0].startswith("| setting | model | case |") and len(bar) == 6
    assert bar[4].startswith("| `hc_go` | Ours [agent_zero_cv] | major | 1.000 | n/a |")
    assert markdown.compared_line(protocol) == ", compared with `agent_zero_cv` (Ours)"
    assert markdown.compared_line(Protocol((), ("ours",), 1, 1)) == ""
    limited = replace(protocol, compare_only=(("agent_zero_cv", ("dm_r0.3",)),))
    assert markdown.compared_line(limited) == (
        ", compared with `agent_zero_cv` (on `dm_r0.3`) (Ours)"
    )
    assert markdown.presets_table(results, "hc_go", limited).splitlines()[2:] == [lines[2]]


def test_pvalue_table_gives_p_and_difference():
    results = statistics.analyse(hand_runs())
    row = markdown.pvalue_table(results, "hc_go").splitlines()[2]
    p = stats.ttest_ind([1, 3], [5, 7], equal_var=False).pvalue
    assert row.startswith(f"| Ours vs S-Attn | {p:.2g} (Δ -4.000 m) |")
    assert "No comparison" in markdown.pvalue_table(results, "hc_stop")


def test_history_line_sums_the_wall_time():
    from pipeline.reproduction import Invocation

    history = (Invocation("d1", "c1", 60.0, 3), Invocation("d2", "c2", 90.0, 1))
    line = markdown.history_line(history)
    assert line.startswith("- Training invocations logged: 2, 2.5 min wall")
    assert "d1: 1.0 min, 3 runs, `c1`; d2: 1.5 min, 1 runs, `c2`" in line
    assert markdown.history_line(()) == "- Training invocations logged: none"


def test_code_line_counts_runs_per_commit():
    runs = hand_runs()
    coded = [replace(run, code=c) for run, c in zip(runs, ["b2", "a1", "b2", None, "a1"])]
    line = markdown.code_line(coded)
    assert line == (
        "- Code (git commit of each run's evaluation): `a1` (2 runs); `b2` (2 runs); "
        "not recorded (1 runs)"
    )
    recorded = RunRecord.from_eval("hc_go", "ours", 0, {**fake_eval(*ADE_FDE), "code": "c3"})
    assert recorded.code == "c3" and recorded.to_json()["code"] == "c3"
    assert RunRecord.from_eval("hc_go", "ours", 0, fake_eval(*ADE_FDE)).code is None


def test_graph_step_line_counts_the_trained_runs_modes():
    trained = {**fake_eval(*ADE_FDE), "best_epoch": 3}
    compiled = RunRecord.from_eval("hc_go", "ours", 1, {**trained, "graph_step": "compiled"})
    assert compiled.graph_step == "compiled" and compiled.to_json()["graph_step"] == "compiled"
    older = RunRecord.from_eval("hc_go", "ours", 0, trained)  # from before the switch: eager
    baseline = RunRecord.from_eval("hc_go", "const_vel", 0, fake_eval(*ADE_FDE))
    assert older.graph_step == "eager" and baseline.graph_step is None
    line = markdown.graph_step_line([older, compiled, baseline, older])
    assert line.endswith("one row): compiled (1 runs); eager (2 runs)")
    assert markdown.graph_step_line([baseline]).endswith("no trained runs")


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_code_version_is_the_checkouts_commit_and_says_dirty(tmp_path, monkeypatch):
    for name in [n for n in os.environ if n.startswith("GIT_")]:  # e.g. set by a git hook
        monkeypatch.delenv(name)
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path))  # no checkout above tmp_path

    def git(*args: str) -> str:
        env = {**os.environ, "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t"}
        env |= {"GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t", "HOME": str(tmp_path)}
        return subprocess.run(
            ["git", "-C", str(repo), *args], check=True, capture_output=True, text=True, env=env
        ).stdout.strip()

    repo = tmp_path / "repo"
    repo.mkdir()
    assert context.code_version(repo) is None  # not a checkout
    git("init", "-q")
    assert context.code_version(repo) is None  # no commit yet
    (repo / "a.txt").write_text("one\n")
    git("add", "a.txt")
    git("commit", "-q", "-m", "first")
    commit = git("rev-parse", "HEAD")
    assert context.code_version(repo) == commit[:12]
    (repo / "new.txt").write_text("untracked files do not count\n")
    assert context.code_version(repo) == commit[:12]
    (repo / "a.txt").write_text("two\n")
    assert context.code_version(repo) == commit[:12] + "+dirty"


# ---------------------------------------------------------------------------------- figures
def test_bar_inputs_from_hand_made_runs():
    results = statistics.analyse(hand_runs())
    bars = figures.bar_inputs(results, "hc_go", "ade", ("s_attn", "nonsmooth", "ours", "const_vel"))
    assert bars.variants == ("s_attn", "ours", "const_vel")  # nonsmooth was not run
    assert bars.cases == ("major", "minor")
    np.testing.assert_allclose(bars.means, [[6.0, 8.0], [2.0, 3.0], [9.0, 9.0]])
    root2 = math.sqrt(2.0)  # sample std of two values d apart is d / sqrt(2)
    np.testing.assert_allclose(bars.errors, [[root2, 0.0], [root2, root2], [0.0, 0.0]])
    fde = figures.bar_inputs(results, "hc_go", "fde", ("ours",))
    np.testing.assert_allclose(fde.means, [[4.0, 6.0]])


def test_size_series_from_hand_made_runs():
    results = statistics.analyse(hand_runs())
    mean, std = figures.series(results, ["hc_go", "missing"], "s_attn", Measure("fde", "minor"))
    np.testing.assert_allclose(mean, [16.0, np.nan])  # 2 x minor ADE 8 in both seeds
    np.testing.assert_allclose(std, [0.0, 0.0])


def with_faithfulness(result: dict, auroc: float | None, shift: float, tv: float | None) -> dict:
    """`result` with an eval.json `faithfulness` block (predictor.faithfulness)."""
    block = {
        "attention_tv": {
            "observed": tv,
            "observed_count": 4,
            "predicted": tv,
            "predicted_count": 4,
        },
        "threshold_m": 0.01,
        "auroc": auroc,
        "auroc_agents": 3,
        "robustness_m": shift,
        "robustness_pairs": 2,
    }
    return {**result, "faithfulness": block}


def test_faithfulness_is_recorded_and_tabled_only_where_measured():
    """Ours: AUROC 0.6, 0.8, shift 0.1, 0.3 m, TV 0.02, 0.04; Const-Vel: shift 0, no attention;
    a baseline evaluated on data without influence records nothing (all None)."""
    runs = [
        RunRecord.from_eval("hc_go", "ours", s, with_faithfulness(fake_eval(*ADE_FDE), a, m, t))
        for s, (a, m, t) in enumerate([(0.6, 0.1, 0.02), (0.8, 0.3, 0.04)])
    ]
    runs.append(
        RunRecord.from_eval(
            "hc_go", "const_vel", 0, with_faithfulness(fake_eval(*ADE_FDE), None, 0.0, None)
        )
    )
    unmeasured = {"attention_tv": {"observed": None, "predicted": None}}
    nothing = RunRecord.from_eval(
        "hc_go", "s_attn", 0, {**fake_eval(*ADE_FDE), "faithfulness": unmeasured}
    )
    assert nothing.faithfulness is None and "faithfulness" not in nothing.to_json()
    assert hand_runs()[0].faithfulness is None
    assert runs[0].to_json()["faithfulness"] == {
        "auroc": 0.6,
        "robustness_m": 0.1,
        "tv_observed": 0.02,
        "tv_predicted": 0.02,
    }
    text = section([*runs, nothing])
    lines = text.splitlines()
    start = next(k for k, line in enumerate(lines) if line.startswith("Attention faithfulness"))
    assert lines[start + 2] == (
        "| variant | attn. AUROC | removal shift [m] | attn. TV observed | attn. TV predicted "
        "| runs |"
    )
    assert lines[start + 4 : start + 7] == [
        "| Ours | 0.700 ± 0.141 | 0.200 ± 0.141 | 0.030 ± 0.014 | 0.030 ± 0.014 | 2 |",
        "| Const-Vel | n/a | 0.000 | n/a | n/a | 1 |",
        "",
    ]
    plain = section([*hand_runs(), nothing])
    assert "faithfulness" not in plain
    block = "\n".join(lines[start : start + 6]) + "\n\n"
    assert text.count(block) == 1
