"""Dataset generation as one library call: a validated config in, an HDF5 dataset file out.

    config = GenerateConfig.for_scenario("halting_car_v3", minor_ratio=0.3)
    result = generate_dataset(config, default_output(config), workers=2)
    print(result.summary())

The training pool holds `num_major` trajectories of the major case and `num_minor` of the minor
case; `val_fraction` of each case is split off for validation. The test split holds `num_test`
trajectories of each case. Trajectory k gets the seed SEED_STRIDE x seed + k, so every trajectory
is reproducible on its own and the output does not depend on the number of workers. Every
trajectory is checked (finite, no collision, no off-road car) before the file is written,
atomically. With `shard_size`, the output is a folder of shard files and an index that reads as
that one file, each shard written as soon as it is done (`pipeline.sharded_generation`).

Speed: episodes are rolled out `batch_scenes` at a time (default
`pipeline.episode_runner.DEFAULT_BATCH_SCENES`) as one batched world, which gives exactly the
episodes of the one-by-one path (`batch_scenes=1`) several times faster; the output does not
depend on it (tested).

Counterfactual ground truth and observation noise (issue 68), both off by default so that the
output of a call without them keeps its bytes: with `influence=True` every trajectory's
influence matrices (`scenarios.counterfactual`: the ADE of each agent's predicted steps when
another is removed, for the whole episode and from the first predicted step) are computed from
the clean run and stored as the optional dataset `influence` (schema 4); they cost about 5 times
the generation (docs/dataset_format.md). With `influence_window_steps=L >= 1` the same per
predicted-time window of L steps (`scenarios.counterfactual.windowed_influence`: the ADE of each
agent over one window when another is removed from the window's first step) is stored as
`influence_windows`, for scenes where whom an agent reacts to changes during the episode; it
costs W/3 to W/2 times `influence` (W windows; docs/dataset_format.md). With
`observation_noise_m=SIGMA > 0` the stored positions of the observed steps get Gaussian noise
(`scenarios.observation_noise`, seeded per trajectory); labels and influence still describe the
clean run, and the file's config records SIGMA under "observation_noise_m".

Interrupts: while episodes are rolled out, SIGINT and SIGTERM are only recorded and handed to the
caller's own handler between episodes, or batches of them
(`pipeline.signals.DeferredSignals`), so Ctrl-C ends a run cleanly with
KeyboardInterrupt (the default SIGINT handler) and no file; worker processes ignore Ctrl-C and
are stopped by this process.
"""

from __future__ import annotations

import dataclasses
import errno
import gc
import os
import sys
import time
from pathlib import Path

import numpy as np

from pipeline.backends import BACKENDS
from pipeline.dataset_plan import (  # noqa: F401 (the generator's public names, re-exported)
    DEFAULT_MINOR_RATIO,
    DEFAULT_SCENARIO,
    FOCAL_AGENTS,
    MAX_ATTEMPTS,
    MAX_MINOR_RATIO,
    MAX_SEED,
    SEED_STRIDE,
    SPLIT_ORDER,
    GenerateConfig,
    GenerationResult,
    UnsafeExpertError,
    check_int,
    dataset_meta,
    default_output,
    is_safe,
    plan,
    rollout_session,
    to_trajectory_set,
)
from pipeline.episode_runner import DEFAULT_BATCH_SCENES, Slot
from pipeline.sharded_generation import generate_sharded
from scenarios import VERSIONS, Scenario
from scenarios.counterfactual import INFLUENCE_KINDS, influence_matrices, windowed_influence
from scenarios.observation_noise import add_observation_noise, check_noise
from scenarios.rollout import Episode
from trajectory_data import format as data_format
from trajectory_data.format import (
    INFLUENCE,
    INFLUENCE_WINDOWS,
    DatasetMeta,
    TrajectorySet,
    write_dataset,
)

assert INFLUENCE_KINDS == data_format.INFLUENCE_KINDS  # the scenarios' order is the format's


