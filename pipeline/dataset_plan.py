"""What a generated dataset is made of, before any episode runs: its validated config
(`GenerateConfig`), the planned trajectories (`plan`: one `Slot` each, with its seed), when an
episode is safe to keep, the rollout session that both the single-file and the sharded
generators roll their rounds out in, and the dataset's meta. `pipeline.generation` writes one
file from it, `pipeline.sharded_generation` a folder of shards.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.episode_runner import Slot, run_slots
from pipeline.signals import DeferredSignals
from scenarios import FAMILIES, VERSIONS, Scenario, lookup, resolve
from scenarios.base import BROWN, GREEN
from scenarios.rollout import Episode
from trajectory_data.format import DatasetMeta, TrajectorySet

FOCAL_AGENTS = (GREEN, BROWN)  # the two main cars: the agents scored and selecting checkpoints

SEED_STRIDE = 1_000_000  # trajectory seeds: SEED_STRIDE * seed + k
# the largest master seed whose trajectory seeds (and their replacements) stay int64, as stored
MAX_SEED = (2**63 - 1) // SEED_STRIDE - 1
DEFAULT_MINOR_RATIO = 0.3  # the paper uses 0.3 and 0.8
# the scenario generated when none is named: the v1 Double Merge, whose labelled car's observed
# state decides the attending car's future (docs/scenarios.md); v0 stays available by name
DEFAULT_SCENARIO = "double_merge_v1"
# The minor case is the rarer one: at most as many minor as major trajectories. To make the
# other case the frequent one, name it as the major case instead of a ratio above 1.
MAX_MINOR_RATIO = 1.0
MAX_ATTEMPTS = 5  # replacement rounds for rejected (unsafe) episodes
SPLIT_ORDER = ("train", "val", "test")


@dataclass(frozen=True)
class GenerateConfig:
    """Everything that determines the output file (stored in it as JSON); validated on creation.

    Build one with `GenerateConfig.for_scenario(...)`, which picks the scenario's default major
    case, the other case as minor, and the minor count from a ratio. Raises ValueError, with one
    line naming the field, on a value out of range.
    """

    scenario: str  # a version name, family_vN (scenarios.version_names())
    major_case: str  # the frequent case, one of the scenario's case_names
    minor_case: str  # the rare case: another of the scenario's case_names
    num_major: int = 50  # training + validation trajectories of the major case, >= 1
    num_minor: int = 15  # training + validation trajectories of the minor case, >= 0
    num_test: int = 50  # test trajectories of each case, >= 0
    val_fraction: float = 0.2  # share of each case's training pool used for validation, [0, 1)
    seed: int = 0  # master seed, >= 0

    def __post_init__(self) -> None:
        _check_scenario(self.scenario)
        cases = VERSIONS[self.scenario].scenario_class.case_names
        for field, value in (("major_case", self.major_case), ("minor_case", self.minor_case)):
            if value not in cases:
                raise ValueError(
                    f"{field} must be one of {', '.join(cases)} for {self.scenario}, got {value!r}"
                )
        if self.minor_case == self.major_case:
            raise ValueError(
                f"minor_case must differ from major_case, both are {self.major_case!r}"
            )
        for field, value, least in (
            ("num_major", self.num_major, 1),
            ("num_minor", self.num_minor, 0),
            ("num_test", self.num_test, 0),
        ):
            check_int(field, value, least)
        if self.num_minor > self.num_major:
            raise ValueError(
                f"num_minor ({self.num_minor}) must be at most num_major ({self.num_major}): the "
                f"minor case is the rarer one; to make {self.minor_case!r} the frequent case, "
                f"make it the major_case"
            )
        if not _is_number(self.val_fraction) or not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {self.val_fraction}")
        check_int("seed", self.seed, 0)
        if self.seed > MAX_SEED:
            raise ValueError(f"seed must be at most {MAX_SEED}, got {self.seed}")

    @classmethod
    def for_scenario(
        cls,
        scenario: str = DEFAULT_SCENARIO,
        *,
        major_case: str | None = None,
        num_major: int = 50,
        minor_ratio: float | None = None,
        num_minor: int | None = None,
        num_test: int = 50,
        val_fraction: float = 0.2,
        seed: int = 0,
    ) -> GenerateConfig:
        """The config with the scenario's defaults filled in (what tools/generate.py builds);
        `scenario` defaults to DEFAULT_SCENARIO; a bare family name means its latest version
        (with a `scenarios.LatestVersionNotice` warning), which the config records.

        `major_case` defaults to the scenario's `default_major_case`; the minor case is the other
        case. The minor count is `num_minor` if given, else round(minor_ratio x num_major) with
        `minor_ratio` in [0, 1] (default DEFAULT_MINOR_RATIO); give one, not both. The minor
        case is never the larger one: for more of the other case, make it the major case.
        """
        version = resolve(scenario, stacklevel=3)
        scenario, code = version.name, version.scenario_class
        cases = code.case_names
        major = code.default_major_case if major_case is None else major_case
        if minor_ratio is not None and num_minor is not None:
            raise ValueError("give either minor_ratio or num_minor, not both")
        if num_minor is None:
            ratio = DEFAULT_MINOR_RATIO if minor_ratio is None else minor_ratio
            if not _is_number(ratio) or not 0.0 <= ratio <= MAX_MINOR_RATIO:
                raise ValueError(
                    f"minor_ratio must be in [0, {MAX_MINOR_RATIO:g}] (the minor case is the "
                    f"rarer one; for more of the other case, make it the major_case), got {ratio}"
                )
            check_int("num_major", num_major, 1)
            num_minor = round(ratio * num_major)
        minor = next(case for case in cases if case != major)  # a bad major is caught below
        return cls(scenario, major, minor, num_major, num_minor, num_test, val_fraction, seed)


def _check_scenario(name: str) -> None:
    """ValueError unless `name` is a registered version (a family name is refused here: the
    config records the exact version; `for_scenario` resolves family names)."""
    if name in FAMILIES:
        raise ValueError(
            f"scenario must name a version, e.g. {FAMILIES[name][-1].name}, got the family "
            f"name {name!r} (GenerateConfig.for_scenario resolves it to the latest version)"
        )
    lookup(name)  # ValueError listing the valid names


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_int(field: str, value: object, least: int) -> None:
    if not isinstance(value, int) or isinstance(value, bool):
        raise ValueError(f"{field} must be an integer, got {value!r}")
    if value < least:
        raise ValueError(f"{field} must be at least {least}, got {value}")


@dataclass(frozen=True)
class GenerationResult:
    """What `generate_dataset` wrote."""

    path: Path  # the dataset file
    meta: DatasetMeta  # as stored in the file
    counts: dict[str, dict[str, int]]  # split -> case -> trajectories
    num_agents: int  # cars per trajectory
    rejected: int  # unsafe episodes replaced with fresh seeds
    seconds: float  # wall time, writing included
    shards: int = 0  # shard files beside `path` (then an index, schema 3); 0: a single file

    def describe(self) -> str:
        """Per-split counts, e.g. "train 40 major + 12 minor; val 10 major + 3 minor; ..."."""
        return "; ".join(
            f"{split} " + " + ".join(f"{n} {case}" for case, n in cases.items())
            for split, cases in self.counts.items()
        )

    def summary(self) -> str:
        """The one-line report tools/generate.py prints."""
        shards = f" and {self.shards} shards" if self.shards else ""
        return (
            f"wrote {self.path}{shards}: {self.describe()} ({self.num_agents} agents, "
            f"{self.meta.num_steps} steps of {self.meta.dt:g} s; {self.rejected} unsafe episodes "
            f"replaced) in {self.seconds:.1f} s"
        )


class UnsafeExpertError(RuntimeError):
    """Some planned trajectories stayed unsafe after MAX_ATTEMPTS rounds of fresh seeds."""


def default_output(config: GenerateConfig, sharded: bool = False) -> Path:
    """data/<scenario>_<major>-major_<num_major>+<num_minor>_seed<seed>.h5 (relative path);
    `sharded`: the same without .h5, a folder (see `generate_dataset`)."""
    name = (
        f"{config.scenario}_{config.major_case}-major_{config.num_major}+{config.num_minor}"
        f"_seed{config.seed}"
    )
    return Path("data") / (name if sharded else f"{name}.h5")


def plan(config: GenerateConfig) -> list[Slot]:
    """All trajectories in file order: train, val, test; major before minor within a split."""
    counts = []
    for case, pool in (
        (config.major_case, config.num_major),
        (config.minor_case, config.num_minor),
    ):
        num_val = round(config.val_fraction * pool)
        counts.append(("train", case, pool - num_val))
        counts.append(("val", case, num_val))
    for case in (config.major_case, config.minor_case):
        counts.append(("test", case, config.num_test))
    counts.sort(key=lambda item: SPLIT_ORDER.index(item[0]))  # stable: major before minor
    cases = [(split, case) for split, case, count in counts for _ in range(count)]
    base = SEED_STRIDE * config.seed
    return [Slot(split, case, base + k) for k, (split, case) in enumerate(cases)]


def is_safe(episode: Episode) -> bool:
    """The stored trajectory is finite and its expert never collided or left the road."""
    finite = np.isfinite(episode.states).all() and np.isfinite(episode.actions).all()
    return bool(finite and not episode.collided and not episode.off_road)


@contextlib.contextmanager
def rollout_session(
    config: GenerateConfig,
    total: int,
    workers: int,
    progress: bool,
    backend: str,
    address: str | None,
    batch_scenes: int,
) -> Iterator[tuple[Callable[[list[Slot]], list[Episode]], tqdm]]:
    """A function rolling out slots in order (`run_slots`), and its progress bar of `total`
    trajectories, inside a Ray session if asked and with signals deferred: what
    `generate_episodes` and the sharded generator (`pipeline.sharded_generation`) roll out
    their rounds with."""
    bar = tqdm(
        total=total,
        desc=f"generate {config.scenario}",
        unit="traj",
        file=sys.stderr,
        dynamic_ncols=True,
        disable=not progress,
    )
    with contextlib.ExitStack() as stack:
        if backend == "ray":
            from pipeline.ray_backend import ray_session

            stack.enter_context(ray_session(address, workers))
        signals = stack.enter_context(DeferredSignals())
        stack.enter_context(bar)

        def roll_out(slots: list[Slot]) -> list[Episode]:
            # locally, no more processes than slots (a replacement or two run here)
            count = workers if backend == "ray" else min(workers, len(slots))
            return run_slots(slots, config.scenario, count, bar, signals, backend, batch_scenes)

        yield roll_out, bar


# ---- what the file holds ------------------------------------------------------------------
def to_trajectory_set(episodes: list[Episode], case_names: tuple[str, ...]) -> TrajectorySet:
    """Stack episodes (all with the same T and N) into one split."""

    def stack(name: str, dtype) -> np.ndarray:
        return np.stack([getattr(e, name) for e in episodes]).astype(dtype)

    states = stack("states", np.float32)  # (n, T, N, 4)
    focal = np.zeros((states.shape[0], states.shape[2]), dtype=bool)  # (n, N)
    focal[:, list(FOCAL_AGENTS)] = True
    return TrajectorySet(
        states=states,
        focal=focal,
        actions=stack("actions", np.float32),
        valid=stack("valid", bool),
        attention=stack("attention", np.int16),
        interaction=stack("interaction", bool),
        case=np.array([case_names.index(e.case) for e in episodes], dtype=np.int8),
        seed=np.array([e.seed for e in episodes], dtype=np.int64),
        roles=stack("roles", np.int8),
    )


def dataset_meta(config: GenerateConfig, scenario: Scenario, rejected: int) -> DatasetMeta:
    scenario_config = scenario.config
    return DatasetMeta(
        scenario=config.scenario,
        dt=float(scenario_config.recorded_dt),
        num_observed=int(scenario_config.num_observed),
        num_predicted=int(scenario_config.num_predicted),
        case_names=tuple(scenario.case_names),
        major_case=config.major_case,
        role_names=tuple(scenario.role_names),
        config={
            "generator": dataclasses.asdict(config),
            "scenario": json.loads(json.dumps(dataclasses.asdict(scenario_config), default=str)),
            "rejected_unsafe_episodes": rejected,
        },
    )
