"""Lanes as centre-lines made of straight segments and circular arcs.

A `Lane` is a chain of pieces (`Segment`, `Arc`) joined end to start, with a width. Its lane
frame is (s, d): s [m] the arc length along the centre-line from the lane's start, d [m] the
signed lateral offset from the centre-line, positive to the left of the driving direction (the
convention of `StraightLane`). Positions, headings and projections are vectorised with numpy over
any number of points. Beyond the two ends the lane frame continues along the end tangents, so a
point just before the start has s < 0 and `contains` is false there.

`LanePath` builds lanes the way a driver describes them: start at a pose, go straight for some
metres, turn left or right along an arc of some radius by some angle.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

JOIN_TOLERANCE_M = 1e-6  # largest gap [m] allowed between the end of a piece and the next start


def _unit(angle: float) -> np.ndarray:
    return np.array([np.cos(angle), np.sin(angle)])


@dataclass(frozen=True)
class Segment:
    """A straight piece of centre-line from `start` to `end` [m]."""

    start: tuple[float, float]
    end: tuple[float, float]

    def __post_init__(self) -> None:
        if not self.length_m > 0:
            raise ValueError(f"a segment needs two distinct end points, got {self.start}")

    @cached_property
    def length_m(self) -> float:
        return float(np.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1]))

    @cached_property
    def start_heading(self) -> float:
        return float(np.arctan2(self.end[1] - self.start[1], self.end[0] - self.start[0]))

    @property
    def end_heading(self) -> float:
        return self.start_heading

    def point(self, s: np.ndarray) -> np.ndarray:
        """Centre-line xy (..., 2) at local arc lengths `s` in [0, length_m]."""
        return np.asarray(self.start) + s[..., None] * _unit(self.start_heading)

    def heading(self, s: np.ndarray) -> np.ndarray:
        return np.full(np.shape(s), self.start_heading)

    def project(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, d, distance) of points (..., 2): s clamped to the piece, d signed (left +),
        distance to the nearest centre-line point of the piece."""
        ux, uy = _unit(self.start_heading)
        rel_x, rel_y = xy[..., 0] - self.start[0], xy[..., 1] - self.start[1]
        along = rel_x * ux + rel_y * uy
        s = np.clip(along, 0.0, self.length_m)
        d = -rel_x * uy + rel_y * ux
        distance = np.hypot(along - s, d)
        return s, d, distance