def generate_episodes(
    config: GenerateConfig,
    *,
    workers: int = 1,
    progress: bool = False,
    backend: str = "local",
    address: str | None = None,
    batch_scenes: int = DEFAULT_BATCH_SCENES,
) -> tuple[list[Slot], list[Episode], int]:
    """Roll out every planned trajectory, replacing unsafe ones with fresh seeds.

    Returns the final slots, their episodes and how many episodes were rejected. Replacement
    seeds continue after the planned ones, in slot order, so the result is deterministic.
    `backend` "local" runs `workers` processes here; "ray" runs chunks as Ray tasks on the
    cluster at `address` (else RAY_ADDRESS, else a local Ray instance with `workers` CPUs; see
    pipeline.ray_backend), with the same result. `batch_scenes` episodes are stepped together as
    one batched world (1: one by one), with the same result.
    Raises UnsafeExpertError if some stay unsafe, KeyboardInterrupt on Ctrl-C (see the module),
    RayUnavailableError if Ray is asked for but not installed.
    """
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    check_int("batch_scenes", batch_scenes, 1)
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    slots = plan(config)
    next_seed = SEED_STRIDE * config.seed + len(slots)
    episodes: list[Episode | None] = [None] * len(slots)
    pending = list(range(len(slots)))
    rejected = 0
    with rollout_session(config, len(slots), workers, progress, backend, address, batch_scenes) as (
        roll_out,
        bar,
    ):
        for _ in range(MAX_ATTEMPTS):
            results = roll_out([slots[i] for i in pending])
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
            bar.total += len(retry)
            pending = retry
            if not pending:
                # pymunk objects are freed by the cyclic garbage collector, through cffi
                # callbacks: free them now, while signals are deferred, not during writing
                gc.collect()
                return slots, episodes, rejected
    raise UnsafeExpertError(
        f"{len(pending)} trajectories were still unsafe after {MAX_ATTEMPTS} "
        "rounds of fresh seeds; the expert policy needs fixing"
    )


# ---- writing --------------------------------------------------------------------------------
def _build_splits(
    slots: list[Slot],
    episodes: list[Episode],
    scenario: Scenario,
    influence: np.ndarray | None = None,
    observation_noise_m: float = 0.0,
    influence_windows: np.ndarray | None = None,
) -> dict[str, TrajectorySet]:
    """The splits' sets, with `influence` (one (2, N, N) per slot) and `influence_windows` (one
    (W, N, N) per slot) attached and the observed positions blurred by `observation_noise_m`
    where given."""
    splits = {}
    case_names = tuple(scenario.case_names)
    for split in SPLIT_ORDER:
        rows = [k for k, slot in enumerate(slots) if slot.split == split]
        data = (
            to_trajectory_set([episodes[k] for k in rows], case_names)
            if rows
            else TrajectorySet.empty(scenario.config.num_steps, episodes[0].states.shape[1])
        )
        if observation_noise_m > 0:
            states = add_observation_noise(
                data.states,
                data.valid,
                data.seed,
                scenario.config.num_observed,
                observation_noise_m,
            )
            data = dataclasses.replace(data, states=states)
        if influence is not None:
            data = dataclasses.replace(data, influence=influence[rows])
        if influence_windows is not None:
            data = dataclasses.replace(data, influence_windows=influence_windows[rows])
        splits[split] = data
    return splits


def slot_influence(
    scenario: Scenario, slots: list[Slot], batch_scenes: int = DEFAULT_BATCH_SCENES
) -> np.ndarray:
    """(len(slots), 2, N, N) float32 influence matrices of the slots' episodes (their plans
    drawn again from their seeds), `batch_scenes` scenes at a time
    (`scenarios.counterfactual.influence_matrices`)."""
    check_int("batch_scenes", batch_scenes, 1)
    parts = [influence_matrices(scenario, [])]
    for start in range(0, len(slots), batch_scenes):
        batch = slots[start : start + batch_scenes]
        parts.append(influence_matrices(scenario, [scenario.plan(s.seed, s.case) for s in batch]))
    return np.concatenate(parts)


