"""Sharded dataset generation: each shard is written as soon as its trajectories are done.

    generate_dataset(config, "data/big", shard_size=1000)  # -> data/big/index.h5 + shards

What `generate_dataset(..., shard_size=N)` runs (see there): the plan (`generation.plan`) is cut
into shards of at most N consecutive trajectories of one split (train, then val, then test), and
the shards are rolled out one after the other, each written (`trajectory_data.shards.ShardedWriter`)
and dropped as soon as it is safe, so memory holds one shard, not the dataset. The index then
reads exactly as the single file `generate_dataset` writes without `shard_size`: same seeds,
arrays, order and metadata.

Unsafe episodes get the same replacement seeds as in `generation.generate_episodes`, which hands
them out round by round in plan order: the first replacement of a slot follows the first
replacements of the slots before it, which the shards before have already settled, so it is
rolled out at once; a second replacement's seed depends on how many first replacements the
whole plan needed, so a shard whose first replacement is unsafe too waits, in memory, until
every shard has had its first round (rare: the shipped experts are almost always safe).
"""

from __future__ import annotations

import dataclasses
import errno
import gc
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

from pipeline.backends import BACKENDS
from pipeline.dataset_plan import (
    MAX_ATTEMPTS,
    SEED_STRIDE,
    GenerateConfig,
    GenerationResult,
    UnsafeExpertError,
    dataset_meta,
    is_safe,
    plan,
    rollout_session,
    to_trajectory_set,
)
from pipeline.episode_runner import DEFAULT_BATCH_SCENES, Slot
from scenarios import VERSIONS
from scenarios.observation_noise import add_observation_noise
from scenarios.rollout import Episode
from trajectory_data.format import DatasetMeta
from trajectory_data.shards import ShardedWriter, check_target

# what a shard hands to its writer: split, position in the split, episodes in plan order
WriteShard = Callable[[str, int, list[Episode]], None]


def shard_plan(slots: list[Slot], shard_size: int) -> list[list[int]]:
    """Plan indices of each shard, in plan order: consecutive slots of one split, at most
    `shard_size` of them (the last shard of a split may be shorter)."""
    shards: list[list[int]] = []
    for index, slot in enumerate(slots):
        last = shards[-1] if shards else None
        if last and slots[last[0]].split == slot.split and len(last) < shard_size:
            last.append(index)
        else:
            shards.append([index])
    return shards


def generate_sharded(
    config: GenerateConfig,
    out: Path,
    shard_size: int,
    *,
    workers: int,
    overwrite: bool,
    progress: bool,
    backend: str,
    address: str | None,
    batch_scenes: int = DEFAULT_BATCH_SCENES,
    observation_noise_m: float = 0.0,
) -> GenerationResult:
    """`generate_dataset` with `shard_size` (arguments checked there): the folder `out`;
    `observation_noise_m` as there (recorded in the index's and every shard's config)."""
    check_target(out, overwrite)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError:  # a file stands where the directory should be (as generation does)
        raise NotADirectoryError(
            errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(out.parent)
        ) from None
    start = time.perf_counter()
    scenario = VERSIONS[config.scenario].make()
    meta = _with_noise(dataset_meta(config, scenario, 0), observation_noise_m)
    # the shards' config: the generator's and the scenario's; the index adds the total of
    # rejected episodes, known only at the end
    shard_meta = dataclasses.replace(
        meta, config={k: v for k, v in meta.config.items() if k != "rejected_unsafe_episodes"}
    )
    counts = {split: dict.fromkeys(meta.case_names, 0) for split in ("train", "val", "test")}
    written = []

    def write(split: str, position: int, episodes: list[Episode]) -> None:
        data = to_trajectory_set(episodes, meta.case_names)
        if observation_noise_m > 0:
            states = add_observation_noise(
                data.states, data.valid, data.seed, meta.num_observed, observation_noise_m
            )
            data = dataclasses.replace(data, states=states)
        writer.write_shard(split, position, data)
        for episode in episodes:
            counts[split][episode.case] += 1
        written.append(data.num_agents)

    with ShardedWriter(out, shard_meta, overwrite=overwrite) as writer:
        rejected = roll_out_by_shard(
            config,
            shard_size,
            write,
            workers=workers,
            progress=progress,
            backend=backend,
            address=address,
            batch_scenes=batch_scenes,
        )
        meta = _with_noise(dataset_meta(config, scenario, rejected), observation_noise_m)
        index = writer.finish(meta)
    return GenerationResult(
        path=index,
        meta=meta,
        counts=counts,
        num_agents=written[0],
        rejected=rejected,
        seconds=time.perf_counter() - start,
        shards=len(written),
    )


