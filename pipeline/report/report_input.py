"""What a reproduction hands its report (`ReportInput`: the protocol, the runs' records, what
the invocation did) and the report built from it (`Report`), as plain records: the reproduction
fills them in, `pipeline.report.document` builds and writes the report, `markdown` renders it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field

from pipeline.protocol import Protocol
from pipeline.report.context import DatasetInfo, MachineInfo
from pipeline.report.records import ClaimRow, Results, RunRecord
from pipeline.report.statistics import STATISTICS


@dataclass(frozen=True)
class RunCounts:
    """What an invocation did with the datasets and runs of its protocol."""

    datasets_generated: int
    datasets_reused: int
    runs: int  # every run of the protocol
    reused: int  # runs whose eval.json was cached
    trained: int
    resumed: int
    failed: int
    failures: tuple[str, ...] = ()  # "run_dir: error" of each failed run
    skipped: int = 0  # runs not started because the time budget ran out
    reused_from_store: int = 0  # of `reused`: read from the results store, not the cache
    kept: int = 0  # results copied into the results store by this invocation

    def to_json(self) -> dict:
        return {**asdict(self), "failures": list(self.failures)}


@dataclass(frozen=True)
class Invocation:
    """One logged invocation that ran jobs."""

    date: str
    command: str
    seconds: float
    runs: int  # jobs run (trained or resumed; const_vel: evaluated)


@dataclass(frozen=True)
class ReportInput:
    """Everything the report needs from a reproduction."""

    protocol: Protocol
    runs: tuple[RunRecord, ...]
    data_paths: Mapping[str, str]  # setting -> dataset file
    scene_files: Mapping[str, Mapping[str, str]]  # setting -> {"ours", "s_attn"} -> scenes.npz
    command: str
    counts: RunCounts
    jobs: int
    seconds: float  # wall time of the reproduction before the report
    history: tuple[Invocation, ...] = ()  # logged invocations that trained runs


@dataclass(frozen=True)
class Report:
    """The input with what is derived from it: statistics, datasets, machine, claims, figures."""

    input: ReportInput
    results: Results
    datasets: Mapping[str, DatasetInfo]  # setting -> its dataset
    size_settings: tuple[str, ...]  # size-study settings run, smallest training set first
    claims: tuple[ClaimRow, ...]
    machine: MachineInfo
    date: str
    figures: Mapping[str, tuple[str, ...]] = field(default_factory=dict)  # section -> files

    def to_json(self) -> dict:
        """The content of results.json."""
        source = self.input
        return {
            "date": self.date,
            "machine": asdict(self.machine),
            "command": source.command,
            "wall_seconds": round(source.seconds, 1),
            "statistics": STATISTICS,
            "protocol": source.protocol.to_json(),
            "datasets": {name: info.to_json() for name, info in self.datasets.items()},
            "counts": source.counts.to_json(),
            "runs": [run.to_json() for run in self.results.runs],
            "aggregates": _by_setting(
                {(s, v): x.to_json() for (s, v), x in self.results.summaries.items()}
            ),
            "tests": _by_setting(
                {
                    (s, f"{f}_vs_{o}"): x.to_json()
                    for (s, f, o), x in self.results.comparisons.items()
                }
            ),
            "claims": [row.to_json() for row in self.claims],
            "figures": {section: list(names) for section, names in self.figures.items()},
        }


def _by_setting(entries: Mapping[tuple[str, str], dict]) -> dict:
    out: dict = {}
    for (setting, key), value in entries.items():
        out.setdefault(setting, {})[key] = value
    return out