def slot_windowed_influence(
    scenario: Scenario,
    slots: list[Slot],
    window_steps: int,
    batch_scenes: int = DEFAULT_BATCH_SCENES,
) -> np.ndarray:
    """(len(slots), W, N, N) float32 influence per time window of `window_steps` steps of the
    slots' episodes (`scenarios.counterfactual.windowed_influence`); about 2 batch_scenes / W
    scenes at a time, so that a call steps about as many worlds as `slot_influence`'s."""
    check_int("batch_scenes", batch_scenes, 1)
    parts = [windowed_influence(scenario, [], window_steps)]
    scenes = max(1, 2 * batch_scenes // parts[0].shape[1])
    for start in range(0, len(slots), scenes):
        batch = [scenario.plan(s.seed, s.case) for s in slots[start : start + scenes]]
        parts.append(windowed_influence(scenario, batch, window_steps))
    return np.concatenate(parts)


def with_options(
    meta: DatasetMeta,
    influence: bool,
    observation_noise_m: float,
    influence_window_steps: int = 0,
) -> DatasetMeta:
    """`meta` recording influence (per window of `influence_window_steps` steps where >= 1)
    and the observation noise where asked (unchanged if not)."""
    if influence:
        meta = dataclasses.replace(meta, recorded=(*meta.recorded, INFLUENCE))
    if influence_window_steps:
        meta = dataclasses.replace(
            meta,
            recorded=(*meta.recorded, INFLUENCE_WINDOWS),
            influence_window_steps=influence_window_steps,
        )
    if observation_noise_m > 0:
        meta = dataclasses.replace(
            meta, config={**meta.config, "observation_noise_m": observation_noise_m}
        )
    return meta


def _check_output(out: Path, overwrite: bool) -> None:
    """Refuse an existing file (unless overwrite) or a directory; create missing directories."""
    if out.is_dir():
        raise IsADirectoryError(f"output {out} is a directory")
    if out.exists() and not overwrite:
        raise FileExistsError(f"output {out} already exists; pass overwrite=True to replace it")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError:  # a file stands where the directory should be
        raise NotADirectoryError(
            errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(out.parent)
        ) from None


def generate_dataset(
    config: GenerateConfig,
    out: str | Path,
    *,
    workers: int = 1,
    overwrite: bool = False,
    progress: bool = True,
    backend: str = "local",
    address: str | None = None,
    batch_scenes: int = DEFAULT_BATCH_SCENES,
    shard_size: int | None = None,
    influence: bool = False,
    observation_noise_m: float = 0.0,
    influence_window_steps: int = 0,
) -> GenerationResult:
    """Roll out `config`'s trajectories, check them, and write the dataset to `out` atomically.

    The output is byte for byte the same for any `workers`, `backend` ("local": processes
    here; "ray": Ray tasks, see `generate_episodes`) and `batch_scenes` (episodes stepped
    together as one batched world; 1: one by one). Missing parent directories are created.
    A progress bar, then a status line while the file is written, go to stderr unless
    `progress` is False.
    Raises FileExistsError if `out` exists and not `overwrite` (checked before any work, and
    again when writing), IsADirectoryError if it is a directory, another OSError if it cannot be
    written, ValueError for workers < 1 or batch_scenes < 1, UnsafeExpertError (see
    `generate_episodes`), and KeyboardInterrupt on Ctrl-C (SIGTERM too where a handler raises
    it), with nothing written.

    `shard_size` (default None: one file): `out` is a folder (no .h5 suffix) of shard files of at
    most `shard_size` trajectories of one split each, plus `out/index.h5`, which reads exactly as
    the single file would (`trajectory_data.shards`; the result's `path`). Each shard is written as
    soon as it is done, so memory holds about one shard (`pipeline.sharded_generation`); the output
    is the same for any `workers` and `backend`. An existing `out` is replaced (with `overwrite`)
    only if it is a file or a sharded dataset's folder, else IsADirectoryError.

    `influence` (default False): also compute and store every trajectory's influence matrices
    (see the module; single files only, ValueError with `shard_size`). `observation_noise_m`
    (default 0, >= 0): Gaussian noise [m] on the observed positions (see the module).
    `influence_window_steps` (default 0: none; else >= 1): also compute and store the influence
    per predicted-time window of that many steps (see the module; single files only).
    """
    out = Path(out)
    observation_noise_m = check_noise(observation_noise_m)
    if not isinstance(influence, bool):
        raise ValueError(f"influence must be True or False, got {influence!r}")
    check_int("influence_window_steps", influence_window_steps, 0)
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    check_int("batch_scenes", batch_scenes, 1)
    if shard_size is not None:
        check_int("shard_size", shard_size, 1)
        if out.suffix in (".h5", ".hdf5"):
            raise ValueError(f"with shard_size, out names a folder (no .h5 suffix), got {out}")
        if influence or influence_window_steps:
            raise ValueError("influence is written to single files only, not with shard_size")
        return generate_sharded(
            config,
            out,
            shard_size,
            workers=workers,
            overwrite=overwrite,
            progress=progress,
            backend=backend,
            batch_scenes=batch_scenes,
            address=address,
            observation_noise_m=observation_noise_m,
        )
    _check_output(out, overwrite)
    start = time.perf_counter()
    slots, episodes, rejected = generate_episodes(
        config,
        workers=workers,
        progress=progress,
        backend=backend,
        address=address,
        batch_scenes=batch_scenes,
    )
    if progress:  # stacking and writing a large set takes seconds: say what is going on
        print(f"writing {len(episodes):,} trajectories to {out} ...", file=sys.stderr, flush=True)
    scenario = VERSIONS[config.scenario].make()
    matrices = windows = None
    if influence:
        if progress:
            print("computing influence matrices ...", file=sys.stderr, flush=True)
        matrices = slot_influence(scenario, slots, batch_scenes)
    if influence_window_steps:
        if progress:
            print("computing influence per time window ...", file=sys.stderr, flush=True)
        windows = slot_windowed_influence(scenario, slots, influence_window_steps, batch_scenes)
    splits = _build_splits(slots, episodes, scenario, matrices, observation_noise_m, windows)
    meta = with_options(
        dataset_meta(config, scenario, rejected),
        influence,
        observation_noise_m,
        influence_window_steps,
    )
    write_dataset(out, meta, splits, overwrite=overwrite)
    counts = {
        split: {name: int((data.case == i).sum()) for i, name in enumerate(meta.case_names)}
        for split, data in splits.items()
    }
    return GenerationResult(
        path=out,
        meta=meta,
        counts=counts,
        num_agents=splits["train"].num_agents,
        rejected=rejected,
        seconds=time.perf_counter() - start,
    )
