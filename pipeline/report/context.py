"""What a report states about where its numbers come from: the machine and the datasets."""

from __future__ import annotations

import os
import platform
from dataclasses import dataclass
from pathlib import Path

from pipeline.report.records import CASES, CaseNames
from predictor.format import SPLITS
from predictor.format_reader import read_meta, read_split


@dataclass(frozen=True)
class MachineInfo:
    """The machine and software a reproduction ran on."""

    cores: int
    cpu_model: str
    torch: str
    torch_threads_per_job: int
    jobs: int  # parallel jobs
    python: str
    platform: str


def cpu_model(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The CPU's model name (Linux /proc/cpuinfo), else what `platform` says, else "unknown"."""
    try:
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info(jobs: int, torch_threads: int = 1) -> MachineInfo:
    """This machine, running `jobs` parallel jobs of `torch_threads` torch threads each."""
    import torch

    return MachineInfo(
        cores=os.cpu_count() or 1,
        cpu_model=cpu_model(),
        torch=torch.__version__,
        torch_threads_per_job=torch_threads,
        jobs=jobs,
        python=platform.python_version(),
        platform=platform.platform(),
    )


@dataclass(frozen=True)
class CaseCounts:
    """Trajectories of the major and the minor case in one split."""

    major: int
    minor: int

    @property
    def label(self) -> str:
        """ "minor+major", the way the paper writes training-set sizes."""
        return f"{self.minor}+{self.major}"


@dataclass(frozen=True)
class DatasetInfo:
    """A dataset file's scenario, case names and per-split, per-case trajectory counts."""

    path: str
    scenario: str
    case_names: CaseNames
    counts: dict[str, CaseCounts]  # split -> counts, in SPLITS order

    @property
    def training_pool(self) -> CaseCounts:
        """Training plus validation trajectories: the size the paper's settings name."""
        train, val = self.counts["train"], self.counts["val"]
        return CaseCounts(train.major + val.major, train.minor + val.minor)

    def to_json(self) -> dict:
        return {
            "path": self.path,
            "scenario": self.scenario,
            "case_names": {"major": self.case_names.major, "minor": self.case_names.minor},
            "counts": {
                split: {"major": c.major, "minor": c.minor} for split, c in self.counts.items()
            },
        }


def dataset_info(path: str) -> DatasetInfo:
    """Read a dataset file's description (counts from the case labels of each split)."""
    meta = read_meta(path)
    names = CaseNames(meta.major_case, next(c for c in meta.case_names if c != meta.major_case))
    counts = {}
    for split in SPLITS:
        case = read_split(path, split).case
        found = {role: int((case == meta.case_names.index(names.of(role))).sum()) for role in CASES}
        counts[split] = CaseCounts(**found)
    return DatasetInfo(path, meta.scenario, names, counts)
