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
from scenarios.controllers import IDMParams, idm_accel, idm_equilibrium_gap

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


class HaltingCar(Scenario):
    """Halting Car scenario (see the module docstring)."""

    name = "halting_car"
    case_names = ("stop", "go")
    default_major_case = "stop"
    config_class = HaltingCarConfig

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

    def _reset_memory(self) -> None:
        self.leader_phase = LeaderPhase.CRUISE
        self.has_stopped = False
        self.stopped_at_s: float | None = None
        self._idm = dataclasses.replace(self.config.idm, time_headway_s=self.plan.time_headway_s)
        labels = np.full(self.num_cars, NO_ATTENTION, dtype=np.int16)
        labels[FOLLOWER] = LEADER
        self._labels = labels

    def update(self, world: World) -> None:
        plan: HaltingCarPlan = self.plan
        now = world.time_s + 1e-9  # tolerate rounding of step_count * dt
        speed = float(world.speed[LEADER])
        phase = self.leader_phase
        if (
            phase == LeaderPhase.CRUISE
            and plan.stops
            and not self.has_stopped
            and now >= plan.brake_start_s
        ):
            phase = LeaderPhase.BRAKE
        if phase == LeaderPhase.BRAKE and speed <= 1e-6:
            phase, self.stopped_at_s, self.has_stopped = LeaderPhase.STOPPED, world.time_s, True
        if phase == LeaderPhase.STOPPED and now >= self.stopped_at_s + plan.stop_duration_s:
            phase = LeaderPhase.RESUME
        if phase == LeaderPhase.RESUME and speed >= plan.cruise_speed_mps - 0.05:
            phase = LeaderPhase.CRUISE
        self.leader_phase = phase

    def _accelerations(self, world: World) -> np.ndarray:
        accel = super()._accelerations(world)  # speed tracking for everybody
        plan: HaltingCarPlan = self.plan
        phase = self.leader_phase
        if phase == LeaderPhase.BRAKE:
            accel[LEADER] = -plan.brake_decel_mps2
        elif phase == LeaderPhase.STOPPED:
            accel[LEADER] = 0.0
        elif phase == LeaderPhase.RESUME:
            missing = plan.cruise_speed_mps - float(world.speed[LEADER])
            accel[LEADER] = min(plan.resume_accel_mps2, missing / self.control_period_s)
        accel[FOLLOWER] = self._follower_accel(world)
        return accel

    def _follower_accel(self, world: World) -> float:
        """IDM towards the leader (free road if the leader was removed)."""
        speed = world.speed[FOLLOWER]
        if world.active[LEADER]:
            length = self.config.car_length_m
            gap = world.xy[LEADER, 0] - world.xy[FOLLOWER, 0] - length
            closing = speed - world.speed[LEADER]
        else:
            gap, closing = np.inf, 0.0
        desired = self.plan.follower_desired_speed_mps
        return float(idm_accel(speed, desired, gap, closing, self._idm))

    def attention_labels(self, world: World) -> np.ndarray:
        return self._labels.copy()

    def interaction(self, world: World) -> bool:
        return self.leader_phase in (LeaderPhase.BRAKE, LeaderPhase.STOPPED)
