"""Halting Car: a follower (green) keeps a safe gap behind a leader (brown) that may stop.

Layout (4 lanes): both main cars in the same inner lane (1 or 2, drawn at random), the brown
leader ahead of the green follower. 20 distractors drive straight at constant speed on lanes 0
and 3 and influence nobody.

Expert:
- leader, case `stop`: cruises, brakes at a random moment with a random constant deceleration
  down to a full stop, stands for a random time, then accelerates at a random rate back to its
  cruising speed; case `go`: cruises at constant speed all episode;
- follower: lane keeping plus the Intelligent Driver Model towards the leader, with a random
  desired speed above the leader's cruise and a random time headway, so its speed follows from
  the gap; its own history cannot tell when it will brake, the leader's can;
- the random draws do not depend on the case: the same seed gives the same initial scene in
  both cases.

Either case can be the frequent (major) one; `default_major_case` is "stop", the first of
`case_names` (as "major" is for Double Merge).

Labels: the follower attends to the leader at every step; the leader and the distractors attend
to nobody (-1). Interaction period: the leader is braking or standing still (never in `go`).

Episode: 60 recorded steps of 0.3 s (18 s; 3 simulation steps of 0.1 s each), 12 observed (3.6 s)
+ 48 predicted. Braking starts between 3.6 s and 4.8 s, so it always falls in the predicted part,
and the whole stop-and-go cycle (at most 4.8 + 4 + 2 + 6 = 16.8 s) fits in the episode.
"""

from __future__ import annotations

import dataclasses
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
from scenarios.controllers import IDMParams, idm_equilibrium_gap
from scenarios.expert import Expert, python_min, scalar_idm_accel

LEADER, FOLLOWER = BROWN, GREEN


@dataclass(frozen=True)
class HaltingCarConfig(ScenarioConfig):
    """Halting Car settings and randomisation ranges (uniform draws over (low, high))."""

    record_every: int = 3  # 0.3 s per recorded step
    num_steps: int = 60  # 18 s
    num_observed: int = 12  # 3.6 s observed, 14.4 s predicted
    main_lanes: tuple[int, ...] = (1, 2)  # the main cars' lane is drawn from these
    cruise_speed_mps: Range = (8.0, 12.0)  # leader's cruising speed
    leader_start_x_m: Range = (70.0, 90.0)
    follower_speed_ratio: Range = (1.1, 1.3)  # follower's IDM desired speed / leader's cruise
    time_headway_s: Range = (1.0, 1.6)  # follower's IDM time headway
    initial_gap_ratio: Range = (0.8, 1.2)  # initial bumper gap / IDM equilibrium gap
    brake_start_s: Range = (3.6, 4.8)  # case stop: when the leader starts braking
    brake_decel_mps2: Range = (3.0, 6.0)
    stop_duration_s: Range = (1.0, 2.0)  # time standing still
    resume_accel_mps2: Range = (2.0, 3.0)
    idm: IDMParams = IDMParams()  # the follower's IDM (time headway replaced per episode)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.main_lanes or not all(
            0 < lane < self.num_lanes - 1 for lane in self.main_lanes
        ):
            raise ValueError("main_lanes must be inner lanes")


@dataclass(frozen=True, eq=False)
class HaltingCarPlan(ScenarioPlan):
    """Random quantities of one Halting Car episode (see `HaltingCarConfig` for ranges)."""

    cruise_speed_mps: float
    follower_desired_speed_mps: float
    time_headway_s: float
    brake_start_s: float
    brake_decel_mps2: float
    stop_duration_s: float
    resume_accel_mps2: float
    stops: bool  # case stop


class LeaderPhase(IntEnum):
    CRUISE = 0
    BRAKE = 1
    STOPPED = 2
    RESUME = 3  # accelerating back to the cruising speed


# The phases as plain ints for array work: numpy converts an IntEnum member slowly (~4 us a
# comparison against ~0.6 us for an int), which one scene's expert pays every step.
CRUISE, BRAKE, STOPPED, RESUME = (int(phase) for phase in LeaderPhase)


