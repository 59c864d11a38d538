"""Double Merge v0 and v1 experts over B scenes (`scenarios.batched_expert`).

Each class mirrors its per-scene scenario method by method (`DoubleMerge` in
scenarios/double_merge.py, `ReactiveDoubleMerge` in scenarios/double_merge_reactive.py): the
rear car's phase, the time the front car was seen settled and the merge start are (B,) arrays;
v1's histories (the rear car's intended accelerations and speeds) are `History` arrays. Python
`min` becomes `python_min`, scalar IDM calls `scalar_idm_accel`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from carlo_lite import BatchedWorld
from scenarios.base import BROWN, GREEN, NO_ATTENTION
from scenarios.batched_expert import BatchedExpert, History, python_min, scalar_idm_accel
from scenarios.controllers import lane_change_reference
from scenarios.double_merge import DoubleMerge, DoubleMergePlan, RearPhase
from scenarios.double_merge_reactive import ReactiveDoubleMerge, ReactiveDoubleMergePlan


class BatchedDoubleMerge(BatchedExpert):
    """`DoubleMerge`'s expert (v0) over B scenes."""

    def __init__(self, scenario: DoubleMerge, plans: Sequence[DoubleMergePlan]) -> None:
        super().__init__(scenario, plans)
        value = self.plan_values
        self.front_car = self.offsets + value("front", np.int64)  # (B,) flat car indices
        self.rear_car = self.offsets + value("rear", np.int64)
        self.front_lane = self.lane_y[self.front_car]  # (B,) y [m] of the lane centres
        self.rear_lane = self.lane_y[self.rear_car]
        self.waiting_y = self.rear_lane + np.sign(self.front_lane - self.rear_lane) * value(
            "wait_offset_m"
        )
        self.front_change_start_s = value("front_change_start_s")
        self.front_change_duration_s = value("front_change_duration_s")
        self.rear_approach_start_s = value("rear_approach_start_s")
        self.rear_approach_duration_s = value("rear_approach_duration_s")
        self.reaction_delay_s = value("reaction_delay_s")
        self.rear_change_duration_s = value("rear_change_duration_s")
        # memory, as DoubleMerge._reset_memory
        self.rear_phase = np.full(self.num_scenes, RearPhase.KEEP, dtype=np.int8)
        self.front_done = np.zeros(self.num_scenes, dtype=bool)
        self.front_done_time_s = np.full(self.num_scenes, np.nan)
        self.merge_start_s = np.full(self.num_scenes, np.nan)
        labels = np.full(self.num_cars, NO_ATTENTION, dtype=np.int16)
        labels[GREEN], labels[BROWN] = BROWN, GREEN
        self._labels = np.tile(labels, (self.num_scenes, 1))  # (B, N)

    def front_settled(self, world: BatchedWorld) -> np.ndarray:
        """(B,) the front car has finished its lane change, as the rear car can see it."""
        _, y, heading, _ = self.flat(world)
        lateral_error = np.abs(y[self.front_car] - self.rear_lane)
        return (lateral_error < self.config.settled_lateral_tol_m) & (
            np.abs(heading[self.front_car]) < self.config.settled_heading_tol_rad
        )

    def update(self, world: BatchedWorld) -> None:
        now = world.time_s + 1e-9  # tolerate rounding of step_count * dt
        seen = ~self.front_done & self.front_settled(world)
        self.front_done_time_s[seen] = world.time_s
        self.front_done |= seen
        phase = self.rear_phase
        approach_end = self.rear_approach_start_s + self.rear_approach_duration_s
        phase[(phase == RearPhase.KEEP) & (now >= self.rear_approach_start_s)] = RearPhase.APPROACH
        phase[(phase == RearPhase.APPROACH) & (now >= approach_end)] = RearPhase.WAIT
        merging = (
            (phase == RearPhase.WAIT)
            & self.front_done
            & (now >= self.front_done_time_s + self.reaction_delay_s)
        )
        phase[merging] = RearPhase.MERGE
        self.merge_start_s[merging] = world.time_s
        merge_end = self.merge_start_s + self.rear_change_duration_s
        phase[(phase == RearPhase.MERGE) & (now >= merge_end)] = RearPhase.DONE

    def _lateral_references(
        self, world: BatchedWorld, control_time: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        target, rate, accel = super()._lateral_references(world, control_time)
        before = self.rear_phase < RearPhase.MERGE
        rear_start = np.where(before, self.rear_approach_start_s, self.merge_start_s)
        rear_duration = np.where(before, self.rear_approach_duration_s, self.rear_change_duration_s)
        rear_origin = np.where(before, self.rear_lane, self.waiting_y)
        rear_goal = np.where(before, self.waiting_y, self.front_lane)
        start = np.stack([self.front_change_start_s, rear_start], axis=1)  # (B, 2) front, rear
        duration = np.stack([self.front_change_duration_s, rear_duration], axis=1)
        origin = np.stack([self.front_lane, rear_origin], axis=1)
        goal = np.stack([self.rear_lane, rear_goal], axis=1)
        cars = np.stack([self.front_car, self.rear_car], axis=1)  # (B, 2)
        target[cars], rate[cars], accel[cars] = lane_change_reference(
            control_time, start, duration, origin, goal
        )
        return target, rate, accel

    def attention_labels(self, world: BatchedWorld) -> np.ndarray:
        return self._labels.copy()

    def interaction(self, world: BatchedWorld) -> np.ndarray:
        return self.rear_phase == RearPhase.WAIT


class BatchedReactiveDoubleMerge(BatchedDoubleMerge):
    """`ReactiveDoubleMerge`'s expert (v1) over B scenes."""

    def __init__(
        self, scenario: ReactiveDoubleMerge, plans: Sequence[ReactiveDoubleMergePlan]
    ) -> None:
        super().__init__(scenario, plans)
        self.cruise_speed_mps = self.plan_values("cruise_speed_mps")
        self.rear_reaction_steps = self.plan_values("rear_reaction_steps", np.int64)
        self.front_reaction_steps = self.plan_values("front_reaction_steps", np.int64)
        self.following = np.zeros(self.num_scenes, dtype=bool)
        steps = self.config.num_steps
        self._rear_seen = History(self.num_scenes, steps)  # rear car's intended accelerations
        self._rear_speeds = History(self.num_scenes, steps)  # rear car's speeds

    def update(self, world: BatchedWorld) -> None:
        _, y, _, speed = self.flat(world)
        departure = (y[self.front_car] - self.front_lane) * np.sign(
            self.rear_lane - self.front_lane
        )
        self.following |= departure >= self.config.follow_trigger_m
        super().update(world)
        self._rear_seen.append(self._rear_intended_accel(world))
        self._rear_speeds.append(speed[self.rear_car])

    def _rear_intended_accel(self, world: BatchedWorld) -> np.ndarray:
        """(B,) the rear car's acceleration for the scene now (see ReactiveDoubleMerge)."""
        x, _, _, speed = self.flat(world)
        rear_speed = speed[self.rear_car]
        accel = self.track(rear_speed, self.cruise_speed_mps)
        closing = rear_speed - speed[self.front_car]
        gap = x[self.front_car] - x[self.rear_car] - self.config.car_length_m
        follow = scalar_idm_accel(
            rear_speed,
            self.cruise_speed_mps,
            gap,
            closing,
            self.config.idm.time_headway_s,
            self.config.idm,
        )
        return np.where(self.following, python_min(accel, follow), accel)

    def _accelerations(self, world: BatchedWorld) -> np.ndarray:
        accel = super()._accelerations(world)
        if len(self._rear_speeds):  # asked before the first update: cruise, as in v0
            target = self._rear_speeds.delayed(self.front_reaction_steps) + (
                self.config.pace_margin_mps
            )
            _, _, _, speed = self.flat(world)
            accel[self.front_car] = self.track(speed[self.front_car], target)
        if len(self._rear_seen):
            accel[self.rear_car] = self._rear_seen.delayed(self.rear_reaction_steps)
        return accel

    def interaction(self, world: BatchedWorld) -> np.ndarray:
        return self.following & (self.rear_phase < RearPhase.MERGE)