def _with_noise(meta: DatasetMeta, observation_noise_m: float) -> DatasetMeta:
    """`meta` with the observation noise in its config where there is some."""
    if observation_noise_m <= 0:
        return meta
    return dataclasses.replace(
        meta, config={**meta.config, "observation_noise_m": observation_noise_m}
    )


def roll_out_by_shard(
    config: GenerateConfig,
    shard_size: int,
    write: WriteShard,
    *,
    workers: int = 1,
    progress: bool = False,
    backend: str = "local",
    address: str | None = None,
    batch_scenes: int = DEFAULT_BATCH_SCENES,
) -> int:
    """Roll out the plan shard by shard, handing each shard's safe episodes to `write` as soon as
    they are settled (see the module for the order); returns how many episodes were rejected.

    Raises UnsafeExpertError, KeyboardInterrupt and RayUnavailableError as
    `generation.generate_episodes` does.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    slots = plan(config)
    seeds = iter(range(SEED_STRIDE * config.seed + len(slots), sys.maxsize))  # replacements
    rejected = 0
    waiting: list[tuple[str, int, list[int]]] = []  # shards held for a second replacement
    held: dict[int, Episode] = {}  # their episodes by plan index
    pending: list[int] = []  # their unsafe slots, in plan order
    with rollout_session(config, len(slots), workers, progress, backend, address, batch_scenes) as (
        roll_out,
        bar,
    ):

        def attempt(indices: list[int], episodes: dict[int, Episode]) -> list[int]:
            """Roll out slots[indices] into `episodes`; the unsafe ones' indices."""
            episodes.update(zip(indices, roll_out([slots[i] for i in indices])))
            return [i for i in indices if not is_safe(episodes[i])]

        def reseed(indices: list[int]) -> None:
            """The next replacement seeds, in plan order (one round after the other)."""
            for i in indices:
                slots[i] = dataclasses.replace(slots[i], seed=next(seeds))
            bar.total += len(indices)

        positions = dict.fromkeys(("train", "val", "test"), 0)
        for shard in shard_plan(slots, shard_size):
            split = slots[shard[0]].split
            position = positions[split]
            positions[split] += 1
            episodes: dict[int, Episode] = {}
            unsafe = attempt(shard, episodes)  # the planned seeds
            rejected += len(unsafe)
            reseed(unsafe)  # first replacements: they follow the earlier shards' ones
            unsafe = attempt(unsafe, episodes) if unsafe else []
            rejected += len(unsafe)
            if unsafe:
                waiting.append((split, position, shard))
                held.update(episodes)
                pending.extend(unsafe)
            else:
                write(split, position, [episodes[i] for i in shard])
        for _ in range(MAX_ATTEMPTS - 2):  # the later rounds, for the shards held
            if not pending:
                break
            reseed(pending)  # after every shard's first replacements, as generate_episodes does
            pending = attempt(pending, held)
            rejected += len(pending)
        if pending:
            raise UnsafeExpertError(
                f"{len(pending)} trajectories were still unsafe after {MAX_ATTEMPTS} "
                "rounds of fresh seeds; the expert policy needs fixing"
            )
        for split, position, shard in waiting:
            write(split, position, [held[i] for i in shard])
        gc.collect()  # as in generate_episodes: pymunk objects freed while signals are deferred
    return rejected
