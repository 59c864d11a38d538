"""Double Merge v1: both main cars react to each other, from inside the observed window on.

Version 0 (`scenarios.double_merge`) has only the rear car react (it waits for the front car to
settle), and both cars track one cruising speed. Version 1 keeps the layout, the cases (which
car starts ahead), the lane swap, the distractors and the episode (60 steps of 0.2 s, 15
observed), and changes the expert so that what the attended car is *observed* doing decides the
attending car's future:

- the rear car lets the front car in: from the start it holds back to its cruise minus a
  per-scene yield speed (0.5-3 m/s, a courtesy the observed window shows as its deceleration);
  once the front car starts to cut in it follows it with the Intelligent Driver Model (fixed
  parameters, desired speed the cruise) with a fixed reaction delay of 0.4 s (its acceleration
  at step t is the one computed from the scene at step t - 2); it moves to its waiting offset
  and merges 0.4 s after it sees the front car settled in its lane, as in v0;
- the front car cuts in only once the bumper gap to the rear car is at least
  `cut_in_min_gap_m + v_rear * cut_in_headway_s` (2 m + 1 s); from its planned start until then
  it drives 1 m/s above the cruise. How soon the gap opens depends mostly on how much the rear
  car yields, which only the rear car's history shows.

Randomness that no observation resolves is removed: the IDM parameters, the cut-in rule, the
speed-up, the reaction delays and the lane-change durations are fixed (v0's duration and delay
ranges are overridden by ranges with equal ends). What stays random is what the observed
window shows: the cruise and initial speeds, the gap between the main cars, the rear car's
yield speed, the planned start, the rear car's approach to its waiting offset, the distractors.

Labels are causal: the rear car attends to the front car at every step (until the cut-in the
step at which it switches to following depends on the front car's position, after it its IDM
reads the front car); the front car attends to the rear car from its planned start until the
step at which it starts its lane change (the gap checks read the rear car; nothing before or
after does); distractors attend to nobody. Interaction period: the front car is watching the
rear car or the rear car is waiting next to the centre line.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from carlo_lite import World
from scenarios.base import NO_ATTENTION, Range, uniform
from scenarios.controllers import IDMParams, idm_accel, speed_tracking_accel
from scenarios.double_merge import DoubleMerge, DoubleMergeConfig, DoubleMergePlan, RearPhase


@dataclass(frozen=True)
class ReactiveDoubleMergeConfig(DoubleMergeConfig):
    """Double Merge v1 settings: v0's with the durations and delays that nothing observed
    reveals fixed, the rear car's courtesy (a uniform draw over (low, high)), the front car's
    cut-in rule and the rear car's car following (fixed)."""

    # v0 ranges made single values: hidden per-scene randomness only blurs the interaction
    front_change_duration_s: Range = (3.5, 3.5)  # v0: 3-4 s
    reaction_delay_s: Range = (0.4, 0.4)  # rear car's merge after the front settled; v0: 0.2-0.8
    rear_change_duration_s: Range = (3.5, 3.5)  # v0: 3-4 s
    # the rear car lets the front car in: it holds back to this much below the cruise
    yield_speed_mps: Range = (0.5, 3.0)  # per scene; its observed deceleration shows it
    # the front car's cut-in (gaps bumper to bumper, v_rear the rear car's speed)
    cut_in_min_gap_m: float = 2.0  # the standstill part of the cut-in gap [m]
    cut_in_headway_s: float = 1.0  # it cuts in once gap >= min gap + v_rear * this
    waiting_speed_up_mps: float = 1.0  # its speed above the cruise while it waits [m/s]
    # the rear car's car following once the front car cuts in
    idm: IDMParams = IDMParams(time_headway_s=1.2)  # desired speed: the cruise
    rear_reaction_delay_s: float = 0.4  # rounded to control steps (2 at 0.2 s)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.yield_speed_mps[0] < 0 or self.waiting_speed_up_mps < 0:
            raise ValueError("yield_speed_mps and waiting_speed_up_mps must not be negative")
        if self.cut_in_headway_s <= 0 or self.rear_reaction_delay_s < 0:
            raise ValueError("need cut_in_headway_s > 0 and rear_reaction_delay_s >= 0")


@dataclass(frozen=True, eq=False)
class ReactiveDoubleMergePlan(DoubleMergePlan):
    """A v0 plan plus the rear car's yield speed and reaction delay in control steps."""

    yield_speed_mps: float = 1.5
    rear_reaction_steps: int = 2


