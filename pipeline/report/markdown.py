"""The text of RESULTS.md, from the typed records of a reproduction (no I/O here)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline.report.records import (
    ATTENTION,
    BASELINES,
    CASES,
    HEADLINE,
    METRICS,
    ORACLE_BASELINES,
    ClaimRow,
    Measure,
    Results,
    compared_variant,
    label,
)
from pipeline.report.statistics import (
    ALPHA,
    ALPHA_S_ATTN,
    STATISTICS,
    size_margins,
)
from pipeline.report.tables import (
    faithfulness_section,
    fmt,
    results_table,
    sample_section,
    table,
)
from predictor.registry import FIXED_ATTENTION  # nothing learned to score

if TYPE_CHECKING:
    from pipeline.protocol import Protocol
    from pipeline.report.report_input import Report


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
    "(difference relative to Correct). Ours-Correct against Ours-Average: as Ours against a "
    f"rival, Correct in Ours' place (alpha {ALPHA}). Size study: the mean margin NonSmooth − Ours "
    "should fall from the smallest to the largest training set (**partly**: only "
    "smallest > largest)."
)
HEADLINE_MEASURES = tuple(Measure(m, c) for c in CASES for m in METRICS)
BAR_RULES = (
    "The bar a trained model must clear (one that loses to simple baselines has a bug, not a "
    "result): Ours' mean main-car ADE below the better of the two oracle ridges (the labelled "
    "car's history, one regression per role or per relation to it; `predictor.baselines`), and "
    "its mean all-agent ADE below constant velocity's, in every case of every setting."
)


def pvalue_table(results: Results, setting: str) -> str:
    """p-values and mean differences of Ours against S-Attn and Ours-NonSmooth."""
    rows = []
    for other in ("s_attn", "nonsmooth"):
        comparison = results.comparison(setting, other)
        if comparison is None:
            continue
        row = [f"Ours vs {label(other)}"]
        for measure in HEADLINE_MEASURES:
            cell = comparison[measure]
            p = p_value(cell.test.p)
            if cell.mean_ours is not None and cell.mean_other is not None:
                p += f" (Δ {cell.mean_ours - cell.mean_other:+.3f} m)"
            row.append(p)
        rows.append(row)
    if not rows:
        return "_No comparison: Ours and S-Attn/Ours-NonSmooth were not both run._"
    header = ["Welch t-test, p (Δ = Ours − other)"] + [
        f"{m.case} {m.quantity.upper()}" for m in HEADLINE_MEASURES
    ]
    return table(header, rows)


def bar_verdict(model: float | None, baseline: float | None) -> str:
    """ "met" where the model's mean is below the baseline's, "not met" otherwise, "n/a" where
    either is missing."""
    if model is None or baseline is None:
        return "n/a"
    return "met" if model < baseline else "not met"


def bar_table(results: Results, settings: Sequence[str], models: Sequence[str] = ("ours",)) -> str:
    """Per setting and case: Ours (and each of `models`, e.g. Ours under a compared preset,
    in a column of its own) against the better oracle ridge (main cars) and against constant
    velocity (all agents), as `BAR_RULES` says."""
    rows = []
    for setting, model in ((s, m) for s in settings for m in models):
        ours = results.summary(setting, model)
        if ours is None:
            continue
        const_vel = results.summary(setting, "const_vel")
        for case in CASES:
            main = ours[Measure("ade", case)].mean
            oracles = [
                (summary[Measure("ade", case)].mean, variant)
                for variant in ORACLE_BASELINES
                if (summary := results.summary(setting, variant)) is not None
                and summary[Measure("ade", case)].mean is not None
            ]
            best, best_name = min(oracles, default=(None, None))
            everyone = Measure("ade", case, "all_agents")
            all_agents = ours[everyone].mean
            constant = None if const_vel is None else const_vel[everyone].mean
            rows.append(
                [f"`{setting}`"]
                + ([label(model)] if len(models) > 1 else [])
                + [
                    case,
                    "n/a" if main is None else f"{main:.3f}",
                    "n/a" if best is None else f"{best:.3f} ({label(best_name)})",
                    bar_verdict(main, best),
                    "n/a" if all_agents is None else f"{all_agents:.3f}",
                    "n/a" if constant is None else f"{constant:.3f}",
                    bar_verdict(all_agents, constant),
                ]
            )
    if not rows:
        return "_Needs Ours and the baselines of at least one setting._"
    header = ["setting"] + (["model"] if len(models) > 1 else []) + ["case", "Ours main ADE"]
    header += ["best oracle ridge main ADE", "main cars", "Ours all-agent ADE"]
    header += ["Const-Vel all-agent ADE", "all agents"]
    return table(header, rows)


def compared_models(protocol: Protocol) -> tuple[str, ...]:
    """The record names of Ours under the protocol's preset and each compared preset."""
    if "ours" not in protocol.compare_variants:
        return ("ours",)
    return ("ours", *(compared_variant("ours", p) for p in protocol.compare_presets))


