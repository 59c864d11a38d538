"""Statistics of a reproduction: summaries over seeds, Welch tests, and the claims' verdicts.

Across training seeds: mean and sample standard deviation (ddof = 1); Ours is compared with every
other trained variant by Welch's two-sided two-sample t-test
(`scipy.stats.ttest_ind(a, b, equal_var=False)`) over the per-seed values.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence

import numpy as np
from scipy import stats

from pipeline.report.records import (
    CASES,
    COMPARED,
    HEADLINE,
    MEASURES,
    METRICS,
    SAMPLE_MEASURES,
    ClaimRow,
    Comparison,
    Difference,
    Measure,
    Results,
    RunRecord,
    Summary,
    VariantSummary,
    Verdict,
    WelchTest,
    split_variant,
)
from predictor.registry import OURS, PAIRS, RIVALS  # noqa: F401 (re-exported)

ALPHA_S_ATTN = 0.01  # the paper's threshold for Ours vs S-Attn
ALPHA = 0.05  # every other comparison
# Ours, the rivals compared with it (in this order) and every (first, other) pair compared come
# from predictor.registry
STATISTICS = (
    "mean +- sample standard deviation (ddof = 1) over training seeds; p-values: "
    "Welch's two-sided two-sample t-test, scipy.stats.ttest_ind(equal_var=False)"
)


# ---------------------------------------------------------------------------------- summaries
def summarize(values: Iterable[float | None]) -> Summary:
    """Mean, sample std (ddof 1; None for fewer than 2) and count of the finite values."""
    kept = [float(v) for v in values if v is not None and math.isfinite(v)]
    if not kept:
        return Summary(None, None, 0)
    std = float(np.std(kept, ddof=1)) if len(kept) > 1 else None
    return Summary(float(np.mean(kept)), std, len(kept))


def welch_test(a: Sequence[float], b: Sequence[float]) -> WelchTest:
    """Welch's two-sided t-test of a against b (None where undefined)."""
    if len(a) < 2 or len(b) < 2:
        return WelchTest(None, None)
    with warnings.catch_warnings():  # identical samples: scipy warns and returns NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        result = stats.ttest_ind(a, b, equal_var=False)
    t, p = float(result.statistic), float(result.pvalue)
    return WelchTest(t if math.isfinite(t) else None, p if math.isfinite(p) else None)


def values(runs: Iterable[RunRecord], measure: Measure) -> list[float]:
    """The runs' values of a measure in seed order; missing ones skipped."""
    ordered = sorted(runs, key=lambda r: r.seed)
    found = [r.values.get(measure) for r in ordered]  # a sampled measure: only runs with samples
    return [float(v) for v in found if v is not None]


def group_runs(runs: Iterable[RunRecord]) -> dict[tuple[str, str], list[RunRecord]]:
    """Runs by (setting, variant), in first-seen order."""
    groups: dict[tuple[str, str], list[RunRecord]] = {}
    for run in runs:
        groups.setdefault((run.setting, run.variant), []).append(run)
    return groups


def aggregate(runs: Iterable[RunRecord]) -> dict[tuple[str, str], VariantSummary]:
    """Every measure of every (setting, variant) summarised over its seeds, and each sampled
    measure (SAMPLE_MEASURES) over the seeds that have it where any has."""
    out = {}
    for (setting, variant), members in group_runs(runs).items():
        sampled = [m for m in SAMPLE_MEASURES if any(m in r.values for r in members)]
        summaries = {m: summarize(values(members, m)) for m in (*MEASURES, *sampled)}
        out[setting, variant] = VariantSummary(setting, variant, len(members), summaries)
    return out


def difference(ours: list[float], other: list[float]) -> Difference:
    """The Welch test of two samples and their means."""
    return Difference(welch_test(ours, other), summarize(ours).mean, summarize(other).mean)


def compare(runs: Iterable[RunRecord]) -> dict[tuple[str, str, str], Comparison]:
    """Every pair of `PAIRS` whose two variants were both run on a setting, and each variant
    run under a compared preset against the same variant under the protocol's preset."""
    groups = group_runs(runs)
    out = {}
    for setting in dict.fromkeys(s for s, _ in groups):
        compared = [
            (name, split_variant(name)[0])
            for s, name in groups
            if s == setting and split_variant(name)[1] is not None
        ]
        for first, other in (*PAIRS, *compared):
            if (setting, first) in groups and (setting, other) in groups:
                cells = {
                    m: difference(
                        values(groups[setting, first], m), values(groups[setting, other], m)
                    )
                    for m in COMPARED
                }
                out[setting, first, other] = Comparison(setting, first, other, cells)
    return out


