"""Roundabout Entry: an entering car yields to a circulating car or goes ahead of it.

Layout: a single-lane roundabout (`carlo_lite.Roundabout`, four arms, traffic
counter-clockwise). The green entering car (`car_0`) approaches from the east arm; the brown
circulating car (`car_1`) comes from the south arm, the one just upstream, and passes the green
car's entry on the ring. Each leaves by the north or the west arm (drawn at random).
Distractor columns (`scenarios.junction`) wait at the north and west yield lines and drive away
on the east and south exits, braking and resuming at random moments; none meets a main car.

Expert:
- green: approaches its yield line (IDM towards the line); once its front is within
  `decision_distance_m` of it, at every control step until it commits it times the brown car's
  arrival at the merge zone (where its entry joins the ring, `conflict_clear_m` either side)
  and goes if the brown car arrives later than it can itself pass the zone plus
  `gap_margin_s`; otherwise it waits at the line. Once it goes it never reconsiders, and it
  follows the brown car (IDM) whenever that car is ahead of it on its route;
- brown: circulates at its speed and follows the green car (IDM) whenever the green car is
  ahead of it on its route (after the green car entered ahead of it).

Cases: `yield` (the brown car arrives first: green waits, enters behind it and follows it) and
`go` (the brown car arrives late: green enters ahead of it, and the brown car closes up behind
it). Which one happens is decided by what the green car reads of the brown car.

Labels: green attends to brown from the start until it goes ahead of it (`go`), or for the
whole episode while brown is ahead of it on its route (`yield`); brown attends to green while
green is ahead of it on its route; the distractors attend to nobody. Interaction period: some
main car attends to the other.

Episode: 50 recorded steps of 0.3 s (15 s), 12 observed (3.6 s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from carlo_lite import BatchedWorld, Lane, RoadLayout, Roundabout
from scenarios.base import BROWN, GREEN, NO_ATTENTION, Range, span, uniform
from scenarios.expert import scalar_idm_accel
from scenarios.junction import (
    JunctionConfig,
    JunctionExpert,
    JunctionPlan,
    JunctionScenario,
    time_to_cover,
)

ENTERING, CIRCULATING = GREEN, BROWN
ENTRY_ARM, UPSTREAM_ARM = 0, 3  # east; south, the arm before it counter-clockwise
EXIT_ARMS = (1, 2)  # north, west
# routes: green to each exit, brown to each exit, then the distractor lanes
GREEN_ROUTES, BROWN_ROUTES = (0, 1), (2, 3)
# the distractor columns' lanes: (arm, "enter" (the straight approach: waits at its yield line)
# or "exit" (drives away))
PLATOON_LANES = ((1, "enter"), (2, "enter"), (0, "exit"), (3, "exit"))


@dataclass(frozen=True)
class RoundaboutEntryConfig(JunctionConfig):
    """Roundabout Entry settings (uniform draws over (low, high))."""

    ring_radius_m: float = 15.0
    entry_radius_m: float = 12.0
    lane_offset_m: float = 2.0  # entry and exit lanes of an arm touch: no median
    roundabout_lane_width_m: float = 4.0
    arm_length_m: float = 200.0  # straight part of each entry and exit lane [m]
    distractor_speed_mps: Range = (4.0, 8.0)
    away_start_m: Range = (20.0, 40.0)  # clear of the ring, which the brown car drives
    decision_distance_m: float = 10.0  # the entering car decides within this of its line
    entry_start_m: Range = (18.0, 30.0)  # its front bumper to its yield line at the start
    approach_speed_mps: Range = (5.0, 7.0)  # entering car's initial and approach speed
    enter_speed_mps: Range = (6.0, 8.0)  # its desired speed once it goes
    circulating_speed_mps: Range = (6.0, 9.0)
    yield_arrival_s: Range = (3.5, 6.5)  # case yield: brown's arrival at the merge zone
    go_arrival_margin_s: Range = (2.0, 4.0)  # case go: after green could pass + margin
    # what brown's arrival is timed from: "start" (the episode's start; green's passage
    # estimated as if it drove at its approach speed from there, v0) or "decision" (the moment
    # green reaches its decision distance, found by stepping its approach to the line as its
    # expert drives it; `yield_arrival_s` then counts from that moment, v1)
    arrival_timing: str = "start"
    green_exit_arms: tuple[int, ...] = (2,)  # the green car's exit is drawn from these (of 1, 2)
    brown_exit_arms: tuple[int, ...] = (2,)
    follow_range_m: float = 40.0  # a car ahead on one's route within this is followed

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.arrival_timing not in ("start", "decision"):
            raise ValueError("arrival_timing must be 'start' or 'decision'")


@dataclass(frozen=True, eq=False)
class RoundaboutEntryPlan(JunctionPlan):
    """A roundabout episode: the junction plan plus the green car's speeds and the case."""

    enter_speed_mps: float = 7.0
    approach_speed_mps: float = 6.0
    circulating_speed_mps: float = 7.0
    yields: bool = True  # case yield


