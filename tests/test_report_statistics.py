"""pipeline.report.statistics on hand-made runs: summaries, Welch tests against scipy and the
formula, comparisons, verdicts, the claims table and the size claim."""

from __future__ import annotations

import math

import numpy as np
import pytest
from report_runs import MAJOR_ADE, MINOR_ADE, fake_eval, hand_runs, sampled_runs
from scipy import stats

from pipeline.report import records, statistics
from pipeline.report.records import MEASURES, Difference, Measure, RunRecord, Summary, WelchTest


def test_summary_is_mean_and_sample_std():
    summary = statistics.summarize([1.0, 2.0, None, 3.0, 4.0, float("nan")])
    assert summary.n == 4 and summary.mean == pytest.approx(2.5)
    assert summary.std == pytest.approx(math.sqrt(5.0 / 3.0))  # squared deviations 5, n-1 3
    assert statistics.summarize([2.0]) == Summary(2.0, None, 1)
    assert statistics.summarize([None]) == Summary(None, None, 0)


def test_welch_test_matches_scipy_and_the_formula():
    a, b = [0.51, 0.48, 0.55, 0.50, 0.47], [0.62, 0.70, 0.58, 0.66]
    result = statistics.welch_test(a, b)
    assert result.p == pytest.approx(stats.ttest_ind(a, b, equal_var=False).pvalue)
    va, vb = np.var(a, ddof=1) / len(a), np.var(b, ddof=1) / len(b)
    t = (np.mean(a) - np.mean(b)) / math.sqrt(va + vb)
    df = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    assert result.t == pytest.approx(t)
    assert result.p == pytest.approx(2 * stats.t.sf(abs(t), df))
    assert statistics.welch_test([1.0], [2.0, 3.0]) == WelchTest(None, None)
    assert statistics.welch_test([1.0, 1.0], [1.0, 1.0]) == WelchTest(None, None)  # no spread


def test_aggregates_of_hand_made_runs():
    results = statistics.analyse(hand_runs())
    ours = results.summary("hc_go", "ours")
    assert ours.runs == 2
    assert ours[MAJOR_ADE] == Summary(2.0, math.sqrt(2.0), 2)  # 1 and 3: std = 2 / sqrt(2)
    assert ours[Measure("attention_weight", "minor")] == Summary(0.25, 0.0, 2)
    assert results.summary("hc_go", "const_vel")[MINOR_ADE] == Summary(9.0, None, 1)
    assert results.summary("hc_go", "nonsmooth") is None
    assert results.has_setting("hc_go") and not results.has_setting("hc_stop")


def test_sampled_measures_are_summarised_over_the_runs_that_have_them():
    results = statistics.analyse(sampled_runs())
    ours, s_attn = results.summary("hc_go", "ours"), results.summary("hc_go", "s_attn")
    assert ours[Measure("min_ade", "major")] == Summary(1.0, math.sqrt(0.5), 2)  # 0.5 and 1.5
    assert ours[Measure("nll", "minor")] == Summary(0.5, pytest.approx(3 / math.sqrt(2)), 2)
    assert s_attn.runs == 2 and s_attn[Measure("min_fde", "major")] == Summary(5.0, None, 1)
    assert s_attn[MAJOR_ADE] == Summary(6.0, math.sqrt(2.0), 2)  # ADE/FDE: both seeds
    plain = statistics.analyse(hand_runs())
    assert set(results.summary("hc_go", "const_vel").summaries) == set(MEASURES)
    assert set(plain.summary("hc_go", "ours").summaries) == set(MEASURES)
    assert plain.summary("hc_go", "ours").to_json() == {
        key: value
        for key, value in ours.to_json().items()
        if key not in ("main_agents", "all_agents")
    } | {
        group: {
            case: {m: cell for m, cell in cells.items() if m in records.METRICS}
            for case, cells in ours.to_json()[group].items()
        }
        for group in ("main_agents", "all_agents")
    }
    assert results.comparisons.keys() == plain.comparisons.keys()


def test_comparisons_of_hand_made_runs():
    results = statistics.analyse(hand_runs())
    assert set(results.comparisons) == {("hc_go", "ours", "s_attn")}  # no baseline compared
    cell = results.comparison("hc_go", "s_attn")[MAJOR_ADE]
    assert (cell.mean_ours, cell.mean_other) == (2.0, 6.0)
    assert cell.test.p == pytest.approx(stats.ttest_ind([1, 3], [5, 7], equal_var=False).pvalue)
    fde = results.comparison("hc_go", "s_attn")[Measure("fde", "major")]
    assert fde.test.p == pytest.approx(stats.ttest_ind([2, 6], [10, 14], equal_var=False).pvalue)


