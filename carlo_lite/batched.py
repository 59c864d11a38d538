"""The simulator: B independent scenes of N cars stepped as one world, arrays with a leading
scene axis (`xy (B, N, 2)`, `heading (B, N)`, `speed (B, N)`, `active (B, N)`).

Stepping one scene costs a few hundred numpy calls on 22-element arrays, so a scene alone spends
its time in call overhead, not arithmetic; `BatchedWorld` steps all B x N cars with the same
calls on B times longer arrays. Every car's arithmetic is element for element the same whatever
B is (the same numpy operations, in the same order, on a flat (B*N,) layout), so a scene evolves
bit for bit as it would alone. `carlo_lite.World` is one scene of it (B = 1) with per-car arrays.

Each scene keeps its own clock (`step_count`, `time_s`, (B,)) and its own removed cars
(`deactivate`): a removed car freezes, takes part in no collision and is not drawn.
`restart(scenes, state)` starts some scenes over (a new episode) while the others go on.
Collision and off-road checks use a numpy broad phase per scene (pairs only within a scene)
and a pymunk narrow phase for the few candidates.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence

import numpy as np

from carlo_lite.collision import CollisionChecker
from carlo_lite.kinematics import CarLimits, bicycle_step, wrap_angle
from carlo_lite.layouts import RoadLayout
from carlo_lite.road import StraightRoad

Road = StraightRoad | RoadLayout  # what cars can drive on

DEFAULT_LENGTH_M = 4.5
DEFAULT_WIDTH_M = 1.8
DEFAULT_WHEELBASE_M = 2.7


def per_car(value: float | Sequence[float] | np.ndarray, num_cars: int, name: str) -> np.ndarray:
    """`value` as one positive finite number per car (N,); ValueError naming `name` otherwise."""
    array = np.broadcast_to(np.asarray(value, dtype=float), (num_cars,)).copy()
    if not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise ValueError(f"{name} must be finite and positive for every car")
    return array


class BatchedWorld:
    """B scenes of the same N car bodies on one road, stepped together.

    Arguments:
        road: the road every scene drives on: a `StraightRoad` (its edges define off-road) or
            any `RoadLayout` (an intersection, a roundabout: a car is off-road when its centre
            lies on no lane).
        state: initial states (B, N, 4) = [x m, y m, heading rad, speed m/s]; headings are
            wrapped to [-pi, pi) and speeds clipped to [0, limits.max_speed_mps].
        length_m, width_m, wheelbase_m: body sizes [m], a scalar or one per car (N,), the same
            in every scene (defaults 4.5, 1.8, 2.7).
        roles: one label per car (e.g. "main_green", "distractor"), for colours and messages.
        dt: simulation step [s] (default 0.1).
        limits: control and speed limits (see `CarLimits`).

    `step(controls)` advances every active car by `dt` under controls (B, N, 2) = [steering
    rad, acceleration m/s^2]; `incidents()` says which active cars overlap another car of their
    scene and which touch or cross a road edge.
    """

    def __init__(
        self,
        road: Road,
        state: np.ndarray,
        *,
        length_m: float | Sequence[float] = DEFAULT_LENGTH_M,
        width_m: float | Sequence[float] = DEFAULT_WIDTH_M,
        wheelbase_m: float | Sequence[float] = DEFAULT_WHEELBASE_M,
        roles: Sequence[str] | None = None,
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
        self.length_m = per_car(length_m, num_cars, "length_m")  # (N,)
        self.width_m = per_car(width_m, num_cars, "width_m")
        self.wheelbase_m = per_car(wheelbase_m, num_cars, "wheelbase_m")
        self.roles = tuple(roles) if roles is not None else ("car",) * num_cars
        if len(self.roles) != num_cars:
            raise ValueError(f"got {len(self.roles)} roles for {num_cars} cars")
        self._shape = (num_scenes, num_cars)
        self._flat_wheelbase = np.tile(self.wheelbase_m, num_scenes)  # (B*N,)
        self._flat_length = np.tile(self.length_m, num_scenes)
        self._flat_width = np.tile(self.width_m, num_scenes)
        if not isinstance(road, (StraightRoad, RoadLayout)):
            raise TypeError(f"road must be a StraightRoad or a RoadLayout, got {type(road)}")
        edges = road.edge_segments() if isinstance(road, StraightRoad) else ()
        self._checker = CollisionChecker(self.length_m, self.width_m, edges)
        self._upper = np.triu(np.ones((num_cars, num_cars), dtype=bool), k=1)  # pairs i < j
        state = state.reshape(num_scenes * num_cars, 4)
        self._xy = state[:, :2].copy()  # (B*N, 2)
        self._heading = wrap_angle(state[:, 2].copy())  # (B*N,)
        self._speed = np.clip(state[:, 3], 0.0, limits.max_speed_mps)  # (B*N,)
        self._active = np.ones(self._shape, dtype=bool)
        self._all_active = True  # no car removed anywhere: the fast paths apply
        self._step_count = np.zeros(num_scenes, dtype=np.int64)

    # --- state -----------------------------------------------------------------------------
    @property
    def num_scenes(self) -> int:
        return self._shape[0]

    @property
    def num_cars(self) -> int:
        """Cars per scene, N."""
        return self._shape[1]

    def _view(self, key: str, make: Callable[[], np.ndarray]) -> np.ndarray:
        """A read-only view, made once per step (a step replaces the state arrays; restart
        and deactivate change them in place, which views follow)."""
        cache = self.__dict__.setdefault("_view_cache", {})
        view = cache.get(key)
        if view is None:
            view = cache[key] = _readonly(make())
        return view

    def _forget_views(self) -> None:
        self.__dict__.pop("_view_cache", None)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state.pop("_view_cache", None)  # views would unpickle as copies, not views
        return state

    @property
    def xy(self) -> np.ndarray:
        """Centre positions [m], (B, N, 2), read-only view."""
        return self._view("xy", lambda: self._xy.reshape(*self._shape, 2))

    @property
    def heading(self) -> np.ndarray:
        """Headings [rad] in [-pi, pi), (B, N), read-only view."""
        return self._view("heading", lambda: self._heading.reshape(self._shape))

    @property
    def speed(self) -> np.ndarray:
        """Speeds [m/s], (B, N), read-only view."""
        return self._view("speed", lambda: self._speed.reshape(self._shape))

    @property
    def active(self) -> np.ndarray:
        """(B, N) bool, read-only view: the car takes part (not removed by `deactivate`)."""
        return self._view("active", lambda: self._active)

    def flat(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Flat read-only views (B*N,), scene-major: x, y, heading, speed, active."""
        return (
            self._view("x", lambda: self._xy[:, 0]),
            self._view("y", lambda: self._xy[:, 1]),
            self._view("flat_heading", lambda: self._heading),
            self._view("flat_speed", lambda: self._speed),
            self._view("flat_active", lambda: self._active.reshape(-1)),
        )

    @property
    def state(self) -> np.ndarray:
        """A copy of the state, (B, N, 4) = [x, y, heading, speed]."""
        flat = np.column_stack([self._xy, self._heading, self._speed])  # (B*N, 4)
        return flat.reshape(*self._shape, 4)

    @property
    def step_count(self) -> np.ndarray:
        """Steps since each scene (re)started, (B,) int64, read-only view."""
        return _readonly(self._step_count)

    @property
    def time_s(self) -> np.ndarray:
        """Each scene's clock [s], (B,): step_count * dt."""
        return self._step_count * self.dt

    def restart(self, scenes: Sequence[int] | np.ndarray, state: np.ndarray) -> None:
        """Start `scenes` (K indices) over from `state` (K, N, 4): clock 0, every car active.

        The other scenes are untouched. ValueError for a state that is not finite (K, N, 4).
        """
        scenes = np.asarray(scenes, dtype=np.int64).reshape(-1)
        state = np.asarray(state, dtype=float)
        if state.shape != (len(scenes), self.num_cars, 4) or not np.all(np.isfinite(state)):
            raise ValueError(
                f"state must be a finite ({len(scenes)}, {self.num_cars}, 4) array, "
                f"got shape {state.shape}"
            )
        rows = (scenes[:, None] * self.num_cars + np.arange(self.num_cars)).reshape(-1)
        flat = state.reshape(-1, 4)
        self._xy[rows] = flat[:, :2]
        self._heading[rows] = wrap_angle(flat[:, 2])
        self._speed[rows] = np.clip(flat[:, 3], 0.0, self.limits.max_speed_mps)
        self._active[scenes] = True
        self._all_active = bool(self._active.all())
        self._step_count[scenes] = 0

    def deactivate(self, cars: np.ndarray) -> None:
        """Remove the cars where `cars` (B, N) bool is set: they freeze, never collide and are
        not drawn, until their scene restarts."""
        cars = np.asarray(cars, dtype=bool)
        if cars.shape != self._shape:
            raise ValueError(f"cars must be a {self._shape} mask, got shape {cars.shape}")
        self._active &= ~cars
        self._all_active = bool(self._active.all())

    def copy(self) -> BatchedWorld:
        """An independent copy (state arrays copied; road and collision checker shared, which
        is safe because the checker holds no state between queries)."""
        clone = copy.copy(self)
        clone._forget_views()
        clone._xy = self._xy.copy()
        clone._heading = self._heading.copy()
        clone._speed = self._speed.copy()
        clone._active = self._active.copy()
        clone._step_count = self._step_count.copy()
        return clone

    def one_scene(self, index: int) -> BatchedWorld:
        """Scene `index` as an independent one-scene batch (same state, clock, removed cars
        and bodies; `World.from_scene` wraps it); IndexError outside [0, num_scenes)."""
        if not 0 <= index < self.num_scenes:
            raise IndexError(f"scene {index} out of range: this world has {self.num_scenes}")
        single = copy.copy(self)
        single._forget_views()
        single._shape = (1, self.num_cars)
        cars = slice(index * self.num_cars, (index + 1) * self.num_cars)
        single._xy, single._heading = self._xy[cars].copy(), self._heading[cars].copy()
        single._speed = self._speed[cars].copy()
        single._active = self._active[index : index + 1].copy()
        single._all_active = bool(single._active.all())
        single._step_count = self._step_count[index : index + 1].copy()
        single._flat_wheelbase, single._flat_length = self.wheelbase_m, self.length_m
        single._flat_width = self.width_m
        return single

    # --- dynamics ---------------------------------------------------------------------------
    def step(self, controls: np.ndarray) -> None:
        """Advance every active car by `dt` under `controls` (B, N, 2) = [steering rad, accel
        m/s^2]; removed cars stay where they are and their controls are ignored.

        Raises ValueError naming the first active car (and its scene when B > 1) with a NaN or
        infinite control; values outside `limits` are clipped.
        """
        controls = np.asarray(controls, dtype=float)
        if controls.shape != (*self._shape, 2):
            raise ValueError(f"controls must have shape {(*self._shape, 2)}, got {controls.shape}")
        controls = controls.reshape(-1, 2)  # (B*N, 2)
        active = None if self._all_active else self._active.reshape(-1)
        if not np.isfinite(controls).all():
            bad = ~np.isfinite(controls).all(axis=1)
            if active is not None:
                bad &= active
            if bad.any():
                self._refuse(int(np.argmax(bad)), controls)
        if active is not None:
            controls = np.where(active[:, None], controls, 0.0)
        xy, heading, speed = bicycle_step(
            self._xy,
            self._heading,
            self._speed,
            self.limits.clip_controls(controls),
            self._flat_wheelbase,
            self.dt,
            self.limits.max_speed_mps,
        )
        if active is None:
            self._xy, self._heading, self._speed = xy, heading, speed
        else:
            self._xy[active] = xy[active]
            self._heading[active] = heading[active]
            self._speed[active] = speed[active]
        self._step_count += 1
        self._forget_views()

    def _refuse(self, flat_index: int, controls: np.ndarray) -> None:
        scene, car = divmod(flat_index, self.num_cars)
        where = f"scene {scene}, car {car}" if self.num_scenes > 1 else f"car {car}"
        raise ValueError(
            f"{where} ({self.roles[car]}) has a non-finite control "
            f"[steering, acceleration] = {controls[flat_index].tolist()}"
        )

    # --- queries ----------------------------------------------------------------------------
    def bounding_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (low (B, N, 2), high (B, N, 2)) [m] of the car bodies."""
        (low_x, low_y), (high_x, high_y) = self._boxes()
        return np.stack([low_x.T, low_y.T], axis=-1), np.stack([high_x.T, high_y.T], axis=-1)

    def _boxes(self) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """The bodies' axis-aligned bounds with the scenes innermost, for long vectorised loops
        in the checks: ((low x, low y), (high x, high y)), (N, B) each [m]."""
        num_scenes, num_cars = self._shape
        x, y, heading = (
            np.ascontiguousarray(values.reshape(num_scenes, num_cars).T)
            for values in (self._xy[:, 0], self._xy[:, 1], self._heading)
        )  # (N, B) each
        cos, sin = np.abs(np.cos(heading)), np.abs(np.sin(heading))
        length, width = self.length_m[:, None], self.width_m[:, None]  # (N, 1)
        half_x = 0.5 * (length * cos + width * sin)
        half_y = 0.5 * (length * sin + width * cos)
        return (x - half_x, y - half_y), (x + half_x, y + half_y)

    def incidents(self) -> tuple[np.ndarray, np.ndarray]:
        """(collided (B, N), off_road (B, N)) bool: the active car overlaps another active car
        of its scene; some part of the active car is outside the road edges. One bounding-box
        computation for both: the cheapest way to check every step."""
        boxes = self._boxes()
        return self._collisions(*boxes), self._off_road(*boxes)

    def collision_pairs(self, scene: int) -> np.ndarray:
        """Pairs (K, 2), i < j, of active cars of `scene` whose bodies overlap."""
        return self._scene_pairs(scene, *self._boxes())

    def _scene_pairs(self, scene: int, low: tuple, high: tuple) -> np.ndarray:
        cars = slice(scene * self.num_cars, (scene + 1) * self.num_cars)
        return self._checker.collision_pairs(
            *_scene_boxes(scene, low, high),
            self._xy[cars],
            self._heading[cars],
            self._active[scene],
        )

    def _candidate_scenes(self, low: tuple, high: tuple) -> np.ndarray:
        """Scenes with at least one pair i < j of active cars with overlapping bounding boxes
        (B,) bool, computed over (N, N, B)."""
        (low_x, low_y), (high_x, high_y) = low, high  # (N, B) each
        close = (
            self._upper[:, :, None]  # pairs i < j
            & (low_x[:, None] <= high_x[None])
            & (high_x[:, None] >= low_x[None])
            & (low_y[:, None] <= high_y[None])
            & (high_y[:, None] >= low_y[None])
        )  # (N, N, B)
        if not self._all_active:
            active = self._active.T  # (N, B)
            close &= active[:, None] & active[None]
        return close.any(axis=(0, 1))

    def _collisions(self, low: tuple, high: tuple) -> np.ndarray:
        hit = np.zeros(self._shape, dtype=bool)
        for scene in np.nonzero(self._candidate_scenes(low, high))[0].tolist():
            hit[scene, self._scene_pairs(scene, low, high).ravel()] = True
        return hit

    def _off_road(self, low: tuple, high: tuple) -> np.ndarray:
        if isinstance(self.road, RoadLayout):
            return self._off_layout()
        d_min, d_max = self.road.lateral_bounds
        num_cars = self.num_cars
        (_, low_y), (_, high_y) = low, high  # (N, B) each
        centre_x = self._xy[:, 0].reshape(self._shape)  # (B, N)
        inside = (
            (low_y.min(axis=0) > d_min)
            & (high_y.max(axis=0) < d_max)
            & (centre_x.min(axis=1) >= 0.0)
            & (centre_x.max(axis=1) <= self.road.length_m)
        )  # (B,) every box strictly between the straight edges: nothing off the road
        off = np.zeros(self._shape, dtype=bool)
        if inside.all():
            return off
        for scene in np.nonzero(~inside)[0].tolist():
            cars = slice(scene * num_cars, (scene + 1) * num_cars)
            xy, active = self._xy[cars], self._active[scene]
            touching = self._checker.edge_contacts(
                *_scene_boxes(scene, low, high), xy, self._heading[cars], active
            )
            off[scene] = (touching | (self.road.lane_index(xy) < 0)) & active
        return off

    def _off_layout(self) -> np.ndarray:
        """(B, N) bool: the active car's centre lies on no lane of the layout (how highway-env
        judges a vehicle on a lane network; a body corner is too strict there: under random
        controls it ended a third of the roundabout's cars within 1.2 s, against a sixth)."""
        off = ~self.road.on_road(self._xy)  # (B*N,)
        return off.reshape(self._shape) & self._active


def _scene_boxes(scene: int, low: tuple, high: tuple) -> tuple[np.ndarray, np.ndarray]:
    """One scene's bounds (low (N, 2), high (N, 2)) from the (N, B) ones."""
    return (
        np.column_stack([low[0][:, scene], low[1][:, scene]]),
        np.column_stack([high[0][:, scene], high[1][:, scene]]),
    )


def _readonly(array: np.ndarray) -> np.ndarray:
    view = array.view()
    view.flags.writeable = False
    return view