class RoundaboutEntryExpert(JunctionExpert):
    """The roundabout expert over B scenes: green's gap acceptance (committed (B,) bool), and
    each main car following the other when it is ahead on its route."""

    plan_fields = ("enter_speed_mps", "approach_speed_mps", "circulating_speed_mps", "yields")

    def _fresh_memory(self, count: int) -> dict[str, np.ndarray]:
        return {
            "committed": np.zeros(count, dtype=bool),
            "green_reads": np.ones(count, dtype=bool),  # green reads brown (until it goes)
            "_green_gap": np.full(count, np.inf),  # bumper gaps to the other main car ahead
            "_brown_gap": np.full(count, np.inf),
        }

    def _ahead_on_route(self, world: BatchedWorld, car: int, other: int) -> np.ndarray:
        """(B,) bumper gap [m] from `car` to `other` along `car`'s route where `other` is on it
        ahead within `follow_range_m` (and present), else inf."""
        scenario: RoundaboutEntry = self.scenario
        gap = np.full(self.num_scenes, np.inf)
        routes = self.at(self.route, car)
        own_s = self.at(self.s, car)
        for index in np.unique(routes).tolist():
            scenes = routes == index
            lane = scenario.routes[index]
            s, d = lane.local_coordinates(world.xy[scenes, other])
            ahead = s - own_s[scenes] - self.config.car_length_m
            on = (
                (np.abs(d) < 0.5 * scenario.lane_width)
                & (ahead > -self.config.car_length_m)
                & (ahead < self.config.follow_range_m)
                & world.active[scenes, other]
            )
            gap[scenes] = np.where(on, ahead, np.inf)
        return gap

    def update(self, world: BatchedWorld) -> None:
        self.read_frames(world)
        scenario: RoundaboutEntry = self.scenario
        config = self.config
        green_s, brown_s = self.at(self.s, ENTERING), self.at(self.s, CIRCULATING)
        brown_merge = scenario.brown_merge_s[self.at(self.route, CIRCULATING) - BROWN_ROUTES[0]]
        distance = brown_merge - config.conflict_clear_m - brown_s
        brown_speed = np.maximum(world.speed[:, CIRCULATING], 0.1)
        passed = brown_s > brown_merge + config.conflict_clear_m
        pending = ~passed & world.active[:, CIRCULATING]
        arrival = np.where(distance > 0, distance / brown_speed, 0.0)
        leave = time_to_cover(
            scenario.green_merge_s + config.conflict_clear_m + 0.5 * config.car_length_m - green_s,
            world.speed[:, ENTERING],
            config.go_accel_mps2,
            self.enter_speed_mps,
        )
        safe = ~pending | (arrival >= leave + config.gap_margin_s)
        near = green_s + 0.5 * config.car_length_m >= scenario.yield_line_s - (
            config.decision_distance_m
        )
        newly = safe & near & world.active[:, ENTERING] & ~self.committed
        # green went ahead of brown where brown had not passed when it went
        self.green_reads &= ~(newly & pending)
        self.committed |= newly
        self._green_gap = self._ahead_on_route(world, ENTERING, CIRCULATING)
        self._brown_gap = self._ahead_on_route(world, CIRCULATING, ENTERING)

    def _main_accelerations(self, world: BatchedWorld) -> np.ndarray:
        scenario: RoundaboutEntry = self.scenario
        config = self.config
        speed = world.speed
        green_s = self.at(self.s, ENTERING)
        to_line = scenario.yield_line_s - green_s - 0.5 * config.car_length_m
        line_gap = np.where(self.committed, np.inf, np.maximum(to_line, 0.0) + 0.1)
        follow = np.isfinite(self._green_gap)
        gap = np.minimum(line_gap, self._green_gap)
        closing = np.where(
            line_gap <= self._green_gap,
            np.where(self.committed, 0.0, speed[:, ENTERING]),
            speed[:, ENTERING] - speed[:, CIRCULATING],
        )
        closing = np.where(np.isfinite(gap), closing, 0.0)
        desired = np.where(self.committed | follow, self.enter_speed_mps, self.approach_speed_mps)
        accel = np.empty((self.num_scenes, 2))
        accel[:, ENTERING] = self.idm(ENTERING, world, desired, gap, closing)
        brown_gap = self._brown_gap
        brown_closing = np.where(
            np.isfinite(brown_gap), speed[:, CIRCULATING] - speed[:, ENTERING], 0.0
        )
        accel[:, CIRCULATING] = self.idm(
            CIRCULATING, world, self.circulating_speed_mps, brown_gap, brown_closing
        )
        return accel

    def attention_labels(self, world: BatchedWorld) -> np.ndarray:
        labels = np.full((self.num_scenes, self.num_cars), NO_ATTENTION, dtype=np.int16)
        green_attends = (self.green_reads & ~self.committed) | np.isfinite(self._green_gap)
        labels[:, ENTERING] = np.where(green_attends, CIRCULATING, NO_ATTENTION)
        brown_attends = np.isfinite(self._brown_gap)
        labels[:, CIRCULATING] = np.where(brown_attends, ENTERING, NO_ATTENTION)
        return labels

    def interaction(self, world: BatchedWorld) -> np.ndarray:
        return (self.attention_labels(world)[:, :2] != NO_ATTENTION).any(axis=1)


