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
from dataclasses import dataclass

import numpy as np

from carlo_lite import World
from scenarios.base import Range, uniform
from scenarios.halting_car import HaltingCar, HaltingCarConfig, HaltingCarPlan


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


class ReactiveHaltingCar(HaltingCar):
    """Halting Car v1 (see the module docstring)."""

    name = "halting_car_v1"
    config_class = ReactiveHaltingCarConfig

    def sample_plan(self, rng: np.random.Generator, case: str) -> ReactiveHaltingCarPlan:
        plan = super().sample_plan(rng, case)
        delay = uniform(rng, self.config.reaction_delay_s)
        steps = max(1, round(delay / self.control_period_s))
        values = {field.name: getattr(plan, field.name) for field in dataclasses.fields(plan)}
        return ReactiveHaltingCarPlan(**values, reaction_steps=steps)

    def _reset_memory(self) -> None:
        super()._reset_memory()
        self._seen: list[float] = []  # IDM accelerations computed so far, one per control step

    def update(self, world: World) -> None:
        super().update(world)
        self._seen.append(super()._follower_accel(world))

    def _follower_accel(self, world: World) -> float:
        """The IDM acceleration of `reaction_steps` control steps ago (before the episode: the
        first one, as if the follower had been driving steadily)."""
        if not self._seen:  # asked before the first update
            return super()._follower_accel(world)
        return self._seen[max(0, len(self._seen) - 1 - self.plan.reaction_steps)]
