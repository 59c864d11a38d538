"""Road layouts made of lanes: a four-way intersection and a single-lane roundabout.

A `RoadLayout` is a set of named `Lane`s; the drivable surface is the union of the lanes (a
point is on the road when it lies within some lane's width), so off-road checks, lane lookup and
rendering work the same for every layout, the straight road included (`StraightRoad.layout()`).
Traffic drives on the right; headings are counter-clockwise from +x [rad]; metres throughout.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from carlo_lite.lanes import Arc, Lane, LanePath, join_lanes

ARMS = ("west", "south", "east", "north")  # counter-clockwise, starting with the arm at -x
TURNS = ("left", "straight", "right")


@dataclass(frozen=True)
class RoadLayout:
    """Named lanes whose union is the road surface."""

    lanes: Mapping[str, Lane]

    def __post_init__(self) -> None:
        if not self.lanes:
            raise ValueError("a road layout needs at least one lane")

    @cached_property
    def names(self) -> tuple[str, ...]:
        return tuple(self.lanes)

    def lane_membership(self, xy: np.ndarray) -> np.ndarray:
        """(..., L) bool: point lies on lane l (in the order of `names`)."""
        xy = np.asarray(xy, dtype=float)
        return np.stack([self.lanes[name].contains(xy) for name in self.names], axis=-1)

    def on_road(self, xy: np.ndarray) -> np.ndarray:
        """(...) bool: the point lies within the width of at least one lane."""
        xy = np.asarray(xy, dtype=float)
        inside = np.zeros(xy.shape[:-1], dtype=bool)
        for lane in self.lanes.values():
            inside |= lane.contains(xy)
        return inside

    def off_road(self, xy: np.ndarray) -> np.ndarray:
        """(...) bool: the point lies on no lane."""
        return ~self.on_road(xy)

    def bounds(self, margin_m: float = 0.0) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) [m] of every lane's surface, plus `margin_m`."""
        points = np.concatenate([lane.sample(0.5) for lane in self.lanes.values()])
        reach = max(lane.width_m for lane in self.lanes.values()) / 2 + margin_m
        low, high = points.min(axis=0) - reach, points.max(axis=0) + reach
        return float(low[0]), float(low[1]), float(high[0]), float(high[1])


def _rotate(xy: tuple[float, float], angle: float) -> tuple[float, float]:
    c, s = np.cos(angle), np.sin(angle)
    return float(c * xy[0] - s * xy[1]), float(s * xy[0] + c * xy[1])


@dataclass(frozen=True)
class Intersection:
    """A four-way intersection of two roads crossing at the origin, one lane each way.

    Each arm (west, south, east, north) has an incoming lane `in_<arm>` ending at the edge of the
    junction box and an outgoing lane `out_<arm>` starting there; through the box every incoming
    lane connects to the three others by `<arm>_left`, `<arm>_straight` (segments) and
    `<arm>_right` (quarter circles). The box is the square |x|, |y| <= half_box_m where
    half_box_m = lane_width_m + corner_radius_m: a right turn follows a circle of radius
    corner_radius_m + lane_width_m / 2 about the box corner, a left turn one of radius
    2 lane_width_m + corner_radius_m - lane_width_m / 2 about the opposite corner.
    """

    lane_width_m: float = 3.5  # width of every lane [m]
    arm_length_m: float = 50.0  # length of each incoming and outgoing lane outside the box [m]
    corner_radius_m: float = 4.0  # kerb radius at the corners: the box reaches past the roads

    def __post_init__(self) -> None:
        if not (self.lane_width_m > 0 and self.arm_length_m > 0 and self.corner_radius_m >= 0):
            raise ValueError("lane_width_m and arm_length_m must be positive, corner_radius_m >= 0")

    @property
    def half_box_m(self) -> float:
        return self.lane_width_m + self.corner_radius_m

    def _approach_pose(self, arm_index: int, x: float) -> tuple[tuple[float, float], float]:
        """Pose on the incoming side of arm `arm_index` at x along its direction of travel."""
        angle = arm_index * np.pi / 2  # the west arm drives along +x; the others are rotations
        return _rotate((x, -self.lane_width_m / 2), angle), angle

    @cached_property
    def layout(self) -> RoadLayout:
        w, b, a = self.lane_width_m, self.half_box_m, self.arm_length_m
        lanes: dict[str, Lane] = {}
        for k, arm in enumerate(ARMS):
            start, heading = self._approach_pose(k, -b - a)
            lanes[f"in_{arm}"] = LanePath(start, heading).straight(a).lane(w)
            far_arm = ARMS[(k + 2) % 4]  # the straight-ahead exit lies on the opposite arm
            start, heading = self._approach_pose(k, b)
            lanes[f"out_{far_arm}"] = LanePath(start, heading).straight(a).lane(w)
            entry = LanePath(*self._approach_pose(k, -b))
            lanes[f"{arm}_left"] = entry.turn(b + w / 2, np.pi / 2).lane(w)
            lanes[f"{arm}_straight"] = entry.straight(2 * b).lane(w)
            lanes[f"{arm}_right"] = entry.turn(b - w / 2, -np.pi / 2).lane(w)
        return RoadLayout(lanes)

    def exit_arm(self, arm: str, turn: str) -> str:
        """The arm a car leaves by when it enters from `arm` and turns `turn`."""
        if arm not in ARMS or turn not in TURNS:
            raise ValueError(f"arm must be one of {ARMS} and turn one of {TURNS}")
        step = {"right": 1, "straight": 2, "left": 3}[turn]
        return ARMS[(ARMS.index(arm) + step) % 4]

    def route(self, arm: str, turn: str) -> Lane:
        """One lane from the far end of arm `arm` through the box (`turn`) to the far end of its
        exit arm."""
        exit_arm = self.exit_arm(arm, turn)
        lanes = self.layout.lanes
        return join_lanes([lanes[f"in_{arm}"], lanes[f"{arm}_{turn}"], lanes[f"out_{exit_arm}"]])