class RoundaboutEntry(JunctionScenario):
    """Roundabout Entry v0 (see the module docstring)."""

    default_name = "roundabout_entry_v0"
    case_names = ("yield", "go")
    default_major_case = "yield"
    config_class = RoundaboutEntryConfig
    expert_class = RoundaboutEntryExpert

    def __init__(
        self, config: RoundaboutEntryConfig | None = None, *, name: str | None = None
    ) -> None:
        super().__init__(config, name=name)
        entry = self.layout.lanes[f"enter_{ENTRY_ARM}"]
        self.yield_line_s = entry.pieces[0].length_m  # end of the straight approach
        self.green_merge_s = entry.length_m  # where the entry joins the ring
        merge_xy = np.array(entry.end)
        self.brown_merge_s = np.array(
            [float(self.routes[r].local_coordinates(merge_xy)[0]) for r in BROWN_ROUTES]
        )

    @property
    def lane_width(self) -> float:
        return self.config.roundabout_lane_width_m

    @property
    def platoon_routes(self) -> tuple[tuple[int, bool], ...]:
        first = len(GREEN_ROUTES) + len(BROWN_ROUTES)
        return tuple((first + k, kind == "enter") for k, (_, kind) in enumerate(PLATOON_LANES))

    def build_layout(self) -> tuple[RoadLayout, tuple[Lane, ...]]:
        config: RoundaboutEntryConfig = self.config
        roundabout = Roundabout(
            ring_radius_m=config.ring_radius_m,
            lane_width_m=config.roundabout_lane_width_m,
            entry_radius_m=config.entry_radius_m,
            lane_offset_m=config.lane_offset_m,
            arm_length_m=config.arm_length_m,
        )
        layout = roundabout.layout
        routes = [roundabout.route(ENTRY_ARM, arm) for arm in EXIT_ARMS]
        routes += [roundabout.route(UPSTREAM_ARM, arm) for arm in EXIT_ARMS]
        for arm, kind in PLATOON_LANES:
            lane = layout.lanes[f"{kind}_{arm}"]
            if kind == "enter":  # the straight approach only: the column waits at its line
                lane = Lane(lane.pieces[:1], lane.width_m)
            routes.append(lane)
        return layout, tuple(routes)

    def sample_plan(self, rng: np.random.Generator, case: str) -> RoundaboutEntryPlan:
        config: RoundaboutEntryConfig = self.config
        yields = self.check_case(case) == "yield"
        green_exit = EXIT_ARMS.index(int(rng.choice(config.green_exit_arms)))
        brown_exit = EXIT_ARMS.index(int(rng.choice(config.brown_exit_arms)))
        approach = uniform(rng, config.approach_speed_mps)
        enter_speed = uniform(rng, config.enter_speed_mps)
        circulating = uniform(rng, config.circulating_speed_mps)
        green_s = (
            self.yield_line_s - uniform(rng, config.entry_start_m) - 0.5 * (config.car_length_m)
        )
        decided_s, decided_speed, decided_at = green_s, approach, 0.0
        if config.arrival_timing == "decision":
            decided_s, decided_speed, decided_at = self.approach_to_decision(green_s, approach)
        leave = decided_at + float(
            time_to_cover(
                np.array(
                    self.green_merge_s
                    + config.conflict_clear_m
                    + 0.5 * config.car_length_m
                    - decided_s
                ),
                np.array(decided_speed),
                config.go_accel_mps2,
                np.array(enter_speed),
            )
        )
        if yields:
            arrival = decided_at + uniform(rng, config.yield_arrival_s)
        else:
            arrival = leave + config.gap_margin_s + uniform(rng, config.go_arrival_margin_s)
        merge = self.brown_merge_s[brown_exit]
        brown_s = max(merge - config.conflict_clear_m - circulating * arrival, config.car_length_m)
        green_route, brown_route = GREEN_ROUTES[green_exit], BROWN_ROUTES[brown_exit]
        main = np.array(
            [
                self.route_start(green_route, green_s, approach),
                self.route_start(brown_route, brown_s, circulating),
            ]
        )
        return self.junction_plan(
            main,
            [green_route, brown_route],
            self.sample_platoons(rng),
            RoundaboutEntryPlan,
            enter_speed_mps=enter_speed,
            approach_speed_mps=approach,
            circulating_speed_mps=circulating,
            yields=yields,
        )

    def approach_to_decision(self, centre_s: float, speed: float) -> tuple[float, float, float]:
        """(s [m], speed [m/s], time [s]) of the green car at the first control step where its
        front is within `decision_distance_m` of its yield line: its approach (IDM towards the
        line at the approach speed `speed`, each control held one period) stepped along its
        route from its centre's arc length `centre_s`, as its expert drives it until it
        decides. The bicycle model's lag makes this an estimate to within a control step."""
        config: RoundaboutEntryConfig = self.config
        period = self.control_period_s
        half = 0.5 * config.car_length_m
        desired = np.array([speed])
        s, time, current = centre_s, 0.0, speed
        while s + half < self.yield_line_s - config.decision_distance_m:
            if time >= config.num_steps * period:
                break  # stopped short of its decision distance (not with valid settings)
            to_line = self.yield_line_s - s - half
            accel = scalar_idm_accel(
                np.array([current]),
                desired,
                np.array([to_line + 0.1]),
                np.array([current]),
                config.idm.time_headway_s,
                config.idm,
            )
            new_speed = max(current + float(accel[0]) * period, 0.0)
            s += 0.5 * (current + new_speed) * period
            current, time = new_speed, time + period
        return s, current, time

    # --- the manual --------------------------------------------------------------------------
    @classmethod
    def manual_description(cls, config: RoundaboutEntryConfig) -> str:
        return (
            f"The green car (`car_0`) approaches a single-lane roundabout from the east at "
            f"{span(config.approach_speed_mps, 'm/s')}; the brown car (`car_1`) circulates at "
            f"{span(config.circulating_speed_mps, 'm/s')} from the south arm past the green "
            f"car's entry. Within {config.decision_distance_m:g} m of its yield line the green "
            f"car goes when the brown car reaches the merge later than it can pass it plus "
            f"{config.gap_margin_s:g} s, and otherwise waits and enters behind it. Case "
            "`yield`: the brown car arrives first; case `go`: the green car enters ahead of it "
            "and the brown car follows it (IDM)."
        )

    @classmethod
    def manual_starting_state(cls, config: RoundaboutEntryConfig) -> str:
        return (
            f"The green car's front {span(config.entry_start_m, 'm')} before its yield line; "
            "the brown car on its route, placed by its arrival time at the merge; distractor "
            "columns of 3 on the north and west approaches (they stop at their yield lines) "
            "and on the east and south exits (they brake and resume)."
        )

    @classmethod
    def manual_labels(cls, config: RoundaboutEntryConfig) -> str:
        return (
            "the green car attends to the brown car until it goes ahead of it, and while the "
            "brown car is ahead of it on its route; the brown car attends to the green car "
            "while that car is ahead of it on its route; the others to nobody; `interaction`: "
            "a main car attends to the other"
        )
