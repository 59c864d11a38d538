"""The per-setting tables of RESULTS.md: the scores of each variant and baseline (ADE/FDE and
attention), their sampled scores (minADE_K, minFDE_K, miss rate, NLL) and the attention's
faithfulness, each a mean and spread over seeds; `pipeline.report.markdown` puts them in the
document. No I/O here."""

from __future__ import annotations

from collections.abc import Sequence

from pipeline.report.records import (
    ATTENTION,
    CASES,
    HEADLINE,
    METRICS,
    SAMPLED,
    CaseNames,
    Group,
    Measure,
    Results,
    Summary,
    label,
)
from pipeline.report.statistics import summarize
from predictor.registry import FIXED_ATTENTION  # nothing learned to score


def fmt(summary: Summary, digits: int = 3) -> str:
    """ "mean ± std", "mean" (one value) or "n/a"."""
    if summary.mean is None:
        return "n/a"
    if summary.std is None:
        return f"{summary.mean:.{digits}f}"
    return f"{summary.mean:.{digits}f} ± {summary.std:.{digits}f}"


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in rows])


def results_table(
    results: Results, setting: str, variants: Sequence[str], group: Group, names: CaseNames
) -> str:
    """Mean ± std of ADE/FDE per case (and, for the headline group, attention accuracy and the
    mean attention weight on the labelled car), one row per variant that was run."""
    header = ["variant"] + [f"{c} ({names.of(c)}) {m.upper()}" for c in CASES for m in METRICS]
    if group == HEADLINE:
        header += [f"attn. {k} {c}" for k in ("acc.", "weight") for c in CASES]
    rows = []
    for variant in variants:
        summary = results.summary(setting, variant)
        if summary is None:
            continue
        row = [label(variant)] + [
            fmt(summary[Measure(m, c, group)]) for c in CASES for m in METRICS
        ]
        if group == HEADLINE:
            row += [
                "n/a" if variant in FIXED_ATTENTION else fmt(summary[Measure(q, c)], digits)
                for q, digits in zip(ATTENTION, (2, 3))
                for c in CASES
            ]
        rows.append(row + [str(summary.runs)])
    return table(header + ["runs"], rows)


SAMPLED_NAMES = {"min_ade": "minADE", "min_fde": "minFDE", "miss_rate": "miss rate", "nll": "NLL"}
SAMPLED_DIGITS = {"min_ade": 3, "min_fde": 3, "miss_rate": 2, "nll": 2}


def sample_section(
    results: Results, setting: str, variants: Sequence[str], names: CaseNames
) -> str | None:
    """The headline group's scores of sampled futures per case (minADE_K and minFDE_K [m],
    miss rate, NLL [nats]), mean ± std over each variant's runs that have them, with a line
    saying what they are; None where no run of the setting was scored on samples (runs stored
    before sampling existed), so the report shows nothing of them."""
    rows, ks, thresholds = [], set(), set()
    for variant in variants:
        summary = results.summary(setting, variant)
        sampled = [
            run
            for run in results.runs
            if run.setting == setting and run.variant == variant and run.sample_k is not None
        ]
        if summary is None or not sampled:
            continue
        ks.update(run.sample_k for run in sampled)
        thresholds.update(run.miss_threshold_m for run in sampled)
        cells = [
            fmt(summary.summaries.get(Measure(q, c), Summary(None, None, 0)), SAMPLED_DIGITS[q])
            for c in CASES
            for q in SAMPLED
        ]
        rows.append([label(variant), *cells, str(len(sampled))])
    if not rows:
        return None
    k = str(next(iter(ks))) if len(ks) == 1 else "K"
    header = ["variant"] + [
        f"{c} ({names.of(c)}) {SAMPLED_NAMES[q]}" + (f"_{k}" if q in ("min_ade", "min_fde") else "")
        for c in CASES
        for q in SAMPLED
    ]
    known = sorted(t for t in thresholds if t is not None)
    miss = (
        " / ".join(f"{t:g}" for t in known) + " m"
        if known and None not in thresholds
        else "the evaluation's threshold (2 m by default)"
    )
    lead = (
        f"Sampled futures of the main cars, K = {', '.join(str(x) for x in sorted(ks))} per car "
        "(`predictor.forecasting.SampleSettings`): minADE/minFDE [m] of the best of the K, miss "
        f"rate (the best final error above {miss}), NLL [nats] of the truth per predicted step; "
        "mean ± std over the runs with samples."
    )
    return lead + "\n\n" + table(header + ["runs"], rows)


FAITHFULNESS_NAMES = {
    "auroc": "attn. AUROC",
    "robustness_m": "removal shift [m]",
    "tv_observed": "attn. TV observed",
    "tv_predicted": "attn. TV predicted",
}


def faithfulness_section(results: Results, setting: str, variants: Sequence[str]) -> str | None:
    """Attention faithfulness of the main cars (eval.json's `faithfulness`,
    predictor.faithfulness), mean ± std over each variant's runs that measured it; None where
    no run of the setting did (runs evaluated before it existed), so the report shows nothing."""
    rows = []
    for variant in variants:
        measured = [
            run.faithfulness
            for run in results.runs
            if run.setting == setting and run.variant == variant and run.faithfulness is not None
        ]
        if not measured:
            continue
        cells = [
            fmt(summarize(values.get(name) for values in measured), 3)
            for name in FAITHFULNESS_NAMES
        ]
        rows.append([label(variant), *cells, str(len(measured))])
    if not rows:
        return None
    lead = (
        "Attention faithfulness (`predictor.faithfulness`): the attention's AUROC against the "
        "influence matrices (influence > 0.01 m), the change of a main car's prediction when "
        "every car without influence on the main cars is removed (CausalAgents' robustness "
        "test, Roelofs et al. 2022), and the attention's total variation per step; mean ± std "
        "over the runs that measured them."
    )
    return lead + "\n\n" + table(["variant", *FAITHFULNESS_NAMES.values(), "runs"], rows)
