"""Collision and off-road checks against hand-made cases and an independent separating-axis test."""

import numpy as np

from carlo_lite import StraightRoad, World, box_corners


def sat_overlap(corners_a: np.ndarray, corners_b: np.ndarray) -> bool:
    """Independent separating-axis test for two convex quadrilaterals (4, 2)."""
    for corners in (corners_a, corners_b):
        edges = np.roll(corners, -1, axis=0) - corners
        for edge in edges:
            axis = np.array([-edge[1], edge[0]])
            proj_a, proj_b = corners_a @ axis, corners_b @ axis
            if proj_a.max() < proj_b.min() or proj_b.max() < proj_a.min():
                return False
    return True


def world_of(xy, heading, road=None) -> World:
    road = road or StraightRoad(num_lanes=4, length_m=1000.0)
    xy = np.asarray(xy, float)
    return World(road, xy, np.asarray(heading, float), np.zeros(len(xy)))


def test_side_by_side_in_adjacent_lanes_do_not_collide():
    world = world_of([[50.0, 1.75], [50.0, 5.25]], [0.0, 0.0])
    assert not world.collisions().any()


def test_overlapping_bumpers_collide():
    world = world_of([[50.0, 1.75], [54.0, 1.75]], [0.0, 0.0])  # 4.0 m apart, 4.5 m long
    assert world.collisions().tolist() == [True, True]
    assert world.collision_pairs().tolist() == [[0, 1]]


def test_gap_just_over_length_is_free():
    world = world_of([[50.0, 1.75], [54.51, 1.75]], [0.0, 0.0])
    assert not world.collisions().any()


def test_rotated_car_corner_reaches_neighbour():
    # Rotated 45 degrees, the front-right corner sits at (2.25 + 0.9, 2.25 - 0.9) / sqrt(2)
    # from the centre; put the other car's rear face just before / after that corner.
    corner = np.array([2.25 + 0.9, 2.25 - 0.9]) / np.sqrt(2)
    y = 3.0 + corner[1]
    hit = world_of([[50.0, 3.0], [50.0 + corner[0] + 2.25 - 0.05, y]], [np.pi / 4, 0.0])
    miss = world_of([[50.0, 3.0], [50.0 + corner[0] + 2.25 + 0.05, y]], [np.pi / 4, 0.0])
    assert hit.collisions().all()
    assert not miss.collisions().any()


def test_inactive_cars_never_collide():
    world = world_of([[50.0, 1.75], [52.0, 1.75], [54.0, 1.75]], [0, 0, 0])
    world.deactivate([1])
    assert world.collision_pairs().tolist() == [[0, 2]]


def test_agrees_with_separating_axis_check_on_random_scenes():
    rng = np.random.default_rng(42)
    disagreements = 0
    hits = 0
    for _ in range(300):
        n = 8
        xy = rng.uniform([0, 0], [20, 14], (n, 2))
        heading = rng.uniform(-np.pi, np.pi, n)
        world = world_of(xy, heading)
        got = {tuple(p) for p in world.collision_pairs().tolist()}
        corners = box_corners(xy, heading, np.full(n, 4.5), np.full(n, 1.8))
        expected = {
            (i, j) for i in range(n) for j in range(i + 1, n) if sat_overlap(corners[i], corners[j])
        }
        hits += len(expected)
        disagreements += len(got ^ expected)
    assert hits > 100  # the scenes really do contain collisions
    assert disagreements == 0


def test_off_road_detection():
    road = StraightRoad(num_lanes=2, lane_width_m=3.5, length_m=1000.0)
    # in lanes: on road; over the right edge; fully outside; rotated across the left edge
    world = world_of(
        [[100.0, 1.75], [200.0, 5.25], [300.0, 0.85], [400.0, -3.0], [500.0, 6.0]],
        [0.0, 0.0, 0.0, 0.0, np.pi / 2],
        road=road,
    )
    assert world.off_road().tolist() == [False, False, True, True, True]


def test_off_road_agrees_with_corner_check_on_random_poses():
    rng = np.random.default_rng(7)
    road = StraightRoad(num_lanes=4, length_m=1000.0)
    xy = np.column_stack([rng.uniform(10, 990, 500), rng.uniform(-3, 17, 500)])
    heading = rng.uniform(-np.pi, np.pi, 500)
    world = world_of(xy, heading, road=road)
    corners_y = box_corners(xy, heading, np.full(500, 4.5), np.full(500, 1.8))[..., 1]
    expected = (corners_y.min(axis=1) <= 0.0) | (corners_y.max(axis=1) >= road.width_m)
    got = world.off_road()
    assert 50 < expected.sum() < 450
    # exactly-touching is measure-zero for random poses
    np.testing.assert_array_equal(got, expected)
