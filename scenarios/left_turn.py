"""Unprotected Left Turn: a car turning left across a stream of oncoming cars waits for a gap.

Layout: a four-way intersection (`carlo_lite.Intersection`, one lane each way, arms of
`arm_length_m`). The green turning car (`car_0`) comes from the south and turns left (west). A
stream of `num_oncoming` brown cars (`car_1` ...) comes from the north and drives straight
through (south) at one common speed, in that order, spaced by random time gaps. Distractor
columns (`scenarios.junction`): cross traffic on the west and east approaches brakes and waits
at its line (a red light), and columns driving away on the east and north exits brake and
resume at random moments; none of them meets a main car's path.

Expert (gap acceptance, `scenarios.junction`): the turning car approaches its stop line reading
the first oncoming car that has not yet left the conflict zone (where the two routes cross,
`conflict_clear_m` either side). Once its front is within `decision_distance_m` of the line, at
every control step until it commits, it goes if that car reaches the zone later than the turning
car can leave it (accelerating at `go_accel_mps2`) plus `gap_margin_s`; otherwise it brakes to
stop at its line (IDM towards the line) and waits. Once
it goes it accelerates to its turning speed and never reconsiders. The oncoming cars keep their
speed (the turning car only goes when it is safe); distractors follow their profiles.

Cases: the first oncoming car always arrives before the turning car could clear the zone, so
it always waits for it. `first_gap` (major): a wide gap follows it, and the turning car goes
in that gap; `later_gap` (minor): a tight gap follows it, so the turning car lets the second
car pass too (and the third when the next gap is tight as well). Gaps are tight
(`tight_gap_s`, too short to turn in) or wide (`wide_gap_s`, long enough); after the second car
they are tight with probability `tight_gap_probability`.

Labels: until it commits, the turning car attends to the oncoming car it is reading (its
attention moves from one oncoming car to the next as each passes: once or twice per episode),
at the step it commits to the car whose gap it takes (that car's distance decided it), then to
nobody; every other car attends to nobody. Interaction period: the turning car is
reading an oncoming car (not yet committed).

Episode: 50 recorded steps of 0.3 s (15 s), 12 observed (3.6 s).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlo_lite import BatchedWorld, Intersection, Lane, RoadLayout
from scenarios.base import (
    BROWN,
    DISTRACTOR,
    GREEN,
    NO_ATTENTION,
    Range,
    span,
    uniform,
)
from scenarios.junction import (
    JunctionConfig,
    JunctionExpert,
    JunctionPlan,
    JunctionScenario,
    conflict_point,
    time_to_cover,
)

TURNING = GREEN  # car 0; the oncoming cars are 1 .. num_oncoming
TURN_ROUTE, ONCOMING_ROUTE = 0, 1  # indices into the scenario's routes
# the distractor columns' lanes: (layout lane, waits at its end)
PLATOON_LANES = (("in_west", True), ("in_east", True), ("out_east", False), ("out_north", False))


@dataclass(frozen=True)
class LeftTurnConfig(JunctionConfig):
    """Unprotected Left Turn settings (uniform draws over (low, high))."""

    arm_length_m: float = 200.0  # each approach and exit lane outside the junction box [m]
    corner_radius_m: float = 4.0
    num_oncoming: int = 3
    decision_distance_m: float = 10.0  # the turning car decides within this of its line
    turn_start_m: Range = (22.0, 34.0)  # turning car's front bumper to its stop line at start
    approach_speed_mps: Range = (6.0, 8.5)  # turning car's initial and approach speed
    turn_speed_mps: Range = (6.0, 8.0)  # its desired speed once it goes
    oncoming_speed_mps: Range = (7.0, 10.0)  # the stream's common speed
    first_arrival_s: Range = (4.0, 6.5)  # the first oncoming car's arrival at the zone
    # time gaps between consecutive oncoming cars: tight (too short to turn in) with
    # probability `tight_gap_probability`, else wide (long enough)
    tight_gap_s: Range = (2.0, 3.5)
    wide_gap_s: Range = (8.5, 11.0)
    tight_gap_probability: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.num_oncoming < 1:
            raise ValueError("num_oncoming must be at least 1")

    @property
    def num_cars(self) -> int:
        return 1 + self.num_oncoming + self.num_distractors


@dataclass(frozen=True, eq=False)
class LeftTurnPlan(JunctionPlan):
    """A left-turn episode: the junction plan plus the turning car's speeds and the case."""

    turn_speed_mps: float = 7.0
    approach_speed_mps: float = 7.0
    waits_twice: bool = False  # case later_gap: a tight gap after the first oncoming car


