"""Typed records of a reproduction's results: one run, per-variant summaries, tests, verdicts.

Every scored number of a run is addressed by a `Measure` (quantity, case role, agent group), so a
run, its summary over seeds and a comparison between variants are flat maps from `Measure` to a
value instead of nested string-keyed dicts. `to_json` methods give the nested layout that
`results.json` has always had (`{group: {case: {metric: ...}}}`), for readers of that file.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from predictor.metrics import ERROR_METRICS
from predictor.registry import LABELS, ORACLE_BASELINES, REPORTED_BASELINES  # noqa: F401

Role = Literal["major", "minor", "overall"]
Group = Literal["main_agents", "all_agents"]
Quantity = Literal[
    "ade", "fde", "attention_accuracy", "attention_weight", "min_ade", "min_fde", "miss_rate", "nll"
]

CASES: tuple[Role, ...] = ("major", "minor")  # the two cases, by role in the setting
ROLES: tuple[Role, ...] = (*CASES, "overall")
METRICS: tuple[Quantity, ...] = tuple(m.name for m in ERROR_METRICS)  # type: ignore[assignment]
GROUPS: tuple[Group, ...] = ("main_agents", "all_agents")
HEADLINE: Group = "main_agents"  # the two interacting cars: the group the claims are about
ATTENTION: tuple[Quantity, ...] = ("attention_accuracy", "attention_weight")
# the scores of sampled futures (predictor.forecasting.SAMPLE_KEYS but k) an eval.json holds per
# group and case when its predictor was evaluated with K > 0 samples; runs stored before
# sampling existed have none, and their records no such measure
SAMPLED: tuple[Quantity, ...] = ("min_ade", "min_fde", "miss_rate", "nll")
GROUPED: tuple[Quantity, ...] = (*METRICS, *SAMPLED)  # scored per agent group
# untrained predictors the report evaluates once per setting (constant velocity, ridge on the
# car's own history, and the oracle ridges with the labelled car's history, the bar a trained
# model must clear), their labels: predictor.registry
BASELINES = REPORTED_BASELINES

# eval.json's `faithfulness` block (predictor.faithfulness) as a run records it: name -> the
# path of keys in the block; runs evaluated before it existed, and baselines on data without
# influence (nothing measured), record none, and the report shows nothing of them
FAITHFULNESS: Mapping[str, tuple[str, ...]] = {
    "auroc": ("auroc",),
    "robustness_m": ("robustness_m",),
    "tv_observed": ("attention_tv", "observed"),
    "tv_predicted": ("attention_tv", "predicted"),
}

PRESET_MARK = "@"  # "ours@agent_zero_cv": a variant trained under a compared preset


def compared_variant(variant: str, preset: str) -> str:
    """The name a variant's runs under a compared preset (not the protocol's) carry in the
    records, so they are summarised and tested apart from the same variant's main runs."""
    return f"{variant}{PRESET_MARK}{preset}"


def split_variant(name: str) -> tuple[str, str | None]:
    """(variant, compared preset or None) of a record's variant name."""
    variant, _, preset = name.partition(PRESET_MARK)
    return variant, preset or None


def label(name: str) -> str:
    """How tables and figures name a record's variant ("Ours [agent_zero_cv]" under a compared
    preset)."""
    variant, preset = split_variant(name)
    return LABELS[variant] if preset is None else f"{LABELS[variant]} [{preset}]"


@dataclass(frozen=True, order=True)
class Measure:
    """One scored number of a run: a quantity for one case role of one agent group.

    Attention quantities are scored on the main agents only (group HEADLINE).
    """

    quantity: Quantity
    case: Role
    group: Group = HEADLINE


ERROR_MEASURES = tuple(Measure(m, c, g) for g in GROUPS for c in ROLES for m in METRICS)
ATTENTION_MEASURES = tuple(Measure(q, c) for q in ATTENTION for c in ROLES)
MEASURES = ERROR_MEASURES + ATTENTION_MEASURES
SAMPLE_MEASURES = tuple(Measure(q, c, g) for g in GROUPS for c in ROLES for q in SAMPLED)
COMPARED = tuple(Measure(m, c, g) for g in GROUPS for c in CASES for m in METRICS)