def test_better_verdicts():
    assert statistics.better_verdict(1.0, 2.0, 0.001, 0.01) == "holds"
    assert statistics.better_verdict(1.0, 2.0, 0.02, 0.01) == "not significant"
    assert statistics.better_verdict(1.0, 2.0, None, 0.01) == "not significant"
    assert statistics.better_verdict(2.0, 1.0, 0.001, 0.01) == "does not hold"
    assert statistics.better_verdict(2.0, 2.0, 0.5, 0.01) == "does not hold"
    assert statistics.better_verdict(None, 1.0, 0.5, 0.01) == "n/a"
    cell = Difference(WelchTest(-5.0, 0.0004), 1.0, 2.0)
    assert statistics.better(cell, 0.01).text == "holds (p<0.001)"


@pytest.mark.parametrize(
    "ours, other, p, text",
    [
        (1.1, 1.0, 0.4, "holds (no significant difference) (+10%, p=0.400)"),
        (0.9, 1.0, 0.01, "holds (ours better) (-10%, p=0.010)"),
        (1.5, 1.0, 0.01, "does not hold (+50%, p=0.010)"),
        (1.5, 1.0, None, "holds (no significant difference) (+50%, p n/a)"),
        (None, 1.0, 0.5, "n/a"),
    ],
)
def test_comparable_verdicts(ours, other, p, text):
    assert statistics.comparable(Difference(WelchTest(None, p), ours, other)).text == text


def test_claims_table_rows_for_run_and_missing_comparisons():
    results = statistics.analyse(hand_runs())
    rows = statistics.claims(results, ["hc_go"], [])
    assert [r.claim for r in rows][:5] == [c[3] for c in statistics.CLAIMS]
    s_attn = rows[0].cells
    p = stats.ttest_ind([1, 3], [5, 7], equal_var=False).pvalue  # 0.106: not < 0.01
    assert s_attn[MAJOR_ADE].text == f"not significant (p={p:.3f})"
    assert rows[1].cells[MAJOR_ADE].text == "n/a (not run)"  # nonsmooth was not run
    assert rows[-1].setting == "size study"
    assert rows[-1].cells[MAJOR_ADE].text == "n/a (needs two size settings)"
    assert rows[0].to_json()["cells"]["major ade"] == s_attn[MAJOR_ADE].text


def test_correct_is_compared_with_average_without_ours():
    """The pathway check (Ours-Correct against Ours-Average) needs no Ours run, and its claim
    row reads the Welch test of the two."""
    rows = [("correct", 0, 1.0), ("correct", 1, 2.0), ("average", 0, 4.0), ("average", 1, 6.0)]
    runs = [
        RunRecord.from_eval(
            "hc_stop", v, s, fake_eval({"major": a, "minor": a}, {"major": a, "minor": a})
        )
        for v, s, a in rows
    ]
    results = statistics.analyse(runs)
    assert set(results.comparisons) == {("hc_stop", "correct", "average")}
    cell = results.comparison("hc_stop", "average", first="correct")[MAJOR_ADE]
    assert (cell.mean_ours, cell.mean_other) == (1.5, 5.0)
    p = stats.ttest_ind([1, 2], [4, 6], equal_var=False).pvalue  # 0.074: not < 0.05
    claims = {row.claim: row for row in statistics.claims(results, ["hc_stop"], [])}
    pathway = claims[statistics.CLAIMS[-1][3]]
    assert pathway.cells[MAJOR_ADE].text == f"not significant (p={p:.3f})"
    assert claims[statistics.CLAIMS[2][3]].cells[MAJOR_ADE].text == "n/a (not run)"  # no Ours


def size_runs(ours_by_size: list[float]) -> list[RunRecord]:
    runs = []
    for k, ours in enumerate(ours_by_size):
        for variant, ade in (("ours", ours), ("nonsmooth", 2.0)):
            result = fake_eval({"major": ade, "minor": ade}, {"major": ade, "minor": ade})
            runs.append(RunRecord.from_eval(f"size{k}", variant, 0, result))
    return runs


@pytest.mark.parametrize(
    "ours_by_size, verdict",
    [
        ([1.0, 1.6, 1.9], "holds"),  # margins 1.0, 0.4, 0.1
        ([1.0, 1.9, 1.6], "partly"),  # margins 1.0, 0.1, 0.4
        ([1.9, 1.6, 1.0], "does not hold"),  # margins 0.1, 0.4, 1.0
    ],
)
def test_size_claim_needs_a_shrinking_margin(ours_by_size, verdict):
    results = statistics.analyse(size_runs(ours_by_size))
    cells = statistics.size_claim(results, ["size0", "size1", "size2"])
    assert len(cells) == 4 and all(v.verdict == verdict for v in cells.values())
    margins = statistics.size_margins(results, ["size0", "size1", "missing"], MAJOR_ADE)
    assert margins == [
        pytest.approx(2.0 - ours_by_size[0]),
        pytest.approx(2.0 - ours_by_size[1]),
        None,
    ]
