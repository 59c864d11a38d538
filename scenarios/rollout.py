"""Run a scenario's expert for whole episodes, directly on carlo_lite (no PettingZoo), and record
them as arrays: `rollout` for one episode, `rollout_batch` for many stepped as one batched world.

    scenario = scenarios.make("double_merge_v1")
    episodes = rollout_batch(scenario, seeds=[0, 1, 2], cases=["major"] * 3)

Each scene's plan is drawn from `np.random.default_rng(seed)`, and a scene's episode is the
same bit for bit whatever else is in its batch (`scenarios.expert`), so `rollout(scenario,
seed, case)` equals the matching entry of any batch. This is what the dataset generator calls;
the PettingZoo environments step the same expert and world (`scenarios.scenes`), so an
environment stepped with expert actions reproduces `rollout`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlo_lite import World
from scenarios.base import Scenario, ScenarioPlan
from scenarios.expert import expert_for


@dataclass(frozen=True, eq=False)
class Episode:
    """One recorded episode: T recorded steps, N cars, recorded every `dt` seconds.

    `actions[t]` is the control applied (held for one recorded step) right after `states[t]`;
    `attention[t]` and `interaction[t]` describe the expert's phase when it chose `actions[t]`.
    `collided` and `off_road` cover every simulated step, not only the recorded ones.
    """

    states: np.ndarray  # (T, N, 4) float32 [x m, y m, heading rad, speed m/s]
    actions: np.ndarray  # (T, N, 2) float32 [steering rad, acceleration m/s^2]
    valid: np.ndarray  # (T, N) bool, car present
    attention: np.ndarray  # (T, N) int16, index of the car reacted to, -1 for none
    interaction: np.ndarray  # (T,) bool, inside the interaction period
    roles: np.ndarray  # (N,) int8, index into the scenario's role_names
    collided: bool
    off_road: bool
    seed: int
    case: str
    dt: float  # seconds between recorded steps
    scenario: str


def advance(
    world: World, controls: np.ndarray, sub_steps: int, remove_crashed: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Step the one-scene `world` `sub_steps` times under held `controls` (N, 2), checking
    every step (`scenarios.scenes.advance_scenes` for a batch).

    Returns per-car flags (N,) bool: collided, off_road during these steps. With
    `remove_crashed`, a car is deactivated (frozen, no longer colliding) as soon as it collides
    or leaves the road.
    """
    from scenarios.scenes import advance_scenes

    collided, off_road = advance_scenes(world.batch, controls[None], sub_steps, remove_crashed)
    return collided[0], off_road[0]


def rollout(
    scenario: Scenario,
    seed: int,
    case: str,
    *,
    rng: np.random.Generator | None = None,
    plan: ScenarioPlan | None = None,
    forced_actions: np.ndarray | None = None,
) -> Episode:
    """Run `scenario`'s expert for one episode of `case` and record it.

    Randomness comes only from `rng` (default `np.random.default_rng(seed)`), or from `plan`
    when one is given (then nothing is drawn). `forced_actions` (T, N, 2) replaces the expert's
    controls wherever it is not NaN (per car and step), to test how the other cars react.
    """
    if plan is None:
        rng = np.random.default_rng(seed) if rng is None else rng
        plan = scenario.sample_plan(rng, scenario.check_case(case))
    forced = None if forced_actions is None else np.asarray(forced_actions)[None]
    return rollout_batch(scenario, [seed], [case], plans=[plan], forced_actions=forced)[0]


def rollout_batch(
    scenario: Scenario,
    seeds: Sequence[int],
    cases: Sequence[str],
    *,
    plans: Sequence[ScenarioPlan] | None = None,
    forced_actions: np.ndarray | None = None,
) -> list[Episode]:
    """Episodes of `scenario` for `seeds` and `cases` (one each, any mix of cases), in order.

    `plans` (one per seed) replaces the plans drawn from the seeds; `forced_actions` (B, T, N,
    2) replaces the expert's controls wherever it is not NaN. Raises ValueError for an unknown
    case, unequal lengths or a forced_actions array of another shape.
    """
    if len(seeds) != len(cases):
        raise ValueError(f"got {len(seeds)} seeds for {len(cases)} cases")
    for case in cases:
        scenario.check_case(case)
    if not seeds:
        return []
    config = scenario.config
    shape = (len(seeds), config.num_steps, scenario.num_cars, 2)
    if forced_actions is not None and forced_actions.shape != shape:
        raise ValueError(
            f"forced_actions must have shape {shape[1:] if len(seeds) == 1 else shape}"
        )
    if plans is None:
        plans = [scenario.plan(seed, case) for seed, case in zip(seeds, cases)]
    elif len(plans) != len(seeds):
        raise ValueError(f"got {len(plans)} plans for {len(seeds)} seeds")
    record = _record(scenario, plans, forced_actions)
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
            dt=config.recorded_dt,
            scenario=scenario.name,
        )
        for b, (seed, case) in enumerate(zip(seeds, cases))
    ]


def _record(
    scenario: Scenario, plans: Sequence[ScenarioPlan], forced_actions: np.ndarray | None
) -> dict[str, np.ndarray]:
    """Step the plans' scenes through one episode with the expert and record it."""
    from scenarios.scenes import advance_scenes

    config = scenario.config
    num_scenes, num_steps, num_cars = len(plans), config.num_steps, scenario.num_cars
    expert = expert_for(scenario, plans)
    world = expert.make_world()
    states = np.empty((num_scenes, num_steps, num_cars, 4), dtype=np.float32)
    actions = np.empty((num_scenes, num_steps, num_cars, 2), dtype=np.float32)
    valid = np.empty((num_scenes, num_steps, num_cars), dtype=bool)
    attention = np.empty((num_scenes, num_steps, num_cars), dtype=np.int16)
    interaction = np.empty((num_scenes, num_steps), dtype=bool)
    collided = np.zeros(num_scenes, dtype=bool)
    off_road = np.zeros(num_scenes, dtype=bool)
    for step in range(num_steps):
        expert.update(world)
        states[:, step] = world.state
        valid[:, step] = world.active
        attention[:, step] = expert.attention_labels(world)
        interaction[:, step] = expert.interaction(world)
        controls = expert.expert_actions(world)  # (B, N, 2) float32
        if forced_actions is not None:
            forced = ~np.isnan(forced_actions[:, step, :, 0])  # (B, N)
            controls[forced] = forced_actions[:, step][forced]
        actions[:, step] = controls
        hit, left = advance_scenes(world, controls, config.record_every)
        collided |= hit.any(axis=1)
        off_road |= left.any(axis=1)
    return {
        "states": states,
        "actions": actions,
        "valid": valid,
        "attention": attention,
        "interaction": interaction,
        "collided": collided,
        "off_road": off_road,
    }
