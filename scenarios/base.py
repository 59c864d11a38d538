"""What every scenario shares: configuration, roles, the road, distractors, and the plan of an
episode.

A scenario is a plain class (no PettingZoo). Per episode it draws a *plan* (initial states and
every random timing) from a `numpy.random.Generator`; its expert (`scenarios.expert.Expert`)
drives one scene per plan in a `carlo_lite.BatchedWorld`, and at every control step
`update(world)` advances its small state machine from what it observes and
`expert_actions(world)` returns the controls of all cars of all scenes as one (B, N, 2) array.
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

from carlo_lite import CarLimits, StraightRoad
from scenarios.controllers import LateralGains

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
    """Base of the scenarios: a configuration, the road and roles, the random plan of an
    episode, and the expert that drives B such episodes at once (`expert_class`).

    Class attributes: `case_names`, `default_major_case`, `role_names`, `config_class`,
    `expert_class`, and `default_name`, the name of the version this code first served. An
    instance's `name` is the version it runs (`scenarios.make("halting_car_v3")` gives the
    reactive Halting Car with v3's settings and that name).
    """

    default_name: ClassVar[str]
    case_names: ClassVar[tuple[str, ...]]
    default_major_case: ClassVar[str]
    role_names: ClassVar[tuple[str, ...]] = ROLE_NAMES
    config_class: ClassVar[type[ScenarioConfig]] = ScenarioConfig
    # the scenes' expert, a `scenarios.expert.Expert` subclass (built by `expert_for`); this
    # module leaves it untyped so that the expert's module, which reads plans, is not imported
    expert_class: ClassVar[type]

    def __init__(self, config: ScenarioConfig | None = None, *, name: str | None = None) -> None:
        config = self.config_class() if config is None else config
        if not isinstance(config, self.config_class):
            raise TypeError(f"{type(self).__name__} needs a {self.config_class.__name__}")
        self.config = config
        self.name = self.default_name if name is None else name
        self.road = StraightRoad(config.num_lanes, config.lane_width_m, config.road_length_m)
        self.roles = np.array(
            [GREEN, BROWN] + [DISTRACTOR] * config.num_distractors, dtype=np.int8
        )  # (N,) index into role_names
        self.role_labels = tuple(ROLE_NAMES[role] for role in self.roles)

    @property
    def num_cars(self) -> int:
        return self.config.num_cars

    @property
    def control_period_s(self) -> float:
        return self.config.recorded_dt

    def position_bounds(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) [m] of the road surface: the straight road's box
        [0, road_length_m] x [0, num_lanes * lane_width_m] (scenarios on a layout override it).
        The environments' observation bounds come from it (`scenarios.scenes`)."""
        return 0.0, 0.0, self.road.length_m, self.road.width_m

    def check_case(self, case: str) -> str:
        if case not in self.case_names:
            raise ValueError(f"{self.name}: unknown case {case!r}; choose from {self.case_names}")
        return case

    @abstractmethod
    def sample_plan(self, rng: np.random.Generator, case: str) -> ScenarioPlan:
        """Draw every random quantity of an episode (initial states, timings) from `rng`."""

    def plan(self, seed: int, case: str) -> ScenarioPlan:
        """The plan of the episode of `seed` and `case`: `sample_plan(default_rng(seed), case)`."""
        return self.sample_plan(np.random.default_rng(seed), self.check_case(case))

    # --- the environment's user manual (scenarios.manual) ----------------------------------
    @classmethod
    @abstractmethod
    def manual_description(cls, config: ScenarioConfig) -> str:
        """The manual's "Description": what the cars do, with `config`'s values."""

    @classmethod
    @abstractmethod
    def manual_starting_state(cls, config: ScenarioConfig) -> str:
        """The manual's "Starting State" (the main cars; distractors are added)."""

    @classmethod
    @abstractmethod
    def manual_labels(cls, config: ScenarioConfig) -> str:
        """Whom each car attends to and when the interaction period is, for "Infos"."""

    @classmethod
    def manual_distractors(cls, config: ScenarioConfig) -> str:
        """How the distractors drive, completing "`car_2` ... `car_21` are distractors"."""
        return f"driving straight at constant speed on lanes 0 and {config.num_lanes - 1}."

    @classmethod
    def manual_split_note(cls, config: ScenarioConfig) -> str:
        """Why the suggested observed / predicted split is where it is (may be empty)."""
        return ""


def span(bounds: Range, unit: str = "") -> str:
    """A range for prose: "2.4 to 3 s", or "4 m/s^2" when both ends are equal."""
    low, high = (f"{value:g}" for value in bounds)
    text = low if low == high else f"{low} to {high}"
    return f"{text} {unit}".rstrip()
