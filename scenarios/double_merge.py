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

from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from carlo_lite import BatchedWorld
from scenarios.base import (
    BROWN,
    GREEN,
    NO_ATTENTION,
    Range,
    Scenario,
    ScenarioConfig,
    ScenarioPlan,
    sample_distractors,
    span,
    uniform,
)
from scenarios.controllers import lane_change_reference
from scenarios.expert import Expert


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


# The phases as plain ints for array work: numpy converts an IntEnum member slowly (~4 us a
# comparison against ~0.6 us for an int), which one scene's expert pays every step.
KEEP, APPROACH, WAIT, MERGE, DONE = (int(phase) for phase in RearPhase)


class DoubleMergeExpert(Expert):
    """Double Merge v0's expert over B scenes (see the module docstring): the rear car's
    phase, the time it saw the front car settled and its merge start are (B,) arrays."""

    plan_fields = (
        "front",
        "rear",
        "wait_offset_m",
        "front_change_start_s",
        "front_change_duration_s",
        "rear_approach_start_s",
        "rear_approach_duration_s",
        "reaction_delay_s",
        "rear_change_duration_s",
    )

    def __init__(self, scenario: DoubleMerge, plans: Sequence[DoubleMergePlan]) -> None:
        super().__init__(scenario, plans)
        labels = np.full(self.num_cars, NO_ATTENTION, dtype=np.int16)
        labels[GREEN], labels[BROWN] = BROWN, GREEN  # the main cars attend to each other
        self._labels = np.tile(labels, (self.num_scenes, 1))  # (B, N)

    def _derive(self) -> None:
        self.front_car = self.offsets + self.front  # (B,) flat car indices
        self.rear_car = self.offsets + self.rear
        self.front_lane = self.lane_y[self.front_car]  # (B,) y [m] of the lane centres
        self.rear_lane = self.lane_y[self.rear_car]
        toward = np.sign(self.front_lane - self.rear_lane)
        self.waiting_y = self.rear_lane + toward * self.wait_offset_m
        # the two lateral moves of a step, (B, 2): the front car's (fixed by the plan) and the
        # rear car's (set per step by its phase)
        self._moves = {
            "start": np.stack([self.front_change_start_s, self.front_change_start_s], axis=1),
            "duration": np.stack([self.front_change_duration_s] * 2, axis=1),
            "origin": np.stack([self.front_lane, self.front_lane], axis=1),
            "goal": np.stack([self.rear_lane, self.rear_lane], axis=1),
        }
        self._moving_cars = np.stack([self.front_car, self.rear_car], axis=1)  # (B, 2)

    def _fresh_memory(self, count: int) -> dict[str, np.ndarray]:
        return {
            "rear_phase": np.full(count, KEEP, dtype=np.int8),
            "front_done": np.zeros(count, dtype=bool),
            "front_done_time_s": np.full(count, np.nan),
            "merge_start_s": np.full(count, np.nan),
        }

    def front_settled(self, world: BatchedWorld) -> np.ndarray:
        """(B,) the front car has finished its lane change, as the rear car can see it (a
        removed front car no longer blocks the rear car)."""
        _, y, heading, _ = self.flat(world)
        lateral_error = np.abs(y[self.front_car] - self.rear_lane)
        settled = (lateral_error < self.config.settled_lateral_tol_m) & (
            np.abs(heading[self.front_car]) < self.config.settled_heading_tol_rad
        )
        return settled | ~world.flat()[4][self.front_car]

    def update(self, world: BatchedWorld) -> None:
        time_s = world.time_s  # (B,)
        now = time_s + 1e-9  # tolerate rounding of step_count * dt
        seen = ~self.front_done & self.front_settled(world)
        self.front_done_time_s[seen] = time_s[seen]
        self.front_done |= seen
        phase = self.rear_phase
        approach_end = self.rear_approach_start_s + self.rear_approach_duration_s
        phase[(phase == KEEP) & (now >= self.rear_approach_start_s)] = APPROACH
        phase[(phase == APPROACH) & (now >= approach_end)] = WAIT
        merging = (
            (phase == WAIT)
            & self.front_done
            & (now >= self.front_done_time_s + self.reaction_delay_s)
        )
        phase[merging] = MERGE
        self.merge_start_s[merging] = time_s[merging]
        merge_end = self.merge_start_s + self.rear_change_duration_s
        phase[(phase == MERGE) & (now >= merge_end)] = DONE

    def _lateral_references(
        self, world: BatchedWorld, control_time: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        target, rate, accel = super()._lateral_references(world, control_time)
        before = self.rear_phase < MERGE
        moves = self._moves  # (B, 2) each: front, rear
        np.copyto(
            moves["start"][:, 1], np.where(before, self.rear_approach_start_s, self.merge_start_s)
        )
        np.copyto(
            moves["duration"][:, 1],
            np.where(before, self.rear_approach_duration_s, self.rear_change_duration_s),
        )
        np.copyto(moves["origin"][:, 1], np.where(before, self.rear_lane, self.waiting_y))
        np.copyto(moves["goal"][:, 1], np.where(before, self.waiting_y, self.front_lane))
        cars = self._moving_cars
        target[cars], rate[cars], accel[cars] = lane_change_reference(
            control_time[:, None], moves["start"], moves["duration"], moves["origin"], moves["goal"]
        )
        return target, rate, accel

    def attention_labels(self, world: BatchedWorld) -> np.ndarray:
        return self._labels.copy()

    def interaction(self, world: BatchedWorld) -> np.ndarray:
        return self.rear_phase == WAIT


class DoubleMerge(Scenario):
    """Double Merge v0 (see the module docstring): plans and the manual's text."""

    default_name = "double_merge_v0"
    case_names = ("major", "minor")
    default_major_case = "major"
    config_class = DoubleMergeConfig
    expert_class = DoubleMergeExpert

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

    @classmethod
    def manual_description(cls, config: DoubleMergeConfig) -> str:
        return (
            f"The green car (`car_0`, lane {config.green_lane}) and the brown car (`car_1`, "
            f"lane {config.brown_lane}) want each other's lane. The front one changes lane "
            f"{span(config.front_change_start_s, 's')} into the episode, in "
            f"{span(config.front_change_duration_s, 's')}; the rear one moves next to the centre "
            f"line and waits until it sees the front car settled in the target lane, then merges "
            f"after a reaction delay of {span(config.reaction_delay_s, 's')}, in "
            f"{span(config.rear_change_duration_s, 's')}. Case `major`: the green car starts "
            f"behind the brown car; case `minor`: ahead of it."
        )

    @classmethod
    def manual_starting_state(cls, config: DoubleMergeConfig) -> str:
        return (
            f"Main cars on their lane centres, heading 0, at a common random cruising speed "
            f"({span(config.cruise_speed_mps, 'm/s')}, +-{config.speed_jitter_mps:g} m/s); the "
            f"rear one at x in [{span(config.rear_start_x_m).replace(' to ', ', ')}] m, the "
            f"front one {span(config.main_gap_m, 'm')} ahead."
        )

    @classmethod
    def manual_labels(cls, config: DoubleMergeConfig) -> str:
        return (
            'the main cars attend to each other (the paper\'s "Correct" oracle), the others to '
            "nobody; `interaction`: the rear main car is waiting next to the centre line"
        )