def analyse(runs: Iterable[RunRecord]) -> Results:
    """The runs with their summaries and comparisons."""
    runs = tuple(runs)
    return Results(runs, aggregate(runs), compare(runs))


# ---------------------------------------------------------------------------------- verdicts
def p_text(p: float | None) -> str:
    return "p n/a" if p is None else ("p<0.001" if p < 0.001 else f"p={p:.3f}")


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


def better(cell: Difference, alpha: float) -> Verdict:
    """Verdict of "Ours is better than the other variant" at level alpha."""
    return Verdict(
        better_verdict(cell.mean_ours, cell.mean_other, cell.test.p, alpha), p_text(cell.test.p)
    )


def comparable(cell: Difference) -> Verdict:
    """Verdict of "Ours is comparable to the other": holds unless the other is better with
    p < ALPHA; the detail gives the difference relative to the other."""
    ours, other, p = cell.mean_ours, cell.mean_other, cell.test.p
    if ours is None or other is None:
        return Verdict("n/a")
    diff = 100.0 * (ours - other) / other if other else float("nan")
    if p is not None and p < ALPHA:
        verdict = "holds (ours better)" if ours < other else "does not hold"
    else:
        verdict = "holds (no significant difference)"
    return Verdict(verdict, f"{diff:+.0f}%, {p_text(p)}")


NOT_RUN = Verdict("n/a", "not run")
CLAIMS = (  # (first variant, other variant, verdict of a comparison cell, claim text)
    (
        OURS,
        "s_attn",
        lambda cell: better(cell, ALPHA_S_ATTN),
        f"Ours beats S-Attn with p < {ALPHA_S_ATTN}",
    ),
    (
        OURS,
        "nonsmooth",
        lambda cell: better(cell, ALPHA),
        f"Ours beats Ours-NonSmooth (p < {ALPHA})",
    ),
    (OURS, "average", lambda cell: better(cell, ALPHA), f"Ours beats Ours-Average (p < {ALPHA})"),
    (OURS, "correct", comparable, "Ours is comparable to Ours-Correct (oracle)"),
    (  # not the paper's: the bar of this project's predictor (the attention has something to find)
        "correct",
        "average",
        lambda cell: better(cell, ALPHA),
        f"not a paper claim: Ours-Correct beats Ours-Average (p < {ALPHA}), so the "
        "interaction pathway carries information",
    ),
)
HEADLINE_CASES = tuple(Measure(m, c, HEADLINE) for c in CASES for m in METRICS)
SIZE_CLAIM = "margin Ours-NonSmooth minus Ours grows as the data shrinks"


def claims(
    results: Results, settings: Sequence[str], size_settings: Sequence[str]
) -> list[ClaimRow]:
    """The paper-claims table: every claim on every setting, then the size-study claim."""
    rows = []
    for setting in settings:
        for first, other, judge, text in CLAIMS:
            comparison = results.comparison(setting, other, first)
            cells = {
                m: NOT_RUN if comparison is None else judge(comparison[m]) for m in HEADLINE_CASES
            }
            rows.append(ClaimRow(setting, text, cells))
    rows.append(ClaimRow("size study", SIZE_CLAIM, size_claim(results, size_settings)))
    return rows


def size_margins(
    results: Results, size_settings: Sequence[str], measure: Measure
) -> list[float | None]:
    """Mean(nonsmooth) - mean(ours) per size setting (in the given order); None where missing."""
    margins = []
    for setting in size_settings:
        ours, other = results.summary(setting, OURS), results.summary(setting, "nonsmooth")
        a = None if other is None else other[measure].mean
        b = None if ours is None else ours[measure].mean
        margins.append(None if a is None or b is None else a - b)
    return margins


def size_claim(results: Results, size_settings: Sequence[str]) -> dict[Measure, Verdict]:
    """ "holds" if the margin falls strictly from the smallest to the largest set at every
    step, "partly" if only smallest > largest, else "does not hold" (settings smallest first)."""
    cells = {}
    for measure in HEADLINE_CASES:
        margins = [m for m in size_margins(results, size_settings, measure) if m is not None]
        if len(margins) < 2:
            cells[measure] = Verdict("n/a", "needs two size settings")
            continue
        steps = [a > b for a, b in zip(margins, margins[1:])]
        verdict = (
            "holds" if all(steps) else "partly" if margins[0] > margins[-1] else "does not hold"
        )
        text = ", ".join(f"{m:+.3f}" for m in margins)
        cells[measure] = Verdict(verdict, f"margins {text} m, smallest set first")
    return cells
