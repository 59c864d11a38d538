"""B scenes of a scenario under the environments' rules, as arrays: the core that the PettingZoo
environment (one scene, `scenarios.env`) and the vector environment (B scenes,
`scenarios.vector_env`) both step, so the two agree scene by scene.

Rules: every car's control (B, N, 2) is held for `record_every` simulation steps; a car that
collides or leaves the road is removed at once (frozen, no longer colliding, presence 0 in the
others' observations) and its agent terminates; an agent's observation (D,) is its own state and
then, for every other car in agent order, a presence flag and that car's state relative to it;
its reward is progress (speed along the road, or along its route at a junction) plus penalties
for a collision and for leaving the road.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlo_lite import BatchedWorld, wrap_angle
from scenarios.base import Scenario, ScenarioConfig, ScenarioPlan
from scenarios.expert import expert_for
from scenarios.junction import JunctionExpert

EGO_FEATURES = 4  # x, y, heading, speed
OTHER_FEATURES = 5  # presence, dx, dy, d_heading, d_speed


def position_box(scenario: Scenario) -> tuple[float, float, float, float]:
    """(x_min, y_min, x_max, y_max) [m] that observed positions are clipped to: the scenario's
    `position_bounds()` rounded outwards to whole metres (so the manual states them exactly;
    the straight road's box [0, length] x [0, width] is kept as it is)."""
    x_min, y_min, x_max, y_max = scenario.position_bounds()
    return (
        float(np.floor(x_min)),
        float(np.floor(y_min)),
        float(np.ceil(x_max)),
        float(np.ceil(y_max)),
    )


def observation_bounds(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds (D,) float32 of one agent's observation; D = 4 + 5 (N - 1).

    Positions lie in the scenario's box (`position_box`); a relative position is at most the
    box's extent either way."""
    x_min, y_min, x_max, y_max = position_box(scenario)
    length, width = x_max - x_min, y_max - y_min
    top_speed = scenario.config.limits.max_speed_mps
    ego_low = [x_min, y_min, -np.pi, 0.0]
    ego_high = [x_max, y_max, np.pi, top_speed]
    other_low = [0.0, -length, -width, -np.pi, -top_speed]
    other_high = [1.0, length, width, np.pi, top_speed]
    num_cars = scenario.num_cars
    low = np.array(ego_low + other_low * (num_cars - 1), dtype=np.float32)
    high = np.array(ego_high + other_high * (num_cars - 1), dtype=np.float32)
    return low, high


def action_bounds(config: ScenarioConfig) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds (2,) float32 of an action [steering rad, acceleration m/s^2]."""
    limits = config.limits
    low = np.array([-limits.max_steer_rad, -limits.max_decel_mps2], dtype=np.float32)
    high = np.array([limits.max_steer_rad, limits.max_accel_mps2], dtype=np.float32)
    return low, high


def _off_diagonal(pairs: np.ndarray) -> np.ndarray:
    """(N, N, ...) -> (N, N-1, ...): entry [i, j] for every j != i, in order (a copy)."""
    num_cars = pairs.shape[0]
    tail = pairs.shape[2:]
    flat = pairs.reshape(num_cars * num_cars, *tail)[1:]
    rows = flat.reshape(num_cars - 1, num_cars + 1, *tail)[:, :num_cars]
    return rows.reshape(num_cars, num_cars - 1, *tail)


def advance_scenes(
    world: BatchedWorld, controls: np.ndarray, sub_steps: int, remove_crashed: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Step `world` `sub_steps` times under held `controls` (B, N, 2), checking every step.

    Returns per-car flags (B, N) bool: collided, off_road during these steps. With
    `remove_crashed`, a car is deactivated (frozen, no longer colliding) as soon as it collides
    or leaves the road.
    """
    collided = np.zeros((world.num_scenes, world.num_cars), dtype=bool)
    off_road = np.zeros_like(collided)
    for _ in range(sub_steps):
        world.step(controls)
        hit, left = world.incidents()
        collided |= hit
        off_road |= left
        if remove_crashed and (hit.any() or left.any()):
            world.deactivate(hit | left)
    return collided, off_road


@dataclass(frozen=True)
class RewardWeights:
    """Reward per agent and step: `speed` x v cos(heading) / max speed, plus `collision` if it
    collided and `off_road` if it left the road during the step. The heading is relative to the
    direction of progress (`Scenes.progress_heading`): the road's on the straight road, the
    car's route's on a junction layout (speed along the route, so circling earns nothing)."""

    speed: float = 0.1
    collision: float = -1.0
    off_road: float = -1.0


class Scenes:
    """B scenes of `scenario`, one per plan, driven by its expert in one batched world."""

    def __init__(self, scenario: Scenario, plans: Sequence[ScenarioPlan]) -> None:
        self.scenario = scenario
        self.config = scenario.config
        self.expert = expert_for(scenario, plans)
        self.world = self.expert.make_world()
        self.num_scenes, self.num_cars = len(plans), scenario.num_cars
        self._low, self._high = observation_bounds(scenario)
        # every car's observation lists the others in agent order, skipping itself: (N, N-1)
        everyone = np.arange(self.num_cars)
        self._others = np.array([np.delete(everyone, index) for index in everyone])

    def restart(self, scenes: np.ndarray, plans: Sequence[ScenarioPlan]) -> None:
        """New episodes in `scenes` from `plans`; call `update` before reading them."""
        self.expert.restart(scenes, plans, self.world)

    def update(self) -> None:
        """Let the expert see the current step (once per step, after `advance` or a start)."""
        self.expert.update(self.world)

    def advance(self, controls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hold `controls` (B, N, 2) for one env step, removing cars that crash; returns
        (collided, off_road) (B, N) bool."""
        return advance_scenes(self.world, controls, self.config.record_every, remove_crashed=True)

    def expert_actions(self) -> np.ndarray:
        """The expert's controls (B, N, 2) float32 for the current step."""
        return self.expert.expert_actions(self.world)

    def observations(self) -> np.ndarray:
        """(N, B, D) float32, agent-major: each agent's ego state, then the others' relative
        states in agent order (so one agent's rows over the scenes are contiguous).

        Computed with the scenes innermost (long vectorised loops), in float64, clipped to the
        bounds and rounded once to float32. The bounds are float32 numbers, so clipping before
        the rounding gives the values that clipping after it would.
        """
        world = self.world
        num_scenes, num_cars = self.num_scenes, self.num_cars
        low, high = self._low, self._high
        state = world.state  # (B, N, 4)
        columns = np.ascontiguousarray(state.transpose(2, 1, 0))  # (4, N, B)
        out = np.empty((num_cars, num_scenes, len(low)), dtype=np.float32)  # (N, B, D)
        out[..., :EGO_FEATURES] = np.clip(
            state.transpose(1, 0, 2), low[:EGO_FEATURES], high[:EGO_FEATURES]
        )
        block = out[..., EGO_FEATURES:].reshape(num_cars, num_scenes, num_cars - 1, OTHER_FEATURES)
        active = world.active
        present = None
        if not active.all():
            present = _off_diagonal(np.broadcast_to(active.T[None], (num_cars, *active.T.shape)))
            block[..., 0] = present.transpose(0, 2, 1)
        else:
            block[..., 0] = 1.0
        for feature in range(EGO_FEATURES):
            column = columns[feature]  # (N, B)
            relative = column[None, :, :] - column[:, None, :]  # (N, N, B): [i, j] = j - i
            if feature == 2:
                relative = wrap_angle(relative)
            relative = _off_diagonal(relative)  # (N, N-1, B)
            if present is not None:
                relative *= present
            bound = EGO_FEATURES + feature + 1  # this feature's bounds, for the first other car
            np.clip(relative, float(low[bound]), float(high[bound]), out=relative)
            block[..., feature + 1] = relative.transpose(0, 2, 1)
        return out

    def rewards(
        self, collided: np.ndarray, off_road: np.ndarray, weights: RewardWeights
    ) -> np.ndarray:
        """(B, N) float: the reward of every car for the step that flagged `collided` and
        `off_road` (B, N)."""
        world = self.world
        forward = world.speed * np.cos(self.progress_heading())  # (B, N) [m/s]
        return (
            weights.speed * forward / self.config.limits.max_speed_mps
            + weights.collision * collided
            + weights.off_road * off_road
        )

    def progress_heading(self) -> np.ndarray:
        """(B, N) [rad]: each car's heading relative to the direction of progress, the road's
        (+x) on the straight road and its route's at its closest point on a layout."""
        world = self.world
        if not isinstance(self.expert, JunctionExpert):
            return world.heading
        self.expert.read_frames(world)  # once per step: the expert's own route frames
        route_heading = self.expert.route_heading.reshape(self.num_scenes, self.num_cars)
        return world.heading - route_heading

    def labels(self) -> tuple[np.ndarray, np.ndarray]:
        """(attention (B, N) int16, interaction (B,) bool) at the current step."""
        return self.expert.attention_labels(self.world), self.expert.interaction(self.world)

    def state(self) -> np.ndarray:
        """Global states (B, N, 4) float32 of every car, clipped to the observation bounds."""
        low, high = self._low[:EGO_FEATURES], self._high[:EGO_FEATURES]
        return np.clip(self.world.state, low, high).astype(np.float32)