class LeftTurnExpert(JunctionExpert):
    """The left-turn expert over B scenes: the turning car's gap acceptance (committed: (B,)
    bool) and the oncoming cars' constant speeds."""

    plan_fields = ("turn_speed_mps", "approach_speed_mps", "waits_twice")

    def __init__(self, scenario: LeftTurn, plans: Sequence[LeftTurnPlan]) -> None:
        self.num_main = 1 + scenario.config.num_oncoming
        super().__init__(scenario, plans)

    def _fresh_memory(self, count: int) -> dict[str, np.ndarray]:
        return {
            "committed": np.zeros(count, dtype=bool),
            "reading": np.full(count, NO_ATTENTION, dtype=np.int16),
        }

    def _oncoming_left(self) -> np.ndarray:
        """(B, K) bool: the oncoming car has not yet left the conflict zone (and is present)."""
        scenario: LeftTurn = self.scenario
        oncoming = slice(1, self.num_main)
        s = self.s.reshape(self.num_scenes, self.num_cars)[:, oncoming]
        return s < scenario.oncoming_conflict_s + self.config.conflict_clear_m

    def update(self, world: BatchedWorld) -> None:
        self.read_frames(world)
        scenario: LeftTurn = self.scenario
        config = self.config
        pending = self._oncoming_left() & world.active[:, 1 : self.num_main]  # (B, K)
        first = np.argmax(pending, axis=1)  # the first car still to pass, in stream order
        any_left = pending.any(axis=1)
        rows = np.arange(self.num_scenes)
        s_all = self.s.reshape(self.num_scenes, self.num_cars)
        speed = world.speed
        car = 1 + first
        distance = scenario.oncoming_conflict_s - config.conflict_clear_m - s_all[rows, car]
        arrival = np.where(
            distance > 0, distance / np.maximum(speed[rows, car], 0.1), 0.0
        )  # (B,) seconds until it enters the zone (0: inside it)
        leave = time_to_cover(
            scenario.turn_conflict_s
            + config.conflict_clear_m
            + 0.5 * config.car_length_m
            - s_all[:, TURNING],
            speed[:, TURNING],
            config.go_accel_mps2,
            self.turn_speed_mps,
        )
        safe = ~any_left | (arrival >= leave + config.gap_margin_s)
        front = s_all[:, TURNING] + 0.5 * config.car_length_m
        near = front >= scenario.stop_line_s - config.decision_distance_m
        newly = safe & near & world.active[:, TURNING] & ~self.committed
        self.committed |= newly
        # it reads the car it times, and at the step it goes the one whose gap it takes
        reading = np.where(self.committed & ~newly, NO_ATTENTION, car)
        self.reading[:] = np.where(any_left, reading, NO_ATTENTION)

    def _main_accelerations(self, world: BatchedWorld) -> np.ndarray:
        scenario: LeftTurn = self.scenario
        s_turn = self.at(self.s, TURNING)
        to_line = scenario.stop_line_s - s_turn - 0.5 * self.config.car_length_m
        gap = np.where(self.committed, np.inf, np.maximum(to_line, 0.0) + 0.1)
        closing = np.where(self.committed, 0.0, world.speed[:, TURNING])
        desired = np.where(self.committed, self.turn_speed_mps, self.approach_speed_mps)
        accel = np.empty((self.num_scenes, self.num_main))
        accel[:, TURNING] = self.idm(TURNING, world, desired, gap, closing)
        accel[:, 1:] = 0.0  # the stream keeps its speed
        return accel

    def attention_labels(self, world: BatchedWorld) -> np.ndarray:
        labels = np.full((self.num_scenes, self.num_cars), NO_ATTENTION, dtype=np.int16)
        labels[:, TURNING] = self.reading
        return labels

    def interaction(self, world: BatchedWorld) -> np.ndarray:
        return self.reading != NO_ATTENTION


