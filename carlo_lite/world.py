"""The world of one scene: a road and a set of cars stored as arrays, stepped together.

`World` is a one-scene view of `carlo_lite.BatchedWorld` (B = 1) with per-car arrays (`xy
(N, 2)`, `heading (N,)`, ...): the dynamics, the removal of cars and the collision checks are
the batched world's, so one scene evolves bit for bit like a scene of any batch.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from carlo_lite.batched import (
    DEFAULT_LENGTH_M,
    DEFAULT_WHEELBASE_M,
    DEFAULT_WIDTH_M,
    BatchedWorld,
    Road,
)
from carlo_lite.kinematics import CarLimits, box_corners


class World:
    """A road with `N` cars, structure of arrays: `xy (N, 2)`, `heading (N,)`, `speed (N,)`.

    Arguments:
        road: the road the cars drive on (its edges define off-road).
        xy: initial centre positions [m], shape (N, 2).
        heading: initial headings [rad], shape (N,); 0 points along +x.
        speed: initial speeds [m/s], shape (N,); clipped to [0, limits.max_speed_mps].
        length_m, width_m, wheelbase_m: body sizes [m], a scalar for all cars or one per car
            (defaults 4.5, 1.8, 2.7).
        roles: one label per car (e.g. "main_green", "distractor"); used for colours only.
        dt: simulation step [s] (default 0.1).
        limits: control and speed limits (see `CarLimits`).

    `step(controls)` advances every active car by `dt` with controls `(N, 2)` = [steering rad,
    acceleration m/s^2]. Inactive cars (see `deactivate`) stay where they are, take part in no
    collision and are not drawn. `batch` is the underlying one-scene `BatchedWorld`.
    """

    def __init__(
        self,
        road: Road,
        xy: np.ndarray,
        heading: np.ndarray,
        speed: np.ndarray,
        *,
        length_m: float | Sequence[float] = DEFAULT_LENGTH_M,
        width_m: float | Sequence[float] = DEFAULT_WIDTH_M,
        wheelbase_m: float | Sequence[float] = DEFAULT_WHEELBASE_M,
        roles: Sequence[str] | None = None,
        dt: float = 0.1,
        limits: CarLimits = CarLimits(),
    ) -> None:
        xy = np.array(xy, dtype=float).reshape(-1, 2)
        state = _state(xy, heading, speed)
        self.batch = BatchedWorld(
            road,
            state[None],
            length_m=length_m,
            width_m=width_m,
            wheelbase_m=wheelbase_m,
            roles=roles,
            dt=dt,
            limits=limits,
        )

    @classmethod
    def of(cls, batch: BatchedWorld) -> World:
        """The one-scene `batch` seen as a `World` (shared, not copied)."""
        if batch.num_scenes != 1:
            raise ValueError(f"a World is one scene, got a batch of {batch.num_scenes}")
        world = cls.__new__(cls)
        world.batch = batch
        return world

    @classmethod
    def from_scene(cls, batch: BatchedWorld, index: int) -> World:
        """Scene `index` of `batch` as an independent `World` (a copy: same state, clock,
        removed cars and bodies); IndexError outside [0, batch.num_scenes)."""
        return cls.of(batch.one_scene(index))

    # --- what the scene is made of ----------------------------------------------------------
    @property
    def road(self) -> Road:
        return self.batch.road

    @property
    def dt(self) -> float:
        return self.batch.dt

    @property
    def limits(self) -> CarLimits:
        return self.batch.limits

    @property
    def roles(self) -> tuple[str, ...]:
        return self.batch.roles

    @property
    def length_m(self) -> np.ndarray:
        return self.batch.length_m

    @property
    def width_m(self) -> np.ndarray:
        return self.batch.width_m

    @property
    def wheelbase_m(self) -> np.ndarray:
        return self.batch.wheelbase_m

    # --- state -----------------------------------------------------------------------------
    @property
    def num_cars(self) -> int:
        return self.batch.num_cars

    @property
    def xy(self) -> np.ndarray:
        """Centre positions [m], (N, 2), read-only view."""
        return self.batch.xy[0]

    @property
    def heading(self) -> np.ndarray:
        """Headings [rad] in [-pi, pi), (N,), read-only view."""
        return self.batch.heading[0]

    @property
    def speed(self) -> np.ndarray:
        """Speeds [m/s], (N,), read-only view."""
        return self.batch.speed[0]

    @property
    def active(self) -> np.ndarray:
        """(N,) bool, read-only view: the car takes part (not removed by `deactivate`)."""
        return self.batch.active[0]

    @property
    def state(self) -> np.ndarray:
        """A copy of the state, (N, 4) = [x, y, heading, speed]."""
        return self.batch.state[0]

    @property
    def step_count(self) -> int:
        return int(self.batch.step_count[0])

    @property
    def time_s(self) -> float:
        return float(self.batch.time_s[0])

    def set_state(self, state: np.ndarray) -> None:
        """Overwrite every car's state with `state` (N, 4), restart the clock and bring back
        removed cars (a new episode). ValueError unless `state` is finite (N, 4)."""
        state = np.asarray(state, dtype=float)
        if state.shape != (self.num_cars, 4) or not np.all(np.isfinite(state)):
            raise ValueError(f"state must be a finite ({self.num_cars}, 4) array")
        self.batch.restart([0], state[None])

    def deactivate(self, indices: int | Sequence[int] | np.ndarray) -> None:
        """Remove cars from the simulation: they freeze, never collide and are not drawn."""
        cars = np.zeros((1, self.num_cars), dtype=bool)
        cars[0, np.asarray(indices, dtype=np.int64)] = True
        self.batch.deactivate(cars)

    def copy(self) -> World:
        """An independent copy (state arrays are copied; the road is shared, it is immutable)."""
        return World.of(self.batch.copy())

    # --- dynamics ---------------------------------------------------------------------------
    def step(self, controls: np.ndarray) -> None:
        """Advance active cars by `dt` under `controls` (N, 2) = [steering rad, accel m/s^2].

        Raises ValueError naming the first car with a NaN or infinite control; values outside
        `limits` are clipped.
        """
        controls = np.asarray(controls, dtype=float)
        if controls.shape != (self.num_cars, 2):
            raise ValueError(f"controls must have shape ({self.num_cars}, 2), got {controls.shape}")
        self.batch.step(controls[None])

    # --- queries ----------------------------------------------------------------------------
    def corners(self) -> np.ndarray:
        """Body rectangle corners (N, 4, 2) [m]."""
        return box_corners(self.xy, self.heading, self.length_m, self.width_m)

    def bounding_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (low (N, 2), high (N, 2)) [m] of the car bodies."""
        low, high = self.batch.bounding_boxes()
        return low[0], high[0]

    def collision_pairs(self) -> np.ndarray:
        """Pairs (K, 2), i < j, of active cars whose bodies overlap."""
        return self.batch.collision_pairs(0)

    def collisions(self) -> np.ndarray:
        """(N,) bool: the car overlaps at least one other active car."""
        return self.incidents()[0]

    def off_road(self) -> np.ndarray:
        """(N,) bool: some part of an active car is outside the road edges."""
        return self.incidents()[1]

    def incidents(self) -> tuple[np.ndarray, np.ndarray]:
        """`(collisions(), off_road())` from one bounding-box computation: the cheapest way to
        check every step."""
        collided, off_road = self.batch.incidents()
        return collided[0], off_road[0]


def _state(xy: np.ndarray, heading: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """(N, 4) state from the per-car arrays; ValueError unless finite and of matching sizes."""
    num_cars = len(xy)
    try:
        state = np.column_stack(
            [xy, np.asarray(heading, dtype=float), np.asarray(speed, dtype=float)]
        )
    except ValueError:
        state = None
    if state is None or state.shape != (num_cars, 4) or not np.all(np.isfinite(state)):
        raise ValueError(f"state must be a finite ({num_cars}, 4) array")
    return state
