"""The world: a road and a set of cars stored as arrays, stepped together."""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np

from carlo_lite.collision import CollisionChecker
from carlo_lite.kinematics import CarLimits, bicycle_step, box_corners, wrap_angle
from carlo_lite.road import StraightRoad

DEFAULT_LENGTH_M = 4.5
DEFAULT_WIDTH_M = 1.8
DEFAULT_WHEELBASE_M = 2.7


def _per_car(value: float | Sequence[float] | np.ndarray, num_cars: int, name: str) -> np.ndarray:
    array = np.broadcast_to(np.asarray(value, dtype=float), (num_cars,)).copy()
    if not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise ValueError(f"{name} must be finite and positive for every car")
    return array


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
    collision and are not drawn.
    """

    def __init__(
        self,
        road: StraightRoad,
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
        num_cars = len(xy)
        if not dt > 0:
            raise ValueError(f"dt must be positive, got {dt}")
        self.road = road
        self.dt = float(dt)
        self.limits = limits
        self.length_m = _per_car(length_m, num_cars, "length_m")
        self.width_m = _per_car(width_m, num_cars, "width_m")
        self.wheelbase_m = _per_car(wheelbase_m, num_cars, "wheelbase_m")
        self.roles = tuple(roles) if roles is not None else ("car",) * num_cars
        if len(self.roles) != num_cars:
            raise ValueError(f"got {len(self.roles)} roles for {num_cars} cars")
        self._checker = CollisionChecker(self.length_m, self.width_m, road.edge_segments())
        self._xy = np.zeros((num_cars, 2))
        self._heading = np.zeros(num_cars)
        self._speed = np.zeros(num_cars)
        self.active = np.ones(num_cars, dtype=bool)
        self.set_state(np.column_stack([xy, np.asarray(heading, float), np.asarray(speed, float)]))

    # --- state -----------------------------------------------------------------------------
    @property
    def num_cars(self) -> int:
        return len(self._speed)

    @property
    def xy(self) -> np.ndarray:
        """Centre positions [m], (N, 2), read-only view."""
        return self._readonly(self._xy)

    @property
    def heading(self) -> np.ndarray:
        """Headings [rad] in [-pi, pi), (N,), read-only view."""
        return self._readonly(self._heading)

    @property
    def speed(self) -> np.ndarray:
        """Speeds [m/s], (N,), read-only view."""
        return self._readonly(self._speed)

    @property
    def state(self) -> np.ndarray:
        """A copy of the state, (N, 4) = [x, y, heading, speed]."""
        return np.column_stack([self._xy, self._heading, self._speed])

    @property
    def time_s(self) -> float:
        return self.step_count * self.dt

    @staticmethod
    def _readonly(array: np.ndarray) -> np.ndarray:
        view = array.view()
        view.flags.writeable = False
        return view

    def set_state(self, state: np.ndarray) -> None:
        """Overwrite every car's state with `state` (N, 4) and restart the clock."""
        state = np.asarray(state, dtype=float)
        if state.shape != (self.num_cars, 4) or not np.all(np.isfinite(state)):
            raise ValueError(f"state must be a finite ({self.num_cars}, 4) array")
        self._xy[:] = state[:, :2]
        self._heading[:] = wrap_angle(state[:, 2])
        self._speed[:] = np.clip(state[:, 3], 0.0, self.limits.max_speed_mps)
        self.step_count = 0

    def deactivate(self, indices: int | Sequence[int] | np.ndarray) -> None:
        """Remove cars from the simulation: they freeze, never collide and are not drawn."""
        self.active[np.asarray(indices, dtype=np.int64)] = False

    def copy(self) -> World:
        """An independent copy (state arrays are copied; the road is shared, it is immutable)."""
        clone = copy.copy(self)
        clone._xy = self._xy.copy()
        clone._heading = self._heading.copy()
        clone._speed = self._speed.copy()
        clone.active = self.active.copy()
        return clone

    # --- dynamics ---------------------------------------------------------------------------
    def step(self, controls: np.ndarray) -> None:
        """Advance active cars by `dt` under `controls` (N, 2) = [steering rad, accel m/s^2].

        Raises ValueError naming the first car with a NaN or infinite control; values outside
        `limits` are clipped.
        """
        controls = np.asarray(controls, dtype=float)
        if controls.shape != (self.num_cars, 2):
            raise ValueError(f"controls must have shape ({self.num_cars}, 2), got {controls.shape}")
        if (
            not np.isfinite(controls).all()
            and (bad := ~np.isfinite(controls).all(axis=1) & self.active).any()
        ):
            car = int(np.argmax(bad))
            raise ValueError(
                f"car {car} ({self.roles[car]}) has a non-finite control "
                f"[steering, acceleration] = {controls[car].tolist()}"
            )
        all_active = self.active.all()
        if not all_active:
            controls = np.where(self.active[:, None], controls, 0.0)
        xy, heading, speed = bicycle_step(
            self._xy,
            self._heading,
            self._speed,
            self.limits.clip_controls(controls),
            self.wheelbase_m,
            self.dt,
            self.limits.max_speed_mps,
        )
        if all_active:
            self._xy, self._heading, self._speed = xy, heading, speed
        else:
            self._xy[self.active] = xy[self.active]
            self._heading[self.active] = heading[self.active]
            self._speed[self.active] = speed[self.active]
        self.step_count += 1

    # --- queries ----------------------------------------------------------------------------
    def corners(self) -> np.ndarray:
        """Body rectangle corners (N, 4, 2) [m]."""
        return box_corners(self._xy, self._heading, self.length_m, self.width_m)

    def collision_pairs(self) -> np.ndarray:
        """Pairs (K, 2), i < j, of active cars whose bodies overlap."""
        return self._collision_pairs(*self.bounding_boxes())

    def collisions(self) -> np.ndarray:
        """(N,) bool: the car overlaps at least one other active car."""
        return self._collisions(*self.bounding_boxes())

    def off_road(self) -> np.ndarray:
        """(N,) bool: some part of an active car is outside the road edges."""
        return self._off_road(*self.bounding_boxes())

    def incidents(self) -> tuple[np.ndarray, np.ndarray]:
        """`(collisions(), off_road())` from one bounding-box computation: the cheapest way to
        check every step."""
        low, high = self.bounding_boxes()
        return self._collisions(low, high), self._off_road(low, high)

    def bounding_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (low (N, 2), high (N, 2)) [m] of the car bodies."""
        cos, sin = np.abs(np.cos(self._heading)), np.abs(np.sin(self._heading))
        half = np.empty_like(self._xy)
        half[:, 0] = 0.5 * (self.length_m * cos + self.width_m * sin)
        half[:, 1] = 0.5 * (self.length_m * sin + self.width_m * cos)
        return self._xy - half, self._xy + half

    def _collision_pairs(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        return self._checker.collision_pairs(low, high, self._xy, self._heading, self.active)

    def _collisions(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        hit = np.zeros(self.num_cars, dtype=bool)
        hit[self._collision_pairs(low, high).ravel()] = True
        return hit

    def _off_road(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        d_min, d_max = self.road.lateral_bounds
        x = self._xy[:, 0]
        if (
            low[:, 1].min() > d_min
            and high[:, 1].max() < d_max
            and x.min() >= 0.0
            and x.max() <= self.road.length_m
        ):  # every box strictly between the (straight) edges: nothing can be off the road
            return np.zeros(self.num_cars, dtype=bool)
        touching = self._checker.edge_contacts(low, high, self._xy, self._heading, self.active)
        lane = self.road.lane_index(self._xy)
        return (touching | (lane < 0)) & self.active