def presets_table(results: Results, setting: str, protocol: Protocol) -> str:
    """One setting's compared variants under the protocol's preset and each compared preset:
    main-car and all-agent ADE and the attention weight per case, and Welch's p of each
    compared preset's main-car ADE against the protocol's preset."""
    header = ["variant [preset]"] + [f"main ADE {c}" for c in CASES]
    header += [f"all-agent ADE {c}" for c in CASES]
    header += [f"attn. weight {c}" for c in CASES] + ["runs", "p main ADE (major, minor)"]
    rows = []
    for variant in protocol.compare_variants:
        presets = protocol.presets_compared_on(setting)
        names = [variant, *(compared_variant(variant, p) for p in presets)]
        for name in names:
            summary = results.summary(setting, name)
            if summary is None:
                continue
            shown = label(name) if name != variant else f"{label(name)} [{protocol.preset}]"
            row = [shown] + [fmt(summary[Measure("ade", c)]) for c in CASES]
            row += [fmt(summary[Measure("ade", c, "all_agents")]) for c in CASES]
            row += [
                "n/a" if variant in FIXED_ATTENTION else fmt(summary[Measure(ATTENTION[1], c)])
                for c in CASES
            ]
            comparison = results.comparison(setting, variant, name)
            tests = (
                ""
                if comparison is None
                else ", ".join(p_value(comparison[Measure("ade", c)].test.p) for c in CASES)
            )
            rows.append(row + [str(summary.runs), tests])
    return table(header, rows) if rows else "_Not run._"


def p_value(p: float | None) -> str:
    """A p-value to two significant digits ("n/a" where undefined)."""
    return "n/a" if p is None else f"{p:.2g}"


def presets_section(report: Report) -> str:
    """The variants of `Protocol.compare_variants` under each preset, per setting."""
    protocol = report.input.protocol
    compared = ", ".join(compared_name(protocol, p) for p in protocol.compare_presets)
    variants = ", ".join(label(v) for v in protocol.compare_variants)
    parts = [
        f"{variants} under `{protocol.preset}` (the report's preset) and {compared}, same "
        "datasets, seeds and epochs; p: Welch's t-test of the main-car ADE against "
        f"`{protocol.preset}`."
    ]
    for setting in protocol.settings:
        if report.results.has_setting(setting.name) and protocol.presets_compared_on(setting.name):
            table_text = presets_table(report.results, setting.name, protocol)
            parts += [f"\n`{setting.name}`:\n", table_text]
    return "\n".join(parts)


def claims_table(rows: Sequence[ClaimRow]) -> str:
    header = ["setting", "claim"] + [f"{m.case} {m.quantity.upper()}" for m in HEADLINE_MEASURES]
    return table(
        header,
        [
            [f"`{row.setting}`", row.claim, *(row.cells[m].text for m in HEADLINE_MEASURES)]
            for row in rows
        ],
    )


def history_line(history: Sequence) -> str:
    """Markdown bullet of the logged invocations that trained runs (wall time)."""
    if not history:
        return "- Training invocations logged: none"
    total = sum(entry.seconds for entry in history) / 60
    items = "; ".join(
        f"{entry.date}: {entry.seconds / 60:.1f} min, {entry.runs} runs, `{entry.command}`"
        for entry in history
    )
    return f"- Training invocations logged: {len(history)}, {total:.1f} min wall in all ({items})"


def code_line(runs: Sequence) -> str:
    """Markdown bullet of the commits whose code evaluated the runs, with their run counts."""
    counts = Counter(run.code for run in runs)
    known = sorted((code, n) for code, n in counts.items() if code is not None)
    items = [f"`{code}` ({n} runs)" for code, n in known]
    if None in counts:
        items.append(f"not recorded ({counts[None]} runs)")
    return "- Code (git commit of each run's evaluation): " + ("; ".join(items) or "no runs")


