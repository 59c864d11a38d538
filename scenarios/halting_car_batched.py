"""Halting Car v0 and v1 experts over B scenes (`scenarios.batched_expert`).

Each class mirrors its per-scene scenario method by method (`HaltingCar` in
scenarios/halting_car.py, `ReactiveHaltingCar` in scenarios/halting_car_reactive.py): the
leader's phase, whether it has stopped and when are (B,) arrays; v1's delayed IDM accelerations
are a `History`. Python `min` becomes `python_min`, scalar IDM calls `scalar_idm_accel`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from carlo_lite import BatchedWorld
from scenarios.base import NO_ATTENTION
from scenarios.batched_expert import BatchedExpert, History, python_min, scalar_idm_accel
from scenarios.halting_car import FOLLOWER, LEADER, HaltingCar, HaltingCarPlan, LeaderPhase
from scenarios.halting_car_reactive import ReactiveHaltingCar, ReactiveHaltingCarPlan


class BatchedHaltingCar(BatchedExpert):
    """`HaltingCar`'s expert (v0) over B scenes."""

    def __init__(self, scenario: HaltingCar, plans: Sequence[HaltingCarPlan]) -> None:
        super().__init__(scenario, plans)
        value = self.plan_values
        self.leader = self.offsets + LEADER  # (B,) flat car indices
        self.follower = self.offsets + FOLLOWER
        self.stops = value("stops", bool)
        self.cruise_speed_mps = value("cruise_speed_mps")
        self.follower_desired_speed_mps = value("follower_desired_speed_mps")
        self.time_headway_s = value("time_headway_s")
        self.brake_start_s = value("brake_start_s")
        self.brake_decel_mps2 = value("brake_decel_mps2")
        self.stop_duration_s = value("stop_duration_s")
        self.resume_accel_mps2 = value("resume_accel_mps2")
        # memory, as HaltingCar._reset_memory
        self.leader_phase = np.full(self.num_scenes, LeaderPhase.CRUISE, dtype=np.int8)
        self.has_stopped = np.zeros(self.num_scenes, dtype=bool)
        self.stopped_at_s = np.full(self.num_scenes, np.nan)
        labels = np.full(self.num_cars, NO_ATTENTION, dtype=np.int16)
        labels[FOLLOWER] = LEADER
        self._labels = np.tile(labels, (self.num_scenes, 1))  # (B, N)

    def update(self, world: BatchedWorld) -> None:
        now = world.time_s + 1e-9  # tolerate rounding of step_count * dt
        speed = world.speed[:, LEADER]  # (B,)
        phase = self.leader_phase
        braking = (
            (phase == LeaderPhase.CRUISE)
            & self.stops
            & ~self.has_stopped
            & (now >= self.brake_start_s)
        )
        phase[braking] = LeaderPhase.BRAKE
        stopping = (phase == LeaderPhase.BRAKE) & (speed <= 1e-6)
        phase[stopping] = LeaderPhase.STOPPED
        self.stopped_at_s[stopping] = world.time_s
        self.has_stopped |= stopping
        resume_at = self.stopped_at_s + self.stop_duration_s
        phase[(phase == LeaderPhase.STOPPED) & (now >= resume_at)] = LeaderPhase.RESUME
        back = (phase == LeaderPhase.RESUME) & (speed >= self.cruise_speed_mps - 0.05)
        phase[back] = LeaderPhase.CRUISE

    def _accelerations(self, world: BatchedWorld) -> np.ndarray:
        accel = super()._accelerations(world)  # speed tracking for everybody
        phase = self.leader_phase
        braking = phase == LeaderPhase.BRAKE
        accel[self.leader[braking]] = -self.brake_decel_mps2[braking]
        accel[self.leader[phase == LeaderPhase.STOPPED]] = 0.0
        resuming = phase == LeaderPhase.RESUME
        if resuming.any():
            missing = self.cruise_speed_mps - world.speed[:, LEADER]
            limit = python_min(self.resume_accel_mps2, missing / self.scenario.control_period_s)
            accel[self.leader[resuming]] = limit[resuming]
        accel[self.follower] = self._follower_accel(world)
        return accel

    def _follower_accel(self, world: BatchedWorld) -> np.ndarray:
        """(B,) IDM towards the leader (the leader is never removed in a batched world)."""
        return self._idm_now(world)

    def _idm_now(self, world: BatchedWorld) -> np.ndarray:
        x, _, _, speed = self.flat(world)
        follower_speed = speed[self.follower]
        gap = x[self.leader] - x[self.follower] - self.config.car_length_m
        closing = follower_speed - speed[self.leader]
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
        return (phase == LeaderPhase.BRAKE) | (phase == LeaderPhase.STOPPED)


class BatchedReactiveHaltingCar(BatchedHaltingCar):
    """`ReactiveHaltingCar`'s expert (v1) over B scenes."""

    def __init__(
        self, scenario: ReactiveHaltingCar, plans: Sequence[ReactiveHaltingCarPlan]
    ) -> None:
        super().__init__(scenario, plans)
        self.reaction_steps = self.plan_values("reaction_steps", np.int64)
        self._seen = History(self.num_scenes, self.config.num_steps)  # IDM accelerations

    def update(self, world: BatchedWorld) -> None:
        super().update(world)
        self._seen.append(self._idm_now(world))

    def _follower_accel(self, world: BatchedWorld) -> np.ndarray:
        """The IDM acceleration of `reaction_steps` control steps ago (see ReactiveHaltingCar)."""
        if not len(self._seen):  # asked before the first update
            return self._idm_now(world)
        return self._seen.delayed(self.reaction_steps)
