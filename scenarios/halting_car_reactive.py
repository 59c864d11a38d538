"""Halting Car v1: the leader's braking is observed, the follower's reaction is predicted.

Version 0 (`scenarios.halting_car`) starts the leader's braking after the observed window
(3.6-4.8 s, the window ends at 3.3 s), so whether it stops cannot be known when prediction
starts, and the follower's IDM reacts at once. Version 1 changes only the expert:

- the leader, case `stop`, starts braking 1.5-2.7 s into the episode: its last 0.6-1.8 s of
  observation already show it (random deceleration 2.5-5 m/s^2, stop 1-2 s, resume as in v0);
  case `go` cruises as before;
- the follower applies the Intelligent Driver Model with a random reaction delay of 0.6 or
  0.9 s (2 or 3 control steps): its acceleration at step t is the IDM acceleration computed from the
  scene at step t - delay. Its braking therefore starts at the end of the observed window or
  after it, and most of its deceleration falls in the predicted part, decided by what the
  leader was observed to do. The time headway is drawn from 1.3-1.9 s (v0: 1.0-1.6 s) to keep
  the delayed follower safe (a delay of 1.2 s with 1.2 s headway collided in 1 of 200 seeds).

Labels are causal: the follower attends to the leader at every step (its IDM always reads the
leader; perturbing the leader changes the follower's later actions, perturbing a distractor
does not), the leader and the distractors attend to nobody. Interaction period: the leader is
braking or standing still. Layout, distractors, episode length (60 steps of 0.3 s, 12
observed) and the random draws shared with v0 are those of v0; the reaction delay is drawn
last, so a v1 plan differs from the v0 plan of the same seed only in the changed ranges.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlo_lite import BatchedWorld
from scenarios.base import Range, span, uniform
from scenarios.expert import History
from scenarios.halting_car import (
    HaltingCar,
    HaltingCarConfig,
    HaltingCarExpert,
    HaltingCarPlan,
    lanes_in_words,
)


@dataclass(frozen=True)
class ReactiveHaltingCarConfig(HaltingCarConfig):
    """Halting Car v1 settings: v0's, with the braking inside the observed window and a
    reaction delay for the follower (uniform draws over (low, high))."""

    brake_start_s: Range = (1.5, 2.7)  # the observation ends at 3.3 s (step 11 of 0.3 s)
    brake_decel_mps2: Range = (2.5, 5.0)
    time_headway_s: Range = (1.3, 1.9)  # follower's IDM time headway
    reaction_delay_s: Range = (0.45, 0.9)  # follower's IDM reaction delay, rounded to 2-3 steps


@dataclass(frozen=True, eq=False)
class ReactiveHaltingCarPlan(HaltingCarPlan):
    """A v0 plan plus the follower's reaction delay."""

    reaction_steps: int = 0  # control steps between what the follower sees and what it does


class ReactiveHaltingCarExpert(HaltingCarExpert):
    """Halting Car v1's expert over B scenes: v0's, with the follower's IDM accelerations
    delayed (a `History` read `reaction_steps` back)."""

    plan_fields = (*HaltingCarExpert.plan_fields, "reaction_steps")

    def __init__(self, scenario: ReactiveHaltingCar, plans: Sequence[ReactiveHaltingCarPlan]):
        super().__init__(scenario, plans)
        self._seen = History(self.num_scenes, self.config.num_steps)  # IDM accelerations

    def restart(self, scenes, plans, world: BatchedWorld) -> None:
        super().restart(scenes, plans, world)
        self._seen.restart(scenes)

    def update(self, world: BatchedWorld) -> None:
        super().update(world)
        self._seen.append(self._idm_now(world))

    def _follower_accel(self, world: BatchedWorld) -> np.ndarray:
        """The IDM acceleration of `reaction_steps` control steps ago (before the episode's
        first update: the one now, as if the follower had been driving steadily)."""
        delayed = self._seen.delayed(self.reaction_steps)
        empty = self._seen.empty()
        return np.where(empty, self._idm_now(world), delayed) if empty.any() else delayed


class ReactiveHaltingCar(HaltingCar):
    """Halting Car v1 (see the module docstring): v0's plan plus the reaction delay."""

    default_name = "halting_car_v1"
    config_class = ReactiveHaltingCarConfig
    expert_class = ReactiveHaltingCarExpert

    def sample_plan(self, rng: np.random.Generator, case: str) -> ReactiveHaltingCarPlan:
        plan = super().sample_plan(rng, case)
        delay = uniform(rng, self.config.reaction_delay_s)
        values = {field.name: getattr(plan, field.name) for field in dataclasses.fields(plan)}
        return ReactiveHaltingCarPlan(**values, reaction_steps=self.delay_steps(delay))

    def delay_steps(self, delay_s: float) -> int:
        """A reaction delay [s] in control steps (at least one)."""
        return max(1, round(delay_s / self.control_period_s))

    @classmethod
    def manual_description(cls, config: ReactiveHaltingCarConfig) -> str:
        period = config.recorded_dt
        steps = sorted({max(1, round(delay / period)) for delay in config.reaction_delay_s})
        observed_s = config.num_observed * period
        return (
            f"The brown leader (`car_1`) and the green follower (`car_0`, behind it) share "
            f"an inner lane ({lanes_in_words(config)}). The leader cruises at "
            f"{span(config.cruise_speed_mps, 'm/s')}; in case `stop` it starts braking "
            f"{span(config.brake_start_s, 's')} into the episode, inside the {observed_s:g} s "
            f"that a predictor observes ({config.num_observed} steps), at "
            f"{span(config.brake_decel_mps2, 'm/s^2')} to a full stop, stands "
            f"{span(config.stop_duration_s, 's')} and accelerates back at "
            f"{span(config.resume_accel_mps2, 'm/s^2')} to its cruising speed; case `go`: it "
            f"keeps its speed. The follower applies the Intelligent Driver Model towards the "
            f"leader with a reaction delay of {' or '.join(f'{s * period:g}' for s in steps)} s "
            f"(its action at step t is the IDM action for the scene at step t - "
            f"{' or '.join(str(s) for s in steps)}), a time headway of "
            f"{span(config.time_headway_s, 's')} and a desired speed "
            f"{span(config.follower_speed_ratio)} x the leader's cruise."
        )

    @classmethod
    def manual_split_note(cls, config: ReactiveHaltingCarConfig) -> str:
        return "so that the leader's braking onset is observed and the follower's reaction is not"