def graph_step_line(runs: Sequence) -> str:
    """Markdown bullet of how many trained runs computed their graph step eager or compiled."""
    counts = Counter(run.graph_step for run in runs if run.graph_step is not None)
    items = [f"{mode} ({counts[mode]} runs)" for mode in sorted(counts)]
    return (
        "- Graph step of the trained runs (`--compile-graph-step`; the same mathematics to float "
        "rounding, one row): " + ("; ".join(items) or "no trained runs")
    )


def settings_table(report: Report) -> str:
    """Per setting: scenario, cases, split sizes, median training time per run, dataset file."""
    rows = []
    for setting in report.input.protocol.settings:
        data = report.datasets[setting.name]
        times = [
            r.train_seconds
            for r in report.results.runs
            if r.setting == setting.name and r.variant not in BASELINES and r.train_seconds
        ]
        median = f"{float(np.median(times)) / 60:.1f}" if times else "n/a"
        rows.append(
            [
                f"`{setting.name}`",
                data.scenario,
                data.case_names.major,
                data.case_names.minor,
                *(counts.label for counts in data.counts.values()),
                median,
                f"`{Path(data.path).name}`",
            ]
        )
    header = ["setting", "scenario", "major case", "minor case", "train (minor+major)", "val"]
    return table(header + ["test", "median train min/run", "dataset"], rows)


def size_section(report: Report) -> str:
    """The margins NonSmooth − Ours per size setting, and the size figure."""
    results, size = report.results, report.size_settings
    if not any(results.has_setting(s) for s in size):
        return "_No size-study setting was run._"
    margins = {m: size_margins(results, size, m) for m in HEADLINE_MEASURES}
    rows = [
        [
            f"`{setting}`",
            report.datasets[setting].training_pool.label,
            *(
                "n/a" if margins[m][k] is None else f"{margins[m][k]:+.3f}"
                for m in HEADLINE_MEASURES
            ),
        ]
        for k, setting in enumerate(size)
    ]
    header = ["setting", "minor+major"] + [
        f"NonSmooth − Ours {m.case} {m.quantity.upper()} [m]" for m in HEADLINE_MEASURES
    ]
    text = table(header, rows)
    if "size" in report.figures:
        text += "\n\n![size study](results/size_study.png)"
    return text


def compared_line(protocol: Protocol) -> str:
    """ ", compared with ..." naming the compared presets and their variants, or ""."""
    if not protocol.compare_presets:
        return ""
    presets = ", ".join(compared_name(protocol, p) for p in protocol.compare_presets)
    return f", compared with {presets} ({', '.join(label(v) for v in protocol.compare_variants)})"


def compared_name(protocol: Protocol, preset: str) -> str:
    """A compared preset in backticks, with the settings `compare_only` limits it to."""
    settings = dict(protocol.compare_only).get(preset)
    if settings is None:
        return f"`{preset}`"
    return f"`{preset}` (on {', '.join(f'`{name}`' for name in settings)})"


def how_produced(report: Report) -> str:
    """The bullets saying what ran, where, and how long it took."""
    source, machine = report.input, report.machine
    protocol, counts = source.protocol, source.counts
    seeds = f"training seeds 0..{protocol.seeds - 1}" if protocol.seeds > 1 else "seed 0"
    compute_h = sum(r.train_seconds or 0.0 for r in report.results.runs) / 3600
    return "\n".join(
        [
            f"- Command: `{source.command}`",
            f"- Date: {report.date}",
            f"- Wall time: {source.seconds / 60:.1f} min for this invocation; "
            f"the training time recorded in all runs sums to {compute_h:.2f} h "
            "(one thread each)",
            history_line(source.history),
            code_line(report.results.runs),
            graph_step_line(report.results.runs),
            f"- Machine: {machine.cores} cores, {machine.cpu_model}; torch "
            f"{machine.torch}, {machine.torch_threads_per_job} torch thread per job, "
            f"{machine.jobs} parallel jobs; Python {machine.python}",
            f"- Configuration preset: `{getattr(protocol, 'preset', 'paper')}` "
            "(predictor/presets.py `PRESETS`)" + compared_line(protocol) + "; "
            f"epochs: {protocol.epochs}; "
            f"seeds per trained variant: {protocol.seeds} ({seeds}); "
            f"baselines ({', '.join(f'`{b}`' for b in BASELINES)}) once per setting "
            "(deterministic)",
            f"- Runs: {counts.runs} ({counts.trained} trained now, {counts.resumed} "
            f"resumed, {counts.reused} reused from the cache or the results store "
            f"({counts.reused_from_store} from the store), {counts.failed} failed"
            + (f", {counts.skipped} not started: time budget" if counts.skipped else "")
            + f"); datasets: {counts.datasets_generated} generated, "
            f"{counts.datasets_reused} reused",
            f"- Statistics: {STATISTICS}",
            "- Machine-readable results (per run and aggregated): `results.json` beside this file",
        ]
    )


