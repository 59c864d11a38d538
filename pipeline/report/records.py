"""Typed records of a reproduction's results: one run, per-variant summaries, tests, verdicts.

Every scored number of a run is addressed by a `Measure` (quantity, case role, agent group), so a
run, its summary over seeds and a comparison between variants are flat maps from `Measure` to a
value instead of nested string-keyed dicts. `to_json` methods give the nested layout that
`results.json` has always had (`{group: {case: {metric: ...}}}`), for readers of that file.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

from predictor.metrics import ERROR_METRICS
from predictor.registry import LABELS, ORACLE_BASELINES, REPORTED_BASELINES  # noqa: F401

Role = Literal["major", "minor", "overall"]
Group = Literal["main_agents", "all_agents"]
Quantity = Literal["ade", "fde", "attention_accuracy", "attention_weight"]

CASES: tuple[Role, ...] = ("major", "minor")  # the two cases, by role in the setting
ROLES: tuple[Role, ...] = (*CASES, "overall")
METRICS: tuple[Quantity, ...] = tuple(m.name for m in ERROR_METRICS)  # type: ignore[assignment]
GROUPS: tuple[Group, ...] = ("main_agents", "all_agents")
HEADLINE: Group = "main_agents"  # the two interacting cars: the group the claims are about
ATTENTION: tuple[Quantity, ...] = ("attention_accuracy", "attention_weight")
# untrained predictors the report evaluates once per setting (constant velocity, ridge on the
# car's own history, and the oracle ridges with the labelled car's history, the bar a trained
# model must clear), their labels: predictor.registry
BASELINES = REPORTED_BASELINES

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
    values: Mapping[Measure, float | None]  # every entry of MEASURES; None where not scored
    train_seconds: float | None = None
    best_epoch: int | None = None
    code: str | None = None  # commit of the code that evaluated it (None: not recorded)
    # how a trained run computed its graph step, "eager" or "compiled" (eval.json's graph_step;
    # trained runs from before the switch record none and were eager); None for a baseline
    graph_step: str | None = None

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
            **nested(self.values),
        }


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
        if measure.quantity in METRICS:
            out.setdefault(measure.group, {}).setdefault(measure.case, {})[measure.quantity] = value
        else:
            out.setdefault(measure.quantity, {})[measure.case] = value
    return out
