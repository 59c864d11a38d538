"""Generate a major/minor trajectory dataset from a scenario's expert and write it to HDF5.

Example: python tools/generate.py --scenario halting_car --minor-ratio 0.3

The training pool holds `--num-major` trajectories of the major case and round(R x num-major)
of the minor case (or `--num-minor` exactly); `--val-fraction` of each case is split off for
validation. The test split holds `--num-test` trajectories of each case. Trajectory k gets the
seed 1_000_000 x seed + k, so every trajectory is reproducible on its own and the output does not
depend on `--workers`. Every trajectory is checked (finite, no collision, no off-road car) before
the file is written, atomically.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.cli import ArgumentParser, fail
from predictor import __version__
from predictor.format import DatasetMeta, TrajectorySet, write_dataset
from scenarios import SCENARIOS
from scenarios.rollout import Episode, rollout

SEED_STRIDE = 1_000_000  # trajectory seeds: SEED_STRIDE * seed + k
MAX_MINOR_RATIO = 10.0  # larger ratios are almost certainly a typo
MAX_ATTEMPTS = 5  # replacement rounds for rejected (unsafe) episodes


@dataclass(frozen=True)
class GenerateConfig:
    """Everything that determines the output file (stored in it as JSON)."""

    scenario: str
    major_case: str
    minor_case: str
    num_major: int = 50  # training + validation trajectories of the major case
    num_minor: int = 15  # training + validation trajectories of the minor case
    num_test: int = 50  # test trajectories of each case
    val_fraction: float = 0.2  # share of each case's training pool used for validation
    seed: int = 0


@dataclass(frozen=True)
class Slot:
    """One trajectory to generate: where it goes and with which seed."""

    split: str
    case: str
    seed: int


def parse_args(argv: list[str] | None = None):
    parser = ArgumentParser(
        prog="generate.py",
        description="Generate a major/minor trajectory dataset (HDF5) from a scenario's expert.",
    )
    parser.add_argument(
        "--scenario", required=True, choices=sorted(SCENARIOS), help="scenario to simulate"
    )
    parser.add_argument(
        "--minor-ratio",
        type=float,
        default=None,
        help="minor-case training trajectories = round(R x num-major) "
        "(default 0.3; the paper uses 0.3 and 0.8)",
    )
    parser.add_argument(
        "--num-minor",
        type=int,
        default=None,
        help="explicit minor-case training count instead of --minor-ratio",
    )
    parser.add_argument(
        "--major-case",
        default=None,
        help="the frequent case (default: double_merge 'major', halting_car 'stop')",
    )
    parser.add_argument(
        "--num-major",
        type=int,
        default=50,
        help="major-case training trajectories, validation included (default 50)",
    )
    parser.add_argument(
        "--num-test", type=int, default=50, help="test trajectories of each case (default 50)"
    )
    parser.add_argument(
        "--val-fraction",
        type=float,
        default=0.2,
        help="share of each case's training trajectories kept for validation, "
        "in [0, 1) (default 0.2)",
    )
    parser.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    parser.add_argument(
        "--workers",
        type=int,
        default=1,
        help="worker processes; the output is identical for any number (default 1)",
    )
    parser.add_argument(
        "--out",
        default=None,
        help="output file (default data/<scenario>_<major>-major_<M>+<m>_seed<S>.h5)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    return parser.parse_args(argv)


def config_from_args(args) -> GenerateConfig:
    """Validate the arguments (exit 2 with one line on a bad value) and build the config."""
    scenario = SCENARIOS[args.scenario]
    cases = tuple(scenario.case_names)
    major = args.major_case if args.major_case is not None else scenario.default_major_case
    if major not in cases:
        fail(f"--major-case must be one of {', '.join(cases)} for {args.scenario}, got {major!r}")
    minor = next(case for case in cases if case != major)
    if args.minor_ratio is not None and args.num_minor is not None:
        fail("give either --minor-ratio or --num-minor, not both")
    if args.num_major < 1:
        fail(f"--num-major must be at least 1, got {args.num_major}")
    if args.num_test < 0:
        fail(f"--num-test must be at least 0, got {args.num_test}")
    if not 0.0 <= args.val_fraction < 1.0:
        fail(f"--val-fraction must be in [0, 1), got {args.val_fraction}")
    if args.workers < 1:
        fail(f"--workers must be at least 1, got {args.workers}")
    if args.seed < 0:
        fail(f"--seed must be non-negative, got {args.seed}")
    if args.num_minor is not None:
        if args.num_minor < 0:
            fail(f"--num-minor must be at least 0, got {args.num_minor}")
        num_minor = args.num_minor
    else:
        ratio = 0.3 if args.minor_ratio is None else args.minor_ratio
        if not 0.0 <= ratio <= MAX_MINOR_RATIO:
            fail(f"--minor-ratio must be in [0, {MAX_MINOR_RATIO:g}], got {ratio}")
        num_minor = round(ratio * args.num_major)
    return GenerateConfig(
        args.scenario,
        major,
        minor,
        args.num_major,
        num_minor,
        args.num_test,
        args.val_fraction,
        args.seed,
    )


def default_output(config: GenerateConfig) -> Path:
    name = (
        f"{config.scenario}_{config.major_case}-major_{config.num_major}+{config.num_minor}"
        f"_seed{config.seed}.h5"
    )
    return Path("data") / name


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
    order = {"train": 0, "val": 1, "test": 2}
    counts.sort(key=lambda item: order[item[0]])  # stable: major before minor
    slots = []
    for split, case, count in counts:
        slots.extend(Slot(split, case, 0) for _ in range(count))
    base = SEED_STRIDE * config.seed
    return [dataclasses.replace(slot, seed=base + k) for k, slot in enumerate(slots)]


# ---- running episodes (in this process or in workers) ---------------------------------------
_SCENARIO = None


def _init_worker(scenario_name: str) -> None:
    global _SCENARIO
    _SCENARIO = SCENARIOS[scenario_name]()


def _run_slot(slot: Slot) -> Episode:
    return rollout(_SCENARIO, slot.seed, slot.case)


def is_safe(episode: Episode) -> bool:
    """The stored trajectory is finite and its expert never collided or left the road."""
    finite = np.isfinite(episode.states).all() and np.isfinite(episode.actions).all()
    return bool(finite and not episode.collided and not episode.off_road)


def run_slots(slots: list[Slot], scenario_name: str, workers: int, progress: tqdm) -> list[Episode]:
    """Roll out every slot, in order; the result does not depend on `workers`."""
    if workers == 1:
        _init_worker(scenario_name)
        episodes = []
        for slot in slots:
            episodes.append(_run_slot(slot))
            progress.update()
        return episodes
    context = multiprocessing.get_context("spawn" if sys.platform == "darwin" else "fork")
    with context.Pool(workers, initializer=_init_worker, initargs=(scenario_name,)) as pool:
        episodes = []
        for episode in pool.imap(_run_slot, slots, chunksize=max(1, len(slots) // (8 * workers))):
            episodes.append(episode)
            progress.update()
        return episodes


def generate(config: GenerateConfig, workers: int = 1) -> tuple[list[Slot], list[Episode], int]:
    """Roll out every planned trajectory, replacing unsafe ones with fresh seeds.

    Returns the final slots, their episodes and how many episodes were rejected. Replacement
    seeds continue after the planned ones, in slot order, so the result is deterministic.
    """
    slots = plan(config)
    next_seed = SEED_STRIDE * config.seed + len(slots)
    episodes: list[Episode | None] = [None] * len(slots)
    pending = list(range(len(slots)))
    rejected = 0
    with tqdm(
        total=len(slots),
        desc=f"generate {config.scenario}",
        unit="traj",
        file=sys.stderr,
        dynamic_ncols=True,
    ) as progress:
        for _ in range(MAX_ATTEMPTS):
            results = run_slots([slots[i] for i in pending], config.scenario, workers, progress)
            retry = []
            for index, episode in zip(pending, results):
                if is_safe(episode):
                    episodes[index] = episode
                else:
                    retry.append(index)
            rejected += len(retry)
            for index in retry:
                slots[index] = dataclasses.replace(slots[index], seed=next_seed)
                next_seed += 1
            progress.total += len(retry)
            pending = retry
            if not pending:
                return slots, episodes, rejected
    raise RuntimeError(
        f"{len(pending)} trajectories were still unsafe after {MAX_ATTEMPTS} "
        "rounds of fresh seeds; the expert policy needs fixing"
    )


def to_trajectory_set(episodes: list[Episode], case_names: tuple[str, ...]) -> TrajectorySet:
    """Stack episodes (all with the same T and N) into one split."""

    def stack(name: str, dtype) -> np.ndarray:
        return np.stack([getattr(e, name) for e in episodes]).astype(dtype)

    return TrajectorySet(
        states=stack("states", np.float32),
        actions=stack("actions", np.float32),
        valid=stack("valid", bool),
        attention=stack("attention", np.int16),
        interaction=stack("interaction", bool),
        case=np.array([case_names.index(e.case) for e in episodes], dtype=np.int8),
        seed=np.array([e.seed for e in episodes], dtype=np.int64),
        roles=stack("roles", np.int8),
    )


def build_splits(slots, episodes, scenario, case_names) -> dict[str, TrajectorySet]:
    scenario_config = scenario.config
    splits = {}
    for split in ("train", "val", "test"):
        chosen = [e for s, e in zip(slots, episodes) if s.split == split]
        splits[split] = (
            to_trajectory_set(chosen, case_names)
            if chosen
            else TrajectorySet.empty(scenario_config.num_steps, episodes[0].states.shape[1])
        )
    return splits


def describe(splits: dict[str, TrajectorySet], case_names: tuple[str, ...]) -> str:
    parts = []
    for split, data in splits.items():
        counts = " + ".join(
            f"{int((data.case == i).sum())} {name}" for i, name in enumerate(case_names)
        )
        parts.append(f"{split} {counts}")
    return "; ".join(parts)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM cleans up like Ctrl-C: no file is left behind


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    config = config_from_args(args)
    out = Path(args.out) if args.out is not None else default_output(config)
    if out.exists() and not args.overwrite:
        fail(f"output {out} already exists; pass --overwrite to replace it")
    if out.is_dir():
        fail(f"output {out} is a directory")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        fail(f"cannot create output directory {out.parent}: {error.strerror or error}")
    start = time.perf_counter()
    try:
        slots, episodes, rejected = generate(config, args.workers)
    except KeyboardInterrupt:
        fail("interrupted; nothing was written", code=130)
    except RuntimeError as error:
        fail(str(error), code=1)
    scenario = SCENARIOS[config.scenario]()
    case_names = tuple(scenario.case_names)
    splits = build_splits(slots, episodes, scenario, case_names)
    scenario_config = scenario.config
    meta = DatasetMeta(
        scenario=config.scenario,
        dt=float(scenario_config.recorded_dt),
        num_observed=int(scenario_config.num_observed),
        num_predicted=int(scenario_config.num_predicted),
        case_names=case_names,
        major_case=config.major_case,
        role_names=tuple(scenario.role_names),
        config={
            "generator": dataclasses.asdict(config),
            "scenario": json.loads(json.dumps(dataclasses.asdict(scenario_config), default=str)),
            "rejected_unsafe_episodes": rejected,
        },
        package_version=__version__,
    )
    try:
        write_dataset(out, meta, splits, overwrite=args.overwrite)
    except KeyboardInterrupt:
        fail("interrupted; nothing was written", code=130)
    except OSError as error:
        fail(f"cannot write {out}: {error.strerror or error}")
    seconds = time.perf_counter() - start
    print(
        f"wrote {out}: {describe(splits, case_names)} "
        f"({splits['train'].num_agents} agents, {meta.num_steps} steps of {meta.dt:g} s; "
        f"{rejected} unsafe episodes replaced) in {seconds:.1f} s"
    )


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, _interrupt)
    main()