@dataclass(frozen=True)
class Roundabout:
    """A single-lane roundabout centred at the origin, traffic counter-clockwise.

    `ring` is the circulating lane: a full circle of centre-line radius ring_radius_m starting
    at polar angle 0. Each arm at polar angle `arm_angles[i]` has an entry lane `enter_<i>`
    (a straight approach, then a right-hand arc of radius entry_radius_m tangent to the ring)
    and an exit lane `exit_<i>` (its mirror image). Entry and exit lanes of an arm run
    lane_offset_m either side of the arm's axis; the entry arc meets the ring at polar angle
    arm_angle + atan2(lane_offset_m + entry_radius_m, x1), x1 = sqrt((R + r)^2 - (e + r)^2),
    where the two circles touch (their centres are R + r apart).
    """

    ring_radius_m: float = 15.0  # centre-line radius of the circulating lane [m]
    lane_width_m: float = 4.0  # width of every lane [m]
    entry_radius_m: float = 12.0  # radius of the entry and exit arcs [m]
    lane_offset_m: float = 3.0  # distance of the entry/exit centre-lines from the arm axis [m]
    arm_length_m: float = 40.0  # straight part of each entry and exit lane [m]
    arm_angles: tuple[float, ...] = field(default=(0.0, np.pi / 2, np.pi, 3 * np.pi / 2))

    def __post_init__(self) -> None:
        positive = (self.ring_radius_m, self.lane_width_m, self.entry_radius_m, self.arm_length_m)
        if min(positive) <= 0:
            raise ValueError("radii, lane width and arm length must be positive")
        if not 0 <= self.lane_offset_m < self.ring_radius_m:
            raise ValueError("lane_offset_m must be in [0, ring_radius_m)")
        if not self.arm_angles:
            raise ValueError("a roundabout needs at least one arm")
        angles = np.sort(np.mod(self.arm_angles, 2 * np.pi))
        gaps = np.diff(np.concatenate([angles, angles[:1] + 2 * np.pi]))
        if gaps.min() <= 2 * self.join_angle:
            raise ValueError(
                f"arms must be more than {np.degrees(2 * self.join_angle):.1f} degrees apart "
                "so that an arm's exit leaves the ring before the next arm's entry joins it"
            )

    @property
    def _join_x(self) -> float:
        """x [m] (in the frame of an arm along +x) where the entry arc leaves the approach."""
        r, e, big_r = self.entry_radius_m, self.lane_offset_m, self.ring_radius_m
        return float(np.sqrt((big_r + r) ** 2 - (e + r) ** 2))

    @property
    def join_angle(self) -> float:
        """Polar angle [rad] from the arm's axis at which the entry arc touches the ring."""
        return float(np.arctan2(self.lane_offset_m + self.entry_radius_m, self._join_x))

    @cached_property
    def layout(self) -> RoadLayout:
        w, r, e, a = self.lane_width_m, self.entry_radius_m, self.lane_offset_m, self.arm_length_m
        x1, sweep = self._join_x, np.pi / 2 - self.join_angle
        ring = Lane((_ring_arc(self.ring_radius_m, 0.0, 2 * np.pi),), w)
        lanes: dict[str, Lane] = {"ring": ring}
        for i, angle in enumerate(self.arm_angles):
            entry = LanePath(_rotate((x1 + a, e), angle), angle + np.pi)
            lanes[f"enter_{i}"] = entry.straight(a).turn(r, -sweep).lane(w)
            ring_point = _rotate(_rotate((self.ring_radius_m, 0.0), -self.join_angle), angle)
            leave = LanePath(ring_point, angle - self.join_angle + np.pi / 2)
            lanes[f"exit_{i}"] = leave.turn(r, -sweep).straight(a).lane(w)
        return RoadLayout(lanes)

    def route(self, entry: int, exit: int) -> Lane:
        """One lane: in by arm `entry`, counter-clockwise round the ring, out by arm `exit`
        (exit == entry goes all the way round)."""
        count = len(self.arm_angles)
        if not (0 <= entry < count and 0 <= exit < count):
            raise ValueError(f"arm indices must be in [0, {count})")
        start = self.arm_angles[entry] + self.join_angle
        stop = self.arm_angles[exit] - self.join_angle
        sweep = np.mod(stop - start, 2 * np.pi)  # > 0: arms are over 2 join_angle apart
        lanes = self.layout.lanes
        ring = Lane((_ring_arc(self.ring_radius_m, start, sweep),), self.lane_width_m)
        return join_lanes([lanes[f"enter_{entry}"], ring, lanes[f"exit_{exit}"]])


def _ring_arc(radius_m: float, start_angle: float, sweep: float) -> Arc:
    return Arc((0.0, 0.0), radius_m, float(start_angle), float(sweep))
