"""Double Merge v1: both main cars react to each other, from inside the observed window.

Version 0 (`scenarios.double_merge`) has only the rear car react (it waits for the front car to
settle), and both cars track one cruising speed. Version 1 keeps the layout, the cases (which
car starts ahead), the lane swap, the distractors and the episode (60 steps of 0.2 s, 15
observed), and changes the expert:

- the front car does not cut in closer than a safe gap: it starts its lane change at its
  planned time only if the bumper gap to the rear car is at least `s0 + v_rear * h_cut` (a
  random cut-in headway); until then it speeds up (a random extra speed) to open the gap, and
  changes lane as soon as the gap allows. Its lane-change start is decided by the rear car's
  observed position and speed;
- the rear car follows the front car with the Intelligent Driver Model (random time headway,
  desired speed a random factor above the cruise) with a random reaction delay (its
  acceleration at step t is the IDM acceleration for the scene at step t - delay), so its speed
  answers the front car's; it moves to its waiting offset and merges after the front car has
  settled in its lane, as in v0.

Labels are causal: the rear car attends to the front car at every step; the front car attends
to the rear car until it starts its lane change (afterwards nothing the rear car does changes
its actions) and to nobody after; distractors attend to nobody. Interaction period: the front
car is waiting for the gap or the rear car is waiting for the front car to settle.
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
    """Double Merge v1 settings: v0's plus the cut-in rule and the rear car's IDM (uniform
    draws over (low, high))."""

    cut_in_headway_s: Range = (0.7, 1.1)  # front car's smallest accepted gap / rear speed
    cut_in_min_gap_m: float = 2.0  # plus this bumper gap [m]
    gap_opening_speed_mps: Range = (2.0, 3.0)  # extra speed of a front car waiting for the gap
    rear_headway_s: Range = (1.0, 1.6)  # rear car's IDM time headway
    rear_speed_ratio: Range = (1.05, 1.2)  # rear car's IDM desired speed / cruise
    rear_reaction_delay_s: Range = (0.4, 0.6)  # rounded to control steps (2-3 at 0.2 s)
    idm: IDMParams = IDMParams()  # the rear car's IDM (time headway replaced per episode)


@dataclass(frozen=True, eq=False)
class ReactiveDoubleMergePlan(DoubleMergePlan):
    """A v0 plan plus the v1 draws."""

    cut_in_headway_s: float = 0.8
    gap_opening_speed_mps: float = 1.5
    rear_headway_s: float = 1.3
    rear_desired_speed_mps: float = 10.0
    rear_reaction_steps: int = 2


class ReactiveDoubleMerge(DoubleMerge):
    """Double Merge v1 (see the module docstring)."""

    name = "double_merge_v1"
    config_class = ReactiveDoubleMergeConfig

    def sample_plan(self, rng: np.random.Generator, case: str) -> ReactiveDoubleMergePlan:
        """A v0 plan (same draws, same order), then the v1 draws."""
        config: ReactiveDoubleMergeConfig = self.config
        plan = super().sample_plan(rng, case)
        values = {field.name: getattr(plan, field.name) for field in dataclasses.fields(plan)}
        values.update(
            cut_in_headway_s=uniform(rng, config.cut_in_headway_s),
            gap_opening_speed_mps=uniform(rng, config.gap_opening_speed_mps),
            rear_headway_s=uniform(rng, config.rear_headway_s),
            rear_desired_speed_mps=plan.cruise_speed_mps * uniform(rng, config.rear_speed_ratio),
            rear_reaction_steps=max(
                1, round(uniform(rng, config.rear_reaction_delay_s) / self.control_period_s)
            ),
        )
        return ReactiveDoubleMergePlan(**values)

    def _reset_memory(self) -> None:
        super()._reset_memory()
        self.front_start_s: float | None = None  # when the front car began its lane change
        self._rear_idm = dataclasses.replace(
            self.config.idm, time_headway_s=self.plan.rear_headway_s
        )
        self._rear_seen: list[float] = []  # rear IDM accelerations, one per control step

    def bumper_gap(self, world: World) -> float:
        """Front minus rear x, minus a car length [m] (inf if either car was removed)."""
        plan: ReactiveDoubleMergePlan = self.plan
        if not (world.active[plan.front] and world.active[plan.rear]):
            return float("inf")
        return float(world.xy[plan.front, 0] - world.xy[plan.rear, 0] - self.config.car_length_m)

    def gap_allows_cut_in(self, world: World) -> bool:
        """The front car may start its lane change: the gap exceeds its safe cut-in gap."""
        plan: ReactiveDoubleMergePlan = self.plan
        safe = self.config.cut_in_min_gap_m + world.speed[plan.rear] * plan.cut_in_headway_s
        return self.bumper_gap(world) >= safe

    def update(self, world: World) -> None:
        plan: ReactiveDoubleMergePlan = self.plan
        now = world.time_s + 1e-9
        if (
            self.front_start_s is None
            and now >= plan.front_change_start_s
            and self.gap_allows_cut_in(world)
        ):
            self.front_start_s = world.time_s
        super().update(world)
        self._rear_seen.append(self._rear_intended_accel(world))

    def front_waiting(self, world: World) -> bool:
        """The front car is past its planned start and waits for the gap."""
        return self.front_start_s is None and world.time_s + 1e-9 >= self.plan.front_change_start_s

    def _rear_intended_accel(self, world: World) -> float:
        """The rear car's acceleration for the scene now: its cruise speed until the front car
        starts to cut in, then IDM towards the front car (free road if it was removed)."""
        plan: ReactiveDoubleMergePlan = self.plan
        if self.front_start_s is None:
            limits = self.config.limits
            return float(
                speed_tracking_accel(
                    world.speed[plan.rear],
                    plan.cruise_speed_mps,
                    self.config.speed_gain_per_s,
                    limits.max_accel_mps2,
                    limits.max_decel_mps2,
                )
            )
        gap = self.bumper_gap(world)
        closing = world.speed[plan.rear] - world.speed[plan.front] if np.isfinite(gap) else 0.0
        speed = world.speed[plan.rear]
        return float(idm_accel(speed, plan.rear_desired_speed_mps, gap, closing, self._rear_idm))

    def front_change_start(self) -> float:
        """When the front car's lane change started [s]; inf while it has not (waiting)."""
        return self.front_start_s if self.front_start_s is not None else float("inf")

    def _accelerations(self, world: World) -> np.ndarray:
        accel = super()._accelerations(world)
        plan: ReactiveDoubleMergePlan = self.plan
        limits = self.config.limits
        if self.front_waiting(world):  # open the gap
            accel[plan.front] = speed_tracking_accel(
                world.speed[plan.front],
                plan.cruise_speed_mps + plan.gap_opening_speed_mps,
                self.config.speed_gain_per_s,
                limits.max_accel_mps2,
                limits.max_decel_mps2,
            )
        seen = self._rear_seen
        if seen:
            accel[plan.rear] = seen[max(0, len(seen) - 1 - plan.rear_reaction_steps)]
        else:
            accel[plan.rear] = self._rear_intended_accel(world)
        return accel

    def attention_labels(self, world: World) -> np.ndarray:
        plan: ReactiveDoubleMergePlan = self.plan
        labels = np.full(self.num_cars, NO_ATTENTION, dtype=np.int16)
        labels[plan.rear] = plan.front
        if self.front_start_s is None:
            labels[plan.front] = plan.rear
        return labels

    def interaction(self, world: World) -> bool:
        return self.front_waiting(world) or self.rear_phase == RearPhase.WAIT