class ReactiveDoubleMerge(DoubleMerge):
    """Double Merge v1 (see the module docstring)."""

    name = "double_merge_v1"
    config_class = ReactiveDoubleMergeConfig

    def sample_plan(self, rng: np.random.Generator, case: str) -> ReactiveDoubleMergePlan:
        """A v0 plan (same draws in the same order, v1's ranges), then the yield speed."""
        config: ReactiveDoubleMergeConfig = self.config
        plan = super().sample_plan(rng, case)
        values = {field.name: getattr(plan, field.name) for field in dataclasses.fields(plan)}
        return ReactiveDoubleMergePlan(
            **values,
            yield_speed_mps=uniform(rng, config.yield_speed_mps),
            rear_reaction_steps=round(config.rear_reaction_delay_s / self.control_period_s),
        )

    def _reset_memory(self) -> None:
        super()._reset_memory()
        self.front_start_s: float | None = None  # when the front car began its lane change
        self.front_watching = False  # this step's front decisions read the rear car
        self._rear_seen: list[float] = []  # rear car's intended accelerations, one per step

    def bumper_gap(self, world: World) -> float:
        """Front minus rear x, minus a car length [m] (inf if either car was removed)."""
        plan: ReactiveDoubleMergePlan = self.plan
        if not (world.active[plan.front] and world.active[plan.rear]):
            return float("inf")
        return float(world.xy[plan.front, 0] - world.xy[plan.rear, 0] - self.config.car_length_m)

    def cut_in_gap(self, world: World) -> float:
        """The smallest gap the front car cuts in with [m]: min gap + v_rear x headway."""
        config: ReactiveDoubleMergeConfig = self.config
        rear_speed = float(world.speed[self.plan.rear])
        return config.cut_in_min_gap_m + rear_speed * config.cut_in_headway_s

    def gap_allows_cut_in(self, world: World) -> bool:
        """The front car may start its lane change: the gap reaches its cut-in gap."""
        return self.bumper_gap(world) >= self.cut_in_gap(world)

    def update(self, world: World) -> None:
        plan: ReactiveDoubleMergePlan = self.plan
        now = world.time_s + 1e-9
        self.front_watching = now >= plan.front_change_start_s and self.front_start_s is None
        if self.front_watching and self.gap_allows_cut_in(world):
            self.front_start_s = world.time_s
        super().update(world)
        self._rear_seen.append(self._rear_intended_accel(world))

    def front_waiting(self) -> bool:
        """The front car is past its planned start and waits for the gap."""
        return self.front_watching and self.front_start_s is None

    def _cruise_accel(self, speed: float, target: float) -> float:
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
        """The rear car's acceleration for the scene now: it holds back (cruise minus its yield
        speed) until the front car starts to cut in, then follows it with the IDM."""
        plan: ReactiveDoubleMergePlan = self.plan
        speed = world.speed[plan.rear]
        if self.front_start_s is None:
            return self._cruise_accel(speed, plan.cruise_speed_mps - plan.yield_speed_mps)
        gap = self.bumper_gap(world)
        closing = speed - world.speed[plan.front] if np.isfinite(gap) else 0.0
        return float(idm_accel(speed, plan.cruise_speed_mps, gap, closing, self.config.idm))

    def front_change_start(self) -> float:
        """When the front car's lane change started [s]; inf while it has not (waiting)."""
        return self.front_start_s if self.front_start_s is not None else float("inf")

    def _accelerations(self, world: World) -> np.ndarray:
        accel = super()._accelerations(world)
        plan: ReactiveDoubleMergePlan = self.plan
        if self.front_waiting():
            target = plan.cruise_speed_mps + self.config.waiting_speed_up_mps
            accel[plan.front] = self._cruise_accel(world.speed[plan.front], target)
        seen = self._rear_seen
        accel[plan.rear] = seen[max(0, len(seen) - 1 - plan.rear_reaction_steps)]
        return accel

    def attention_labels(self, world: World) -> np.ndarray:
        plan: ReactiveDoubleMergePlan = self.plan
        labels = np.full(self.num_cars, NO_ATTENTION, dtype=np.int16)
        labels[plan.rear] = plan.front
        if self.front_watching:
            labels[plan.front] = plan.rear
        return labels

    def interaction(self, world: World) -> bool:
        return self.front_watching or self.rear_phase == RearPhase.WAIT
