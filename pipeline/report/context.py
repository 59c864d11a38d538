"""What a report states about where its numbers come from: the machine, the code and the
datasets."""

from __future__ import annotations

import os
import platform
import subprocess
from dataclasses import dataclass
from pathlib import Path

from pipeline.report.records import CASES, CaseNames
from trajectory_data.format import SPLITS
from trajectory_data.reader import read_meta, read_split


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


REPO_ROOT = Path(__file__).resolve().parents[2]


def code_version(root: Path = REPO_ROOT) -> str | None:
    """The commit the code at `root` is checked out at (12 hex digits), with "+dirty" if
    tracked files differ from it; None outside a git checkout or without git. Kept in each
    run's eval.json: a protocol completed over several sittings may span commits, and a
    reader of the results store should see which code produced each run."""

    def git(*args: str) -> str:
        done = subprocess.run(
            ["git", "-C", str(root), *args], capture_output=True, text=True, timeout=30
        )
        if done.returncode != 0:
            raise OSError(done.stderr.strip())
        return done.stdout.strip()

    try:
        commit = git("rev-parse", "HEAD")[:12]
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):  # no git, not a checkout, no commit yet
        return None
    return commit + ("+dirty" if dirty else "")


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