def setting_section(report: Report, setting) -> list[str]:
    """Tables (and bar figure) of one setting."""
    results, variants = report.results, report.input.protocol.variants
    names = report.datasets[setting.name].case_names
    parts = [
        f"\n### `{setting.name}`: {setting.title}\n",
        results_table(results, setting.name, variants, HEADLINE, names),
        "",
    ]
    sampled = sample_section(results, setting.name, variants, names)
    if sampled is not None:
        parts += [sampled, ""]
    faithful = faithfulness_section(results, setting.name, variants)
    if faithful is not None:
        parts += [faithful, ""]
    parts += [
        pvalue_table(results, setting.name),
        "",
        "<details><summary>All agents (22 cars)</summary>\n",
        results_table(results, setting.name, variants, "all_agents", names),
        "\n</details>",
    ]
    if f"bars_{setting.name}.png" in report.figures.get("bars", []):
        parts.append(f"\n![ADE/FDE {setting.name}](results/bars_{setting.name}.png)")
    return parts


def viewer_lines(names: Sequence[str]) -> list[str]:
    """The links to the viewer pages of the drawn scenes (`view_<setting>.html`)."""
    if not names:
        return []
    links = ", ".join(
        f"[`{n.removeprefix('view_').removesuffix('.html')}`](results/{n})" for n in names
    )
    return [
        f"These scenes in the viewer, with Ours' predictions and attention at every step: {links} "
        "(one HTML file each; it opens from disk in a browser, no server or network needed).\n"
    ]


def render(report: Report, notes: str | None, notes_name: str) -> str:
    """The markdown text; `notes` (the lead's discussion, verbatim) ends it when given."""
    protocol, counts = report.input.protocol, report.input.counts
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
    parts += ["\n## How this was produced\n", how_produced(report)]
    if counts.failures:
        parts.append(
            "\nFailed runs (diverged, raised, or their worker died twice):\n\n"
            + "\n".join(f"- `{line}`" for line in counts.failures)
        )
    parts += ["\n## Settings and datasets\n", settings_table(report), "", NOTES]
    parts.append("\n## Results (main cars: the two interacting cars)\n")
    for setting in protocol.settings:
        parts += setting_section(report, setting)
    settings = [setting.name for setting in protocol.settings]
    parts += [
        "\n## The bar: simple baselines\n",
        BAR_RULES,
        "",
        bar_table(report.results, settings, compared_models(protocol)),
    ]
    if protocol.compare_presets:
        parts += ["\n## Presets side by side\n", presets_section(report)]
    parts += ["\n## Training-set size study (Double Merge, Fig. 4)\n", size_section(report)]
    parts += ["\n## Paper claims\n", CLAIM_RULES, "", claims_table(report.claims)]
    parts.append("\n## Trajectories and attention (Fig. 6)\n")
    parts += [f"![scene](results/{name})\n" for name in report.figures.get("scenes", [])] or [
        "_Needs Ours and S-Attn (seed 0) of at least one setting._"
    ]
    parts += viewer_lines(report.figures.get("viewers", ()))
    parts.append("\n## Sample trajectories (test split, ground-truth experts)\n")
    parts += [f"![samples](results/{name})\n" for name in report.figures.get("samples", [])]
    parts += [
        "\n## Discussion\n",
        notes.rstrip()
        if notes is not None
        else f"_No `{notes_name}` yet: the lead writes it after looking at the results._",
    ]
    return "\n".join(parts) + "\n"
