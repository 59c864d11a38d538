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
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlo_lite import BatchedWorld
from scenarios.base import Range, span
from scenarios.controllers import IDMParams
from scenarios.double_merge import (
    MERGE,
    DoubleMerge,
    DoubleMergeConfig,
    DoubleMergeExpert,
    DoubleMergePlan,
)
from scenarios.expert import History, python_min, scalar_idm_accel


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


class ReactiveDoubleMergeExpert(DoubleMergeExpert):
    """Double Merge v1's expert over B scenes: v0's lane changes, with the rear car's car
    following (delayed, a `History` of its intended accelerations) and the front car's pacing
    (a `History` of the rear car's speeds)."""

    plan_fields = (
        *DoubleMergeExpert.plan_fields,
        "cruise_speed_mps",
        "rear_reaction_steps",
        "front_reaction_steps",
    )

    def __init__(self, scenario: ReactiveDoubleMerge, plans: Sequence[ReactiveDoubleMergePlan]):
        super().__init__(scenario, plans)
        steps = self.config.num_steps
        self._rear_seen = History(self.num_scenes, steps)  # rear car's intended accelerations
        self._rear_speeds = History(self.num_scenes, steps)  # rear car's speeds

    def _fresh_memory(self, count: int) -> dict[str, np.ndarray]:
        # following: the rear car has seen the front car leave its lane
        return {**super()._fresh_memory(count), "following": np.zeros(count, dtype=bool)}

    def restart(self, scenes, plans, world: BatchedWorld) -> None:
        super().restart(scenes, plans, world)
        self._rear_seen.restart(scenes)
        self._rear_speeds.restart(scenes)

    def update(self, world: BatchedWorld) -> None:
        _, y, _, speed = self.flat(world)
        departure = (y[self.front_car] - self.front_lane) * np.sign(
            self.rear_lane - self.front_lane
        )
        front_present = world.flat()[4][self.front_car]
        self.following |= front_present & (departure >= self.config.follow_trigger_m)
        super().update(world)
        self._rear_seen.append(self._rear_intended_accel(world))
        self._rear_speeds.append(speed[self.rear_car])

    def _rear_intended_accel(self, world: BatchedWorld) -> np.ndarray:
        """(B,) the rear car's acceleration for the scene now: cruise, and once it has seen the
        front car leave its lane the IDM towards it (the lower of the two); a removed front
        car is no longer followed."""
        x, _, _, speed, active = world.flat()
        rear_speed = speed[self.rear_car]
        accel = self.track(rear_speed, self.cruise_speed_mps)
        closing = rear_speed - speed[self.front_car]
        gap = x[self.front_car] - x[self.rear_car] - self.config.car_length_m
        both = active[self.front_car] & active[self.rear_car]
        if not both.all():
            gap = np.where(both, gap, np.inf)
        follow = scalar_idm_accel(
            rear_speed,
            self.cruise_speed_mps,
            gap,
            closing,
            self.config.idm.time_headway_s,
            self.config.idm,
        )
        following = self.following & active[self.front_car]
        return np.where(following, python_min(accel, follow), accel)

    def _accelerations(self, world: BatchedWorld) -> np.ndarray:
        accel = super()._accelerations(world)
        speeds, intended = self._rear_speeds, self._rear_seen
        seen = ~speeds.empty()  # before the first update: cruise, as in v0
        if seen.any():
            target = speeds.delayed(self.front_reaction_steps) + self.config.pace_margin_mps
            _, _, _, speed = self.flat(world)
            pacing = self.track(speed[self.front_car], target)
            accel[self.front_car] = np.where(seen, pacing, accel[self.front_car])
            delayed = intended.delayed(self.rear_reaction_steps)
            accel[self.rear_car] = np.where(seen, delayed, accel[self.rear_car])
        return accel

    def interaction(self, world: BatchedWorld) -> np.ndarray:
        return self.following & (self.rear_phase < MERGE)


class ReactiveDoubleMerge(DoubleMerge):
    """Double Merge v1 (see the module docstring): v0's plan plus both reaction delays."""

    default_name = "double_merge_v1"
    config_class = ReactiveDoubleMergeConfig
    expert_class = ReactiveDoubleMergeExpert

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

    @classmethod
    def manual_description(cls, config: ReactiveDoubleMergeConfig) -> str:
        return (
            f"The green car (`car_0`, lane {config.green_lane}) and the brown car (`car_1`, "
            f"lane {config.brown_lane}) want each other's lane; case `major`: green starts "
            f"behind, `minor`: ahead. The front car starts its lane change "
            f"{span(config.front_change_start_s, 's')} into the episode. Once the rear car sees "
            f"the front car {config.follow_trigger_m:g} m out of its lane centre it follows it "
            f"with the Intelligent Driver Model (time headway {config.idm.time_headway_s:g} s, "
            f"desired speed the cruise, reaction delay {config.rear_reaction_delay_s:g} s), so "
            f"it brakes as much as the observed gap and speeds ask; it moves next to the centre "
            f"line and merges {span(config.reaction_delay_s, 's')} after the front car has "
            f"settled. The front car paces the rear car: it tracks the rear car's speed as seen "
            f"{config.front_reaction_delay_s:g} s earlier plus {config.pace_margin_mps:g} m/s, so "
            f"it answers the rear car's braking mostly after the observed window. The lane "
            f"changes take {span(config.front_change_duration_s, 's')} (front) and "
            f"{span(config.rear_change_duration_s, 's')} (rear)."
        )

    @classmethod
    def manual_labels(cls, config: ReactiveDoubleMergeConfig) -> str:
        return (
            "the main cars attend to each other, each reacting to the other, the others to "
            "nobody; `interaction`: from the rear car seeing the front car leave its lane until "
            "it starts its own lane change"
        )
