"""Double Merge: two main cars in the two inner lanes swap lanes, the rear one waiting its turn.

Layout (4 lanes, lane 0 the rightmost): the green car starts in lane 2, the brown car in lane 1.
In case `major` the green car starts behind the brown car, in case `minor` ahead of it (as in the
paper). 20 distractors drive straight at constant speed on lanes 0 and 3 and influence nobody.

Expert:
- the front main car changes to the other inner lane at a random time with a smooth (quintic)
  lateral profile of random duration;
- the rear main car first moves to a random waiting offset next to the centre line, then waits
  until it *observes* the front car settled in the target lane (lateral error and heading below
  tolerances; never a fixed clock), then after a random reaction delay makes its own lane change;
- both main cars track a common random cruising speed; distractors keep lane and speed.

Labels: the two main cars attend to each other at every step (the paper's "Correct" oracle; only
the rear car's expert actually depends on the other car), distractors attend to nobody (-1).
Interaction period: the rear car is waiting next to the centre line (from the end of its approach
until it starts to merge).

Episode: 60 recorded steps of 0.2 s (12 s; 2 simulation steps of 0.1 s each), 15 observed +
45 predicted. The rear car cannot start merging before 3.4 s (front start >= 0.5 s, duration
>= 3 s, then settling and >= 0.2 s delay), so the wait's end and the merge always fall in the
predicted part, while the front car's manoeuvre starts in the observed part.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from carlo_lite import World
from scenarios.base import (
    BROWN,
    GREEN,
    NO_ATTENTION,
    Range,
    Scenario,
    ScenarioConfig,
    ScenarioPlan,
    sample_distractors,
    uniform,
)
from scenarios.controllers import lane_change_reference


@dataclass(frozen=True)
class DoubleMergeConfig(ScenarioConfig):
    """Double Merge settings and randomisation ranges (uniform draws over (low, high))."""

    record_every: int = 2  # 0.2 s per recorded step
    num_steps: int = 60  # 12 s
    num_observed: int = 15  # 3 s observed, 9 s predicted
    green_lane: int = 2  # the left inner lane
    brown_lane: int = 1  # the right inner lane
    cruise_speed_mps: Range = (8.0, 12.0)  # common cruising speed of the main cars
    speed_jitter_mps: float = 0.3  # initial speeds are cruise +- this
    rear_start_x_m: Range = (50.0, 70.0)
    main_gap_m: Range = (10.0, 18.0)  # front minus rear x, centre to centre
    front_change_start_s: Range = (0.5, 2.0)
    front_change_duration_s: Range = (3.0, 4.0)
    rear_approach_start_s: Range = (0.2, 1.0)
    rear_approach_duration_s: Range = (1.2, 1.8)
    wait_offset_m: Range = (0.6, 0.9)  # waiting position: lateral shift toward the centre line
    reaction_delay_s: Range = (0.2, 0.8)  # after seeing the front car settled
    rear_change_duration_s: Range = (3.0, 4.0)
    settled_lateral_tol_m: float = 0.25  # front car "finished": |y - target lane centre| below
    settled_heading_tol_rad: float = 0.02  # ... and |heading| below


@dataclass(frozen=True, eq=False)
class DoubleMergePlan(ScenarioPlan):
    """Random quantities of one Double Merge episode (see `DoubleMergeConfig` for ranges)."""

    front: int  # agent index of the front main car
    rear: int
    cruise_speed_mps: float
    front_change_start_s: float
    front_change_duration_s: float
    rear_approach_start_s: float
    rear_approach_duration_s: float
    wait_offset_m: float
    reaction_delay_s: float
    rear_change_duration_s: float


class RearPhase(IntEnum):
    KEEP = 0  # driving in its lane
    APPROACH = 1  # moving to the waiting position next to the centre line
    WAIT = 2  # waiting for the front car to finish its lane change
    MERGE = 3  # changing lane
    DONE = 4  # in the target lane


class DoubleMerge(Scenario):
    """Double Merge scenario (see the module docstring)."""

    name = "double_merge"
    case_names = ("major", "minor")
    default_major_case = "major"
    config_class = DoubleMergeConfig

    def sample_plan(self, rng: np.random.Generator, case: str) -> DoubleMergePlan:
        """Draw an episode; the draws do not depend on `case`, only the car order does."""
        config: DoubleMergeConfig = self.config
        cruise = uniform(rng, config.cruise_speed_mps)
        speeds = cruise + rng.uniform(-1.0, 1.0, size=2) * config.speed_jitter_mps  # (rear, front)
        rear_x = uniform(rng, config.rear_start_x_m)
        front_x = rear_x + uniform(rng, config.main_gap_m)
        timings = {
            name: uniform(rng, getattr(config, name))
            for name in (
                "front_change_start_s",
                "front_change_duration_s",
                "rear_approach_start_s",
                "rear_approach_duration_s",
                "wait_offset_m",
                "reaction_delay_s",
                "rear_change_duration_s",
            )
        }
        distractors, distractor_lane_y = sample_distractors(rng, config, self.road)
        rear, front = (GREEN, BROWN) if self.check_case(case) == "major" else (BROWN, GREEN)
        lane_y = np.empty(2)
        lane_y[GREEN] = self.road.lane_center_y(config.green_lane)
        lane_y[BROWN] = self.road.lane_center_y(config.brown_lane)
        main = np.zeros((2, 4))
        main[rear] = (rear_x, lane_y[rear], 0.0, speeds[0])
        main[front] = (front_x, lane_y[front], 0.0, speeds[1])
        return DoubleMergePlan(
            initial_state=np.concatenate([main, distractors]),
            lane_y=np.concatenate([lane_y, distractor_lane_y]),
            target_speed=np.concatenate([[cruise, cruise], distractors[:, 3]]),
            front=front,
            rear=rear,
            cruise_speed_mps=cruise,
            **timings,
        )

    def _reset_memory(self) -> None:
        self.rear_phase = RearPhase.KEEP
        self.front_done_time_s: float | None = None
        self.merge_start_s: float | None = None
        labels = np.full(self.num_cars, NO_ATTENTION, dtype=np.int16)
        labels[GREEN], labels[BROWN] = BROWN, GREEN
        self._labels = labels

    def front_settled(self, world: World) -> bool:
        """The front car has finished its lane change, as the rear car can see it."""
        plan: DoubleMergePlan = self.plan
        front = plan.front
        if not world.active[front]:
            return True  # a removed front car no longer blocks the rear car
        lateral_error = abs(world.xy[front, 1] - plan.lane_y[plan.rear])
        return bool(
            lateral_error < self.config.settled_lateral_tol_m
            and abs(world.heading[front]) < self.config.settled_heading_tol_rad
        )

    def update(self, world: World) -> None:
        plan: DoubleMergePlan = self.plan
        now = world.time_s + 1e-9  # tolerate rounding of step_count * dt
        if self.front_done_time_s is None and self.front_settled(world):
            self.front_done_time_s = world.time_s
        phase = self.rear_phase
        if phase == RearPhase.KEEP and now >= plan.rear_approach_start_s:
            phase = RearPhase.APPROACH
        if (
            phase == RearPhase.APPROACH
            and now >= plan.rear_approach_start_s + plan.rear_approach_duration_s
        ):
            phase = RearPhase.WAIT
        if (
            phase == RearPhase.WAIT
            and self.front_done_time_s is not None
            and now >= self.front_done_time_s + plan.reaction_delay_s
        ):
            phase, self.merge_start_s = RearPhase.MERGE, world.time_s
        if phase == RearPhase.MERGE and now >= self.merge_start_s + plan.rear_change_duration_s:
            phase = RearPhase.DONE
        self.rear_phase = phase

    def _lateral_references(
        self, world: World, control_time: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        target, rate, accel = super()._lateral_references(world, control_time)
        plan: DoubleMergePlan = self.plan
        front, rear = plan.front, plan.rear
        front_lane, rear_lane = plan.lane_y[front], plan.lane_y[rear]
        waiting_y = rear_lane + np.sign(front_lane - rear_lane) * plan.wait_offset_m
        if self.rear_phase < RearPhase.MERGE:
            rear_move = (
                plan.rear_approach_start_s,
                plan.rear_approach_duration_s,
                rear_lane,
                waiting_y,
            )
        else:
            rear_move = (self.merge_start_s, plan.rear_change_duration_s, waiting_y, front_lane)
        front_move = (
            self.front_change_start(),
            plan.front_change_duration_s,
            front_lane,
            rear_lane,
        )
        start, duration, origin, goal = np.array([front_move, rear_move]).T  # (2,) each
        cars = [front, rear]
        target[cars], rate[cars], accel[cars] = lane_change_reference(
            control_time, start, duration, origin, goal
        )
        return target, rate, accel

    def front_change_start(self) -> float:
        """When the front car's lane change starts [s] (v0: the planned time)."""
        return self.plan.front_change_start_s

    def attention_labels(self, world: World) -> np.ndarray:
        return self._labels.copy()

    def interaction(self, world: World) -> bool:
        return self.rear_phase == RearPhase.WAIT
