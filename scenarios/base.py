"""What every scenario shares: configuration, roles, the road, distractors and the expert's
control assembly.

A scenario is a plain class (no PettingZoo). Per episode it draws a *plan* (initial states and
every random timing) from a `numpy.random.Generator`, builds a `carlo_lite.World`, and then, at
every control step, `update(world)` advances its small state machine from what it observes and
`expert_actions(world)` returns the expert's controls for all cars as one (N, 2) array.
`expert_actions` is a pure function of the world and that state machine, so it can be called
any number of times per step.

Agent order is fixed: index 0 is the green main car, index 1 the brown main car, then the
distractors (first the rightmost lane's, then the leftmost lane's, each from back to front).
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from carlo_lite import CarLimits, StraightRoad, World
from scenarios.controllers import LateralGains, lateral_steering, speed_tracking_accel

ROLE_NAMES: tuple[str, ...] = ("main_green", "main_brown", "distractor")
GREEN, BROWN, DISTRACTOR = 0, 1, 2  # indices into ROLE_NAMES; also the main cars' agent indices
NO_ATTENTION = -1

Range = tuple[float, float]  # (low, high) of a uniform draw


@dataclass(frozen=True)
class ScenarioConfig:
    """Settings shared by every scenario (SI units). Ranges are (low, high) of uniform draws.

    The expert acts once per recorded step and holds its controls over `record_every`
    simulation steps of `dt_sim`; collisions and road edges are checked at every simulation step.
    """

    dt_sim: float = 0.1  # simulation step [s]
    record_every: int = 2  # simulation steps per recorded (and control) step
    num_steps: int = 60  # recorded steps per episode, T (the initial state is step 0)
    num_observed: int = 15  # suggested observed (history) steps; the rest are predicted
    num_lanes: int = 4
    lane_width_m: float = 3.5
    road_length_m: float = 600.0
    car_length_m: float = 4.5
    car_width_m: float = 1.8
    wheelbase_m: float = 2.7
    num_distractors: int = 20  # split evenly over the two outer lanes
    distractor_speed_mps: Range = (7.0, 13.0)  # one constant speed per outer lane
    distractor_first_x_m: Range = (0.0, 20.0)  # x of the rearmost distractor of each lane
    distractor_gap_m: Range = (9.0, 20.0)  # centre-to-centre gap between lane neighbours
    speed_gain_per_s: float = 1.5  # speed tracking gain [1/s]
    lateral_gains: LateralGains = LateralGains()
    limits: CarLimits = CarLimits()

    def __post_init__(self) -> None:
        if not (self.dt_sim > 0 and self.record_every >= 1):
            raise ValueError("dt_sim must be positive and record_every at least 1")
        if not 1 <= self.num_observed < self.num_steps:
            raise ValueError("need 1 <= num_observed < num_steps")
        if self.num_lanes < 4 or self.num_distractors < 0:
            raise ValueError("need at least 4 lanes and a non-negative number of distractors")
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.name.endswith(("_m", "_s", "_mps", "_mps2", "_rad", "_ratio")) and isinstance(
                value, tuple
            ):
                if len(value) != 2 or not value[0] <= value[1]:
                    raise ValueError(f"{field.name} must be a (low, high) range, got {value}")
        if self.distractor_gap_m[0] <= self.car_length_m:
            raise ValueError("distractor_gap_m must exceed the car length")

    @property
    def num_predicted(self) -> int:
        return self.num_steps - self.num_observed

    @property
    def recorded_dt(self) -> float:
        """Seconds between recorded steps (= the expert's control period), rounded to 1e-12 s
        so that 0.1 * 3 reads 0.3."""
        return round(self.dt_sim * self.record_every, 12)

    @property
    def duration_s(self) -> float:
        """Simulated time of one episode [s]: num_steps control periods."""
        return self.num_steps * self.recorded_dt

    @property
    def num_cars(self) -> int:
        return 2 + self.num_distractors

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (ranges become lists) including the derived quantities."""
        values = dataclasses.asdict(self)
        values.update(num_predicted=self.num_predicted, recorded_dt=self.recorded_dt)
        return values


def uniform(rng: np.random.Generator, bounds: Range) -> float:
    """One draw from U[low, high]."""
    return float(rng.uniform(bounds[0], bounds[1]))


@dataclass(frozen=True, eq=False)
class ScenarioPlan:
    """Everything random about an episode, drawn at reset. Arrays are per car (N rows)."""

    initial_state: np.ndarray  # (N, 4) [x, y, heading, speed]
    lane_y: np.ndarray  # (N,) y [m] of each car's starting lane centre
    target_speed: np.ndarray  # (N,) cruising speed [m/s]


def sample_distractors(
    rng: np.random.Generator, config: ScenarioConfig, road: StraightRoad
) -> tuple[np.ndarray, np.ndarray]:
    """Distractor states (M, 4) and their lane-centre y (M,) on the two outer lanes.

    Each outer lane gets one random constant speed and cars at random gaps, so no distractor can
    ever catch up with another. The rightmost lane gets the extra car when M is odd.
    """
    outer_lanes = (0, config.num_lanes - 1)
    counts = (config.num_distractors - config.num_distractors // 2, config.num_distractors // 2)
    states, lane_y = [], []
    for lane, count in zip(outer_lanes, counts):
        speed = uniform(rng, config.distractor_speed_mps)
        first = uniform(rng, config.distractor_first_x_m)
        gaps = rng.uniform(*config.distractor_gap_m, size=max(count - 1, 0))
        x = first + np.concatenate([[0.0], np.cumsum(gaps)])[:count]  # (count,)
        y = road.lane_center_y(lane)
        states.append(
            np.column_stack([x, np.full(count, y), np.zeros(count), np.full(count, speed)])
        )
        lane_y.append(np.full(count, y))
    return np.concatenate(states).reshape(-1, 4), np.concatenate(lane_y)


class Scenario(ABC):
    """Base of the scenarios: subclasses draw a plan and steer the two main cars.

    Class attributes: `name`, `case_names`, `default_major_case`, `role_names`, `config_class`.
    """

    name: ClassVar[str]
    case_names: ClassVar[tuple[str, ...]]
    default_major_case: ClassVar[str]
    role_names: ClassVar[tuple[str, ...]] = ROLE_NAMES
    config_class: ClassVar[type[ScenarioConfig]] = ScenarioConfig

    def __init__(self, config: ScenarioConfig | None = None) -> None:
        config = self.config_class() if config is None else config
        if not isinstance(config, self.config_class):
            raise TypeError(f"{self.name} needs a {self.config_class.__name__}")
        self.config = config
        self.road = StraightRoad(config.num_lanes, config.lane_width_m, config.road_length_m)
        self.roles = np.array(
            [GREEN, BROWN] + [DISTRACTOR] * config.num_distractors, dtype=np.int8
        )  # (N,) index into role_names
        self.role_labels = tuple(ROLE_NAMES[role] for role in self.roles)
        self.plan: ScenarioPlan | None = None
        self.case: str | None = None

    @property
    def num_cars(self) -> int:
        return self.config.num_cars

    @property
    def control_period_s(self) -> float:
        return self.config.recorded_dt

    def check_case(self, case: str) -> str:
        if case not in self.case_names:
            raise ValueError(f"{self.name}: unknown case {case!r}; choose from {self.case_names}")
        return case

    # --- episode ----------------------------------------------------------------------------
    @abstractmethod
    def sample_plan(self, rng: np.random.Generator, case: str) -> ScenarioPlan:
        """Draw every random quantity of an episode (initial states, timings) from `rng`."""

    @abstractmethod
    def _reset_memory(self) -> None:
        """Reset the expert's state machine at the start of an episode."""

    def reset(
        self,
        rng: np.random.Generator | int | None,
        case: str,
        plan: ScenarioPlan | None = None,
    ) -> World:
        """Start an episode of `case`: draw a plan (unless given) and build its world."""
        self.check_case(case)
        if plan is None:
            rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
            plan = self.sample_plan(rng, case)
        self.plan, self.case = plan, case
        self._reset_memory()
        config = self.config
        state = plan.initial_state
        return World(
            self.road,
            state[:, :2],
            state[:, 2],
            state[:, 3],
            length_m=config.car_length_m,
            width_m=config.car_width_m,
            wheelbase_m=config.wheelbase_m,
            roles=self.role_labels,
            dt=config.dt_sim,
            limits=config.limits,
        )

    @abstractmethod
    def update(self, world: World) -> None:
        """Advance the expert's state machine from the current world (once per control step)."""

    # --- expert -----------------------------------------------------------------------------
    def expert_actions(self, world: World) -> np.ndarray:
        """Expert controls (N, 2) float32 [steering rad, acceleration m/s^2] for every car.

        float32 so that a recorded action is exactly the control that was applied.
        """
        # Lateral references are taken half a period ahead: the hold delays the response.
        control_time = world.time_s + 0.5 * self.control_period_s
        target, rate, accel_ff = self._lateral_references(world, control_time)
        steering = lateral_steering(
            world.xy[:, 1],
            world.heading,
            world.speed,
            target,
            rate,
            self.config.wheelbase_m,
            self.config.lateral_gains,
            accel_ff,
        )
        acceleration = self._accelerations(world)
        return np.stack([steering, acceleration], axis=1).astype(np.float32)

    def _lateral_references(
        self, world: World, control_time: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lateral reference, rate, acceleration (N,) each; default: keep the starting lane."""
        num_cars = self.num_cars
        return self.plan.lane_y.copy(), np.zeros(num_cars), np.zeros(num_cars)

    def _accelerations(self, world: World) -> np.ndarray:
        """Accelerations (N,); default: track each car's cruising speed."""
        limits = self.config.limits
        return speed_tracking_accel(
            world.speed,
            self.plan.target_speed,
            self.config.speed_gain_per_s,
            limits.max_accel_mps2,
            limits.max_decel_mps2,
        )

    @abstractmethod
    def attention_labels(self, world: World) -> np.ndarray:
        """(N,) int16: index of the car each car reacts to, -1 for none."""

    @abstractmethod
    def interaction(self, world: World) -> bool:
        """Whether the current step lies in the scenario's interaction period."""
