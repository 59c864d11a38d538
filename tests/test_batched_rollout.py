"""scenarios.rollout_batch against its truth, `rollout` one scene at a time: every Episode array
and flag bit for bit equal, for every scenario with a batched expert, both cases mixed in one
batch, batches of 1 and of sizes that split the seeds unevenly, and scenes whose expert collides
or leaves the road (perturbed configs). A scenario without a batched expert falls back."""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest

from scenarios import (
    SCENARIOS,
    DoubleMerge,
    DoubleMergeConfig,
    Episode,
    ReactiveDoubleMerge,
    ReactiveDoubleMergeConfig,
    ReactiveHaltingCar,
    ReactiveHaltingCarConfig,
    rollout,
)
from scenarios.base import Scenario
from scenarios.batched_expert import scalar_idm_accel
from scenarios.batched_rollout import BATCHED_EXPERTS, has_batched_expert, rollout_batch
from scenarios.controllers import IDMParams, idm_accel

SEEDS_PER_CASE = 40
ARRAYS = ("states", "actions", "valid", "attention", "interaction", "roles")
FIELDS = ("collided", "off_road", "seed", "case", "dt", "scenario")


def assert_same_episode(got: Episode, want: Episode) -> None:
    label = f"seed {want.seed} {want.case}"
    for name in ARRAYS:
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and a.shape == b.shape, f"{label}: {name}"
        np.testing.assert_array_equal(a, b, err_msg=f"{label}: {name}")
    for name in FIELDS:
        assert getattr(got, name) == getattr(want, name), f"{label}: {name}"


def mixed_slots(scenario: Scenario, num: int, first_seed: int = 0) -> tuple[list, list]:
    """`num` seeds per case, the cases in a fixed random order in one list."""
    seeds = list(range(first_seed, first_seed + 2 * num))
    order = np.random.default_rng(first_seed).permutation(2 * num) % 2
    return seeds, [scenario.case_names[k] for k in order]


@cache
def reference(name: str) -> tuple[Episode, ...]:
    scenario = SCENARIOS[name]()
    seeds, cases = mixed_slots(scenario, SEEDS_PER_CASE)
    return tuple(rollout(scenario, seed, case) for seed, case in zip(seeds, cases))


def test_every_registered_scenario_has_a_batched_expert():
    assert set(BATCHED_EXPERTS) == set(SCENARIOS.values())


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_batched_rollout_equals_rollout_scene_by_scene(name):
    scenario = SCENARIOS[name]()
    seeds, cases = mixed_slots(scenario, SEEDS_PER_CASE)
    assert {cases.count(case) for case in scenario.case_names} == {SEEDS_PER_CASE}
    want = reference(name)
    # batches of 1, 13, 13, ... and the rest: sizes that do not divide the 80 seeds
    bounds = [0, 1, *range(14, len(seeds), 13), len(seeds)]
    got = []
    for start, end in zip(bounds[:-1], bounds[1:]):
        got += rollout_batch(scenario, seeds[start:end], cases[start:end])
    assert len(got) == len(want)
    for episode, truth in zip(got, want):
        assert_same_episode(episode, truth)


PERTURBED = {  # configs under which some experts collide or leave the road, others do not
    "double_merge_v1 waits on the far side": ReactiveDoubleMerge(
        ReactiveDoubleMergeConfig(wait_offset_m=(-8.0, -0.5))
    ),
    "double_merge waits on the far side": DoubleMerge(DoubleMergeConfig(wait_offset_m=(-8.0, 0.9))),
    "halting_car_v1 short headway": ReactiveHaltingCar(
        ReactiveHaltingCarConfig(time_headway_s=(0.1, 1.0), brake_decel_mps2=(4.0, 8.0))
    ),
}


@pytest.mark.parametrize("label", sorted(PERTURBED))
def test_collisions_and_off_road_flags_match_rollout(label):
    scenario = PERTURBED[label]
    seeds, cases = mixed_slots(scenario, 20, first_seed=100)
    want = [rollout(scenario, seed, case) for seed, case in zip(seeds, cases)]
    got = rollout_batch(scenario, seeds, cases)
    unsafe = [e.collided or e.off_road for e in want]
    assert any(unsafe) and not all(unsafe)  # the batch mixes unsafe and safe scenes
    for episode, truth in zip(got, want):
        assert_same_episode(episode, truth)


def test_scalar_idm_accel_is_idm_accel_on_scalars():
    """The per-scene experts call idm_accel with numpy scalars (C `pow`); so must the batch."""
    rng = np.random.default_rng(5)
    count = 3000
    speed = rng.uniform(0.0, 15.0, count)
    desired = rng.uniform(8.0, 16.0, count)
    gap = rng.uniform(-1.0, 40.0, count)
    closing = rng.uniform(-5.0, 5.0, count)
    headway = rng.uniform(1.0, 2.0, count)
    params = IDMParams()
    got = scalar_idm_accel(speed, desired, gap, closing, headway, params)
    want = [
        idm_accel(
            speed[k],
            float(desired[k]),
            gap[k],
            closing[k],
            dataclasses.replace(params, time_headway_s=float(headway[k])),
        )
        for k in range(count)
    ]
    np.testing.assert_array_equal(got, np.array(want))


class RenamedHaltingCar(ReactiveHaltingCar):
    """A subclass: it may change the expert, so it must not inherit the batched one."""

    name = "renamed_halting_car"


def test_a_scenario_without_batched_expert_falls_back_to_rollout():
    scenario = RenamedHaltingCar()
    assert not has_batched_expert(scenario) and has_batched_expert(ReactiveHaltingCar())
    got = rollout_batch(scenario, [3, 4], ["go", "stop"])
    for episode, seed, case in zip(got, [3, 4], ["go", "stop"]):
        assert_same_episode(episode, rollout(scenario, seed, case))
        assert episode.scenario == "renamed_halting_car"


def test_bad_arguments():
    scenario = ReactiveHaltingCar()
    with pytest.raises(ValueError, match="2 seeds for 1 cases"):
        rollout_batch(scenario, [1, 2], ["go"])
    with pytest.raises(ValueError, match="unknown case"):
        rollout_batch(scenario, [1, 2], ["go", "major"])
    assert rollout_batch(scenario, [], []) == []
