"""Double Merge v1: both main cars react to each other, from inside the observed window on.

Version 0 (`scenarios.double_merge`) has only the rear car react (it waits for the front car to
settle), and both cars track one cruising speed. Version 1 keeps the layout, the cases (which
car starts ahead), the lane swap, the distractors, the front car's planned lane change (it
starts 0.5-2 s into the episode) and the episode (60 steps of 0.2 s, 15 observed), and changes
the expert so that what each main car is *observed* doing decides the other's future:

- the rear car lets the front car in: once it sees the front car leave its lane centre (by
  0.2 m towards the rear car's lane) it follows it with the Intelligent Driver Model (the
  package's default parameters, desired speed the cruise), so how hard it brakes is set by the
  gap and the speeds it observes; it moves to its waiting offset and merges 0.4 s after it sees
  the front car settled, as in v0. Its accelerations act after a fixed reaction delay of 0.4 s
  (the acceleration at step t is the one computed from the scene at step t - 2);
- the front car paces the rear car: it tracks the rear car's speed as it saw it 0.8 s earlier,
  plus a fixed margin of 1 m/s (so the gap keeps opening).

The rear car sees the front car leave its lane by 2.8 s at the latest (the end of the observed
window), brakes 0.4 s later as far as the gap asks, and the front car answers it 0.8 s after
that, mostly in the predicted window: how much it slows is told by the rear car's observed
state, not by its own history. The rear car's braking is told by the gap and the front car's
speed, its merge by the front car's observed lane change. Randomness that no observation
resolves is removed: the reaction delays, the margin, the IDM parameters and the lane-change
durations are fixed (v0's duration and delay ranges are overridden by ranges with equal ends).

Labels are causal: each main car attends to the other at every step (the front car's speed
target is the rear car's delayed speed; the rear car's car following and merge read the front
car); distractors attend to nobody. Interaction period: from the step the rear car sees the
front car leave its lane until the rear car starts its own lane change.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from carlo_lite import World
from scenarios.base import BROWN, GREEN, NO_ATTENTION, Range
from scenarios.controllers import IDMParams, idm_accel, speed_tracking_accel
from scenarios.double_merge import DoubleMerge, DoubleMergeConfig, DoubleMergePlan, RearPhase


@dataclass(frozen=True)
class ReactiveDoubleMergeConfig(DoubleMergeConfig):
    """Double Merge v1 settings: v0's with the durations and delays that nothing observed
    reveals fixed, the rear car's car following and the front car's pacing (fixed)."""

    # v0 ranges made single values: hidden per-scene randomness only blurs the interaction
    front_change_duration_s: Range = (3.5, 3.5)  # v0: 3-4 s
    reaction_delay_s: Range = (0.4, 0.4)  # rear car's merge after the front settled; v0: 0.2-0.8
    rear_change_duration_s: Range = (3.5, 3.5)  # v0: 3-4 s
    # the rear car lets the front car in
    follow_trigger_m: float = 0.2  # front car's departure from its lane centre the rear car sees
    idm: IDMParams = IDMParams()  # rear car's car following (headway 1.5 s); desired: cruise
    rear_reaction_delay_s: float = 0.4  # rounded to control steps (2 at 0.2 s)
    # the front car paces the rear car
    pace_margin_mps: float = 1.0  # front speed target: the rear car's seen speed plus this
    front_reaction_delay_s: float = 0.8  # it sees the rear car's speed this late (4 steps)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.follow_trigger_m <= 0 or self.pace_margin_mps < 0:
            raise ValueError("need follow_trigger_m > 0 and pace_margin_mps >= 0")
        if min(self.rear_reaction_delay_s, self.front_reaction_delay_s) < 0:
            raise ValueError("reaction delays must not be negative")


@dataclass(frozen=True, eq=False)
class ReactiveDoubleMergePlan(DoubleMergePlan):
    """A v0 plan plus both reaction delays in control steps."""

    rear_reaction_steps: int = 2
    front_reaction_steps: int = 4


class ReactiveDoubleMerge(DoubleMerge):
    """Double Merge v1 (see the module docstring)."""

    name = "double_merge_v1"
    config_class = ReactiveDoubleMergeConfig

    def sample_plan(self, rng: np.random.Generator, case: str) -> ReactiveDoubleMergePlan:
        """A v0 plan (same draws in the same order, v1's ranges) with the reaction delays."""
        config: ReactiveDoubleMergeConfig = self.config
        plan = super().sample_plan(rng, case)
        values = {field.name: getattr(plan, field.name) for field in dataclasses.fields(plan)}
        period = self.control_period_s
        return ReactiveDoubleMergePlan(
            **values,
            rear_reaction_steps=round(config.rear_reaction_delay_s / period),
            front_reaction_steps=round(config.front_reaction_delay_s / period),
        )

    def _reset_memory(self) -> None:
        super()._reset_memory()
        labels = np.full(self.num_cars, NO_ATTENTION, dtype=np.int16)
        labels[GREEN], labels[BROWN] = BROWN, GREEN
        self._labels = labels
        self.following = False  # the rear car has seen the front car leave its lane
        self._rear_seen: list[float] = []  # rear car's intended accelerations, one per step
        self._rear_speeds: list[float] = []  # rear car's speed, one per step

    def bumper_gap(self, world: World) -> float:
        """Front minus rear x, minus a car length [m] (inf if either car was removed)."""
        plan: ReactiveDoubleMergePlan = self.plan
        if not (world.active[plan.front] and world.active[plan.rear]):
            return float("inf")
        return float(world.xy[plan.front, 0] - world.xy[plan.rear, 0] - self.config.car_length_m)

    def lateral_departure(self, world: World) -> float:
        """How far the front car has moved from its lane centre towards the rear car's [m]."""
        plan: ReactiveDoubleMergePlan = self.plan
        lane, target = plan.lane_y[plan.front], plan.lane_y[plan.rear]
        return float((world.xy[plan.front, 1] - lane) * np.sign(target - lane))

    def update(self, world: World) -> None:
        plan: ReactiveDoubleMergePlan = self.plan
        if not self.following and world.active[plan.front]:
            self.following = self.lateral_departure(world) >= self.config.follow_trigger_m
        super().update(world)
        self._rear_seen.append(self._rear_intended_accel(world))
        self._rear_speeds.append(float(world.speed[plan.rear]))

    def _track(self, speed: float, target: float) -> float:
        """Speed tracking acceleration with the scenario's gain and the car limits."""
        limits = self.config.limits
        return float(
            speed_tracking_accel(
                speed,
                target,
                self.config.speed_gain_per_s,
                limits.max_accel_mps2,
                limits.max_decel_mps2,
            )
        )

    def _rear_intended_accel(self, world: World) -> float:
        """The rear car's acceleration for the scene now: cruise, and once it has seen the
        front car leave its lane the IDM towards it (the lower of the two)."""
        plan: ReactiveDoubleMergePlan = self.plan
        speed = float(world.speed[plan.rear])
        accel = self._track(speed, plan.cruise_speed_mps)
        if self.following and world.active[plan.front]:
            closing = speed - float(world.speed[plan.front])
            gap = self.bumper_gap(world)
            follow = idm_accel(speed, plan.cruise_speed_mps, gap, closing, self.config.idm)
            accel = min(accel, float(follow))
        return accel

    def _accelerations(self, world: World) -> np.ndarray:
        accel = super()._accelerations(world)
        plan: ReactiveDoubleMergePlan = self.plan
        speeds = self._rear_speeds
        if speeds:  # asked before the first update: cruise, as in v0
            seen = speeds[max(0, len(speeds) - 1 - plan.front_reaction_steps)]
            target = seen + self.config.pace_margin_mps
            accel[plan.front] = self._track(float(world.speed[plan.front]), target)
        intended = self._rear_seen
        if intended:
            accel[plan.rear] = intended[max(0, len(intended) - 1 - plan.rear_reaction_steps)]
        return accel

    def attention_labels(self, world: World) -> np.ndarray:
        return self._labels.copy()

    def interaction(self, world: World) -> bool:
        return self.following and self.rear_phase < RearPhase.MERGE