class HaltingCarExpert(Expert):
    """Halting Car v0's expert over B scenes (see the module docstring): the leader's phase,
    whether it has stopped and when are (B,) arrays."""

    plan_fields = (
        "stops",
        "cruise_speed_mps",
        "follower_desired_speed_mps",
        "time_headway_s",
        "brake_start_s",
        "brake_decel_mps2",
        "stop_duration_s",
        "resume_accel_mps2",
    )

    def __init__(self, scenario: HaltingCar, plans: Sequence[HaltingCarPlan]) -> None:
        super().__init__(scenario, plans)
        self.leader = self.offsets + LEADER  # (B,) flat car indices
        self.follower = self.offsets + FOLLOWER
        labels = np.full(self.num_cars, NO_ATTENTION, dtype=np.int16)
        labels[FOLLOWER] = LEADER  # the follower attends to the leader at every step
        self._labels = np.tile(labels, (self.num_scenes, 1))  # (B, N)

    def _fresh_memory(self, count: int) -> dict[str, np.ndarray]:
        return {
            "leader_phase": np.full(count, CRUISE, dtype=np.int8),
            "has_stopped": np.zeros(count, dtype=bool),
            "stopped_at_s": np.full(count, np.nan),
        }

    def update(self, world: BatchedWorld) -> None:
        time_s = world.time_s  # (B,)
        now = time_s + 1e-9  # tolerate rounding of step_count * dt
        speed = world.speed[:, LEADER]  # (B,)
        phase = self.leader_phase
        braking = (phase == CRUISE) & self.stops & ~self.has_stopped & (now >= self.brake_start_s)
        phase[braking] = BRAKE
        stopping = (phase == BRAKE) & (speed <= 1e-6)
        phase[stopping] = STOPPED
        self.stopped_at_s[stopping] = time_s[stopping]
        self.has_stopped |= stopping
        resume_at = self.stopped_at_s + self.stop_duration_s
        phase[(phase == STOPPED) & (now >= resume_at)] = RESUME
        back = (phase == RESUME) & (speed >= self.cruise_speed_mps - 0.05)
        phase[back] = CRUISE

    def _accelerations(self, world: BatchedWorld) -> np.ndarray:
        accel = super()._accelerations(world)  # speed tracking for everybody
        phase = self.leader_phase
        braking = phase == BRAKE
        accel[self.leader[braking]] = -self.brake_decel_mps2[braking]
        accel[self.leader[phase == STOPPED]] = 0.0
        resuming = phase == RESUME
        if resuming.any():
            missing = self.cruise_speed_mps - world.speed[:, LEADER]
            limit = python_min(self.resume_accel_mps2, missing / self.scenario.control_period_s)
            accel[self.leader[resuming]] = limit[resuming]
        accel[self.follower] = self._follower_accel(world)
        return accel

    def _follower_accel(self, world: BatchedWorld) -> np.ndarray:
        """(B,) the follower's acceleration: IDM towards the leader now."""
        return self._idm_now(world)

    def _idm_now(self, world: BatchedWorld) -> np.ndarray:
        """(B,) IDM towards the leader, or the free road where the leader was removed."""
        x, _, _, speed = self.flat(world)
        follower_speed = speed[self.follower]
        gap = x[self.leader] - x[self.follower] - self.config.car_length_m
        closing = follower_speed - speed[self.leader]
        present = world.active[:, LEADER]
        if not present.all():
            gap, closing = np.where(present, gap, np.inf), np.where(present, closing, 0.0)
        return scalar_idm_accel(
            follower_speed,
            self.follower_desired_speed_mps,
            gap,
            closing,
            self.time_headway_s,
            self.config.idm,
        )

    def attention_labels(self, world: BatchedWorld) -> np.ndarray:
        return self._labels.copy()

    def interaction(self, world: BatchedWorld) -> np.ndarray:
        phase = self.leader_phase
        return (phase == BRAKE) | (phase == STOPPED)


