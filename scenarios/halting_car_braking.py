"""Halting Car v4: v3, with distractors that brake and resume as the leader does.

In versions 0-3 the 20 distractors drive at constant speed, so the mean of all cars' motion is
a scaled copy of the leader's braking, and a model that averages over cars does the attention's
job (issue 68: on v1, 0 of 10 seeds met the attention bar). Here each of the two outer lanes is
one column whose cars share a speed profile (`scenarios.junction.profile_speed`): at a random
moment the column brakes at a random deceleration to a random lower speed, or to a stop, holds
it and accelerates back. All cars of a column get the same acceleration, so their gaps never
change: no distractor reacts to another car and none is reacted to (they influence nobody), yet
their braking is as strong as the leader's and uncorrelated with it.

Everything else is v3: its settings are this config's defaults, and its draws come first, so a
v4 plan is the v3 plan of the same seed plus the columns' profiles.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from carlo_lite import BatchedWorld
from scenarios.base import DISTRACTOR, Range, span, uniform
from scenarios.halting_car_reactive import (
    ReactiveHaltingCar,
    ReactiveHaltingCarConfig,
    ReactiveHaltingCarExpert,
    ReactiveHaltingCarPlan,
)
from scenarios.junction import profile_speed

# each car's profile in the plan: (N,) arrays, the main cars' never braking
PROFILE = (
    "column_brake_at_s",
    "column_decel_mps2",
    "column_low_speed_mps",
    "column_hold_s",
    "column_resume_accel_mps2",
)


@dataclass(frozen=True)
class BrakingDistractorsHaltingCarConfig(ReactiveHaltingCarConfig):
    """Halting Car v4 settings: v3's (as defaults) and the distractor columns' profiles."""

    brake_start_s: Range = (2.4, 3.0)
    reaction_delay_s: Range = (0.9, 0.9)
    stop_duration_s: Range = (1.5, 1.5)
    resume_accel_mps2: Range = (2.5, 2.5)
    cruise_speed_mps: Range = (9.0, 11.0)
    brake_decel_mps2: Range = (4.0, 4.0)
    column_brake_start_s: Range = (0.5, 15.0)  # when an outer lane's column starts braking
    column_decel_mps2: Range = (2.0, 5.0)
    column_slow_ratio: Range = (0.0, 0.5)  # the speed it brakes to / its cruise (0: a stop)
    column_hold_s: Range = (0.5, 3.0)
    column_resume_accel_mps2: Range = (1.5, 3.0)


@dataclass(frozen=True, eq=False)
class BrakingDistractorsHaltingCarPlan(ReactiveHaltingCarPlan):
    """A v3 plan plus each car's profile (N,) arrays; the main cars' never brake."""

    column_brake_at_s: np.ndarray | None = None
    column_decel_mps2: np.ndarray | None = None
    column_low_speed_mps: np.ndarray | None = None
    column_hold_s: np.ndarray | None = None
    column_resume_accel_mps2: np.ndarray | None = None


class BrakingDistractorsHaltingCarExpert(ReactiveHaltingCarExpert):
    """v3's expert; the distractors track their column's profile (deadbeat over one control
    period) instead of a constant speed."""

    def _derive(self) -> None:
        super()._derive()
        for name in PROFILE:
            setattr(self, name, np.concatenate([getattr(p, name) for p in self.plans]))
        self._distractor = np.tile(self.scenario.roles == DISTRACTOR, self.num_scenes)

    def _accelerations(self, world: BatchedWorld) -> np.ndarray:
        accel = super()._accelerations(world)
        period = self.scenario.control_period_s
        cars = self._distractor
        target = profile_speed(
            np.repeat(world.time_s, self.num_cars)[cars] + period,
            self.target_speed[cars],
            *(getattr(self, name)[cars] for name in PROFILE),
        )
        limits = self.config.limits
        accel[cars] = np.clip(
            (target - world.speed.reshape(-1)[cars]) / period,
            -limits.max_decel_mps2,
            limits.max_accel_mps2,
        )
        return accel


class BrakingDistractorsHaltingCar(ReactiveHaltingCar):
    """Halting Car v4 (see the module docstring)."""

    default_name = "halting_car_v4"
    config_class = BrakingDistractorsHaltingCarConfig
    expert_class = BrakingDistractorsHaltingCarExpert

    def sample_plan(self, rng: np.random.Generator, case: str) -> BrakingDistractorsHaltingCarPlan:
        plan = super().sample_plan(rng, case)
        config: BrakingDistractorsHaltingCarConfig = self.config
        lanes = np.round(plan.lane_y / config.lane_width_m - 0.5).astype(int)  # (N,)
        values = {name: np.zeros(self.num_cars) for name in PROFILE}
        values["column_brake_at_s"][:] = np.inf  # the main cars never brake on a profile
        values["column_decel_mps2"][:] = values["column_resume_accel_mps2"][:] = 1.0
        values["column_low_speed_mps"][:] = plan.target_speed
        for lane in (0, config.num_lanes - 1):  # one column per outer lane
            cars = (lanes == lane) & (self.roles == DISTRACTOR)
            cruise = plan.target_speed[cars]
            values["column_brake_at_s"][cars] = uniform(rng, config.column_brake_start_s)
            values["column_decel_mps2"][cars] = uniform(rng, config.column_decel_mps2)
            values["column_low_speed_mps"][cars] = cruise * uniform(rng, config.column_slow_ratio)
            values["column_hold_s"][cars] = uniform(rng, config.column_hold_s)
            values["column_resume_accel_mps2"][cars] = uniform(rng, config.column_resume_accel_mps2)
        fields = {f.name: getattr(plan, f.name) for f in dataclasses.fields(plan)}
        return BrakingDistractorsHaltingCarPlan(**{**fields, **values})

    @classmethod
    def manual_distractors(cls, config: BrakingDistractorsHaltingCarConfig) -> str:
        return (
            f"on lanes 0 and {config.num_lanes - 1}, each lane's cars braking together at a "
            f"random moment ({span(config.column_brake_start_s, 's')}) at "
            f"{span(config.column_decel_mps2, 'm/s^2')} to {span(config.column_slow_ratio)} of "
            f"their speed (0: a stop), holding it {span(config.column_hold_s, 's')} and "
            "accelerating back; none of them reacts to another car."
        )
