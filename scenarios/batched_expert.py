"""The expert of a scenario for B scenes at once: its state machine as arrays over scenes.

A `BatchedExpert` holds the plans of B episodes of one scenario (drawn per scene exactly as
`Scenario.reset` draws them, then stacked) and drives a `carlo_lite.BatchedWorld` of those
scenes: `update(world)` advances every scene's state machine, `expert_actions(world)` gives the
controls (B, N, 2), `attention_labels` (B, N) and `interaction` (B,) the labels. Each method
mirrors its `Scenario` counterpart operation for operation, so every scene's episode is bit for
bit the one `scenarios.rollout` records (tested in tests/test_batched_rollout.py).

Float semantics, the one trap: where the per-scene expert works on numpy *scalars* (one car's
speed and gap), numpy's scalar `x ** y` calls the C library's `pow`, while the same power on an
array uses a vectorised (SIMD) `pow` that differs in the last bit for a few per cent of inputs.
`scalar_idm_accel` therefore takes those powers element by element with Python floats (the
same C `pow`). Arrays in the per-scene path (lane-change references, steering, kinematics) stay
arrays here, and numpy's vectorised functions give every element the same result whatever the
array's length or stride (tested).

Agent order, flat layout: the expert works on flat (B*N,) arrays, scene-major (car n of scene
b at b*N + n), the layout `BatchedWorld` steps.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence

import numpy as np

from carlo_lite import BatchedWorld
from scenarios.base import Scenario, ScenarioPlan
from scenarios.controllers import IDMParams, lateral_steering, speed_tracking_accel


def scalar_idm_accel(
    speed_mps: np.ndarray,
    desired_speed_mps: np.ndarray,
    gap_m: np.ndarray,
    approach_rate_mps: np.ndarray,
    time_headway_s: np.ndarray | float,
    params: IDMParams,
) -> np.ndarray:
    """`controllers.idm_accel` per scene (B,), bit for bit what it returns for scalar inputs.

    The two powers are taken with Python floats (C `pow`, as numpy scalars do), everything else
    (exactly rounded arithmetic, max, clip) with arrays, in the same order.
    """
    ratio = speed_mps / desired_speed_mps  # (B,)
    powered = np.array([r**params.exponent for r in ratio.tolist()])
    free_road = 1.0 - powered
    dynamic = speed_mps * time_headway_s + speed_mps * approach_rate_mps / (
        2.0 * np.sqrt(params.max_accel_mps2 * params.comfortable_decel_mps2)
    )
    desired_gap = params.min_gap_m + np.maximum(dynamic, 0.0)
    gap = np.maximum(gap_m, 0.1)  # a touching car brakes at the limit
    squared = np.array([q**2 for q in (desired_gap / gap).tolist()])
    accel = params.max_accel_mps2 * (free_road - squared)
    return np.clip(accel, -params.max_decel_mps2, params.max_accel_mps2)


def python_min(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Elementwise `min(first, second)` as Python computes it: `second` only if strictly less."""
    return np.where(second < first, second, first)


class History:
    """One value per scene and control step, (steps, B), read back with a per-scene delay."""

    def __init__(self, num_scenes: int, capacity: int) -> None:
        self._values = np.empty((max(capacity, 1), num_scenes))
        self._count = 0
        self._scenes = np.arange(num_scenes)

    def __len__(self) -> int:
        return self._count

    def append(self, values: np.ndarray) -> None:
        if self._count == len(self._values):  # more steps than planned: grow
            self._values = np.concatenate([self._values, np.empty_like(self._values)])
        self._values[self._count] = values
        self._count += 1

    def delayed(self, steps: np.ndarray) -> np.ndarray:
        """The value appended `steps` (B,) appends before the last one (the first one if fewer)."""
        rows = np.maximum(0, self._count - 1 - steps)
        return self._values[rows, self._scenes]


class BatchedExpert(ABC):
    """A scenario's expert over B scenes (see the module docstring).

    Subclasses implement `update`, `attention_labels`, `interaction` and, where the scenario
    does, `_lateral_references` and `_accelerations`; they must mirror the per-scene expert.
    """

    def __init__(self, scenario: Scenario, plans: Sequence[ScenarioPlan]) -> None:
        self.scenario = scenario
        self.config = scenario.config
        self.plans = tuple(plans)
        self.num_scenes, self.num_cars = len(self.plans), scenario.num_cars
        self.offsets = np.arange(self.num_scenes) * self.num_cars  # (B,) flat index of car 0
        self.lane_y = np.concatenate([plan.lane_y for plan in self.plans])  # (B*N,)
        self.target_speed = np.concatenate([plan.target_speed for plan in self.plans])

    def plan_values(self, name: str, dtype: type = float) -> np.ndarray:
        """Field `name` of every scene's plan, (B,)."""
        return np.array([getattr(plan, name) for plan in self.plans], dtype=dtype)

    def make_world(self) -> BatchedWorld:
        """The scenes' world at the start of the episode (as `Scenario.reset` builds each)."""
        config = self.config
        return BatchedWorld(
            self.scenario.road,
            np.stack([plan.initial_state for plan in self.plans]),  # (B, N, 4)
            length_m=config.car_length_m,
            width_m=config.car_width_m,
            wheelbase_m=config.wheelbase_m,
            dt=config.dt_sim,
            limits=config.limits,
        )

    @staticmethod
    def flat(world: BatchedWorld) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Flat read-only views of `world`: x, y, heading, speed, (B*N,) each."""
        xy = world.xy.reshape(-1, 2)
        return xy[:, 0], xy[:, 1], world.heading.reshape(-1), world.speed.reshape(-1)

    @abstractmethod
    def update(self, world: BatchedWorld) -> None:
        """Advance every scene's state machine (once per control step)."""

    def expert_actions(self, world: BatchedWorld) -> np.ndarray:
        """Expert controls (B, N, 2) float32 [steering rad, acceleration m/s^2]."""
        control_time = world.time_s + 0.5 * self.scenario.control_period_s
        target, rate, accel_ff = self._lateral_references(world, control_time)  # (B*N,) each
        _, y, heading, speed = self.flat(world)
        steering = lateral_steering(
            y,
            heading,
            speed,
            target,
            rate,
            self.config.wheelbase_m,
            self.config.lateral_gains,
            accel_ff,
        )
        acceleration = self._accelerations(world)  # (B*N,)
        actions = np.stack([steering, acceleration], axis=1).astype(np.float32)  # (B*N, 2)
        return actions.reshape(self.num_scenes, self.num_cars, 2)

    def _lateral_references(
        self, world: BatchedWorld, control_time: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lateral reference, rate, acceleration (B*N,) each; default: keep the starting lane."""
        size = len(self.lane_y)
        return self.lane_y.copy(), np.zeros(size), np.zeros(size)

    def _accelerations(self, world: BatchedWorld) -> np.ndarray:
        """Accelerations (B*N,); default: track each car's cruising speed."""
        return self.track(world.speed.reshape(-1), self.target_speed)

    def track(self, speed: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Speed tracking acceleration with the scenario's gain and the car limits."""
        limits = self.config.limits
        return speed_tracking_accel(
            speed,
            target,
            self.config.speed_gain_per_s,
            limits.max_accel_mps2,
            limits.max_decel_mps2,
        )

    @abstractmethod
    def attention_labels(self, world: BatchedWorld) -> np.ndarray:
        """(B, N) int16: index of the car each car reacts to, -1 for none."""

    @abstractmethod
    def interaction(self, world: BatchedWorld) -> np.ndarray:
        """(B,) bool: the current step lies in the scene's interaction period."""