class HaltingCar(Scenario):
    """Halting Car v0 (see the module docstring): plans and the manual's text."""

    default_name = "halting_car_v0"
    case_names = ("stop", "go")
    default_major_case = "stop"
    config_class = HaltingCarConfig
    expert_class = HaltingCarExpert

    def sample_plan(self, rng: np.random.Generator, case: str) -> HaltingCarPlan:
        config: HaltingCarConfig = self.config
        lane = int(rng.choice(config.main_lanes))
        cruise = uniform(rng, config.cruise_speed_mps)
        leader_x = uniform(rng, config.leader_start_x_m)
        desired = cruise * uniform(rng, config.follower_speed_ratio)
        headway = uniform(rng, config.time_headway_s)
        idm = dataclasses.replace(config.idm, time_headway_s=headway)
        gap = float(idm_equilibrium_gap(cruise, desired, idm))
        gap *= uniform(rng, config.initial_gap_ratio)
        timings = {
            name: uniform(rng, getattr(config, name))
            for name in (
                "brake_start_s",
                "brake_decel_mps2",
                "stop_duration_s",
                "resume_accel_mps2",
            )
        }
        distractors, distractor_lane_y = sample_distractors(rng, config, self.road)
        y = self.road.lane_center_y(lane)
        main = np.zeros((2, 4))
        main[LEADER] = (leader_x, y, 0.0, cruise)
        main[FOLLOWER] = (leader_x - gap - config.car_length_m, y, 0.0, cruise)
        return HaltingCarPlan(
            initial_state=np.concatenate([main, distractors]),
            lane_y=np.concatenate([[y, y], distractor_lane_y]),
            target_speed=np.concatenate([[desired, cruise], distractors[:, 3]]),
            cruise_speed_mps=cruise,
            follower_desired_speed_mps=desired,
            time_headway_s=headway,
            stops=self.check_case(case) == "stop",
            **timings,
        )

    @classmethod
    def manual_description(cls, config: HaltingCarConfig) -> str:
        return (
            f"The brown leader (`car_1`) and the green follower (`car_0`, behind it) share "
            f"an inner lane ({lanes_in_words(config)}). Case `stop`: the leader brakes "
            f"{span(config.brake_start_s, 's')} into the episode with a deceleration of "
            f"{span(config.brake_decel_mps2, 'm/s^2')} to a full stop, stands "
            f"{span(config.stop_duration_s, 's')}, then accelerates at "
            f"{span(config.resume_accel_mps2, 'm/s^2')} back to its cruising speed. Case `go`: "
            f"it keeps its speed. The follower's expert is the Intelligent Driver Model towards "
            f"the leader (time headway {span(config.time_headway_s, 's')}, desired speed "
            f"{span(config.follower_speed_ratio)} x the leader's cruise)."
        )

    @classmethod
    def manual_starting_state(cls, config: HaltingCarConfig) -> str:
        return (
            f"Leader at x in [{span(config.leader_start_x_m).replace(' to ', ', ')}] m at its "
            f"cruising speed ({span(config.cruise_speed_mps, 'm/s')}); follower at the same "
            f"speed, {span(config.initial_gap_ratio)} times the IDM equilibrium gap behind it; "
            "both on the lane centre, heading 0."
        )

    @classmethod
    def manual_labels(cls, config: HaltingCarConfig) -> str:
        return (
            "the follower attends to the leader, the others to nobody; `interaction`: the "
            "leader is braking or standing still"
        )

    @classmethod
    def manual_split_note(cls, config: HaltingCarConfig) -> str:
        return "so that the leader's stop falls in the predicted part"


def lanes_in_words(config: HaltingCarConfig) -> str:
    """The main cars' lane choice in words: "1 or 2, at random"."""
    lanes = [str(lane) for lane in config.main_lanes]
    if len(lanes) == 1:
        return f"lane {lanes[0]}"
    return f"{', '.join(lanes[:-1])} or {lanes[-1]}, at random"