@dataclass(frozen=True)
class CaseNames:
    """The scenario's case names behind the roles "major" (the frequent case) and "minor"."""

    major: str
    minor: str

    def of(self, role: Role) -> str:
        return self.major if role == "major" else self.minor


@dataclass(frozen=True)
class RunRecord:
    """The scores of one (setting, variant, training seed), read from its eval.json."""

    setting: str
    variant: str
    seed: int
    case_names: CaseNames
    # every entry of MEASURES, and of SAMPLE_MEASURES for a run scored on samples; None where
    # not scored
    values: Mapping[Measure, float | None]
    train_seconds: float | None = None
    best_epoch: int | None = None
    code: str | None = None  # commit of the code that evaluated it (None: not recorded)
    # how a trained run computed its graph step, "eager" or "compiled" (eval.json's graph_step;
    # trained runs from before the switch record none and were eager); None for a baseline
    graph_step: str | None = None
    sample_k: int | None = None  # K sampled futures per agent behind SAMPLE_MEASURES (None: none)
    miss_threshold_m: float | None = None  # [m] of the miss rate (None: eval.json records none)
    # FAITHFULNESS's values (None: eval.json measures none of them)
    faithfulness: Mapping[str, float | None] | None = None

    @classmethod
    def from_eval(cls, setting: str, variant: str, seed: int, result: dict) -> RunRecord:
        """Read the scores an eval.json holds (names mapped to major/minor roles)."""
        major = result["major_case"]
        names = CaseNames(major, next(c for c in result["case_names"] if c != major))
        accuracy = result["attention_accuracy"]
        values: dict[Measure, float | None] = {}
        for measure in MEASURES:
            if measure.quantity in METRICS:
                source = result[measure.group]
            else:
                source = accuracy
            part = (
                source["overall"]
                if measure.case == "overall"
                else source["cases"][names.of(measure.case)]
            )
            key = {"attention_accuracy": "accuracy", "attention_weight": "mean_weight"}.get(
                measure.quantity, measure.quantity
            )
            values[measure] = part.get(key)
        sample_k = result[HEADLINE]["overall"].get("k") or None  # 0 or absent: no samples
        if sample_k is not None:
            for measure in SAMPLE_MEASURES:
                group = result[measure.group]
                part = (
                    group["overall"]
                    if measure.case == "overall"
                    else group["cases"][names.of(measure.case)]
                )
                values[measure] = part.get(measure.quantity)
        return cls(
            setting,
            variant,
            seed,
            names,
            values,
            result.get("train_seconds"),
            result.get("best_epoch"),
            result.get("code"),
            result.get("graph_step", "eager" if result.get("best_epoch") is not None else None),
            None if sample_k is None else int(sample_k),
            (result.get("sampling") or {}).get("miss_threshold_m") if sample_k else None,
            faithfulness_values(result.get("faithfulness")),
        )

    def to_json(self) -> dict:
        """The run as `results.json` lists it."""
        return {
            "setting": self.setting,
            "variant": self.variant,
            "seed": self.seed,
            "case_names": {"major": self.case_names.major, "minor": self.case_names.minor},
            "train_seconds": self.train_seconds,
            "best_epoch": self.best_epoch,
            "code": self.code,
            "graph_step": self.graph_step,
            **self.sampling_json(),
            **({} if self.faithfulness is None else {"faithfulness": dict(self.faithfulness)}),
            **nested(self.values),
        }

    def sampling_json(self) -> dict[str, Any]:
        """The samples behind the run's SAMPLE_MEASURES, for `results.json`; empty without
        samples (a run stored before sampling existed is listed as it always was)."""
        if self.sample_k is None:
            return {}
        return {"sample_k": self.sample_k, "miss_threshold_m": self.miss_threshold_m}


