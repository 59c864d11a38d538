"""What the junction scenarios share: cars that follow routes through a `carlo_lite` road
layout, distractor platoons that brake on their own, and gap acceptance at a conflict point.

- A *route* is one `carlo_lite.Lane` from a car's start to its exit (`Intersection.route`,
  `Roundabout.route`, or one lane of the layout). Every car follows its route: the steering
  tracks the route's centre-line (lateral offset d = 0) with the curvature as feed-forward, so
  `lateral_steering` sees the lane frame (d, heading relative to the route) of the car.
- A *platoon* is a column of distractors on one lane that share one speed profile (cruise, brake
  at a random moment to a lower speed or to a stop, hold, accelerate back) applied as the same
  acceleration to every car of the column: the gaps inside a column never change, so no
  distractor ever reacts to another car and none is ever reacted to (no causal link), yet they
  change speed and brake as the labelled cars do, so no average over cars can replace
  attention. A column that stops short of the junction waits at its line for the episode.
- *Gap acceptance*: a car that must give way at a conflict point (the crossing of two routes)
  goes when the car it yields to reaches the conflict zone later than it can itself leave the
  zone plus a margin, and otherwise stops at its line; it re-reads the scene every control
  step until it commits, and then never reconsiders.

Plans of these scenarios keep `ScenarioPlan.lane_y` as the lateral reference relative to each
car's route (0: its centre-line).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from carlo_lite import BatchedWorld, Lane, RoadLayout, wrap_angle
from scenarios.base import Range, Scenario, ScenarioConfig, ScenarioPlan, span, uniform
from scenarios.controllers import IDMParams, lateral_steering
from scenarios.expert import Expert, scalar_idm_accel

NEVER_S = 1e9  # a time [s] that never comes (a platoon that never brakes)


@dataclass(frozen=True)
class JunctionConfig(ScenarioConfig):
    """Settings shared by the junction scenarios (SI units; ranges are uniform draws).

    The straight-road fields of `ScenarioConfig` (num_lanes, road_length_m) are not used;
    `lane_width_m` is the width of the intersection's lanes (the roundabout has its own).
    """

    record_every: int = 3  # 0.3 s per recorded (control) step
    num_steps: int = 50  # 15 s
    num_observed: int = 12  # 3.6 s observed, 11.4 s predicted
    num_distractors: int = 12  # columns of `platoon_size` cars on the scenario's free lanes
    platoon_size: int = 3  # distractors per column
    distractor_speed_mps: Range = (5.0, 10.0)  # one cruising speed per column
    distractor_gap_m: Range = (9.0, 16.0)  # centre-to-centre gap inside a column
    platoon_brake_start_s: Range = (0.5, 9.0)  # when a column starts braking
    platoon_decel_mps2: Range = (1.5, 4.0)
    platoon_slow_ratio: Range = (0.0, 0.6)  # the speed it brakes to / its cruise
    platoon_hold_s: Range = (0.5, 3.0)  # time at the low speed
    platoon_resume_accel_mps2: Range = (1.0, 2.0)
    away_start_m: Range = (2.0, 20.0)  # a driving-away column's last car from its lane's start
    queue_stop_margin_m: Range = (1.0, 6.0)  # a waiting column's front bumper to its line
    conflict_clear_m: float = 5.5  # half length of a conflict zone along each route [m]
    gap_margin_s: float = 1.2  # gap acceptance: spare time after leaving the zone [s]
    go_accel_mps2: float = 2.0  # acceleration assumed when timing a gap [m/s^2]
    idm: IDMParams = IDMParams(time_headway_s=1.2)  # main cars' car following and stopping

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.platoon_size < 1 or self.num_distractors % self.platoon_size:
            raise ValueError("num_distractors must be a multiple of platoon_size (>= 1)")
        if self.distractor_gap_m[0] <= self.car_length_m:
            raise ValueError("distractor_gap_m must exceed the car length")


@dataclass(frozen=True, eq=False)
class JunctionPlan(ScenarioPlan):
    """A junction episode: per car (N,) its route, cruising speed and platoon speed profile."""

    route: np.ndarray  # (N,) int, index into the scenario's `routes`
    brake_at_s: np.ndarray  # (N,) when the car's profile starts braking (NEVER_S: never)
    decel_mps2: np.ndarray  # (N,)
    low_speed_mps: np.ndarray  # (N,) the speed it brakes to
    hold_s: np.ndarray  # (N,) time at the low speed (inf: for good)
    resume_accel_mps2: np.ndarray  # (N,)


def profile_speed(
    time_s: np.ndarray,
    cruise: np.ndarray,
    brake_at: np.ndarray,
    decel: np.ndarray,
    low: np.ndarray,
    hold: np.ndarray,
    resume: np.ndarray,
) -> np.ndarray:
    """The speed [m/s] of a platoon profile at `time_s` (all arrays of one shape): `cruise`
    until `brake_at`, down at `decel` to `low`, `hold` seconds there, up at `resume` to
    `cruise`."""
    slowed = brake_at + (cruise - low) / decel
    resumed = slowed + hold
    speed = np.where(time_s < brake_at, cruise, cruise - decel * (time_s - brake_at))
    speed = np.where(time_s < slowed, speed, low)
    rising = np.minimum(low + resume * (time_s - resumed), cruise)
    return np.where(time_s < resumed, speed, rising)


def time_to_cover(
    distance_m: np.ndarray, speed_mps: np.ndarray, accel_mps2: float, top_speed_mps: np.ndarray
) -> np.ndarray:
    """Seconds to drive `distance_m` from `speed_mps`, accelerating at `accel_mps2` up to
    `top_speed_mps` (0 for distances <= 0). Elementwise, closed form."""
    distance = np.maximum(distance_m, 0.0)
    speed = np.minimum(speed_mps, top_speed_mps)
    ramp_time = (top_speed_mps - speed) / accel_mps2
    ramp_distance = 0.5 * (speed + top_speed_mps) * ramp_time
    in_ramp = (np.sqrt(speed * speed + 2.0 * accel_mps2 * distance) - speed) / accel_mps2
    beyond = ramp_time + (distance - ramp_distance) / np.maximum(top_speed_mps, 1e-9)
    return np.where(distance <= ramp_distance, in_ramp, beyond)


def conflict_point(first: Lane, second: Lane, step_m: float = 0.05) -> tuple[float, float]:
    """Arc lengths (s on `first`, s on `second`) [m] where the two centre-lines cross (their
    closest points, sampled every `step_m`)."""
    s1 = np.arange(0.0, first.length_m, step_m)
    s2 = np.arange(0.0, second.length_m, step_m)
    p1, p2 = first.position(s1), second.position(s2)
    best = (np.inf, 0.0, 0.0)
    for start in range(0, len(s1), 512):  # bounded memory: 512 x len(s2) distances at a time
        block = p1[start : start + 512]
        distance = np.hypot(block[:, None, 0] - p2[None, :, 0], block[:, None, 1] - p2[None, :, 1])
        i, j = np.unravel_index(np.argmin(distance), distance.shape)
        if distance[i, j] < best[0]:
            best = (float(distance[i, j]), float(s1[start + i]), float(s2[j]))
    if best[0] > 0.5:
        raise ValueError(f"the routes do not cross (closest {best[0]:.2f} m apart)")
    return best[1], best[2]


class JunctionScenario(Scenario):
    """A scenario on a road layout: `layout` (the road), `routes` (one `Lane` per route) and
    the `platoon_lanes` its distractor columns may use, with whether each column drives away
    (brakes and resumes) or waits at the lane's end (stops at a line for good)."""

    config_class = JunctionConfig
    # (route index, True: the column waits at the route's end) for each distractor column;
    # set by the subclass in `build` (as many as num_distractors / platoon_size)
    platoon_routes: tuple[tuple[int, bool], ...]

    def __init__(self, config: JunctionConfig | None = None, *, name: str | None = None) -> None:
        super().__init__(config, name=name)
        self.layout, self.routes = self.build_layout()
        self.road = self.layout
        columns = self.config.num_distractors // self.config.platoon_size
        if columns > len(self.platoon_routes):
            raise ValueError(
                f"{self.name}: {columns} distractor columns but only "
                f"{len(self.platoon_routes)} free lanes"
            )

    def build_layout(self) -> tuple[RoadLayout, tuple[Lane, ...]]:
        """The road layout and the routes (subclasses)."""
        raise NotImplementedError

    @classmethod
    def manual_distractors(cls, config: JunctionConfig) -> str:
        return (
            f"in columns of {config.platoon_size} on lanes that no main car uses, the cars "
            f"of a column sharing one speed profile (cruising at "
            f"{span(config.distractor_speed_mps, 'm/s')}, then braking to a slower speed or to "
            "a stop at its line, and resuming); none of them reacts to another car."
        )

    def position_bounds(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) [m] of the road surface."""
        return self.layout.bounds()

    def sample_platoons(self, rng: np.random.Generator) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Distractor columns: initial states (M, 4), and per car (M,) route, cruise speed and
        profile (`JunctionPlan` fields). A waiting column brakes so that its front car stops
        `queue_stop_margin_m` before its route's end; a driving-away column brakes at a random
        moment to a random lower speed, holds and resumes."""
        config: JunctionConfig = self.config
        columns = config.num_distractors // config.platoon_size
        states, fields = [], {name: [] for name in PROFILE_FIELDS}
        for route_index, waits in self.platoon_routes[:columns]:
            lane = self.routes[route_index]
            size = config.platoon_size
            speed = uniform(rng, config.distractor_speed_mps)
            gaps = rng.uniform(*config.distractor_gap_m, size=size - 1)
            decel = uniform(rng, config.platoon_decel_mps2)
            if waits:
                margin = uniform(rng, config.queue_stop_margin_m)
                stop_s = lane.length_m - margin - 0.5 * config.car_length_m
                braking = speed * speed / (2.0 * decel)
                lead_s = stop_s - braking - speed * uniform(rng, config.platoon_brake_start_s)
                lead_s = max(lead_s, float(gaps.sum()) + config.car_length_m)
                brake_at = (stop_s - braking - lead_s) / speed
                low, hold, resume = 0.0, np.inf, 1.0
            else:
                back = float(gaps.sum()) + config.car_length_m  # the last car's rear on it
                lead_s = back + uniform(rng, config.away_start_m)
                brake_at = uniform(rng, config.platoon_brake_start_s)
                low = speed * uniform(rng, config.platoon_slow_ratio)
                hold = uniform(rng, config.platoon_hold_s)
                resume = uniform(rng, config.platoon_resume_accel_mps2)
            s = lead_s - np.concatenate([[0.0], np.cumsum(gaps)])  # front car first
            xy = lane.position(s)
            heading = wrap_angle(lane.heading_at(s))  # as the world stores it: [-pi, pi)
            states.append(np.column_stack([xy, heading, np.full(size, speed)]))
            values = (route_index, speed, brake_at, decel, low, hold, resume)
            for name, value in zip(PROFILE_FIELDS, values):
                fields[name].append(np.full(size, value))
        return np.concatenate(states), {k: np.concatenate(v) for k, v in fields.items()}

    def route_start(self, route_index: int, s: float, speed: float) -> np.ndarray:
        """[x, y, heading, speed] of a car `s` metres along route `route_index`."""
        lane = self.routes[route_index]
        x, y = lane.position(s)
        return np.array([x, y, float(wrap_angle(lane.heading_at(s))), speed])

    def junction_plan(
        self,
        main_states: np.ndarray,
        main_routes: Sequence[int],
        distractors: tuple[np.ndarray, dict[str, np.ndarray]],
        plan_class: type[JunctionPlan],
        **values,
    ) -> JunctionPlan:
        """A plan of main cars (`main_states` (K, 4), cruising at their start speed, never
        braking on a profile) and the distractor columns of `sample_platoons`."""
        states, columns = distractors
        count = len(main_states)
        main = {
            "route": np.asarray(main_routes, dtype=np.int64),
            "target_speed": main_states[:, 3],
            "brake_at_s": np.full(count, NEVER_S),
            "decel_mps2": np.ones(count),
            "low_speed_mps": main_states[:, 3],
            "hold_s": np.zeros(count),
            "resume_accel_mps2": np.ones(count),
        }
        arrays = {name: np.concatenate([main[name], columns[name]]) for name in (*PROFILE_FIELDS,)}
        num_cars = count + len(states)
        return plan_class(
            initial_state=np.concatenate([main_states, states]),
            lane_y=np.zeros(num_cars),
            **arrays,
            **values,
        )


