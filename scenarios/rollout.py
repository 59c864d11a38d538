"""Run the expert for one episode directly on carlo_lite (no PettingZoo) and record it as arrays.

This is what the dataset generator calls; the PettingZoo environments step the world through the
same `advance` function, so an environment stepped with expert actions reproduces `rollout`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from carlo_lite import World
from scenarios.base import Scenario, ScenarioPlan


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
    """Step `world` `sub_steps` times under held `controls` (N, 2), checking every step.

    Returns per-car flags (N,) bool: collided, off_road during these steps (`world.incidents()`
    after every step). With `remove_crashed`, a car is deactivated (frozen, no longer
    colliding) as soon as it collides or leaves the road.
    """
    collided = np.zeros(world.num_cars, dtype=bool)
    off_road = np.zeros(world.num_cars, dtype=bool)
    for _ in range(sub_steps):
        world.step(controls)
        hit, left = world.incidents()
        collided |= hit
        off_road |= left
        if remove_crashed and (collided.any() or off_road.any()):
            world.deactivate(np.nonzero((collided | off_road) & world.active)[0])
    return collided, off_road


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
    config = scenario.config
    num_steps, num_cars = config.num_steps, scenario.num_cars
    if forced_actions is not None and forced_actions.shape != (num_steps, num_cars, 2):
        raise ValueError(f"forced_actions must have shape {(num_steps, num_cars, 2)}")
    rng = np.random.default_rng(seed) if rng is None and plan is None else rng
    world = scenario.reset(rng, case, plan=plan)
    states = np.empty((num_steps, num_cars, 4), dtype=np.float32)
    actions = np.empty((num_steps, num_cars, 2), dtype=np.float32)
    valid = np.empty((num_steps, num_cars), dtype=bool)
    attention = np.empty((num_steps, num_cars), dtype=np.int16)
    interaction = np.empty(num_steps, dtype=bool)
    collided = off_road = False
    for step in range(num_steps):
        scenario.update(world)
        states[step] = world.state
        valid[step] = world.active
        attention[step] = scenario.attention_labels(world)
        interaction[step] = scenario.interaction(world)
        controls = scenario.expert_actions(world)  # (N, 2) float32
        if forced_actions is not None:
            forced = ~np.isnan(forced_actions[step, :, 0])
            controls[forced] = forced_actions[step, forced]
        actions[step] = controls
        hit, left = advance(world, controls, config.record_every)
        collided |= bool(hit.any())
        off_road |= bool(left.any())
    return Episode(
        states=states,
        actions=actions,
        valid=valid,
        attention=attention,
        interaction=interaction,
        roles=scenario.roles.copy(),
        collided=collided,
        off_road=off_road,
        seed=int(seed),
        case=case,
        dt=config.recorded_dt,
        scenario=scenario.name,
    )
