"""Collision and off-road checks: a numpy broad phase and a pymunk narrow phase.

Every car is a pymunk box on a kinematic body (never a dynamic one, so pymunk never pushes cars
around); the road edges are static segments. A vectorised broad phase (axis-aligned bounding
boxes of the cars against each other and against the edges) picks the few candidates worth an
exact test; only those cars' bodies are moved to their current pose and queried with
`Space.shape_query`. In ordinary traffic, side-by-side cars included, there are no candidates
and pymunk is not called at all.
"""

from __future__ import annotations

import numpy as np
import pymunk

_EDGE_TAG = -1  # marker for road-edge shapes in the shape -> car index map


class CollisionChecker:
    """Answers car-car overlap and car-edge contact queries for a fixed set of cars and edges."""

    def __init__(
        self,
        length: np.ndarray,
        width: np.ndarray,
        edges: tuple[tuple[tuple[float, float], tuple[float, float]], ...],
    ) -> None:
        self._length = np.asarray(length, dtype=float)
        self._width = np.asarray(width, dtype=float)
        num_cars = len(self._length)
        self._upper = np.triu(np.ones((num_cars, num_cars), dtype=bool), k=1)  # pairs i < j
        self._edges = np.asarray(edges, dtype=float).reshape(-1, 2, 2)  # (E, 2, 2)
        self._edge_low = self._edges.min(axis=1)  # (E, 2) edge bounding boxes
        self._edge_high = self._edges.max(axis=1)
        self._space = pymunk.Space()
        self._bodies: list[pymunk.Body] = []
        self._shapes: list[pymunk.Poly] = []
        self._owner: dict[pymunk.Shape, int] = {}
        for index, (length_m, width_m) in enumerate(zip(self._length, self._width)):
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            shape = pymunk.Poly.create_box(body, (float(length_m), float(width_m)))
            self._space.add(body, shape)
            self._bodies.append(body)
            self._shapes.append(shape)
            self._owner[shape] = index
        for start, end in self._edges:
            segment = pymunk.Segment(self._space.static_body, tuple(start), tuple(end), 0.0)
            self._space.add(segment)
            self._owner[segment] = _EDGE_TAG

    def __getstate__(self) -> dict:
        # pymunk objects are rebuilt on unpickling rather than pickled.
        return {"length": self._length, "width": self._width, "edges": self._edges}

    def __setstate__(self, state: dict) -> None:
        edges = tuple(tuple(map(tuple, edge)) for edge in state["edges"])
        self.__init__(state["length"], state["width"], edges)

    def _sync(self, indices: np.ndarray, xy: np.ndarray, heading: np.ndarray) -> None:
        for index in indices.tolist():
            body = self._bodies[index]
            body.position = (float(xy[index, 0]), float(xy[index, 1]))
            body.angle = float(heading[index])
            self._space.reindex_shapes_for_body(body)

    def _touching(self, index: int) -> list[int]:
        """Owners of all shapes overlapping car `index` (car indices, or _EDGE_TAG for edges)."""
        hits = self._space.shape_query(self._shapes[index])
        return [self._owner[hit.shape] for hit in hits if hit.contact_point_set.points]

    def candidate_pairs(self, low: np.ndarray, high: np.ndarray, active: np.ndarray) -> np.ndarray:
        """Pairs (K, 2), i < j, of active cars whose axis-aligned bounding boxes overlap.

        `low`, `high` (N, 2) are the boxes' corners; side-by-side cars in adjacent lanes are
        already ruled out here.
        """
        overlap_x = (low[:, None, 0] <= high[None, :, 0]) & (high[:, None, 0] >= low[None, :, 0])
        overlap_y = (low[:, None, 1] <= high[None, :, 1]) & (high[:, None, 1] >= low[None, :, 1])
        close = overlap_x & overlap_y & self._upper  # (N, N)
        if not active.all():
            close &= active[:, None] & active[None, :]
        first, second = np.nonzero(close)
        return np.stack([first, second], axis=1)

    def collision_pairs(
        self,
        low: np.ndarray,
        high: np.ndarray,
        xy: np.ndarray,
        heading: np.ndarray,
        active: np.ndarray,
    ) -> np.ndarray:
        """Pairs (K, 2), i < j, of active cars whose bodies overlap (touching counts).

        `low`, `high` (N, 2) are the cars' axis-aligned bounding boxes (the broad phase).
        """
        candidates = self.candidate_pairs(low, high, active)
        if len(candidates) == 0:
            return candidates
        self._sync(np.unique(candidates), xy, heading)
        pairs = []
        for first, second in candidates.tolist():
            if second in self._touching(first):
                pairs.append((first, second))
        return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)

    def edge_contacts(
        self,
        low: np.ndarray,
        high: np.ndarray,
        xy: np.ndarray,
        heading: np.ndarray,
        active: np.ndarray,
    ) -> np.ndarray:
        """(N,) bool: active cars whose body touches a road edge.

        `low`, `high` (N, 2) are the cars' axis-aligned bounding boxes (the broad phase).
        """
        overlaps = (low[:, None, :] <= self._edge_high) & (high[:, None, :] >= self._edge_low)
        candidates = np.nonzero(overlaps.all(axis=2).any(axis=1) & active)[0]
        touching = np.zeros(len(xy), dtype=bool)
        if len(candidates) == 0:
            return touching
        self._sync(candidates, xy, heading)
        for index in candidates.tolist():
            touching[index] = _EDGE_TAG in self._touching(index)
        return touching
