"""Many independent scenes stepped as one world: B scenes of N cars, arrays with a leading scene
axis (`xy (B, N, 2)`, `heading (B, N)`, `speed (B, N)`).

Stepping one scene costs a few hundred numpy calls on 22-element arrays, so a single `World`
spends its time in call overhead, not arithmetic. `BatchedWorld` steps all B x N cars with the
same calls on B times longer arrays. Every car's arithmetic is element for element the one
`World` does (the same numpy operations, in the same order, on the same flat layout), so a scene
of a batched world evolves bit for bit like a `World` built from the same state under the same
controls (tested). Collision and off-road checks use the same broad phase per scene (pairs only
within a scene) and the same pymunk narrow phase for the few candidates.

All cars are always active: a batched world has no `deactivate` (the dataset generator never
removes cars; use `World` for that).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from carlo_lite.collision import CollisionChecker
from carlo_lite.kinematics import CarLimits, bicycle_step, wrap_angle
from carlo_lite.road import StraightRoad
from carlo_lite.world import (
    DEFAULT_LENGTH_M,
    DEFAULT_WHEELBASE_M,
    DEFAULT_WIDTH_M,
    World,
    _per_car,
)


class BatchedWorld:
    """B scenes of the same N car bodies on one road, stepped together.

    Arguments:
        road: the road every scene drives on.
        state: initial states (B, N, 4) = [x m, y m, heading rad, speed m/s]; headings are
            wrapped to [-pi, pi) and speeds clipped to [0, limits.max_speed_mps], as in `World`.
        length_m, width_m, wheelbase_m: body sizes [m], a scalar or one per car (N,), the same
            in every scene (defaults 4.5, 1.8, 2.7).
        dt: simulation step [s] (default 0.1).
        limits: control and speed limits (see `CarLimits`).

    `step(controls)` advances every car by `dt` under controls (B, N, 2) = [steering rad,
    acceleration m/s^2]; `incidents()` says which cars overlap another car of their scene and
    which touch or cross a road edge.
    """

    def __init__(
        self,
        road: StraightRoad,
        state: np.ndarray,
        *,
        length_m: float | Sequence[float] = DEFAULT_LENGTH_M,
        width_m: float | Sequence[float] = DEFAULT_WIDTH_M,
        wheelbase_m: float | Sequence[float] = DEFAULT_WHEELBASE_M,
        dt: float = 0.1,
        limits: CarLimits = CarLimits(),
    ) -> None:
        state = np.asarray(state, dtype=float)
        if state.ndim != 3 or state.shape[2] != 4 or not np.all(np.isfinite(state)):
            raise ValueError(f"state must be a finite (B, N, 4) array, got shape {state.shape}")
        if not dt > 0:
            raise ValueError(f"dt must be positive, got {dt}")
        num_scenes, num_cars = state.shape[:2]
        self.road = road
        self.dt = float(dt)
        self.limits = limits
        self.length_m = _per_car(length_m, num_cars, "length_m")  # (N,)
        self.width_m = _per_car(width_m, num_cars, "width_m")
        self.wheelbase_m = _per_car(wheelbase_m, num_cars, "wheelbase_m")
        self._shape = (num_scenes, num_cars)
        flat = num_scenes * num_cars
        self._flat_wheelbase = np.tile(self.wheelbase_m, num_scenes)  # (B*N,)
        self._flat_length = np.tile(self.length_m, num_scenes)
        self._flat_width = np.tile(self.width_m, num_scenes)
        self._checker = CollisionChecker(self.length_m, self.width_m, road.edge_segments())
        self._active = np.ones(num_cars, dtype=bool)  # for the per-scene narrow phase
        self._upper = np.triu(np.ones((num_cars, num_cars), dtype=bool), k=1)  # pairs i < j
        state = state.reshape(flat, 4)
        self._xy = state[:, :2].copy()  # (B*N, 2), the layout World steps
        self._heading = wrap_angle(state[:, 2].copy())  # (B*N,)
        self._speed = np.clip(state[:, 3], 0.0, limits.max_speed_mps)  # (B*N,)
        self.step_count = 0

    # --- state -----------------------------------------------------------------------------
    @property
    def num_scenes(self) -> int:
        return self._shape[0]

    @property
    def num_cars(self) -> int:
        """Cars per scene, N."""
        return self._shape[1]

    @property
    def xy(self) -> np.ndarray:
        """Centre positions [m], (B, N, 2), read-only view."""
        return _readonly(self._xy.reshape(*self._shape, 2))

    @property
    def heading(self) -> np.ndarray:
        """Headings [rad] in [-pi, pi), (B, N), read-only view."""
        return _readonly(self._heading.reshape(self._shape))

    @property
    def speed(self) -> np.ndarray:
        """Speeds [m/s], (B, N), read-only view."""
        return _readonly(self._speed.reshape(self._shape))

    @property
    def state(self) -> np.ndarray:
        """A copy of the state, (B, N, 4) = [x, y, heading, speed]."""
        flat = np.column_stack([self._xy, self._heading, self._speed])  # (B*N, 4)
        return flat.reshape(*self._shape, 4)

    @property
    def time_s(self) -> float:
        return self.step_count * self.dt

    def scene(self, index: int) -> World:
        """Scene `index` as an independent `World` (same state, clock and bodies); IndexError
        outside [0, num_scenes)."""
        if not 0 <= index < self.num_scenes:
            raise IndexError(f"scene {index} out of range: this world has {self.num_scenes}")
        cars = slice(index * self.num_cars, (index + 1) * self.num_cars)
        world = World(
            self.road,
            self._xy[cars],
            self._heading[cars],
            self._speed[cars],
            length_m=self.length_m,
            width_m=self.width_m,
            wheelbase_m=self.wheelbase_m,
            dt=self.dt,
            limits=self.limits,
        )
        world.step_count = self.step_count
        return world

    # --- dynamics ---------------------------------------------------------------------------
    def step(self, controls: np.ndarray) -> None:
        """Advance every car by `dt` under `controls` (B, N, 2) = [steering rad, accel m/s^2].

        Raises ValueError naming the first scene and car with a NaN or infinite control; values
        outside `limits` are clipped.
        """
        controls = np.asarray(controls, dtype=float)
        if controls.shape != (*self._shape, 2):
            raise ValueError(f"controls must have shape {(*self._shape, 2)}, got {controls.shape}")
        controls = controls.reshape(-1, 2)  # (B*N, 2)
        if not np.isfinite(controls).all():
            scene, car = divmod(int(np.argmax(~np.isfinite(controls).all(axis=1))), self.num_cars)
            raise ValueError(
                f"scene {scene}, car {car} has a non-finite control "
                f"[steering, acceleration] = {controls[scene * self.num_cars + car].tolist()}"
            )
        self._xy, self._heading, self._speed = bicycle_step(
            self._xy,
            self._heading,
            self._speed,
            self.limits.clip_controls(controls),
            self._flat_wheelbase,
            self.dt,
            self.limits.max_speed_mps,
        )
        self.step_count += 1

    # --- queries ----------------------------------------------------------------------------
    def bounding_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (low (B, N, 2), high (B, N, 2)) [m] of the car bodies."""
        cos, sin = np.abs(np.cos(self._heading)), np.abs(np.sin(self._heading))
        half = np.empty_like(self._xy)  # (B*N, 2)
        half[:, 0] = 0.5 * (self._flat_length * cos + self._flat_width * sin)
        half[:, 1] = 0.5 * (self._flat_length * sin + self._flat_width * cos)
        shape = (*self._shape, 2)
        return (self._xy - half).reshape(shape), (self._xy + half).reshape(shape)

    def incidents(self) -> tuple[np.ndarray, np.ndarray]:
        """(collided (B, N), off_road (B, N)) bool: the car overlaps another car of its scene;
        some part of the car is outside the road edges (as `World.incidents`, per scene)."""
        low, high = self.bounding_boxes()
        return self._collisions(low, high), self._off_road(low, high)

    def _candidate_scenes(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """Scenes with at least one pair i < j of overlapping bounding boxes (B,) bool."""
        overlap_x = (low[:, :, None, 0] <= high[:, None, :, 0]) & (
            high[:, :, None, 0] >= low[:, None, :, 0]
        )  # (B, N, N)
        overlap_y = (low[:, :, None, 1] <= high[:, None, :, 1]) & (
            high[:, :, None, 1] >= low[:, None, :, 1]
        )
        return (overlap_x & overlap_y & self._upper).any(axis=(1, 2))

    def _collisions(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        hit = np.zeros(self._shape, dtype=bool)
        xy, heading = self.xy, self.heading
        for scene in np.nonzero(self._candidate_scenes(low, high))[0].tolist():
            pairs = self._checker.collision_pairs(
                low[scene], high[scene], xy[scene], heading[scene], self._active
            )
            hit[scene, pairs.ravel()] = True
        return hit

    def _off_road(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        d_min, d_max = self.road.lateral_bounds
        x = self.xy[..., 0]  # (B, N)
        inside = (
            (low[..., 1].min(axis=1) > d_min)
            & (high[..., 1].max(axis=1) < d_max)
            & (x.min(axis=1) >= 0.0)
            & (x.max(axis=1) <= self.road.length_m)
        )  # (B,) every box strictly between the straight edges: nothing off the road
        off = np.zeros(self._shape, dtype=bool)
        xy, heading = self.xy, self.heading
        for scene in np.nonzero(~inside)[0].tolist():
            touching = self._checker.edge_contacts(
                low[scene], high[scene], xy[scene], heading[scene], self._active
            )
            off[scene] = touching | (self.road.lane_index(xy[scene]) < 0)
        return off


def _readonly(array: np.ndarray) -> np.ndarray:
    view = array.view()
    view.flags.writeable = False
    return view