@dataclass(frozen=True)
class Arc:
    """A circular piece of centre-line: `center` [m], `radius_m`, the polar angle `start_angle`
    [rad] of its first point seen from the centre, and a signed `sweep` [rad]: positive turns left
    (counter-clockwise), negative turns right. |sweep| <= 2 pi (a full circle is allowed)."""

    center: tuple[float, float]
    radius_m: float
    start_angle: float
    sweep: float

    def __post_init__(self) -> None:
        if not self.radius_m > 0:
            raise ValueError(f"arc radius must be positive, got {self.radius_m}")
        if not 0 < abs(self.sweep) <= 2 * np.pi + 1e-12:
            raise ValueError(f"arc sweep must be in (0, 2 pi] in magnitude, got {self.sweep}")

    @property
    def length_m(self) -> float:
        return self.radius_m * abs(self.sweep)

    @property
    def _sign(self) -> float:
        return 1.0 if self.sweep > 0 else -1.0

    @property
    def start(self) -> tuple[float, float]:
        x, y = np.asarray(self.center) + self.radius_m * _unit(self.start_angle)
        return float(x), float(y)

    @property
    def end(self) -> tuple[float, float]:
        x, y = np.asarray(self.center) + self.radius_m * _unit(self.start_angle + self.sweep)
        return float(x), float(y)

    @property
    def start_heading(self) -> float:
        return self.start_angle + self._sign * np.pi / 2

    @property
    def end_heading(self) -> float:
        return self.start_angle + self.sweep + self._sign * np.pi / 2

    def point(self, s: np.ndarray) -> np.ndarray:
        angle = self.start_angle + self._sign * s / self.radius_m
        return np.asarray(self.center) + self.radius_m * np.stack(
            [np.cos(angle), np.sin(angle)], axis=-1
        )

    def heading(self, s: np.ndarray) -> np.ndarray:
        return self.start_heading + self._sign * s / self.radius_m

    def project(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, d, distance) as `Segment.project`; for the arc d = +-(radius - rho) where rho is
        the distance from the centre (the centre side is the left of a left turn)."""
        rel_x, rel_y = xy[..., 0] - self.center[0], xy[..., 1] - self.center[1]
        rho = np.hypot(rel_x, rel_y)
        # angle travelled from the start in the driving sense, in [0, 2 pi)
        travelled = np.mod(self._sign * (np.arctan2(rel_y, rel_x) - self.start_angle), 2 * np.pi)
        span = abs(self.sweep)
        beyond = travelled > span
        # outside the swept angle: the nearer end (by angle) is the nearest point of the arc
        to_start = 2 * np.pi - travelled
        nearer_end = np.where(to_start < travelled - span, 0.0, span)
        angle = np.where(beyond, nearer_end, travelled)
        s = self.radius_m * angle
        d = self._sign * (self.radius_m - rho)
        nearest = self.point(s)
        distance = np.hypot(xy[..., 0] - nearest[..., 0], xy[..., 1] - nearest[..., 1])
        return s, d, distance


Piece = Segment | Arc


@dataclass(frozen=True)
class Lane:
    """A lane: a chain of `pieces` (each starting where the previous ends) and a width [m]."""

    pieces: tuple[Piece, ...]
    width_m: float = 3.5

    def __post_init__(self) -> None:
        if not self.pieces:
            raise ValueError("a lane needs at least one piece")
        if not self.width_m > 0:
            raise ValueError(f"lane width must be positive, got {self.width_m}")
        for i, (a, b) in enumerate(zip(self.pieces[:-1], self.pieces[1:])):
            gap = float(np.hypot(a.end[0] - b.start[0], a.end[1] - b.start[1]))
            if gap > JOIN_TOLERANCE_M:
                raise ValueError(f"lane piece {i + 1} starts {gap:.3g} m from the end of piece {i}")

    @cached_property
    def _offsets(self) -> np.ndarray:
        """Arc length [m] at the start of each piece, and the total at the end (P + 1,)."""
        return np.concatenate([[0.0], np.cumsum([p.length_m for p in self.pieces])])

    @property
    def length_m(self) -> float:
        return float(self._offsets[-1])

    @property
    def start(self) -> tuple[float, float]:
        return self.pieces[0].start

    @property
    def end(self) -> tuple[float, float]:
        return self.pieces[-1].end

    def _locate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Piece index and local arc length (clamped into the piece) of lane arc lengths `s`."""
        index = np.clip(
            np.searchsorted(self._offsets, s, side="right") - 1, 0, len(self.pieces) - 1
        )
        local = s - self._offsets[index]
        return index, local

    def _centre(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre-line xy (..., 2) and heading (...) at `s`, continued along the end tangents."""
        index, local = self._locate(s)
        xy = np.empty(s.shape + (2,))
        heading = np.empty(s.shape)
        for i, piece in enumerate(self.pieces):
            mask = index == i
            if not mask.any():
                continue
            clamped = np.clip(local[mask], 0.0, piece.length_m)
            overshoot = local[mask] - clamped  # nonzero only before the start or past the end
            h = piece.heading(clamped)
            xy[mask] = piece.point(clamped) + overshoot[:, None] * np.stack(
                [np.cos(h), np.sin(h)], axis=-1
            )
            heading[mask] = h
        return xy, heading

    def curvature_at(self, s: np.ndarray | float) -> np.ndarray:
        """Signed curvature [1/m] of the centre-line at arc lengths `s`: +1/radius on a left arc,
        -1/radius on a right arc, 0 on segments and beyond the ends."""
        s = np.asarray(s, dtype=float)
        index, local = self._locate(s)
        signed = np.array(
            [0.0 if isinstance(p, Segment) else p._sign / p.radius_m for p in self.pieces]
        )
        inside = (local >= 0.0) & (local <= self.length_m) & (s >= 0.0) & (s <= self.length_m)
        return np.where(inside, signed[index], 0.0)

    def heading_at(self, s: np.ndarray | float) -> np.ndarray:
        """Lane direction [rad] at arc lengths `s`; continuous along each arc, not wrapped to
        (-pi, pi] (compare headings modulo 2 pi)."""
        return self._centre(np.asarray(s, dtype=float))[1]

    def position(self, s: np.ndarray | float, d: np.ndarray | float = 0.0) -> np.ndarray:
        """World xy (..., 2) of lane coordinates (s, d)."""
        s, d = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(d, dtype=float))
        xy, heading = self._centre(s)
        return xy + d[..., None] * np.stack([-np.sin(heading), np.cos(heading)], axis=-1)

    def local_coordinates(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lane coordinates (s, d) of world points `xy` (..., 2), by projection to the nearest
        point of the centre-line (the first piece wins a tie). Before the start and past the end
        the frame follows the end tangents (s < 0 or s > length_m)."""
        s, d, _ = self._project(np.asarray(xy, dtype=float))
        return s, d

    def _project(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        best_s = best_d = best_distance = None
        for offset, piece in zip(self._offsets, self.pieces):
            s, d, distance = piece.project(xy)
            s = s + offset
            if best_distance is None:
                best_s, best_d, best_distance = s, d, distance
                continue
            closer = distance < best_distance
            best_s = np.where(closer, s, best_s)
            best_d = np.where(closer, d, best_d)
            best_distance = np.where(closer, distance, best_distance)
        # continue the frame along the end tangents where the nearest point is an end point
        for s_end, pose_xy, pose_h, before in (
            (0.0, self.start, self.pieces[0].start_heading, True),
            (self.length_m, self.end, self.pieces[-1].end_heading, False),
        ):
            at_end = np.isclose(best_s, s_end, rtol=0.0, atol=1e-12)
            if not at_end.any():
                continue
            rel_x, rel_y = xy[..., 0] - pose_xy[0], xy[..., 1] - pose_xy[1]
            along = rel_x * np.cos(pose_h) + rel_y * np.sin(pose_h)
            across = -rel_x * np.sin(pose_h) + rel_y * np.cos(pose_h)
            # the tolerance keeps points level with an end (rounding of cos(pi / 2)) at s_end
            outside = at_end & ((along < -1e-9) if before else (along > 1e-9))
            best_s = np.where(outside, s_end + along, best_s)
            best_d = np.where(outside, across, best_d)
        return best_s, best_d, best_distance

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """(...) bool: the point lies on the lane (0 <= s <= length, |d| <= width / 2)."""
        s, d = self.local_coordinates(xy)
        return (s >= 0) & (s <= self.length_m) & (np.abs(d) <= self.width_m / 2)

    def sample(self, step_m: float = 1.0) -> np.ndarray:
        """Centre-line points (K, 2) from start to end, at most `step_m` apart."""
        count = max(2, int(np.ceil(self.length_m / step_m)) + 1)
        return self.position(np.linspace(0.0, self.length_m, count))

    def then(self, other: Lane) -> Lane:
        """This lane followed by `other` (which must start where this one ends); this width."""
        return Lane(self.pieces + other.pieces, self.width_m)


def join_lanes(lanes: Sequence[Lane]) -> Lane:
    """One lane through `lanes` in order (a route), with the first lane's width."""
    if not lanes:
        raise ValueError("join_lanes needs at least one lane")
    pieces: tuple[Piece, ...] = ()
    for lane in lanes:
        pieces += lane.pieces
    return Lane(pieces, lanes[0].width_m)


@dataclass(frozen=True)
class LanePath:
    """A builder of lane centre-lines: a pose (`xy` [m], `heading` [rad]) and the pieces so far.

    `LanePath((0, 0), 0.0).straight(10).turn(8.0, np.pi / 2).lane(3.5)` goes 10 m along +x and
    then turns left on a circle of radius 8 m by 90 degrees.
    """

    xy: tuple[float, float]
    heading: float
    pieces: tuple[Piece, ...] = ()

    def straight(self, length_m: float) -> LanePath:
        """Go straight ahead for `length_m` metres."""
        end = np.asarray(self.xy, dtype=float) + length_m * _unit(self.heading)
        piece = Segment(tuple(map(float, self.xy)), (float(end[0]), float(end[1])))
        return LanePath(piece.end, self.heading, self.pieces + (piece,))

    def turn(self, radius_m: float, angle: float) -> LanePath:
        """Follow a circle of `radius_m` by `angle` [rad]: positive left, negative right."""
        sign = 1.0 if angle > 0 else -1.0
        center = np.asarray(self.xy, dtype=float) + sign * radius_m * _unit(
            self.heading + np.pi / 2
        )
        start_angle = self.heading - sign * np.pi / 2
        piece = Arc((float(center[0]), float(center[1])), float(radius_m), start_angle, angle)
        return LanePath(piece.end, self.heading + angle, self.pieces + (piece,))

    def lane(self, width_m: float = 3.5) -> Lane:
        """The lane along the pieces so far."""
        return Lane(self.pieces, width_m)
