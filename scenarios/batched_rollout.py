"""Roll out many episodes of one scenario as one batched world: `rollout_batch`.

    episodes = rollout_batch(ReactiveDoubleMerge(), seeds=[0, 1, 2], cases=["major"] * 3)

gives the same list as `[rollout(scenario, seed, case) for ...]`, bit for bit (every Episode
array and flag; tested), several times faster: B scenes are stepped together in a
`carlo_lite.BatchedWorld` by the scenario's `BatchedExpert`, so numpy's per-call overhead is
paid once per step for all scenes instead of once per scene. Each scene's plan is drawn from
`np.random.default_rng(seed)` exactly as `rollout` draws it.

Scenarios with a batched expert are those in `BATCHED_EXPERTS`, matched by exact class (a
subclass may change the expert, so it does not inherit its parent's batched one): the four
registered scenarios, v0 and v1 of Double Merge and Halting Car. For any other scenario
`rollout_batch` falls back to `rollout`, one scene at a time, with the same result.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scenarios.base import Scenario
from scenarios.batched_expert import BatchedExpert
from scenarios.double_merge import DoubleMerge
from scenarios.double_merge_batched import BatchedDoubleMerge, BatchedReactiveDoubleMerge
from scenarios.double_merge_reactive import ReactiveDoubleMerge
from scenarios.halting_car import HaltingCar
from scenarios.halting_car_batched import BatchedHaltingCar, BatchedReactiveHaltingCar
from scenarios.halting_car_fixed_brake import FixedBrakeHaltingCar
from scenarios.halting_car_late import LateBrakeHaltingCar
from scenarios.halting_car_reactive import ReactiveHaltingCar
from scenarios.rollout import Episode, rollout

BATCHED_EXPERTS: dict[type[Scenario], type[BatchedExpert]] = {
    DoubleMerge: BatchedDoubleMerge,
    ReactiveDoubleMerge: BatchedReactiveDoubleMerge,
    HaltingCar: BatchedHaltingCar,
    ReactiveHaltingCar: BatchedReactiveHaltingCar,
    LateBrakeHaltingCar: BatchedReactiveHaltingCar,  # v1's expert, v2's ranges (in the plans)
    FixedBrakeHaltingCar: BatchedReactiveHaltingCar,  # v1's expert, v3's ranges
}


def has_batched_expert(scenario: Scenario) -> bool:
    """Whether `rollout_batch` steps `scenario` as a batched world (else it falls back)."""
    return type(scenario) in BATCHED_EXPERTS


def rollout_batch(scenario: Scenario, seeds: Sequence[int], cases: Sequence[str]) -> list[Episode]:
    """Episodes of `scenario` for `seeds` and `cases` (one each, any mix of cases), in order.

    The result equals `rollout(scenario, seed, case)` for every pair. Raises ValueError for an
    unknown case or unequal lengths.
    """
    if len(seeds) != len(cases):
        raise ValueError(f"got {len(seeds)} seeds for {len(cases)} cases")
    expert_class = BATCHED_EXPERTS.get(type(scenario))
    if expert_class is None:
        return [rollout(scenario, seed, case) for seed, case in zip(seeds, cases)]
    if not seeds:
        return []
    plans = [
        scenario.sample_plan(np.random.default_rng(seed), scenario.check_case(case))
        for seed, case in zip(seeds, cases)
    ]
    expert = expert_class(scenario, plans)
    record = _record(expert)
    return [
        Episode(
            states=record["states"][b],
            actions=record["actions"][b],
            valid=record["valid"][b],
            attention=record["attention"][b],
            interaction=record["interaction"][b],
            roles=scenario.roles.copy(),
            collided=bool(record["collided"][b]),
            off_road=bool(record["off_road"][b]),
            seed=int(seed),
            case=case,
            dt=scenario.config.recorded_dt,
            scenario=scenario.name,
        )
        for b, (seed, case) in enumerate(zip(seeds, cases))
    ]


def _record(expert: BatchedExpert) -> dict[str, np.ndarray]:
    """Step the expert's scenes through one episode, as `rollout` does for one scene."""
    config = expert.config
    num_scenes, num_steps, num_cars = expert.num_scenes, config.num_steps, expert.num_cars
    world = expert.make_world()
    states = np.empty((num_scenes, num_steps, num_cars, 4), dtype=np.float32)
    actions = np.empty((num_scenes, num_steps, num_cars, 2), dtype=np.float32)
    attention = np.empty((num_scenes, num_steps, num_cars), dtype=np.int16)
    interaction = np.empty((num_scenes, num_steps), dtype=bool)
    collided = np.zeros(num_scenes, dtype=bool)
    off_road = np.zeros(num_scenes, dtype=bool)
    for step in range(num_steps):
        expert.update(world)
        states[:, step] = world.state
        attention[:, step] = expert.attention_labels(world)
        interaction[:, step] = expert.interaction(world)
        controls = expert.expert_actions(world)  # (B, N, 2) float32
        actions[:, step] = controls
        for _ in range(config.record_every):
            world.step(controls)
            hit, left = world.incidents()  # (B, N) each
            collided |= hit.any(axis=1)
            off_road |= left.any(axis=1)
    return {
        "states": states,
        "actions": actions,
        "valid": np.ones((num_scenes, num_steps, num_cars), dtype=bool),  # no car is removed
        "attention": attention,
        "interaction": interaction,
        "collided": collided,
        "off_road": off_road,
    }