class LeftTurn(JunctionScenario):
    """Unprotected Left Turn v0 (see the module docstring)."""

    default_name = "left_turn_v0"
    case_names = ("first_gap", "later_gap")
    default_major_case = "first_gap"
    config_class = LeftTurnConfig
    expert_class = LeftTurnExpert

    def __init__(self, config: LeftTurnConfig | None = None, *, name: str | None = None) -> None:
        super().__init__(config, name=name)
        config = self.config
        roles = [GREEN] + [BROWN] * config.num_oncoming + [DISTRACTOR] * config.num_distractors
        self.roles = np.array(roles, dtype=np.int8)
        self.role_labels = tuple(self.role_names[role] for role in self.roles)
        turn, oncoming = self.routes[TURN_ROUTE], self.routes[ONCOMING_ROUTE]
        self.turn_conflict_s, self.oncoming_conflict_s = conflict_point(turn, oncoming)
        self.stop_line_s = self.config.arm_length_m  # the box edge on the turning car's route

    @property
    def platoon_routes(self) -> tuple[tuple[int, bool], ...]:
        return tuple((2 + k, waits) for k, (_, waits) in enumerate(PLATOON_LANES))

    def build_layout(self) -> tuple[RoadLayout, tuple[Lane, ...]]:
        config: LeftTurnConfig = self.config
        junction = Intersection(config.lane_width_m, config.arm_length_m, config.corner_radius_m)
        layout = junction.layout
        routes = (junction.route("south", "left"), junction.route("north", "straight"))
        return layout, routes + tuple(layout.lanes[name] for name, _ in PLATOON_LANES)

    def sample_plan(self, rng: np.random.Generator, case: str) -> LeftTurnPlan:
        config: LeftTurnConfig = self.config
        waits_twice = self.check_case(case) == "later_gap"
        approach = uniform(rng, config.approach_speed_mps)
        turn_speed = uniform(rng, config.turn_speed_mps)
        front_to_line = uniform(rng, config.turn_start_m)
        s_turn = self.stop_line_s - front_to_line - 0.5 * config.car_length_m
        stream_speed = uniform(rng, config.oncoming_speed_mps)
        first = uniform(rng, config.first_arrival_s)
        tight = rng.random(config.num_oncoming - 1) < config.tight_gap_probability
        if len(tight):
            tight[0] = waits_twice  # the case decides the gap after the first car
        gaps = np.where(
            tight,
            rng.uniform(*config.tight_gap_s, size=len(tight)),
            rng.uniform(*config.wide_gap_s, size=len(tight)),
        )
        arrivals = first + np.concatenate([[0.0], np.cumsum(gaps)])
        zone_entry = self.oncoming_conflict_s - config.conflict_clear_m
        oncoming_s = zone_entry - stream_speed * arrivals
        # a car beyond the arm starts near its end, the ones before it keep their spacing
        spacing = config.distractor_gap_m[0]
        nearest = config.car_length_m  # the rear of a car never starts off the arm
        for k in reversed(range(len(oncoming_s))):
            oncoming_s[k] = max(oncoming_s[k], nearest)
            nearest = oncoming_s[k] + spacing
        main = [self.route_start(TURN_ROUTE, s_turn, approach)]
        main += [self.route_start(ONCOMING_ROUTE, s, stream_speed) for s in oncoming_s]
        routes = [TURN_ROUTE] + [ONCOMING_ROUTE] * config.num_oncoming
        return self.junction_plan(
            np.array(main),
            routes,
            self.sample_platoons(rng),
            LeftTurnPlan,
            turn_speed_mps=turn_speed,
            approach_speed_mps=approach,
            waits_twice=waits_twice,
        )

    # --- the manual --------------------------------------------------------------------------
    @classmethod
    def manual_description(cls, config: LeftTurnConfig) -> str:
        return (
            f"The green car (`car_0`) comes from the south at "
            f"{span(config.approach_speed_mps, 'm/s')} and turns left across a stream of "
            f"{config.num_oncoming} brown oncoming cars (`car_1` ... `car_{config.num_oncoming}`, "
            f"one common speed of {span(config.oncoming_speed_mps, 'm/s')}, time gaps of "
            f"{span(config.tight_gap_s, 's')} or {span(config.wide_gap_s, 's')}). It reads the "
            f"first oncoming car that has not "
            f"passed the crossing point and goes when that car arrives later than it can clear "
            f"the crossing plus {config.gap_margin_s:g} s; otherwise it stops at its line and "
            "waits. The first oncoming car always arrives first; case `first_gap`: a wide gap "
            "follows it and the green car turns in it; case `later_gap`: a tight one, so it "
            "lets two or more cars pass."
        )

    @classmethod
    def manual_starting_state(cls, config: LeftTurnConfig) -> str:
        return (
            f"The green car's front {span(config.turn_start_m, 'm')} before its stop line; the "
            "oncoming cars on their approach, placed by their arrival times; distractor columns "
            "of 3 on the west and east approaches (they stop at their lines) and on the east "
            "and north exits (they brake and resume)."
        )

    @classmethod
    def manual_labels(cls, config: LeftTurnConfig) -> str:
        return (
            "the green car attends to the oncoming car it is waiting for, moving to the next "
            "as each passes, and to nobody once it goes; the others to nobody; `interaction`: "
            "the green car is waiting for an oncoming car"
        )
