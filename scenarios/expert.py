"""A scenario's expert over B scenes at once: its state machine as arrays over scenes.

An `Expert` holds the plans of B episodes of one scenario (each drawn from its own seed by
`Scenario.sample_plan`) and drives a `carlo_lite.BatchedWorld` of those scenes:
`update(world)` advances every scene's state machine from what it observes (once per control
step), `expert_actions(world)` gives the controls (B, N, 2), `attention_labels` (B, N) and
`interaction` (B,) the labels. `restart(scenes, plans)` starts new episodes in some scenes
while the others go on (the vector environment's autoreset). One scene is B = 1: the
PettingZoo environment, `rollout` and the dataset generator all run this one implementation.

Each scene keeps its own clock (`world.time_s`, (B,)) and its own removed cars
(`world.active`): an expert reads a removed car as absent (a free road ahead, a front car that
no longer blocks), as the scenario's docstrings say.

Float semantics, the one trap: where the expert works on one car per scene (a follower's speed
and gap), a power must be taken with Python floats (C `pow`), never on a numpy array, whose
vectorised (SIMD) `pow` differs in the last bit for a few per cent of inputs. So that a scene's
episode does not depend on how many scenes run beside it (and the published datasets, made
when the expert was written per scene, keep their bytes), `scalar_idm_accel` takes those powers
element by element. Everything else is elementwise arithmetic and numpy's vectorised functions,
which give every element the same result whatever the array's length or stride (tested).

Layout: per-car values are flat (B*N,) arrays, scene-major (car n of scene b at b*N + n), the
layout `BatchedWorld` steps; per-scene values are (B,) arrays.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import ClassVar

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
    (exactly rounded arithmetic, max, clip) with arrays, in the same order. A gap of `inf` is a
    free road.
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
    """One value per scene and control step, read back with a per-scene delay; each scene
    counts its own steps, so a restarted scene starts an empty history."""

    def __init__(self, num_scenes: int, capacity: int) -> None:
        self._values = np.empty((max(capacity, 1), num_scenes))  # (steps, B)
        self._count = np.zeros(num_scenes, dtype=np.int64)
        self._scenes = np.arange(num_scenes)

    def empty(self) -> np.ndarray:
        """(B,) bool: nothing appended since the scene (re)started."""
        return self._count == 0

    def append(self, values: np.ndarray) -> None:
        """Append one value (B,) per scene."""
        if self._count.max() == len(self._values):  # more steps than planned: grow
            self._values = np.concatenate([self._values, np.empty_like(self._values)])
        self._values[self._count, self._scenes] = values
        self._count += 1

    def delayed(self, steps: np.ndarray) -> np.ndarray:
        """The value appended `steps` (B,) appends before the last one (the first one if fewer);
        meaningless for empty scenes."""
        rows = np.maximum(0, self._count - 1 - steps)
        return self._values[rows, self._scenes]

    def restart(self, scenes: np.ndarray) -> None:
        self._count[scenes] = 0


class Expert(ABC):
    """A scenario's expert over B scenes (see the module docstring).

    Subclasses name the plan fields they read in `plan_fields` (loaded as (B,) arrays of the
    same names), derive what follows from them in `_derive`, give their state machine's
    initial values in `_fresh_memory`, and implement `update`, `attention_labels`,
    `interaction` and, where the scenario does, `_lateral_references` and `_accelerations`.
    """

    plan_fields: ClassVar[tuple[str, ...]] = ()

    def __init__(self, scenario: Scenario, plans: Sequence[ScenarioPlan]) -> None:
        if not plans:
            raise ValueError("an expert needs at least one plan")
        self.scenario = scenario
        self.config = scenario.config
        self.plans = list(plans)
        self.num_scenes, self.num_cars = len(self.plans), scenario.num_cars
        self.scenes = np.arange(self.num_scenes)
        self.offsets = self.scenes * self.num_cars  # (B,) flat index of car 0
        self.lane_y = np.concatenate([plan.lane_y for plan in self.plans])  # (B*N,)
        self.target_speed = np.concatenate([plan.target_speed for plan in self.plans])
        for name in self.plan_fields:
            setattr(self, name, np.array([getattr(plan, name) for plan in self.plans]))
        self._derive()
        for name, values in self._fresh_memory(self.num_scenes).items():
            setattr(self, name, values)

    # --- episodes ---------------------------------------------------------------------------
    def make_world(self) -> BatchedWorld:
        """The scenes' world at the start of their episodes."""
        config = self.config
        return BatchedWorld(
            self.scenario.road,
            np.stack([plan.initial_state for plan in self.plans]),  # (B, N, 4)
            length_m=config.car_length_m,
            width_m=config.car_width_m,
            wheelbase_m=config.wheelbase_m,
            roles=self.scenario.role_labels,
            dt=config.dt_sim,
            limits=config.limits,
        )

    def restart(
        self, scenes: Sequence[int] | np.ndarray, plans: Sequence[ScenarioPlan], world: BatchedWorld
    ) -> None:
        """Start new episodes in `scenes` from `plans` (one per scene): their plan values, a
        fresh state machine, and their cars in `world` back at the plans' initial states."""
        scenes = np.asarray(scenes, dtype=np.int64).reshape(-1)
        if len(plans) != len(scenes):
            raise ValueError(f"got {len(plans)} plans for {len(scenes)} scenes")
        for scene, plan in zip(scenes.tolist(), plans):
            self.plans[scene] = plan
        rows = (self.offsets[scenes][:, None] + np.arange(self.num_cars)).reshape(-1)
        self.lane_y[rows] = np.concatenate([plan.lane_y for plan in plans])
        self.target_speed[rows] = np.concatenate([plan.target_speed for plan in plans])
        for name in self.plan_fields:
            getattr(self, name)[scenes] = [getattr(plan, name) for plan in plans]
        self._derive()
        for name, values in self._fresh_memory(len(scenes)).items():
            getattr(self, name)[scenes] = values
        world.restart(scenes, np.stack([plan.initial_state for plan in plans]))

    def _derive(self) -> None:  # noqa: B027 (a hook; most experts derive nothing)
        """Compute what follows from the plan arrays (called again after every restart)."""

    def _fresh_memory(self, count: int) -> dict[str, np.ndarray]:
        """The state machine at the start of an episode, for `count` scenes: name -> array with
        a leading axis of `count` (stored as attributes of that name)."""
        return {}

    # --- control ----------------------------------------------------------------------------
    @staticmethod
    def flat(world: BatchedWorld) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Flat read-only views of `world`: x, y, heading, speed, (B*N,) each."""
        return world.flat()[:4]

    @abstractmethod
    def update(self, world: BatchedWorld) -> None:
        """Advance every scene's state machine (once per control step)."""

    def expert_actions(self, world: BatchedWorld) -> np.ndarray:
        """Expert controls (B, N, 2) float32 [steering rad, acceleration m/s^2].

        float32 so that a recorded action is exactly the control that was applied.
        """
        # Lateral references are taken half a period ahead: the hold delays the response.
        control_time = world.time_s + 0.5 * self.scenario.control_period_s  # (B,)
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
        actions = np.empty((self.num_scenes, self.num_cars, 2), dtype=np.float32)
        flat = actions.reshape(-1, 2)  # (B*N, 2), a view
        flat[:, 0] = steering  # rounded to float32 as it is stored
        flat[:, 1] = self._accelerations(world)
        return actions

    def _lateral_references(
        self, world: BatchedWorld, control_time: np.ndarray
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

    # --- labels -----------------------------------------------------------------------------
    @abstractmethod
    def attention_labels(self, world: BatchedWorld) -> np.ndarray:
        """(B, N) int16: index of the car each car reacts to, -1 for none."""

    @abstractmethod
    def interaction(self, world: BatchedWorld) -> np.ndarray:
        """(B,) bool: the current step lies in the scene's interaction period."""


def expert_for(scenario: Scenario, plans: Sequence[ScenarioPlan]) -> Expert:
    """The expert driving one scene per plan: the scenario's `expert_class`."""
    return scenario.expert_class(scenario, plans)