PROFILE_FIELDS = (
    "route",
    "target_speed",
    "brake_at_s",
    "decel_mps2",
    "low_speed_mps",
    "hold_s",
    "resume_accel_mps2",
)


class JunctionExpert(Expert):
    """The experts of the junction scenarios over B scenes: every car follows its route;
    distractors (and any car a subclass leaves to it) track their platoon profile; subclasses
    give the main cars' accelerations (`_main_accelerations`).

    Per step, `update` reads every car's route frame (s along its route, lateral offset d,
    route heading and curvature) once; `expert_actions` uses it."""

    num_main: ClassVar[int] = 2  # cars 0 .. num_main - 1 are driven by `_main_accelerations`

    def __init__(self, scenario: JunctionScenario, plans: Sequence[JunctionPlan]) -> None:
        super().__init__(scenario, plans)
        self._frame_steps = np.full(self.num_scenes, -1)
        self._frame_world: BatchedWorld | None = None

    def _derive(self) -> None:
        plans = self.plans
        for name in PROFILE_FIELDS:
            if name != "target_speed":
                setattr(self, name, np.concatenate([getattr(p, name) for p in plans]))

    def restart(self, scenes, plans, world: BatchedWorld) -> None:
        super().restart(scenes, plans, world)
        self._frame_steps = np.full(self.num_scenes, -1)

    # --- route frames -----------------------------------------------------------------------
    def read_frames(self, world: BatchedWorld) -> None:
        """s, d, route heading and curvature (B*N,) of every car on its route."""
        if world is self._frame_world and np.array_equal(self._frame_steps, world.step_count):
            return  # read already at this step of this world
        x, y, heading, speed = self.flat(world)
        xy = np.column_stack([x, y])
        self.s, self.d = np.zeros(len(x)), np.zeros(len(x))
        self.route_heading, self.curvature = np.zeros(len(x)), np.zeros(len(x))
        ahead = 0.5 * self.scenario.control_period_s * speed  # half a hold ahead
        for index in np.unique(self.route).tolist():
            cars = self.route == index
            lane = self.scenario.routes[index]
            s, d = lane.local_coordinates(xy[cars])
            self.s[cars], self.d[cars] = s, d
            self.route_heading[cars] = lane.heading_at(s)
            self.curvature[cars] = lane.curvature_at(s + ahead[cars])
        self._frame_steps, self._frame_world = world.step_count.copy(), world

    def expert_actions(self, world: BatchedWorld) -> np.ndarray:
        self.read_frames(world)
        _, _, heading, speed = self.flat(world)
        steering = lateral_steering(
            self.d,
            wrap_angle(heading - self.route_heading),
            speed,
            0.0,
            0.0,
            self.config.wheelbase_m,
            self.config.lateral_gains,
            np.maximum(speed, self.config.lateral_gains.min_speed_mps) ** 2 * self.curvature,
        )
        actions = np.empty((self.num_scenes, self.num_cars, 2), dtype=np.float32)
        flat = actions.reshape(-1, 2)
        flat[:, 0] = steering
        flat[:, 1] = self._accelerations(world)
        return actions

    # --- speeds -----------------------------------------------------------------------------
    def _accelerations(self, world: BatchedWorld) -> np.ndarray:
        """Every car tracks its profile (deadbeat over one control period); the main cars then
        get `_main_accelerations`."""
        period = self.scenario.control_period_s
        time_next = np.repeat(world.time_s, self.num_cars) + period
        target = profile_speed(
            time_next,
            self.target_speed,
            self.brake_at_s,
            self.decel_mps2,
            self.low_speed_mps,
            self.hold_s,
            self.resume_accel_mps2,
        )
        limits = self.config.limits
        accel = np.clip(
            (target - world.speed.reshape(-1)) / period,
            -limits.max_decel_mps2,
            limits.max_accel_mps2,
        )
        main = accel.reshape(self.num_scenes, self.num_cars)
        main[:, : self.num_main] = self._main_accelerations(world)
        return accel

    def _main_accelerations(self, world: BatchedWorld) -> np.ndarray:
        """(B, num_main) accelerations of the main cars."""
        raise NotImplementedError

    def idm(
        self,
        car: int,
        world: BatchedWorld,
        desired_mps: np.ndarray,
        gap_m: np.ndarray,
        closing_mps: np.ndarray,
    ) -> np.ndarray:
        """(B,) IDM acceleration of main car `car` (an inf gap: a free road)."""
        speed = world.speed[:, car]
        return scalar_idm_accel(
            speed.copy(),
            desired_mps,
            gap_m,
            closing_mps,
            self.config.idm.time_headway_s,
            self.config.idm,
        )

    def at(self, values: np.ndarray, car: int) -> np.ndarray:
        """(B,) the per-car flat `values` of car `car` in every scene."""
        return values.reshape(self.num_scenes, self.num_cars)[:, car]