def faithfulness_values(block: dict | None) -> dict[str, float | None] | None:
    """FAITHFULNESS's values of an eval.json `faithfulness` block; None where it has none."""
    values: dict[str, float | None] = {}
    for name, path in FAITHFULNESS.items():
        value: Any = block
        for key in path:
            value = value.get(key) if isinstance(value, dict) else None
        values[name] = None if value is None else float(value)
    return values if any(v is not None for v in values.values()) else None


@dataclass(frozen=True)
class Summary:
    """Mean and sample standard deviation (ddof 1) of the available values, and their count.

    `mean` is None without values, `std` None with fewer than two.
    """

    mean: float | None
    std: float | None
    n: int


@dataclass(frozen=True)
class VariantSummary:
    """One variant of one setting summarised over its training seeds."""

    setting: str
    variant: str
    runs: int
    summaries: Mapping[Measure, Summary]

    def __getitem__(self, measure: Measure) -> Summary:
        return self.summaries[measure]

    def to_json(self) -> dict:
        return {"seeds": self.runs, **nested(self.summaries)}


@dataclass(frozen=True)
class WelchTest:
    """Welch's two-sided two-sample t-test; None where undefined (fewer than two values a
    side, or no spread in either)."""

    t: float | None
    p: float | None


@dataclass(frozen=True)
class Difference:
    """One variant against another on one measure (`Comparison`): the test and both means
    (`mean_ours` is the first variant's, Ours in every comparison but one)."""

    test: WelchTest
    mean_ours: float | None
    mean_other: float | None


@dataclass(frozen=True)
class Comparison:
    """One trained variant (`first`: Ours, or Ours-Correct against Ours-Average) against
    another of the same setting, on every COMPARED measure."""

    setting: str
    first: str
    other: str
    cells: Mapping[Measure, Difference]

    def __getitem__(self, measure: Measure) -> Difference:
        return self.cells[measure]

    def to_json(self) -> dict:
        return nested(
            {
                measure: {
                    "t": cell.test.t,
                    "p": cell.test.p,
                    "mean_ours": cell.mean_ours,
                    "mean_other": cell.mean_other,
                }
                for measure, cell in self.cells.items()
            }
        )


@dataclass(frozen=True)
class Results:
    """Every run of a reproduction with its summaries and comparisons (statistics.analyse)."""

    runs: tuple[RunRecord, ...]
    summaries: Mapping[tuple[str, str], VariantSummary]  # (setting, variant)
    comparisons: Mapping[tuple[str, str, str], Comparison]  # (setting, first, other variant)

    def summary(self, setting: str, variant: str) -> VariantSummary | None:
        return self.summaries.get((setting, variant))

    def comparison(self, setting: str, other: str, first: str = "ours") -> Comparison | None:
        return self.comparisons.get((setting, first, other))

    def has_setting(self, setting: str) -> bool:
        return any(s == setting for s, _ in self.summaries)


@dataclass(frozen=True)
class Verdict:
    """Whether a claim holds for one case and metric: "holds", "not significant", "partly",
    "does not hold", "n/a"... plus the evidence (p-value, difference or margins)."""

    verdict: str
    detail: str = ""

    @property
    def text(self) -> str:
        return f"{self.verdict} ({self.detail})" if self.detail else self.verdict


@dataclass(frozen=True)
class ClaimRow:
    """One row of the paper-claims table: a claim checked on one setting (or the size study)."""

    setting: str
    claim: str
    cells: Mapping[Measure, Verdict] = field(default_factory=dict)  # headline measures

    def to_json(self) -> dict:
        return {
            "setting": self.setting,
            "claim": self.claim,
            "cells": {f"{m.case} {m.quantity}": v.text for m, v in self.cells.items()},
        }


def nested(values: Mapping[Measure, object]) -> dict:
    """{group: {case: {metric: value}}} for errors, {quantity: {case: value}} for attention:
    the layout of `results.json`."""
    out: dict = {}
    for measure, value in values.items():
        if isinstance(value, Summary):
            value = {"mean": value.mean, "std": value.std, "n": value.n}
        if measure.quantity in GROUPED:
            out.setdefault(measure.group, {}).setdefault(measure.case, {})[measure.quantity] = value
        else:
            out.setdefault(measure.quantity, {})[measure.case] = value
    return out
