"""Road geometry: lanes as geometric objects and a straight multi-lane road built from them.

A lane is geometry (a reference line with a width), not a number; curved lanes live in
`carlo_lite.lanes` (`Lane`: segments and arcs) and `StraightLane.as_lane()` /
`StraightRoad.layout()` express this road in that model. Coordinates are SI metres; the road
frame is (s, d): s along the road from its start, d lateral from its right edge, positive to the
left.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from carlo_lite.lanes import Lane, Segment
from carlo_lite.layouts import RoadLayout


@dataclass(frozen=True)
class StraightLane:
    """A straight lane from `start` to `end` (metres) with a width [m].

    Lane coordinates: s [m] along the centre line from `start`, d [m] lateral offset from the
    centre line, positive to the left of the driving direction.
    """

    start: tuple[float, float]
    end: tuple[float, float]
    width_m: float = 3.5

    @cached_property
    def length_m(self) -> float:
        return float(np.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1]))

    @cached_property
    def _direction(self) -> np.ndarray:
        delta = np.asarray(self.end, dtype=float) - np.asarray(self.start, dtype=float)
        return delta / np.linalg.norm(delta)

    def heading_at(self, s: np.ndarray | float) -> np.ndarray:
        """Lane direction [rad] at longitudinal positions `s` (constant for a straight lane)."""
        heading = np.arctan2(self._direction[1], self._direction[0])
        return np.full(np.shape(s), heading)

    def position(self, s: np.ndarray | float, d: np.ndarray | float) -> np.ndarray:
        """World xy (..., 2) of lane coordinates (s, d)."""
        s, d = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(d, dtype=float))
        ux, uy = self._direction
        x = self.start[0] + s * ux - d * uy
        y = self.start[1] + s * uy + d * ux
        return np.stack([x, y], axis=-1)

    def local_coordinates(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lane coordinates (s, d) of world points `xy` (..., 2)."""
        xy = np.asarray(xy, dtype=float)
        rel_x = xy[..., 0] - self.start[0]
        rel_y = xy[..., 1] - self.start[1]
        ux, uy = self._direction
        return rel_x * ux + rel_y * uy, -rel_x * uy + rel_y * ux

    def as_lane(self) -> Lane:
        """This lane in the general lane model: one straight `Segment`, same frame (s, d)."""
        return Lane((Segment(self.start, self.end),), self.width_m)


@dataclass(frozen=True)
class StraightRoad:
    """A straight road along +x with `num_lanes` parallel lanes of equal width.

    The road spans x in [0, length_m] and y in [0, num_lanes * lane_width_m]; lane 0 is the
    lowest-y lane, its centre at y = lane_width_m / 2. Lane markings separate adjacent lanes;
    the outer boundaries are the road edges (leaving them counts as off-road).
    """

    num_lanes: int = 4
    lane_width_m: float = 3.5
    length_m: float = 500.0

    def __post_init__(self) -> None:
        if self.num_lanes < 1:
            raise ValueError(f"num_lanes must be >= 1, got {self.num_lanes}")
        if not (self.lane_width_m > 0 and self.length_m > 0):
            raise ValueError("lane_width_m and length_m must be positive")

    @cached_property
    def lanes(self) -> tuple[StraightLane, ...]:
        """Lanes ordered from the right edge (lowest y) to the left edge."""
        return tuple(
            StraightLane(
                start=(0.0, self.lane_center_y(i)),
                end=(self.length_m, self.lane_center_y(i)),
                width_m=self.lane_width_m,
            )
            for i in range(self.num_lanes)
        )

    @property
    def width_m(self) -> float:
        return self.num_lanes * self.lane_width_m

    @property
    def lateral_bounds(self) -> tuple[float, float]:
        """Road edges (d_min, d_max) in the road frame [m]."""
        return 0.0, self.width_m

    def lane_center_y(self, lane: int) -> float:
        """y [m] of the centre line of lane `lane`."""
        if not 0 <= lane < self.num_lanes:
            raise IndexError(f"lane {lane} out of range [0, {self.num_lanes})")
        return (lane + 0.5) * self.lane_width_m

    def to_road_frame(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Road-frame (s, d) of points `xy` (..., 2): s along the road, d from its right edge."""
        xy = np.asarray(xy, dtype=float)
        return xy[..., 0].copy(), xy[..., 1].copy()

    def from_road_frame(self, s: np.ndarray | float, d: np.ndarray | float) -> np.ndarray:
        """World xy (..., 2) of road-frame coordinates (s, d)."""
        s, d = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(d, dtype=float))
        return np.stack([s, d], axis=-1)

    def lane_index(self, xy: np.ndarray) -> np.ndarray:
        """Index of the lane holding each point of `xy` (..., 2); -1 where it is off the road."""
        s, d = self.to_road_frame(xy)
        index = np.floor(d / self.lane_width_m).astype(np.int64)
        on_road = (d >= 0) & (d < self.width_m) & (s >= 0) & (s <= self.length_m)
        return np.where(on_road, index, -1)

    def layout(self) -> RoadLayout:
        """This road as a `RoadLayout` of its lanes (`lane_0` on the right edge, ...), for the
        layout-generic off-road checks and rendering; the fast paths above stay as they are."""
        return RoadLayout({f"lane_{i}": lane.as_lane() for i, lane in enumerate(self.lanes)})

    def edge_segments(self) -> tuple[tuple[tuple[float, float], tuple[float, float]], ...]:
        """The road edges as world-frame segments ((x0, y0), (x1, y1))."""
        return tuple(((0.0, y), (self.length_m, y)) for y in self.lateral_bounds)

    def marking_lines_y(self) -> tuple[float, ...]:
        """y [m] of the dashed markings between adjacent lanes."""
        return tuple(i * self.lane_width_m for i in range(1, self.num_lanes))
